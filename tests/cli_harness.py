"""Run the ``citylod`` command as a user does: a subprocess, with a time-out and an RSS cap set by the harness.

The limits belong to the test, not to the product: a hostile input that makes citylod hang or grow without
bound fails the test here instead of stalling the run or the machine.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tests.paths import ROOT

RSS_CAP_BYTES = 3 << 30  # address space cap; numba and PROJ map about 1.5 GB of virtual memory at start-up


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str


def _limits(cap: int) -> None:
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))


def run_cli(args: Sequence[str | Path], *, timeout_s: float = 60.0, cap_bytes: int = RSS_CAP_BYTES,
            cwd: Path | None = None) -> Result:
    """``citylod ARGS`` in a subprocess; a time-out fails the calling test (``subprocess.TimeoutExpired``)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    r = subprocess.run([sys.executable, "-m", "citylod.cli", "-q", *map(str, args)], capture_output=True,
                       text=True, timeout=timeout_s, env=env, cwd=cwd,
                       preexec_fn=lambda: _limits(cap_bytes))
    return Result(r.returncode, r.stdout, r.stderr)


def assert_clean_refusal(r: Result, name: str, *leftover_dirs: Path) -> None:
    """Exit 2, one stderr line naming ``name``, no traceback, and nothing half-written left behind."""
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and name in lines[0] and "Traceback" not in r.stderr, r.stderr[-2000:]
    for d in leftover_dirs:
        if d.exists():
            junk = [p.name for p in d.iterdir() if p.name.endswith((".partial", ".tmp")) or ".tmp" in p.name]
            assert not junk, junk


_BATCH = r"""
import contextlib, io, json, sys, traceback
from citylod.cli import main
out = []
for argv in json.loads(sys.stdin.read()):
    err, std = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
        except BaseException:
            traceback.print_exc()
            rc = "exception"
    out.append([rc, std.getvalue(), err.getvalue()])
sys.stdout.write(json.dumps(out))
"""


def run_cli_batch(argvs: Sequence[Sequence[str | Path]], *, timeout_s: float = 120.0,
                  cap_bytes: int = RSS_CAP_BYTES) -> list[Result]:
    """Several ``citylod`` command lines through its ``main()``, one after the other in one subprocess.

    The same path as :func:`run_cli` (argument parsing, the command, the error handling of ``main``) without
    paying the interpreter's start-up per case; the time-out and memory cap hold for the whole batch.
    """
    import json

    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    payload = json.dumps([["-q", *map(str, a)] for a in argvs])
    r = subprocess.run([sys.executable, "-c", _BATCH], input=payload, capture_output=True, text=True,
                       timeout=timeout_s, env=env, preexec_fn=lambda: _limits(cap_bytes))
    assert r.returncode == 0, r.stderr[-3000:]
    return [Result(rc if isinstance(rc, int) else -999, so, se) for rc, so, se in json.loads(r.stdout)]


def start_cli(args: Sequence[str | Path], *, cap_bytes: int = RSS_CAP_BYTES) -> subprocess.Popen[bytes]:
    """``citylod ARGS`` started in a subprocess (same limits as :func:`run_cli`), for tests that signal it."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    return subprocess.Popen([sys.executable, "-m", "citylod.cli", "-q", *map(str, args)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            preexec_fn=lambda: _limits(cap_bytes))


def descendants(pid: int) -> set[int]:
    """Live descendants of ``pid`` (from /proc; zombies count as gone)."""
    parent_of: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[0] != "Z":
            parent_of[int(stat.parent.name)] = int(fields[1])
    found: set[int] = set()
    frontier = {pid}
    while frontier:
        frontier = {c for c, p in parent_of.items() if p in frontier} - found
        found |= frontier
    return found


def alive(pids: set[int]) -> set[int]:
    """Those of ``pids`` that still run (not gone, not zombies)."""
    out = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        if state != "Z":
            out.add(pid)
    return out
