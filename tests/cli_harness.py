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
