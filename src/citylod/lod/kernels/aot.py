"""The DSM build's kernels compiled ahead of time, so that a process runs them without starting numba.

A fresh process that calls its first numba kernel starts numba's runtime (its typing and lowering
registries) and loads every cached kernel it calls (eleven in a DSM build, twelve with
``metric="hausdorff"``), on one core before the workers fork: a large share of a small build
(docs/PERFORMANCE_LOG.md has the numbers). :func:`build` compiles the same kernels, with the
argument types a build passes them, into one extension module with numba's ahead-of-time compiler
(``numba.pycc``); importing it takes under a millisecond and starts nothing. ``make`` runs it (``citylod
build-kernels``) into a folder per machine and source (:func:`kernel_dir`).

It is an accelerator, never a requirement. The call sites take the kernel through :func:`kernel`, which
answers the compiled-ahead version only when all of these hold, and the JIT kernel otherwise (the same
code, the same LLVM, the same results: a test builds hard rasters both ways and compares the bytes):

- the module was built for this source: its folder's name is a hash of the kernel modules' sources, the
  numba and Python versions and the CPU (it is compiled for this CPU's instruction set, as numba's JIT
  compiles), so editing a kernel makes it stale at once, and a stale module is never loaded;
- the caller runs on the process's main thread. ``numba.pycc``'s wrappers hold the GIL while the kernel
  runs, where the JIT kernels release it (``nogil``): builds on threads (the thread executor, Dask
  workers, a GUI's worker thread) keep running in parallel on the JIT kernels. Worker processes, forked
  or spawned, and inline builds run their tasks on their main thread;
- the arguments have exactly the types it was compiled for. ``numba.pycc``'s wrappers do not check them
  (an int8 array passed for a bool one is read as bool), so :func:`kernel` checks dtype, dimensions,
  layout and writability of every array and the kind of every scalar, and falls back to the JIT kernel
  on any difference.

``numba.pycc`` is marked "pending deprecation" by numba (since 0.57; no replacement released yet). Where
it is missing or fails, :func:`build` reports why and the JIT kernels run as before.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import os
import platform
import shutil
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

#: The kernels a DSM build calls from Python, by module: everything compiled into them comes along.
EXPORTS: dict[str, tuple[str, ...]] = {
    "citylod.lod.kernels.tin_kernels": ("build_tin", "simplify_runs", "border_fans", "forced_mask", "z_ordered",
                                "live_mesh"),
    "citylod.lod.kernels.certify": ("certify_block", "_edge_table", "skirt_strip", "_grid_sample_error"),
    "citylod.lod.kernels.octree": ("_bounds",),
    "citylod.lod.kernels.hausdorff": ("hausdorff_block",),
}
#: The modules whose source the compiled code comes from (the hash in :func:`kernel_dir`).
SOURCES = ("tin_kernels.py", "certify.py", "octree.py", "sort.py", "hausdorff.py", "distance.py", "aot.py")
_MODULE = "_citylod_dsm_kernels"
_MANIFEST = "manifest.json"
#: Hex digits of the source/machine hash naming a kernel folder.
_KEY_LEN = 20
#: Folders (≈ 1 MB each) kept beside a new one: other checkouts or versions sharing the cache keep theirs.
_KEEP = 8

_lock = threading.Lock()
_loaded = False
_table: dict[Any, list[tuple[Callable[..., Any], tuple[tuple[Any, ...], ...]]]] = {}
_enabled = True


def kernel(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)``: through the compiled-ahead kernel when it may be used (see the module docstring),
    else through ``fn``, the JIT kernel. Arguments are positional (the compiled-ahead wrappers take no
    keywords)."""
    if _enabled and threading.get_ident() == threading.main_thread().ident:
        if not _loaded:
            load()
        for compiled, spec in _table.get(fn, ()):
            if _matches(spec, args):
                return compiled(*args)
    return fn(*args)


def _matches(spec: tuple[tuple[Any, ...], ...], args: tuple[Any, ...]) -> bool:
    if len(spec) != len(args):
        return False
    for s, a in zip(spec, args, strict=True):
        if s[0] == "a":  # ("a", dtype, ndim, C-contiguous required)
            if (type(a) is not np.ndarray or a.dtype != s[1] or a.ndim != s[2] or not a.flags.writeable
                    or not a.flags.aligned or (s[3] and not a.flags.c_contiguous)):
                return False
        elif s[0] == "f":  # what numba types as float64 (a float32 scalar would get a float32 kernel)
            if not isinstance(a, float):
                return False
        elif s[0] == "i":  # what numba types as int64 (an int32 scalar would get an int32 kernel)
            if not (type(a) is int or type(a) is np.int64):
                return False
        elif s[0] == "b":
            if not isinstance(a, (bool, np.bool_)):
                return False
        else:
            return False
    return True


@contextmanager
def disabled() -> Iterator[None]:
    """Run the JIT kernels only, in this process, inside the block (tests; :func:`build` itself)."""
    global _enabled
    before, _enabled = _enabled, False
    try:
        yield
    finally:
        _enabled = before


def available() -> bool:
    """Whether the compiled-ahead kernels for this source and machine are built and loaded."""
    return _enabled and load()


def kernel_dir() -> Path:
    """Where :func:`build` puts the module for this source, numba, Python and CPU:
    ``$CITYLOD_KERNEL_DIR``, else ``$XDG_CACHE_HOME/citylod/kernels`` (``~/.cache/citylod/kernels``), then
    one folder per hash."""
    root = os.environ.get("CITYLOD_KERNEL_DIR")
    if root:
        base = Path(root)
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "citylod" / "kernels"
    return base / _key()


def _key(sources: Path | None = None) -> str:
    import llvmlite.binding as ll
    import numba

    h = hashlib.sha256()
    here = sources or Path(__file__).parent
    for name in SOURCES:
        h.update(name.encode() + b"\0" + (here / name).read_bytes() + b"\0")
    for part in (numba.__version__, sys.version, platform.machine(), ll.get_host_cpu_name(),
                 ll.get_host_cpu_features().flatten(), json.dumps(EXPORTS, sort_keys=True)):
        h.update(str(part).encode() + b"\0")
    return h.hexdigest()[:_KEY_LEN]


def load() -> bool:
    """Import the compiled-ahead module when it is built for this source and machine (once per process;
    True when it is loaded). A broken one is ignored, with a warning."""
    global _loaded
    if _loaded:
        return bool(_table)
    with _lock:
        if not _loaded:
            try:
                _load_into(_table, kernel_dir())
            except Exception as exc:  # a half-written or foreign folder: the JIT kernels still run
                _table.clear()
                warnings.warn(f"compiled-ahead kernels not used ({exc}); the JIT kernels run instead",
                              RuntimeWarning, stacklevel=2)
            _loaded = True
    return bool(_table)


def _load_into(table: dict[Any, Any], folder: Path) -> None:
    manifest = folder / _MANIFEST
    if not manifest.is_file():
        return
    doc = json.loads(manifest.read_text())
    spec = importlib.util.spec_from_file_location(_MODULE, folder / doc["file"])
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {folder / doc['file']}")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    for entry in doc["exports"]:
        jit = getattr(importlib.import_module(entry["module"]), entry["name"])
        argspec = tuple((a[0], np.dtype(a[1]), a[2], a[3]) if a[0] == "a" else tuple(a) for a in entry["args"])
        table.setdefault(jit, []).append((getattr(mod, entry["export"]), argspec))


def _argspec(t: Any) -> list[Any]:
    from numba.core import types

    if isinstance(t, types.Array):
        if not t.mutable or not t.aligned or t.layout not in ("C", "A"):
            raise TypeError(f"unsupported array type {t}")
        return ["a", str(np.dtype(t.dtype.name)), t.ndim, t.layout == "C"]
    if isinstance(t, types.Boolean):
        return ["b"]
    if isinstance(t, types.Integer):
        if t != types.int64:
            raise TypeError(f"unsupported scalar type {t}")
        return ["i"]
    if isinstance(t, types.Float):
        if t != types.float64:
            raise TypeError(f"unsupported scalar type {t}")
        return ["f"]
    raise TypeError(f"unsupported argument type {t}")


def _look_again() -> None:
    """The module now exists: if this process looked before it did (and found nothing, so no compiled
    kernel is in use), let the next :func:`load` look again."""
    global _loaded
    with _lock:
        if _loaded and not _table:
            _loaded = False


def build(exercise: Callable[[], object], *, force: bool = False,
          log: Callable[[str], object] = print) -> Path | None:
    """Compile the kernels ahead of time into :func:`kernel_dir` (nothing to do when it exists); returns
    the folder, or None when they cannot be compiled here (why is logged; the JIT kernels run).

    The argument types are the ones the caller's workload passes: ``exercise`` (for the DSM build,
    :func:`citylod.lod.build.dsm.exercise_kernels`, a small build) is run first on the JIT kernels, and
    every signature each kernel was called with is compiled. The caller hands it in, so this module
    knows no builder. The folder is written under a temporary
    name and renamed when complete.
    """
    folder = kernel_dir()
    if (folder / _MANIFEST).is_file() and not force:
        _look_again()
        log(f"compiled-ahead kernels are up to date: {folder}")
        return folder
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        log(f"cannot write the compiled-ahead kernels to {folder.parent} ({exc}); set CITYLOD_KERNEL_DIR to a "
            "writable folder. The JIT kernels will run")
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numba.pycc's pending-deprecation notice
            from numba.pycc import CC
    except ImportError as exc:
        log(f"numba.pycc is not available ({exc}); the JIT kernels will run")
        return None
    with disabled():
        exercise()
    exports = []
    cc = CC(_MODULE)
    cc.verbose = False
    cc.target_cpu = "host"  # what numba's JIT compiles for; the folder's key has the CPU in it
    for modname, names in EXPORTS.items():
        mod = importlib.import_module(modname)
        for name in names:
            disp = getattr(mod, name)
            for i, (sig, cres) in enumerate(disp.overloads.items()):
                try:
                    args = [_argspec(t) for t in sig]
                except TypeError as exc:
                    log(f"{modname}.{name}{sig}: {exc}; left to the JIT kernel")
                    continue
                export = f"{modname.rsplit('.', 1)[1]}__{name}__{i}"
                cc.export(export, cres.signature)(disp.py_func)
                exports.append({"module": modname, "name": name, "export": export, "args": args})
    if not exports:
        log("no kernel was called by the small build; nothing compiled")
        return None
    tmp = Path(tempfile.mkdtemp(prefix=folder.name + ".", dir=folder.parent))
    try:
        cc.output_dir = str(tmp)
        log(f"compiling {len(exports)} kernels ahead of time (about a minute)")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cc.compile()
        built = [p.name for p in tmp.iterdir() if p.name.startswith(_MODULE) and p.suffix in (".so", ".pyd")]
        if len(built) != 1:
            raise RuntimeError(f"numba.pycc wrote {sorted(p.name for p in tmp.iterdir())}")
        (tmp / _MANIFEST).write_text(json.dumps({"file": built[0], "exports": exports}, indent=1))
        _install(tmp, folder, force)
    except Exception as exc:  # no C compiler, a numba without pycc support for a construct, ...
        shutil.rmtree(tmp, ignore_errors=True)
        log(f"compiling ahead of time failed ({type(exc).__name__}: {exc}); the JIT kernels will run")
        return None
    _prune(folder.parent, keep=_KEEP)
    _look_again()
    log(f"compiled-ahead kernels written to {folder}")
    return folder


def _install(tmp: Path, folder: Path, force: bool) -> None:
    """Rename the complete ``tmp`` to ``folder``. Another process may have built the same kernels meanwhile
    (two test workers, two builds): then theirs stay, unless ``force``."""
    if folder.exists() and (force or not (folder / _MANIFEST).is_file()):
        shutil.rmtree(folder)  # replaced on request, or a folder without its manifest (not written by build)
    try:
        os.replace(tmp, folder)
    except OSError:
        if not (folder / _MANIFEST).is_file():
            raise
        shutil.rmtree(tmp)


def _prune(parent: Path, keep: int) -> None:
    """Remove all but the ``keep`` most recently built kernel folders under ``parent`` (a folder's manifest
    is written last), and temporary folders of builds that died more than a day ago. Only folders named
    as :func:`build` names them are touched; a process that loaded a removed module keeps running it."""
    built = []
    for p in parent.iterdir():
        if not p.is_dir():
            continue
        stem, _, rest = p.name.partition(".")
        if len(stem) != _KEY_LEN or any(ch not in "0123456789abcdef" for ch in stem):
            continue
        if rest:
            if time.time() - p.stat().st_mtime > 86400:
                shutil.rmtree(p, ignore_errors=True)
        elif (p / _MANIFEST).is_file():
            built.append(((p / _MANIFEST).stat().st_mtime, p))
    for _, p in sorted(built, reverse=True)[keep:]:
        shutil.rmtree(p, ignore_errors=True)
