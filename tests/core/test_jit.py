"""numba's start without its BLAS probe (citylod.core.jit): faster, and nothing that needs BLAS breaks."""

from __future__ import annotations

import subprocess
import sys


def _run(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip().splitlines()[-1]


def test_kernels_start_without_scipy_linalg() -> None:
    """A fresh process that loads and runs a TIN kernel has not imported scipy.linalg (≈0.2 s of numba's
    start); with numba's own start it would have, through the probe."""
    out = _run(
        "import sys, numpy as np\n"
        "from citylod.lod.kernels import tin\n"
        "z = np.add.outer(np.arange(9.0), np.arange(7.0) ** 2)\n"
        "v, f = tin.triangulate(z, None, 0.1)\n"
        "import numba.np.arraymath as am\n"
        "print(len(f) > 0, am._HAVE_BLAS, 'scipy.linalg' in sys.modules)\n")
    assert out == "True True False"


def test_blas_users_still_compile_after_the_deferred_probe() -> None:
    """Kernels that use BLAS (np.dot of matrices) and LAPACK (eigh) compile and agree with numpy after the
    probe was skipped: numba's linear-algebra lowering runs its own probe then."""
    out = _run(
        "import numpy as np, numba\n"
        "from citylod.core.jit import defer_blas_probe\n"
        "defer_blas_probe()\n"
        "@numba.njit\n"
        "def f(a, b):\n"
        "    return np.dot(a, b), np.linalg.eigh(a @ a.T)[0]\n"
        "rng = np.random.default_rng(0)\n"
        "a, b = rng.random((5, 4)), rng.random((4, 3))\n"
        "d, w = f(a, b)\n"
        "print(np.allclose(d, a @ b), np.allclose(w, np.linalg.eigh(a @ a.T)[0]))\n")
    assert out == "True True"
