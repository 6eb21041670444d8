"""The README's scripting examples run as written (its public API is what users copy)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.paths import ROOT

pytestmark = pytest.mark.render


def test_readme_python_examples_run(tmp_path, monkeypatch) -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 2, "the README lost its scripting examples"
    monkeypatch.chdir(tmp_path)
    ns: dict[str, object] = {}
    exec(compile("\n".join(blocks), "README.md", "exec"), ns)
    rgb = ns["rgb"]
    assert isinstance(rgb, np.ndarray) and rgb.shape == (360, 640, 3)
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 100, "the render is blank"
    shot = tmp_path / "city" / "pyvista.png"
    assert shot.is_file()
    layer = ns["layer"]
    assert layer.stats.tiles > 0 and layer.stats.triangles > 0  # type: ignore[attr-defined]
    poly = ns["poly"]
    mesh = ns["mesh"]
    assert poly.n_cells == int((~mesh.skirt).sum()) and poly.n_points == len(mesh.vertices)  # type: ignore[attr-defined]
    layer.close()  # type: ignore[attr-defined]
    # The plotter stays open, as in a user's script: the renderers of later tests in this process draw
    # next to its GLX context (tests/render/test_gl_contexts.py has the scenarios).
