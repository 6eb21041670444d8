"""The layering of the design: nothing below render/ imports VTK or Qt; dependencies point one way."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.paths import ROOT


def test_import_contracts_hold() -> None:
    exe = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(exe), "--no-cache"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def _module_graph() -> dict[str, set[str]]:
    import grimp

    graph = grimp.build_graph("citylod", cache_dir=None)
    return {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, with an explicit stack)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in edges:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles_between_modules() -> None:
    """Every import counts, also those inside functions: a lazy import still ties two modules together."""
    cycles = _cycles(_module_graph())
    assert not cycles, cycles


def test_pure_layers_import_without_vtk_or_qt() -> None:
    code = (
        "import sys, pkgutil, importlib, citylod\n"
        "for pkg in ('core', 'io', 'lod', 'semantics', 'sample'):\n"
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
