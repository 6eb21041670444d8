"""The DSM benchmark runs end to end on a small raster: its child process, the warm builds and pydelatin
taken in turns, and the baselines measured with the certifier. Numbers are not asserted (timings belong
to the report); what is asserted could only fail if the benchmark were broken."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import from_origin

from citylod.bench.dsm_bench import bench_dsm, dsm_markdown


def test_bench_dsm_small_raster(tmp_path: Path) -> None:
    yy, xx = np.mgrid[0:97, 0:97]
    z = (30.0 + 0.05 * xx + 2.0 * np.sin(yy / 6.0)).astype(np.float32)
    z[20:40, 30:55] += 12.0  # a building with façades
    path = tmp_path / "dsm.tif"
    with rasterio.open(path, "w", driver="GTiff", width=97, height=97, count=1, dtype="float32",
                       crs="EPSG:32632", transform=from_origin(500_000.0, 5_400_000.0, 1.0, 1.0)) as ds:
        ds.write(z, 1)
    r = bench_dsm(path, tmp_path / "out", progress=False)
    ours, pyd = r["meshers"][0], r["meshers"][1]
    assert r["build_seconds"] > 0 and r["warm_seconds"] > 0 and pyd["seconds"] > 0
    assert ours["true_error_m"] <= ours["asked_error_m"] * (1 + 1e-6)
    assert pyd["triangles"] > 0 and pyd["true_error_m"] > 0  # façades between samples: above its bound
    assert np.isclose(r["warm_vs_pydelatin_time"], r["warm_seconds"] / pyd["seconds"])
    assert "pydelatin" in dsm_markdown([r])
    assert r["kernels"] in ("compiled-ahead", "JIT")  # the report says which ran (make builds them ahead)
    assert ("nothing to start" in dsm_markdown([r])) == (r["kernels"] == "compiled-ahead")
    assert not (tmp_path / "out" / "tiles_dsm_warm").exists()
