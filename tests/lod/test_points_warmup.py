"""`citylod build-kernels` fills numba's cache for points builds: a later build of another cloud, in a fresh
process, compiles none of citylod's kernels (the first build otherwise compiles for about 20 s)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from citylod.sample import make_sample

_BUILD = textwrap.dedent("""
    import sys, warnings
    from pathlib import Path
    warnings.simplefilter("ignore")
    import laspy
    from numba.core import event
    from citylod.lod.build.points import build_points

    src, tmp = Path(sys.argv[1]), Path(sys.argv[2])
    plain = laspy.convert(laspy.read(src), point_format_id=1, file_version="1.2")  # no colour, like AHN
    plain.write(tmp / "plain.laz")
    with event.install_recorder("numba:compile") as rec:
        for i, f in enumerate((src, tmp / "plain.laz")):
            build_points([f], tmp / f"t{i}", crs="EPSG:32632", workers=0, progress=False)
    mods = {d.data["dispatcher"].py_func.__module__ + "." + d.data["dispatcher"].py_func.__qualname__
            for _, d in rec.buffer if getattr(d, "data", None) and d.data.get("dispatcher") is not None}
    print(" ".join(sorted(m for m in mods if m.startswith("citylod"))))
""")


def test_after_the_warm_up_a_points_build_compiles_nothing(tmp_path) -> None:
    info = make_sample(tmp_path / "s", size=129)  # ≈ 33 k points: internal nodes, planes
    cli = [sys.executable, "-m", "citylod", "-q", "build-kernels"]
    subprocess.run(cli, check=True, capture_output=True, timeout=600)
    out = subprocess.run([sys.executable, "-c", _BUILD, str(info.files["points"]), str(tmp_path)], check=True,
                         capture_output=True, text=True, timeout=600)
    assert out.stdout.strip() == "", f"compiled in the build: {out.stdout.strip()}"
