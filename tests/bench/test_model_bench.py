"""The Delft comparison's scores on footprints whose answers are known by hand."""

from __future__ import annotations

from shapely.geometry import box

from citylod.bench.model_bench import footprint_scores


def test_footprint_scores_per_building_and_per_block() -> None:
    # two terraced houses 5 × 10 m side by side, and a shed far away; derived: one footprint over the whole
    # row (0.2 m short at one end, simplified apart into two pieces 0.3 m apart) and nothing at the shed
    truth = [("a", box(0, 0, 5, 10), 9.0), ("b", box(5, 0, 10, 10), 9.5), ("shed", box(30, 0, 33, 3), 2.5),
             ("outside", box(200, 0, 210, 10), 5.0)]
    derived = [("d1", box(0.2, 0, 6.0, 10), 9.3), ("d2", box(6.3, 0, 10, 10), 10.8)]
    res = footprint_scores(truth, derived, box(-5, -5, 100, 100))
    per = {p["id"]: p for p in res["per_building"]}
    assert res["reference_buildings"] == 3  # "outside" is not inside the extent
    # a: IoU with d1 = 4.8·10 / (5·10 + 1·10) = 0.8; b: with d2 = 3.7 / 5 = 0.74
    assert abs(per["a"]["iou"] - 0.8) < 1e-9 and abs(per["b"]["iou"] - 0.74) < 1e-9
    assert per["shed"]["iou"] == 0.0 and per["shed"]["derived_height"] is None
    assert abs(res["median_iou"] - 0.74) < 1e-9
    # heights: a 0.3 m off (within 1 m), b 1.3 m off, the shed unmatched
    assert abs(res["heights_within_1m"] - 1 / 3) < 1e-9
    # blocks: the row (d1 and d2 touch within 0.5 m: one derived block 0.2..10) and the shed
    assert res["blocks"] == 2
    assert abs(res["median_block_iou"] - 0.5 * (9.8 / 10 + 0.0)) < 1e-3


def test_border_cues_find_a_border_only_in_the_cue_that_marks_it() -> None:
    """A row of three 6 × 10 m houses under one flat roof with height noise, each with its own roof
    intensity: the intensity steps at the two borders exceed every cut inside a house (AUC 1), the height
    steps do not (AUC near 0.5)."""
    import numpy as np

    from citylod.bench.model_bench import border_cues

    rng = np.random.default_rng(3)
    houses = [box(6.0 * k, 0.0, 6.0 * (k + 1), 10.0) for k in range(3)]
    x, y = rng.uniform(0, 18, 20000), rng.uniform(0, 10, 20000)
    z = 8.0 + rng.normal(0, 0.05, x.size)
    inten = np.choose(np.minimum((x // 6).astype(int), 2), [60.0, 140.0, 90.0]) + rng.normal(0, 5, x.size)
    res = border_cues(houses, np.column_stack([x, y, z, inten]))
    assert res["borders"] == 2 and res["cuts"] >= 4
    assert res["intensity"]["auc"] == 1.0
    assert min(res["intensity"]["border_p50_p75_p90"]) > 40 > max(res["intensity"]["cut_p50_p75_p90"])
    assert 0.1 < res["height"]["auc"] < 0.9
