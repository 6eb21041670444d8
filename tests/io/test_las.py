"""LAS/LAZ input: headers first, chunked decoding, and clear errors naming the file."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from citylod.core.errors import EmptyInputError, GeoreferenceError, InputError
from citylod.io.las import decode_seconds, iter_points, read_info, read_metadata, supports
from tests.lod.test_points_cloud import make_cloud
from tests.paths import DELFT


@pytest.fixture(scope="module")
def cloud(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    path = tmp_path_factory.mktemp("las") / "cloud.laz"
    return path, make_cloud(path, n_terrain=20_000)


def test_supports_by_suffix_and_magic(tmp_path: Path, cloud: tuple[Path, np.ndarray]) -> None:
    assert supports(cloud[0])
    assert supports(tmp_path / "missing.LAS")
    renamed = tmp_path / "cloud.bin"
    renamed.write_bytes(cloud[0].read_bytes()[:64])
    assert supports(renamed)
    other = tmp_path / "x.tif"
    other.write_bytes(b"II*\x00rest")
    assert not supports(other)


def test_metadata_from_headers(cloud: tuple[Path, np.ndarray]) -> None:
    path, pts = cloud
    meta = read_metadata([path])
    assert meta.point_count == len(pts)
    assert meta.crs.to_epsg() == 28992
    assert meta.has_rgb
    np.testing.assert_allclose(meta.lo, pts[:, :3].min(axis=0), atol=1e-3)
    np.testing.assert_allclose(meta.hi, pts[:, :3].max(axis=0), atol=1e-3)


def test_chunks_keep_attributes_and_scale_rgb(cloud: tuple[Path, np.ndarray]) -> None:
    path, pts = cloud
    chunks = list(iter_points(path, chunk_points=7_000))
    assert max(len(c) for c in chunks) <= 7_000
    recs = np.concatenate(chunks)
    np.testing.assert_array_equal(recs["x"], pts[:, 0])
    np.testing.assert_array_equal(recs["intensity"], pts[:, 3])
    np.testing.assert_array_equal(recs["classification"], pts[:, 4])
    np.testing.assert_array_equal(recs["return_number"], pts[:, 5])
    las = laspy.read(path)
    np.testing.assert_array_equal(recs["red"], np.asarray(las.red) >> 8)
    # A segment read with seek is the same as the slice of a full read.
    seg = np.concatenate(list(iter_points(path, start=10_001, count=5_000, chunk_points=2_000)))
    np.testing.assert_array_equal(seg, recs[10_001:15_001])


def test_truncated_laz_names_the_file(tmp_path: Path, cloud: tuple[Path, np.ndarray]) -> None:
    cut = tmp_path / "cut.laz"
    data = cloud[0].read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.laz") as info:
        for _ in iter_points(cut, chunk_points=5_000):
            pass
    assert "truncated" in str(info.value) or "ends after" in str(info.value)


def test_truncated_las_names_the_file(tmp_path: Path, cloud: tuple[Path, np.ndarray]) -> None:
    las = laspy.read(cloud[0])
    full = tmp_path / "full.las"
    las.write(full)
    cut = tmp_path / "cut.las"
    data = full.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.las"):
        for _ in iter_points(cut, chunk_points=5_000):
            pass


def test_garbage_is_an_input_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.laz"
    bad.write_bytes(b"LASF" + b"\x00" * 10)
    with pytest.raises(InputError, match=r"bad\.laz"):
        read_info(bad)
    with pytest.raises(InputError, match=r"nope\.laz"):
        read_info(tmp_path / "nope.laz")


def test_empty_file(tmp_path: Path) -> None:
    empty = tmp_path / "empty.laz"
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.add_crs(pyproj.CRS.from_epsg(28992))
    laspy.LasData(hdr).write(empty)
    with pytest.raises(EmptyInputError, match=r"empty\.laz"):
        read_metadata([empty])


def test_missing_crs_needs_override(tmp_path: Path) -> None:
    path = tmp_path / "nocrs.laz"
    make_cloud(path, n_terrain=2_000, crs=None, rgb=False)
    with pytest.raises(GeoreferenceError, match=r"nocrs\.laz.*--crs"):
        read_metadata([path])
    meta = read_metadata([path], crs="EPSG:28992")
    assert meta.crs.to_epsg() == 28992
    assert not meta.has_rgb


def test_different_crs_refused(tmp_path: Path) -> None:
    a, b = tmp_path / "a.laz", tmp_path / "b.laz"
    make_cloud(a, n_terrain=1_000)
    make_cloud(b, n_terrain=1_000, crs=pyproj.CRS.from_epsg(32631))
    with pytest.raises(GeoreferenceError, match=r"b\.laz"):
        read_metadata([a, b])


@pytest.mark.realdata
def test_delft_headers() -> None:
    files = sorted(DELFT.glob("ahn3_cropped_*.laz"))
    if len(files) != 2:
        pytest.skip(f"real data not found in {DELFT}")
    with pytest.raises(GeoreferenceError, match="--crs"):  # the AHN3 crops carry no CRS VLR
        read_metadata(files)
    meta = read_metadata(files, crs="EPSG:28992")
    assert meta.point_count == 640_510 + 208_432
    assert meta.files[0].point_format == 1 and not meta.has_rgb
    assert decode_seconds(files) > 0


@pytest.mark.parametrize("fmt", [1, 3, 6, 7])
def test_compiled_scan_matches_the_numpy_conversion(tmp_path: Path, fmt: int) -> None:
    """The points builder's compiled pass 1 (records, positions, grid cells, intensity histogram, bounds
    in one go, from laspy's raw columns) gives what the plain conversion and octree.quantize give, for
    point formats with and without colour and both layouts of return number and class (0–5, 6–10)."""
    from citylod.lod.build.points import _scan_segment
    from citylod.lod.kernels.octree import quantize

    rng = np.random.default_rng(fmt)
    n = 3_000
    hdr = laspy.LasHeader(point_format=fmt, version="1.4")
    hdr.offsets = np.array([85_000.0, 446_000.0, 0.0])
    hdr.scales = np.array([0.001, 0.001, 0.01])
    las = laspy.LasData(hdr)
    las.x = 85_000 + rng.uniform(0, 300, n)
    las.y = 446_000 + rng.uniform(0, 300, n)
    las.z = rng.uniform(-5, 60, n)
    las.intensity = rng.integers(0, 65_535, n, dtype=np.uint16)
    las.classification = rng.integers(0, 19 if fmt >= 6 else 31, n, dtype=np.uint8)
    las.return_number = rng.integers(1, 8 if fmt < 6 else 15, n, dtype=np.uint8)
    if fmt in (3, 7):
        las.red, las.green, las.blue = (rng.integers(0, 65_535, n, dtype=np.uint16) for _ in range(3))
    path = tmp_path / f"f{fmt}.laz"
    las.write(path)
    recs = np.concatenate(list(iter_points(path)))
    xyz = np.stack([recs["x"], recs["y"], recs["z"]], axis=1)
    cube_lo, size = (85_010.0, 446_020.0, -10.0), 250.0  # some points outside: clamped
    got_recs, got_xyz, got_q = np.empty(n, recs.dtype), np.empty((n, 3)), np.empty((n, 3), np.int64)
    _c, _k, lo, hi, hist = _scan_segment(cube_lo, size, str(path), 0, n, "unused", into=(got_recs, got_xyz, got_q))
    assert got_recs.tobytes() == recs.tobytes()
    np.testing.assert_array_equal(got_xyz, xyz)
    np.testing.assert_array_equal(got_q, quantize(xyz, np.asarray(cube_lo), size))
    np.testing.assert_array_equal(hist, np.bincount(recs["intensity"], minlength=1 << 16))
    np.testing.assert_array_equal(lo, xyz.min(axis=0))
    np.testing.assert_array_equal(hi, xyz.max(axis=0))
    assert (recs["red"] > 0).any() == (fmt in (3, 7))
