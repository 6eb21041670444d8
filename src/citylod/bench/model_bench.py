"""Ridges and eaves of the sample city against the truth: the constrained model, its ablation, pymeshlab.

The sample city's roofs are known in closed form (:mod:`citylod.sample.city`), so every ridge and eave is a
known 3D segment. A building's features are *kept* by a mesh when, on each of its ridge and eave segments,
90 % of the points sampled every 0.25 m (0.5 m clear of the segment ends, where chimneys or trees do not
cover them) lie within ``tol`` (0.5 m) of the mesh, distances measured in 3D to the nearest triangle.

:func:`compare` runs, on one DSM grid of the city, the full grid triangulation, the shape-constrained
simplification at a certified bound ε, the same collapse without shapes, and pymeshlab's quadric edge
collapse (``meshing_decimation_quadric_edge_collapse``) at the constrained and at the unconstrained
result's triangle counts, and
reports triangles, the share of buildings whose features are kept, and the Hausdorff distance to the grid
that pymeshlab samples (an independent check of the certified bound).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.lod.build.model import simplify_grid
from citylod.sample.city import KIND_BUILDING, SampleCity

F64 = npt.NDArray[np.float64]


def feature_segments(city: SampleCity) -> list[list[tuple[F64, F64]]]:
    """Per building its ridge and eave segments, each a pair of (3,) CRS points.

    Gable: the ridge and the two eaves along the ridge (the gable ends are verges, not eaves); hip: the
    ridge (when over 1 m long) and the four eaves; flat: every edge of the footprint rings at eave height.
    """
    out: list[list[tuple[F64, F64]]] = []
    for b in city.buildings:
        segs: list[tuple[F64, F64]] = []
        if b.roof == "flat":
            for ring in (b.footprint, *b.holes):
                for i in range(len(ring)):
                    p, q = ring[i], ring[(i + 1) % len(ring)]
                    segs.append((np.array([p[0], p[1], b.eave]), np.array([q[0], q[1], b.eave])))
        else:
            a, h = float(b.parts[0, 2]), float(b.parts[0, 3])
            r = a if b.roof == "gable" else a - h
            uv = [((-r, 0.0), (r, 0.0), b.ridge)] if r > 0.5 else []
            uv += [((-a, -h), (a, -h), b.eave), ((-a, h), (a, h), b.eave)]
            if b.roof == "hip":
                uv += [((-a, -h), (-a, h), b.eave), ((a, -h), (a, h), b.eave)]
            for p, q, z in uv:
                w = b.to_world(np.array([p, q], dtype=np.float64))
                segs.append((np.array([w[0, 0], w[0, 1], z]), np.array([w[1, 0], w[1, 1], z])))
        out.append(segs)
    return out


def _point_triangle_distance(p: F64, a: F64, b: F64, c: F64) -> F64:
    """Distances (P, T) from points (P, 3) to triangles (T, 3) each (Ericson 2005, closest point on a
    triangle, vectorised over the pairs)."""
    p = p[:, None, :]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        q = a + ab * v[..., None] + ac * w[..., None]  # interior
        # edge and vertex regions
        t_ab = np.clip(d1 / np.where(d1 - d3 != 0, d1 - d3, 1.0), 0, 1)
        t_ac = np.clip(d2 / np.where(d2 - d6 != 0, d2 - d6, 1.0), 0, 1)
        t_bc = np.clip((d4 - d3) / np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) + (d5 - d6), 1.0), 0, 1)
    cand = [q, a + ab * t_ab[..., None], a + ac * t_ac[..., None], b + (c - b) * t_bc[..., None]]
    inside = (va >= 0) & (vb >= 0) & (vc >= 0)
    dist = [np.linalg.norm(p - x, axis=-1) for x in cand]
    best = np.minimum(np.minimum(dist[1], dist[2]), dist[3])
    return np.where(inside, np.minimum(dist[0], best), best)


def kept_fraction(city: SampleCity, pos: F64, faces: npt.NDArray[np.int64], *, tol: float = 0.5,
                  share: float = 0.9) -> tuple[float, int]:
    """Share of the buildings (with at least one measurable segment) whose ridges and eaves the mesh
    ``pos`` (V, 3) CRS, ``faces`` (M, 3) keeps within ``tol``; and the number of buildings measured."""
    tri = pos[faces]
    tlo, thi = tri.min(axis=1), tri.max(axis=1)
    passed = measured = 0
    for b, segs in zip(city.buildings, feature_segments(city), strict=True):
        ok_all = True
        any_seg = False
        cx, cy = b.center
        for p, q in segs:
            length = float(np.linalg.norm(q[:2] - p[:2]))
            if length < 1.5:
                continue
            t = np.arange(0.5, length - 0.5 + 1e-9, 0.25) / length
            pts = p + (q - p) * t[:, None]
            # measurable where the building's own roof forms the surface just inside the line
            inward = np.array([cx, cy]) - pts[:, :2]
            inward /= np.maximum(np.linalg.norm(inward, axis=1, keepdims=True), 1e-9)
            probe = pts[:, :2] + 0.3 * inward
            _, kind, idx = city.surface_with_kind(probe[:, 0], probe[:, 1])
            valid = (kind == KIND_BUILDING) & (idx == b.index) & ~city.nodata_mask(probe[:, 0], probe[:, 1])
            pts = pts[valid]
            if len(pts) < 4:
                continue
            any_seg = True
            lo, hi = pts.min(axis=0) - tol - 1.0, pts.max(axis=0) + tol + 1.0
            near = np.all((thi >= lo) & (tlo <= hi), axis=1)
            if not near.any():
                ok_all = False
                continue
            tn = tri[near]
            d = _point_triangle_distance(pts, tn[:, 0], tn[:, 1], tn[:, 2]).min(axis=1)
            if np.mean(d <= tol) < share:
                ok_all = False
        if any_seg:
            measured += 1
            passed += int(ok_all)
    return passed / max(measured, 1), measured


@dataclass
class Row:
    """One method's result."""

    method: str
    triangles: int
    kept: float
    seconds: float
    hausdorff_sampled: float


def _pymeshlab_hausdorff(pos: F64, faces: npt.NDArray[np.int64], gpos: F64, gfaces: npt.NDArray[np.int64]) -> float:
    """Symmetric Hausdorff distance between two meshes as pymeshlab samples it (vertices, edges, faces)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    o = gpos.mean(axis=0)
    ms.add_mesh(pymeshlab.Mesh(pos - o, faces.astype(np.int32)))
    ms.add_mesh(pymeshlab.Mesh(gpos - o, gfaces.astype(np.int32)))
    n = int(4 * len(gpos))
    a = ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1, samplevert=True, sampleedge=True, sampleface=True,
                                  samplenum=n)["max"]
    b = ms.get_hausdorff_distance(sampledmesh=1, targetmesh=0, samplevert=True, sampleedge=True, sampleface=True,
                                  samplenum=n)["max"]
    return float(max(a, b))


def pymeshlab_decimate(pos: F64, faces: npt.NDArray[np.int64], target: int) -> tuple[F64, npt.NDArray[np.int64]]:
    """pymeshlab's quadric edge collapse to ``target`` triangles (boundary and normals preserved, planar
    quadrics on: its settings for surfaces with flat regions)."""
    import pymeshlab

    o = pos.mean(axis=0)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(pos - o, faces.astype(np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target), preserveboundary=True, preservenormal=True,
                                                preservetopology=True, planarquadric=True, qualitythr=0.3)
    m = ms.current_mesh()
    return m.vertex_matrix() + o, m.face_matrix().astype(np.int64)


def plot_meshes(city: SampleCity, meshes: list[tuple[str, F64, npt.NDArray[np.int64]]], path: str,
                half: float = 30.0) -> None:
    """Top views of meshes side by side around the pitched roof nearest the city's centre: faces shaded by a sun from
    the north-west, edges drawn, the true ridges and eaves in red (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    mid = np.array(city.pixel_centers()[0].mean()), np.array(city.pixel_centers()[1].mean())
    pitched = [b for b in city.buildings if b.roof != "flat"] or city.buildings
    b = min(pitched, key=lambda b: float(np.hypot(b.center[0] - mid[0], b.center[1] - mid[1])))
    cx, cy = b.center
    segs = [s for bs in feature_segments(city) for s in bs]
    sun = np.array([-1.0, 1.0, 1.4]) / np.linalg.norm([-1.0, 1.0, 1.4])
    fig, axes = plt.subplots(1, len(meshes), figsize=(6 * len(meshes), 6.4))
    for ax, (name, pos, faces) in zip(np.atleast_1d(axes), meshes, strict=True):
        tri = pos[faces]
        keep = np.all((np.abs(tri[:, :, 0] - cx) < half * 1.5) & (np.abs(tri[:, :, 1] - cy) < half * 1.5), axis=1)
        tri = tri[keep]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        n *= np.sign(n[:, 2:3] + 1e-12)
        shade = np.clip(n @ sun, 0.05, 1.0)
        pc = PolyCollection(tri[:, :, :2], facecolors=plt.cm.gray(shade), edgecolors="tab:blue", linewidths=0.4)
        ax.add_collection(pc)
        for p, q in segs:
            ax.plot([p[0], q[0]], [p[1], q[1]], color="red", lw=0.8, alpha=0.8)
        ax.set_xlim(cx - half, cx + half)
        ax.set_ylim(cy - half, cy + half)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{name}: {len(faces)} triangles", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def compare(city: SampleCity, max_error: float, *, hausdorff: bool = True, share: float = 0.9,
            plot: str | None = None) -> list[Row]:
    """The four methods of the module docstring on the city's DSM grid (pixel centres, no-data masked);
    with ``plot`` a PNG of the constrained mesh beside pymeshlab's at the same triangle count."""
    x, y = city.pixel_centers()
    F = city.surface_height(x, y)
    V = ~city.nodata_mask(x, y)
    F = np.where(V, F, 0.0)
    _H, _W = F.shape
    d = city.spacing
    allpos = np.column_stack([x.reshape(-1), y.reshape(-1), F.reshape(-1)])

    def mesh_of(faces: npt.NDArray[np.int64]) -> tuple[F64, npt.NDArray[np.int64]]:
        ids, inv = np.unique(faces, return_inverse=True)
        return allpos[ids], inv.reshape(-1, 3)

    from citylod.lod.kernels.collapse import grid_triangles

    gpos, gfaces = mesh_of(grid_triangles(V))
    rows = [Row("grid (full triangulation)", len(gfaces), kept_fraction(city, gpos, gfaces, share=share)[0], 0.0, 0.0)]
    con = simplify_grid(F, V, d, d, max_error)
    cpos, cfaces = mesh_of(con.faces)
    unc = simplify_grid(F, V, d, d, max_error, constrained=False)
    upos, ufaces = mesh_of(unc.faces)
    t = time.perf_counter()
    ppos, pfaces = pymeshlab_decimate(gpos, gfaces, len(cfaces))
    tp = time.perf_counter() - t
    t = time.perf_counter()
    qpos, qfaces = pymeshlab_decimate(gpos, gfaces, len(ufaces))
    tq = time.perf_counter() - t
    if plot:
        plot_meshes(city, [(f"constrained, certified ≤ {max_error:g} m (3D)", cpos, cfaces),
                           ("pymeshlab quadric edge collapse", ppos, pfaces)], plot)
    for name, (p, f), secs in ((f"constrained, certified ≤ {max_error:g} m", (cpos, cfaces), con.seconds),
                               (f"unconstrained QEM, certified ≤ {max_error:g} m", (upos, ufaces), unc.seconds),
                               ("pymeshlab QEC, constrained's triangles", (ppos, pfaces), tp),
                               ("pymeshlab QEC, unconstrained's triangles", (qpos, qfaces), tq)):
        hd = _pymeshlab_hausdorff(p, f, gpos, gfaces) if hausdorff else float("nan")
        rows.append(Row(name, len(f), kept_fraction(city, p, f, share=share)[0], secs, hd))
    return rows


def tile_tree_leaf_triangles(dsm: str, out_dir: str, max_error: float) -> int:
    """Triangles (skirts excluded) in the leaves of the DSM tile tree built at the same leaf bound."""
    from citylod.io.tiles3d.tileset import open_tileset
    from citylod.lod.build.dsm import build_dsm

    build_dsm(dsm, out_dir, max_error=max_error, workers=0, progress=False, metric="vertical")  # same leaves, faster
    ts = open_tileset(out_dir)
    total = 0
    stack = [ts.root]
    while stack:
        t = stack.pop()
        if t.children:
            stack.extend(t.children)
            continue
        if t.content_bytes:
            for m in t.load_content().meshes:
                total += int(len(m.faces) - (0 if m.skirt is None else m.skirt.sum()))
    return total


def _footprints(model: object) -> list[tuple[str, object, float | None]]:
    """(id, shapely footprint, measuredHeight) of each Building: its GroundSurface polygons, else its
    lowest horizontal polygon, projected to the plane."""
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    out = []
    for o in model.objects:  # type: ignore[attr-defined]
        if o.type != "Building" or not o.surfaces:
            continue
        ground = [poly for poly, sem in zip(o.surfaces, o.semantics or [None] * len(o.surfaces), strict=False)
                  if sem == "GroundSurface"]
        if not ground:
            flat = [poly for poly in o.surfaces if np.ptp(poly[0][:, 2]) < 0.01]
            if not flat:
                continue
            zmin = min(float(poly[0][0, 2]) for poly in flat)
            ground = [poly for poly in flat if abs(float(poly[0][0, 2]) - zmin) < 0.01]
        geom = unary_union([Polygon(poly[0][:, :2], [r[:, :2] for r in poly[1:]]).buffer(0) for poly in ground])
        h = o.attributes.get("measuredHeight")
        if h is None:
            pts = o.points()
            h = float(pts[:, 2].max() - pts[:, 2].min())
        out.append((o.id, geom, float(h)))
    return out


def footprint_scores(truth: list[tuple[str, object, float | None]], derived: list[tuple[str, object, float | None]],
                     extent: object, *, touch: float = 0.5) -> dict[str, Any]:
    """The asked measures and a second, block-wise one, for reference buildings ``truth`` against ``derived``
    ((id, shapely footprint, height) each), counting only reference buildings at least 90 % inside ``extent``.

    Asked: per reference building the IoU with the derived footprint that overlaps it most, and whether that
    footprint's height is within 1 m of the reference's. Second measure (not the asked one): per *block*
    (union of reference footprints that touch, within 0.1 m) the IoU with the union of the derived
    footprints that touch each other (within ``touch`` m: they are polygonised and simplified one by one,
    so neighbours' shared borders do not coincide) and overlap it most, which shows how much of the gap is terraced
    houses the DSM does not separate.
    """
    from shapely.ops import unary_union
    from shapely.strtree import STRtree

    ref = [(k, g, h) for k, g, h in truth if not g.is_empty and g.intersection(extent).area >= 0.9 * g.area]
    dg = [g for _, g, _ in derived]
    tree = STRtree(dg) if dg else None
    ious, hok, per = [], [], []
    for k, g, h in ref:
        best, bh = 0.0, None
        for j in ([] if tree is None else tree.query(g)):
            if not dg[j].intersects(g):
                continue
            iou = g.intersection(dg[j]).area / g.union(dg[j]).area
            if iou > best:
                best, bh = iou, derived[j][2]
        ious.append(best)
        ok = bh is not None and h is not None and abs(bh - h) <= 1.0
        hok.append(ok)
        per.append({"id": k, "iou": best, "height": h, "derived_height": bh})

    def blocks(geoms: list[Any], gap: float) -> list[Any]:
        merged = unary_union([g.buffer(0.5 * gap) for g in geoms])
        return [p.buffer(-0.5 * gap) for p in getattr(merged, "geoms", [merged])]

    rb, db = blocks([g for _, g, _ in ref], 0.1), blocks(dg, touch) if dg else []
    block_ious = [max((b.intersection(d).area / b.union(d).area for d in db if d.intersects(b)), default=0.0)
                  for b in rb]
    return {"reference_buildings": len(ious), "derived_buildings": len(derived),
            "median_iou": float(np.median(ious)) if ious else float("nan"),
            "heights_within_1m": float(np.mean(hok)) if hok else float("nan"),
            "blocks": len(rb), "median_block_iou": float(np.median(block_ious)) if block_ious else float("nan"),
            "per_building": per}


def reference_heights_from_points(truth: list[tuple[str, object, float | None]], las_files: list[str],
                                  ground: dict[str, float]) -> dict[str, float]:
    """Per reference building, the 90th percentile of the building points (ASPRS class 6) inside its
    footprint above ``ground[id]``: the statistic the reference heights appear to use, so that comparing
    it with the reference shows how many reference heights this point cloud can reproduce at all."""
    import shapely

    from citylod.io.las import iter_points

    xyz = []
    for f in las_files:
        for pts in iter_points(f, raw=True):
            keep = np.asarray(pts.classification) == 6
            xyz.append(np.column_stack([np.asarray(a, np.float64)[keep] for a in (pts.x, pts.y, pts.z)]))
    p = np.concatenate(xyz)
    tree = shapely.STRtree(shapely.points(p[:, 0], p[:, 1]))
    out = {}
    for k, g, _ in truth:
        idx = tree.query(g, predicate="contains")
        if len(idx) and k in ground:
            out[k] = float(np.percentile(p[idx, 2], 90)) - ground[k]
    return out


def border_cues(footprints: list[Any], pts: F64, *, width: float = 1.25, cuts: int = 2,
                seed: int = 1) -> dict[str, Any]:
    """Whether the borders between touching footprints show in the points: per shared border (≥ 3 m), the
    step in median height and median ``pts[:, 3]`` (intensity) between the points within ``width`` m on either
    side, against the same steps across cuts parallel to that border 1.5–4 m inside each of the two
    footprints (``cuts`` per footprint). ``pts``: (n, 4) x, y, z, intensity of the roof returns.

    Returns the steps' medians and percentiles for borders and cuts, and for each cue the AUC (the probability
    that a border's step exceeds a cut's: 0.5 means the cue says nothing about where a border is).
    """
    import shapely
    from shapely import affinity

    rng = np.random.default_rng(seed)
    tree = shapely.STRtree(shapely.points(pts[:, 0], pts[:, 1]))

    def steps(line: Any, a: Any, b: Any) -> tuple[float, float] | None:
        idx = tree.query(line.buffer(width))
        if not len(idx):
            return None
        q = pts[idx]
        sa = shapely.contains_xy(a, q[:, 0], q[:, 1])
        sb = shapely.contains_xy(b, q[:, 0], q[:, 1])
        if sa.sum() < 8 or sb.sum() < 8:
            return None
        return (abs(float(np.median(q[sa, 2]) - np.median(q[sb, 2]))),
                abs(float(np.median(q[sa, 3]) - np.median(q[sb, 3]))))

    border: list[tuple[float, float]] = []
    cut: list[tuple[float, float]] = []
    ftree = shapely.STRtree(footprints)
    for i, gi in enumerate(footprints):
        for j in ftree.query(gi):
            if j <= i:
                continue
            shared = shapely.line_merge(gi.boundary.intersection(footprints[j].boundary))
            lines = [g for g in getattr(shared, "geoms", [shared]) if g.geom_type == "LineString" and g.length >= 3]
            if not lines:
                continue
            seg = max(lines, key=lambda g: g.length)
            st = steps(seg, gi, footprints[j])
            if st is None:
                continue
            border.append(st)
            (x0, y0), (x1, y1) = seg.coords[0], seg.coords[-1]
            n = np.array([y0 - y1, x1 - x0]) / max(seg.length, 1e-9)
            for g in (gi, footprints[j]):
                for _ in range(cuts):
                    off = n * rng.uniform(1.5, 4.0) * rng.choice([-1.0, 1.0])
                    line = affinity.scale(affinity.translate(seg, off[0], off[1]), 3.0, 3.0)
                    c = line.intersection(g)
                    if c.is_empty or c.geom_type != "LineString" or c.length < 3:
                        continue
                    halves = sorted(getattr(g.difference(line.buffer(0.01)), "geoms", []), key=lambda h: -h.area)
                    if len(halves) >= 2:
                        st = steps(c, halves[0], halves[1])
                        if st is not None:
                            cut.append(st)
    out: dict[str, Any] = {"borders": len(border), "cuts": len(cut)}
    if not border or not cut:
        return out
    b, r = np.asarray(border), np.asarray(cut)
    for k, name in ((0, "height"), (1, "intensity")):
        out[name] = {"border_p50_p75_p90": [float(np.percentile(b[:, k], q)) for q in (50, 75, 90)],
                     "cut_p50_p75_p90": [float(np.percentile(r[:, k], q)) for q in (50, 75, 90)],
                     "auc": float(np.mean(b[:, k][:, None] > r[:, k][None, :])
                                  + 0.5 * np.mean(b[:, k][:, None] == r[:, k][None, :]))}
    return out


def delft_border_cues(data_dir: str) -> dict[str, Any]:
    """:func:`border_cues` on Delft: the reference footprints of ``testarea.city.json`` and the last returns
    of the building points (ASPRS class 6) of the AHN3 tiles."""
    from pathlib import Path

    from citylod.io.city.read import read_city_model
    from citylod.io.las import iter_points

    d = Path(data_dir)
    rows = []
    for f in sorted(d.glob("ahn3_*.laz")):
        for p in iter_points(f, raw=True):
            keep = (np.asarray(p.classification) == 6) & (np.asarray(p.return_number) == np.asarray(p.number_of_returns))
            rows.append(np.column_stack([np.asarray(a, np.float64)[keep] for a in (p.x, p.y, p.z, p.intensity)]))
    truth = _footprints(read_city_model(d / "testarea.city.json", lod=1))
    return border_cues([g for _, g, _ in truth], np.concatenate(rows))


def plot_delft(tif: str, truth: list[tuple[str, Any, float | None]], derived: list[tuple[str, Any, float | None]],
               per: list[dict[str, Any]], path: str, ceiling: dict[str, float] | None = None) -> None:
    """Left: the DSM around the reference buildings in grey, their footprints in cyan with each one's IoU
    and reference / derived height, the derived footprints in red. Right: derived against reference heights
    coloured by IoU, and ``ceiling`` (id → height from the points in the reference footprint) as crosses
    (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import rasterio

    with rasterio.open(tif) as ds:
        dsm, b = ds.read(1), ds.bounds
    dsm = np.where(dsm < -1000, np.nan, dsm)
    score = {p["id"]: p for p in per}
    x0 = min(g.bounds[0] for _, g, _ in truth) - 5
    y0 = min(g.bounds[1] for _, g, _ in truth) - 5
    x1 = max(g.bounds[2] for _, g, _ in truth) + 5
    y1 = max(g.bounds[3] for _, g, _ in truth) + 5
    fig, (ax, hx) = plt.subplots(1, 2, figsize=(23, 16 * (y1 - y0) / (x1 - x0)),
                                 gridspec_kw={"width_ratios": [16, 7]})
    ref_h = np.array([p["height"] for p in per], float)
    der_h = np.array([np.nan if p["derived_height"] is None else p["derived_height"] for p in per], float)
    iou = np.array([p["iou"] for p in per], float)
    sc = hx.scatter(ref_h, der_h, c=iou, cmap="viridis", vmin=0, vmax=1, s=18)
    lim = [0, float(np.nanmax(np.concatenate([ref_h, der_h]))) + 1]
    hx.plot(lim, lim, "k-", lw=0.8)
    hx.fill_between(lim, [v - 1 for v in lim], [v + 1 for v in lim], color="0.85", zorder=0)
    if ceiling:
        ch = np.array([ceiling.get(p["id"], np.nan) for p in per], float)
        hx.scatter(ref_h, ch, marker="x", color="tab:red", s=14, lw=0.8,
                   label="class-6 points' 90th percentile in the reference footprint")
        hx.legend(loc="upper left", fontsize=8)
    hx.set_xlim(lim)
    hx.set_ylim(lim)
    hx.set_aspect("equal")
    hx.set_xlabel("reference measuredHeight (m)")
    hx.set_ylabel("derived height of the best-overlapping footprint (m)")
    hx.set_title("heights (grey: within 1 m; colour: IoU)")
    fig.colorbar(sc, ax=hx, shrink=0.5, label="IoU")
    ax.imshow(dsm, extent=(b.left, b.right, b.bottom, b.top), cmap="gray", vmin=-1, vmax=16, interpolation="nearest")
    for _, g, _ in derived:
        for poly in getattr(g, "geoms", [g]):
            ax.plot(*poly.exterior.xy, "-", color="tab:red", lw=1.0)
    for k, g, _ in truth:
        for poly in getattr(g, "geoms", [g]):
            ax.plot(*poly.exterior.xy, "-", color="c", lw=1.2)
        if k in score:
            sc = score[k]
            dh = "–" if sc["derived_height"] is None else f"{sc['derived_height']:.1f}"
            ax.text(g.centroid.x, g.centroid.y, f"{sc['iou']:.2f}\n{sc['height']:.1f}/{dh}", fontsize=5,
                    ha="center", va="center", color="yellow")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_title("Delft: reference footprints (cyan; IoU, reference/derived height in m) and derived ones (red)")
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def delft(data_dir: str, out_dir: str, *, spacing: float = 0.5, progress: bool = False,
          plot: str | None = None) -> dict[str, Any]:
    """Rasterise the two AHN3 tiles at ``spacing``, build the model, and compare the derived buildings with
    ``testarea.city.json`` (:func:`footprint_scores`: the asked per-building IoU and heights, and the
    block-wise IoU as a second measure). Two further, labelled, diagnostics of the heights: the reference
    heights reproduced within 1 m by the 90th percentile of the class-6 points inside the *reference*
    footprints (the ceiling this point cloud allows), and by the derived DSM's 90th percentile inside the
    reference footprints above the derived ground (the rasterisation and ground estimate alone)."""
    from pathlib import Path

    from shapely.geometry import box

    from citylod.io.city.read import read_city_model
    from citylod.io.raster import read_info
    from citylod.lod.build.model import build_model, rasterize_las

    d = Path(data_dir)
    out = Path(out_dir)
    las = sorted(str(f) for f in d.glob("ahn3_*.laz"))
    tif = rasterize_las(las, out / "delft_dsm.tif", spacing=spacing, crs="EPSG:28992")
    rep = build_model(tif, out / "model", workers=0, progress=progress)
    derived = _footprints(read_city_model(out / "model" / "buildings.city.json", lod=1))
    ref_model = read_city_model(d / "testarea.city.json", lod=1)
    truth = _footprints(ref_model)
    info = read_info(tif)
    a, _, c, _, e, f = info.transform
    extent = box(c, f + e * info.height, c + a * info.width, f).buffer(-2.0)
    res = footprint_scores(truth, derived, extent)
    res.update(triangles=rep.triangles, samples=rep.samples, seconds=rep.seconds)
    # diagnostics of the heights, under the reference footprints
    import rasterio
    from rasterio.features import geometry_mask

    base = {o.id: float(o.points()[:, 2].min()) for o in ref_model.objects if o.type == "Building"}
    pts = reference_heights_from_points(truth, las, base)
    inside = {p["id"] for p in res["per_building"]}
    with rasterio.open(tif) as ds:
        dsm, gnd, tr = ds.read(1), ds.read(2), ds.transform
    ok_pts, ok_dsm = [], []
    for k, g, h in truth:
        if k not in inside or h is None:
            continue
        m = ~geometry_mask([g], dsm.shape, tr) & (dsm > -1000)
        if m.any():
            hd = float(np.percentile(dsm[m], 90) - np.percentile(gnd[m], 10))
            ok_dsm.append(abs(hd - h) <= 1.0)
        ok_pts.append(k in pts and abs(pts[k] - h) <= 1.0)
    res["heights_within_1m_points_in_reference_footprints"] = float(np.mean(ok_pts)) if ok_pts else float("nan")
    res["heights_within_1m_dsm_in_reference_footprints"] = float(np.mean(ok_dsm)) if ok_dsm else float("nan")
    if plot:
        plot_delft(str(tif), truth, derived, res["per_building"], plot, ceiling=pts)
    return res


def memory_run(work_dir: str, *, size: int = 20480, block: int = 1025, limit_mib: int = 1400, cell: int = 512,
               max_error: float = 0.5, seed: int = 7) -> dict[str, float]:
    """Build the model of a raster larger than the memory the build may use, and measure its peak.

    The raster is ``size``² float32 samples (tiled, deflate; 1.6 GiB as an array at the default size),
    no-data except a ``block``² window of the sample city at 0.5 m in its middle, so that the run takes
    minutes. ``citylod build model`` runs in a child process whose address space is capped at
    ``limit_mib`` MiB (``RLIMIT_AS``), in process (``--workers 0``); its peak resident memory is read
    from ``getrusage(RUSAGE_CHILDREN)``.
    """
    import resource
    import subprocess
    import sys
    from pathlib import Path

    import rasterio
    from affine import Affine
    from rasterio.windows import Window

    from citylod.sample.city import make_city

    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    tif = work / "big_dsm.tif"
    city = make_city(block, seed=seed, spacing=0.5)
    x, y = city.pixel_centers()
    F = city.surface_height(x, y)
    F = np.where(city.nodata_mask(x, y), -9999.0, F).astype(np.float32)
    off = (size - block) // 2
    with rasterio.open(tif, "w", driver="GTiff", width=size, height=size, count=1, dtype="float32",
                       crs="EPSG:32632", transform=Affine(0.5, 0, 500000.0, 0, -0.5, 5400000.0), nodata=-9999.0,
                       tiled=True, blockxsize=512, blockysize=512, compress="deflate") as ds:
        ds.write(F, 1, window=Window(off, off, block, block))
    limit = limit_mib * 1024 * 1024

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    cmd = [sys.executable, "-c", "import sys; from citylod.cli import main; sys.exit(main(sys.argv[1:]))", "-q", "build", "model", str(tif), "-o", str(work / "model"),
           "--workers", "0", "--cell", str(cell), "--max-error", str(max_error)]
    t = time.perf_counter()
    proc = subprocess.run(cmd, preexec_fn=cap, capture_output=True, text=True, check=False)
    secs = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    if proc.returncode != 0:
        raise RuntimeError(f"build failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return {"raster_samples": float(size * size), "raster_mib_float32": size * size * 4 / 2**20,
            "limit_mib": float(limit_mib), "peak_rss_mib": peak, "seconds": secs,
            "valid_samples": float(block * block), "vertices_per_second": block * block / secs}


def main(argv: list[str] | None = None) -> None:
    """``python -m citylod.bench.model_bench --size 385 --max-error 1.0``: the comparison as a table."""
    import argparse
    import tempfile

    from citylod.sample.city import make_city
    from citylod.sample.files import make_sample

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("--size", type=int, default=385)
    ap.add_argument("--spacing", type=float, default=0.5)
    ap.add_argument("--max-error", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--share", type=float, default=0.9, help="share of a segment's points within 0.5 m to keep it")
    ap.add_argument("--plot", help="PNG: the constrained mesh beside pymeshlab's at the same triangle count (with "
                    "--delft: the derived footprints over the reference ones)")
    ap.add_argument("--work", help="folder for temporary files (default: the system's; --delft keeps its raster "
                    "and model there)")
    ap.add_argument("--delft", help="folder with the AHN3 tiles and testarea.city.json: run the Delft check")
    ap.add_argument("--border-cues", action="store_true",
                    help="with --delft: instead, whether the borders between touching reference buildings show in "
                         "the roof points' height or intensity (border_cues)")
    ap.add_argument("--memory-cell", type=int,
                    help="instead: build the model of the sample DSM with cells of this many samples in this process "
                         "and print its peak resident memory")
    ap.add_argument("--memory-limit", type=int, metavar="MIB",
                    help="instead: build a 20480² raster (1.6 GiB as float32) in a child capped at MIB MiB of "
                         "address space and print its peak resident memory")
    a = ap.parse_args(argv)
    if a.border_cues and not a.delft:
        ap.error("--border-cues needs --delft DIR (the AHN3 tiles and testarea.city.json)")
    if a.memory_limit:
        with tempfile.TemporaryDirectory(dir=a.work) as tmp:
            print(memory_run(tmp, limit_mib=a.memory_limit))
        return
    if a.memory_cell:
        import resource

        from citylod.lod.build.model import build_model

        with tempfile.TemporaryDirectory() as tmp:
            info = make_sample(tmp, size=a.size, seed=a.seed, spacing=a.spacing)
            rep = build_model(info.files["dsm"], f"{tmp}/model", max_error=a.max_error, cell=a.memory_cell, workers=0,
                              progress=False)
        print(rep.summary())
        print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
        return
    if a.delft and a.border_cues:
        print(delft_border_cues(a.delft))
        return
    if a.delft:
        with tempfile.TemporaryDirectory() as tmp:
            res = delft(a.delft, a.work or tmp, progress=True, plot=a.plot)
        res.pop("per_building")
        print(res)
        return
    city = make_city(a.size, seed=a.seed, spacing=a.spacing)
    rows = compare(city, a.max_error, share=a.share, plot=a.plot)
    print(f"sample city {a.size}² at {a.spacing} m, {len(city.buildings)} buildings, ε = {a.max_error} m, "
          f"segment kept when {100 * a.share:g} % of its points are within 0.5 m")
    print(f"{'method':52s} {'triangles':>9s} {'kept':>6s} {'seconds':>8s} {'Hausdorff (sampled)':>20s}")
    for r in rows:
        print(f"{r.method:52s} {r.triangles:9d} {100 * r.kept:5.1f}% {r.seconds:8.1f} {r.hausdorff_sampled:20.3f}")
    print(f"throughput of the constrained run: {a.size * a.size / rows[1].seconds:,.0f} vertices/s")
    with tempfile.TemporaryDirectory() as tmp:
        info = make_sample(tmp, size=a.size, seed=a.seed, spacing=a.spacing)
        leaves = tile_tree_leaf_triangles(str(info.files["dsm"]), f"{tmp}/dsm", a.max_error)
    print(f"DSM tile tree leaves at the same bound: {leaves} triangles, "
          f"{leaves / rows[1].triangles:.2f}x the constrained model")


if __name__ == "__main__":
    main()
