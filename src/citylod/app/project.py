"""Project files: what an analyst set up in a window, saved so that it reopens to the same view.

A project (``*.citylod``, JSON) holds the sources with their display (visibility, opacity, colour mode,
point size and shape), the LOD settings, the camera, the project's bookmarks, the city objects' state
(highlight colours, hidden, isolated, selected), the clipping box, the class filter, EDL and the
ellipsoidal-distance switch. Source paths are stored relative to the project file when they lie beside or
below it, so a project folder can be moved or shared as a whole; absolute otherwise.

Reading validates everything before anything is opened, so a damaged project fails with one line naming
the file and the problem (:class:`~citylod.core.errors.InputError`), and nothing of it is half-applied.
No Qt here; the main window calls :func:`save_project` and :func:`read_project` / :func:`apply_project`.

Examples
--------
>>> import json, tempfile, pathlib
>>> from citylod.app.models import Bookmarks, Document
>>> from citylod.core.camera import Camera
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> doc = Document()
>>> cam = Camera((0.0, -50.0, 30.0), (0.0, 0.0, 0.0))
>>> path = save_project(d / "p.citylod", doc, cam, Bookmarks({"north": cam}))
>>> p = read_project(path)
>>> p.camera == cam, p.bookmarks.names()
(True, ['north'])
>>> doc.close()
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from citylod.app.models import Bookmarks, Document
from citylod.core.camera import Camera
from citylod.core.errors import InputError
from citylod.core.fileio import atomic_write_text
from citylod.io.tiles3d.remote import is_url, unfold_url

__all__ = ["PROJECT_SUFFIX", "Project", "apply_project", "project_dict", "read_project", "save_project"]

PROJECT_SUFFIX = ".citylod"
_FORMAT = "citylod-project"
_VERSION = 1


@dataclass
class Project:
    """A project as read from a file (paths resolved, values checked)."""

    path: Path
    layers: list[dict[str, Any]] = field(default_factory=list)
    camera: Camera | None = None
    bookmarks: Bookmarks = field(default_factory=Bookmarks)
    state: dict[str, Any] = field(default_factory=dict)
    lod: dict[str, Any] = field(default_factory=dict)
    display: dict[str, Any] = field(default_factory=dict)


def _rel(path: Path, base: Path) -> str:
    if is_url(path):  # a tileset on a web server: its URL as typed
        return unfold_url(path)
    p = Path(os.path.abspath(path))
    try:
        return p.relative_to(Path(os.path.abspath(base))).as_posix()
    except ValueError:
        return str(p)


def project_dict(document: Document, camera: Camera | None, bookmarks: Bookmarks, base: Path) -> dict[str, Any]:
    """The JSON object of a project whose file lies in folder ``base``."""
    layers = []
    for e in document.entries:
        row: dict[str, Any] = {"path": _rel(e.path, base), "kind": e.kind, "visible": e.visible,
                               "opacity": e.opacity, "color_by": e.color_by}
        if e.layer is not None:
            row["point_size_px"] = float(e.layer.point_size_px)
            row["point_round"] = bool(e.layer.point_round)
        layers.append(row)
    st = document.state
    clip = document.clip_box
    return {
        "format": _FORMAT, "version": _VERSION,
        "layers": layers,
        "camera": None if camera is None else camera.to_dict(),
        "bookmarks": {k: c.to_dict() for k, c in bookmarks.items.items()},
        "state": {"highlight": {oid: list(map(float, rgba)) for oid, rgba in st.colors.items()},
                  "hidden": sorted(st.hidden),
                  "isolated": None if st.isolated is None else sorted(st.isolated),
                  "selection": sorted(st.selection)},
        "lod": {"tau_px": document.lod.tau_px, "point_budget": document.lod.point_budget,
                "color_by_level": document.lod.color_by_level, "target_ms": document.lod.target_ms},
        "display": {"edl": document.edl, "ellipsoidal": document.ellipsoidal,
                    "clip_box": None if clip is None else [clip[0].tolist(), clip[1].tolist()],
                    "class_filter": None if document.class_filter is None else sorted(document.class_filter)},
    }


def save_project(path: str | os.PathLike[str], document: Document, camera: Camera | None,
                 bookmarks: Bookmarks) -> Path:
    """Write the project file atomically (a failed write leaves any earlier file as it was)."""
    p = Path(path)
    if p.suffix != PROJECT_SUFFIX:
        p = p.with_name(p.name + PROJECT_SUFFIX)
    text = json.dumps(project_dict(document, camera, bookmarks, p.parent), indent=1)
    return atomic_write_text(p, text + "\n")


def _fail(path: Path, problem: str) -> InputError:
    return InputError(f"not a usable citylod project: {problem}", path)


def read_project(path: str | os.PathLike[str]) -> Project:
    """Read and check a project file; raises :class:`InputError` naming the file and the problem."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("project file not found", p) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _fail(p, f"cannot read it as JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != _FORMAT:
        raise _fail(p, f"no \"format\": \"{_FORMAT}\" object")
    if data.get("version") != _VERSION:
        raise _fail(p, f"version {data.get('version')!r}, this citylod reads version {_VERSION}")
    out = Project(p)
    layers = data.get("layers", [])
    if not isinstance(layers, list):
        raise _fail(p, "\"layers\" is not a list")
    for i, row in enumerate(layers):
        if not isinstance(row, dict) or not isinstance(row.get("path"), str):
            raise _fail(p, f"layer {i} has no path")
        clean = dict(row)
        if is_url(row["path"]):
            clean["path"] = unfold_url(row["path"])  # fetched when the layer opens
        else:
            src = Path(row["path"])
            src = src if src.is_absolute() else p.parent / src
            if not src.exists():
                raise _fail(p, f"layer {i}: {src} does not exist")
            clean["path"] = src
        try:
            clean["opacity"] = float(row.get("opacity", 1.0))
            clean["visible"] = bool(row.get("visible", True))
            if "point_size_px" in row:
                clean["point_size_px"] = float(row["point_size_px"])
        except (TypeError, ValueError):
            raise _fail(p, f"layer {i}: opacity or point size is not a number") from None
        out.layers.append(clean)
    try:
        if data.get("camera") is not None:
            out.camera = Camera.from_dict(data["camera"], str(p))
        for name, cam in (data.get("bookmarks") or {}).items():
            out.bookmarks.items[str(name)] = Camera.from_dict(cam, str(p))
    except (InputError, AttributeError, TypeError, ValueError) as exc:
        raise _fail(p, f"a camera is not valid ({exc})") from None
    for key in ("state", "lod", "display"):
        val = data.get(key) or {}
        if not isinstance(val, dict):
            raise _fail(p, f"\"{key}\" is not an object")
        setattr(out, key, val)
    target = out.lod.get("target_ms", 0.0)
    if isinstance(target, bool) or not isinstance(target, int | float) or not 0 <= target < float("inf"):
        raise _fail(p, f"\"target_ms\" is not a frame time in ms: {target!r}")
    box = out.display.get("clip_box")
    if box is not None and np.asarray(box, dtype=float).shape != (2, 3):
        raise _fail(p, "\"clip_box\" is not two 3D corners")
    return out


def apply_project(document: Document, project: Project) -> None:
    """Open the project's sources into an empty ``document`` and restore their display, the LOD settings
    and the objects' state. The camera and bookmarks are the caller's (they belong to the view)."""
    for row in project.layers:
        entry = document.open(row["path"])
        index = document.entries.index(entry)
        if row.get("color_by") and entry.layer is not None:
            document.set_color_by(index, str(row["color_by"]))
        if "point_size_px" in row and entry.layer is not None:
            document.set_point_size(index, row["point_size_px"], bool(row.get("point_round", False)))
        document.set_opacity(index, row["opacity"])
        document.set_visible(index, row["visible"])
    lod = project.lod
    if "tau_px" in lod:
        document.set_tau(float(lod["tau_px"]))
    if "point_budget" in lod:
        document.set_point_budget(int(lod["point_budget"]))
    if lod.get("color_by_level"):
        document.set_color_by_level(True)
    if lod.get("target_ms"):  # budget mode; projects saved before it have no key (fixed budgets)
        document.set_target_ms(float(lod["target_ms"]))
    disp = project.display
    document.ellipsoidal = bool(disp.get("ellipsoidal", False))
    if disp.get("edl"):
        document.set_edl(True)
    if disp.get("clip_box") is not None:
        lo, hi = disp["clip_box"]
        document.set_clip_box((lo, hi))
    if disp.get("class_filter") is not None:
        document.set_class_filter(int(c) for c in disp["class_filter"])
    st = project.state
    for oid, rgba in (st.get("highlight") or {}).items():
        document.state.highlight([str(oid)], tuple(float(c) for c in rgba))
    if st.get("hidden"):
        document.state.hide(str(o) for o in st["hidden"])
    if st.get("isolated") is not None:
        document.state.isolate(str(o) for o in st["isolated"])
    if st.get("selection"):
        document.select([str(o) for o in st["selection"]])
    document.notify("layers")  # panels rebuild from the restored entries
