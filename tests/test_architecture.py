"""The layering of the design: nothing below render/ imports VTK or Qt; dependencies point one way."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_hold() -> None:
    exe = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(exe), "--no-cache"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_pure_layers_import_without_vtk_or_qt() -> None:
    code = (
        "import sys, pkgutil, importlib, citylod\n"
        "for pkg in ('core', 'io', 'lod', 'semantics'):\n"
        "    m = importlib.import_module('citylod.' + pkg)\n"
        "    for info in pkgutil.walk_packages(m.__path__, m.__name__ + '.'):\n"
        "        importlib.import_module(info.name)\n"
        "bad = sorted(n for n in sys.modules if n.split('.')[0] in ('vtk', 'vtkmodules', 'pyvista', 'PySide6'))\n"
        "assert not bad, bad\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_no_process_wide_vtk_render_state() -> None:
    """VTK's SetResolveCoincidentTopology* are static: one call shifts the depth of every mapper in the
    process (it broke off-screen point renders after the GUI drew a measurement). Per-mapper
    SetRelativeCoincidentTopology* parameters are the way."""
    import re

    bad = [str(p.relative_to(ROOT)) for p in (ROOT / "src").rglob("*.py")
           if re.search(r"\.SetResolveCoincidentTopology\w*\(", p.read_text())]
    assert not bad, bad


def test_ruff_is_clean() -> None:
    exe = Path(sys.executable).with_name("ruff")
    result = subprocess.run([str(exe), "check", "src", "tests"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout[-3000:]
