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
