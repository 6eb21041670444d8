"""numba's start, made cheaper: the modules that define compiled kernels call :func:`defer_blas_probe`.

numba loads its numpy support (``numba.np.arraymath``) when a process first compiles or loads a kernel, and
that module probes for BLAS at import by importing ``scipy.linalg.cython_blas``. Importing it runs
``scipy.linalg/__init__``, which imports the whole of scipy.linalg and scipy's array-API layer: a large
part of numba's start in a fresh process (docs/PERFORMANCE_LOG.md has the numbers), for nothing
citylod's kernels use.

:func:`defer_blas_probe` lets numba's import of ``numba.np.arraymath`` skip the probe. The probe only sets
whether numba registers ``np.dot`` and friends; they are registered, and numba's linear-algebra lowering
calls the same probe again when a kernel actually uses one (then scipy.linalg is imported as before, and a
missing BLAS is reported as numba reports it). scipy is a dependency of citylod, so the answer the skipped
probe would give is known.

It leans on numba's module layout (``numba.np.linalg.ensure_blas``, called by ``numba.np.arraymath``
at import), which is not public API: where that layout differs, or numba's numpy support is already
loaded, it does nothing and numba starts as it always does. ``numba.np.arraymath`` binds the probe by name
at its import and calls it only then; numba's linear algebra calls its own, restored, name.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import sys
from collections.abc import Sequence
from types import ModuleType

_TARGET = "numba.np.arraymath"
_installed = False


def defer_blas_probe() -> None:
    """Have numba's import of ``numba.np.arraymath`` skip its BLAS probe (see the module docstring).

    Nothing is imported here: a one-shot import hook waits for numba to import that module when it first
    needs it (its first compile or cached load), so the rest of numba's start stays where it was and is
    timed where it was. Safe to call any number of times, from any kernel module."""
    global _installed
    if _installed or _TARGET in sys.modules:
        return
    _installed = True
    sys.meta_path.insert(0, _Finder())


class _Finder(importlib.abc.MetaPathFinder):
    # It stays on sys.meta_path once it has fired (the import system may be iterating that list when it
    # is called), answering None to everything: one string comparison per import.
    fired = False

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if self.fired or fullname != _TARGET:
            return None
        self.fired = True  # one shot; the real finders answer from here on (also the lookup below)
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        spec.loader = _ProbeSkippingLoader(spec.loader)
        return spec


class _ProbeSkippingLoader(importlib.abc.Loader):
    def __init__(self, inner: importlib.abc.Loader) -> None:
        self.inner = inner

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self.inner.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        linalg = sys.modules.get("numba.np.linalg") or _import("numba.np.linalg")
        probe = getattr(linalg, "ensure_blas", None)
        if linalg is None or not callable(probe):
            self.inner.exec_module(module)
            return
        # what arraymath binds and calls at its import (numba ships no stubs for its internals)
        linalg.ensure_blas = _no_probe  # type: ignore[attr-defined]
        try:
            self.inner.exec_module(module)
        finally:
            linalg.ensure_blas = probe  # type: ignore[attr-defined]


def _no_probe() -> None:
    return None


def _import(name: str) -> ModuleType | None:
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


__all__ = ["defer_blas_probe"]
