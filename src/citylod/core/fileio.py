"""Writing outputs so that nothing half-written is ever left behind.

Every file citylod writes goes to a temporary name beside its destination and is renamed into place when
complete (``os.replace`` is atomic on one file system); every output folder is built as ``OUT.partial`` and
published the same way. Standard library only.
"""

from __future__ import annotations

import functools
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from citylod.core.errors import CitylodError, InputError


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], object], *, suffix: str = "") -> Path:
    """Run ``write(tmp)`` on a temporary name beside ``path``, then rename it into place.

    ``suffix`` ends the temporary name, for writers that choose the format by extension (``np.savez``,
    image writers). On any failure the temporary file is removed and the exception propagates.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.tmp{os.getpid()}{suffix}")
    try:
        write(tmp)
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)
    return p


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes | memoryview) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return atomic_write(path, lambda t: t.write_bytes(data))


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_write(path, lambda t: t.write_text(text, encoding="utf-8"))


# The names atomic_write gives its temporaries: ".<name>.tmp<pid>[<suffix>]".
_TEMPORARY = re.compile(r"\..+\.tmp\d+(\.[A-Za-z0-9]+)?")


def remove_temporaries(folder: str | os.PathLike[str]) -> int:
    """Delete the temporaries :func:`atomic_write` left in ``folder`` (recursively) when its process was
    killed between writing and renaming; returns how many. A build that resumed after SIGKILL rewrote the
    file itself, so its output would otherwise carry a stray ``.x.glb.tmp1234`` (seen once in
    tests/cli/test_kill.py)."""
    n = 0
    for path in Path(folder).rglob(".*.tmp*"):
        if path.is_file() and _TEMPORARY.fullmatch(path.name):
            path.unlink(missing_ok=True)
            n += 1
    return n


def publish_dir(partial: str | os.PathLike[str], out: str | os.PathLike[str], *,
                marker: str = "tileset.json") -> None:
    """Move the finished folder ``partial`` to ``out``, replacing a previous output there; temporaries
    that killed writers left in it are removed first (:func:`remove_temporaries`).

    A non-empty ``out`` that lacks ``marker`` (so is not an earlier output of the same kind) is refused
    rather than deleted: a mistyped ``-o`` must never remove a user's folder.
    """
    src, dst = Path(partial), Path(out)
    remove_temporaries(src)
    if not dst.exists():
        os.replace(src, dst)
        return
    if not (dst / marker).exists() and any(dst.iterdir()):
        raise InputError(f"output folder exists and holds no {marker}; refusing to replace it", dst)
    old = dst.with_name(f".{dst.name}.old{os.getpid()}")
    shutil.rmtree(old, ignore_errors=True)
    os.replace(dst, old)
    os.replace(src, dst)
    shutil.rmtree(old, ignore_errors=True)


_F = TypeVar("_F", bound=Callable[..., Any])


def discard_partial_on_refusal(func: _F) -> _F:
    """Decorate a builder ``f(inputs, out_dir, ...)`` so that refused input leaves no ``out_dir.partial``.

    A builder writes into ``<out_dir>.partial`` and keeps it when interrupted, to resume. When it stops on a
    :class:`CitylodError` (bad input found part-way: a truncated file, a raster that cannot be placed), a
    partial folder that this call created holds nothing worth resuming, so it is removed; one that existed
    before the call (an earlier interrupted build) is left as it was.
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        out = kwargs.get("out_dir", args[1] if len(args) > 1 else None)
        partial = None if out is None else Path(out).with_name(Path(out).name + ".partial")
        existed = partial is None or partial.exists()
        try:
            return func(*args, **kwargs)
        except CitylodError:
            if not existed and partial is not None:
                shutil.rmtree(partial, ignore_errors=True)
            raise

    return wrapper  # type: ignore[return-value]
