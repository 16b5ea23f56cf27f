"""Golden tests of the scene-flow metrics: values worked out by hand below."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.metrics import aggregate, mean_over_runs, point_errors, scene_metrics

# A hand-built scene of four points; ground-truth flows (metres) and their norms:
GT = np.array(
    [
        [1.0, 0.0, 0.0],  # |g| = 1
        [0.0, 0.04, 0.0],  # |g| = 0.04
        [0.0, 0.0, 2.0],  # |g| = 2
        [0.3, 0.4, 0.0],  # |g| = 0.5
    ]
)


def test_zero_flow_golden() -> None:
    m = scene_metrics(np.zeros_like(GT), GT)
    # EPE = |g| = 1, 0.04, 2, 0.5  ->  mean = 3.54 / 4 = 0.885
    assert m["EPE3D"] == pytest.approx(3.54 / 4, abs=1e-12)
    # rel = |g| / (|g| + 1e-4) ≈ 1 for every point, so only EPE can make a point accurate:
    # point 2 has EPE 0.04 < 0.05 (strict) and < 0.1 (relaxed); no other point has EPE < 0.1.
    assert m["Acc3DS"] == pytest.approx(1 / 4)
    assert m["Acc3DR"] == pytest.approx(1 / 4)
    # every rel ≈ 1 > 0.1, so every point is an outlier
    assert m["Outliers3D"] == pytest.approx(1.0)
    assert m["n_points"] == 4
    assert "moving" not in m and "static" not in m


def test_constant_flow_golden() -> None:
    pred = np.tile([0.0, 0.0, 1.92], (4, 1))
    m = scene_metrics(pred, GT)
    # f − g per point:
    #   1: (−1, 0, 1.92)      EPE = sqrt(1 + 1.92²)            = sqrt(4.6864)
    #   2: (0, −0.04, 1.92)   EPE = sqrt(0.04² + 1.92²)        = sqrt(3.688)
    #   3: (0, 0, −0.08)      EPE = 0.08, rel = 0.08 / 2.0001 ≈ 0.04
    #   4: (−0.3, −0.4, 1.92) EPE = sqrt(0.09 + 0.16 + 1.92²)  = sqrt(3.9364)
    epe = [np.sqrt(4.6864), np.sqrt(3.688), 0.08, np.sqrt(3.9364)]
    assert m["EPE3D"] == pytest.approx(sum(epe) / 4, abs=1e-9)
    assert m["EPE3D"] == pytest.approx((2.1648095 + 1.9204166 + 0.08 + 1.9840363) / 4, abs=1e-6)
    # only point 3 is accurate: strict because rel 0.04 < 0.05 (EPE 0.08 ≥ 0.05), relaxed by EPE 0.08 < 0.1
    assert m["Acc3DS"] == pytest.approx(0.25)
    assert m["Acc3DR"] == pytest.approx(0.25)
    # points 1, 2, 4 have EPE > 0.3; point 3 has EPE 0.08 ≤ 0.3 and rel 0.04 ≤ 0.1
    assert m["Outliers3D"] == pytest.approx(0.75)


def test_each_branch_of_the_definitions() -> None:
    gt = np.array([[0, 0, 10.0], [0, 0.02, 0], [0.5, 0, 0], [0, 0, 0]])
    pred = np.array([[0, 0, 10.7], [0, 0.1, 0], [0.53, 0, 0], [0, 0, 0.2]])
    # A: EPE 0.7, rel 0.7/10.0001 ≈ 0.07  -> strict no, relaxed yes (rel < 0.1), outlier yes (EPE > 0.3)
    # B: EPE 0.08, rel 0.08/0.0201 ≈ 3.98 -> strict no, relaxed yes (EPE < 0.1), outlier yes (rel > 0.1)
    # C: EPE 0.03, rel 0.03/0.5001 ≈ 0.06 -> strict yes (EPE < 0.05), relaxed yes, outlier no
    # D: EPE 0.2, rel 0.2/1e-4 = 2000     -> strict no, relaxed no, outlier yes
    err = point_errors(pred, gt)
    np.testing.assert_allclose(err["epe"], [0.7, 0.08, 0.03, 0.2], atol=1e-12)
    np.testing.assert_allclose(err["rel"], [0.7 / 10.0001, 0.08 / 0.0201, 0.03 / 0.5001, 0.2 / 1e-4], rtol=1e-9)
    assert err["acc_strict"].tolist() == [False, False, True, False]
    assert err["acc_relax"].tolist() == [True, True, True, False]
    assert err["outlier"].tolist() == [True, True, False, True]
    m = scene_metrics(pred, gt)
    assert m["EPE3D"] == pytest.approx(1.01 / 4)
    assert (m["Acc3DS"], m["Acc3DR"], m["Outliers3D"]) == pytest.approx((0.25, 0.75, 0.75))


def test_mask_and_moving_subsets() -> None:
    gt = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0]])
    pred = np.array([[0, 0, 1.0], [0, 0, 1.2], [0, 0, 1.5], [0, 0, 9.0]])  # EPE 0, 0.2, 0.5, 8
    moving = np.array([False, True, True, False])
    mask = np.array([True, True, True, False])  # the EPE-8 point is not scored
    m = scene_metrics(pred, gt, mask=mask, moving=moving)
    assert m["n_points"] == 3
    assert m["EPE3D"] == pytest.approx((0 + 0.2 + 0.5) / 3)
    assert m["static"]["n_points"] == 1 and m["static"]["EPE3D"] == pytest.approx(0.0)
    assert m["moving"]["n_points"] == 2 and m["moving"]["EPE3D"] == pytest.approx(0.35)
    # a scene without moving points has no "moving" entry
    m2 = scene_metrics(pred, gt, moving=np.zeros(4, bool))
    assert "moving" not in m2 and m2["static"]["n_points"] == 4


def test_aggregate_is_mean_per_scene_then_over_scenes() -> None:
    # scene 1: three points with EPE 0.1; scene 2: one point with EPE 0.5 (different sizes)
    gt1, pred1 = np.zeros((3, 3)), np.tile([0.1, 0, 0], (3, 1))
    gt2, pred2 = np.zeros((1, 3)), np.array([[0, 0.5, 0]])
    s1 = scene_metrics(pred1, gt1, moving=np.array([True, False, False]))
    s2 = scene_metrics(pred2, gt2, moving=np.array([False]))
    agg = aggregate([s1, s2])
    # per scene 0.1 and 0.5 -> 0.3 over scenes (pooling the four points would give 0.8 / 4 = 0.2)
    assert agg["EPE3D"] == pytest.approx(0.3)
    assert agg["EPE3D"] != pytest.approx(0.2)
    assert agg["n_scenes"] == 2 and agg["n_points"] == 4
    # outliers: gt = 0 makes rel huge, so all points are outliers in both scenes
    assert agg["Outliers3D"] == pytest.approx(1.0)
    # only scene 1 has moving points: the moving subset averages scene 1 alone
    assert agg["moving"]["n_scenes"] == 1 and agg["moving"]["EPE3D"] == pytest.approx(0.1)
    # static: scene 1 (0.1, two points) and scene 2 (0.5) -> 0.3
    assert agg["static"]["n_scenes"] == 2 and agg["static"]["EPE3D"] == pytest.approx(0.3)
    with_std = aggregate([s1, s2], with_std=True)
    assert with_std["EPE3D_std"] == pytest.approx(0.2)  # population std of {0.1, 0.5}
    assert "EPE3D_std" not in agg


def test_mean_over_runs() -> None:
    runs = [{"EPE3D": 0.1, "Acc3DS": 0.5, "Acc3DR": 0.6, "Outliers3D": 0.4, "n_scenes": 2, "n_points": 9},
            {"EPE3D": 0.3, "Acc3DS": 0.7, "Acc3DR": 0.8, "Outliers3D": 0.2, "n_scenes": 2, "n_points": 9}]
    out = mean_over_runs(runs)
    assert out["EPE3D"] == pytest.approx(0.2) and out["EPE3D_std"] == pytest.approx(0.1)
    assert out["Acc3DS"] == pytest.approx(0.6) and out["n_runs"] == 2


def test_bad_inputs() -> None:
    with pytest.raises(ValueError, match="shape"):
        scene_metrics(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="no points"):
        scene_metrics(np.zeros((2, 3)), np.zeros((2, 3)), mask=np.zeros(2, bool))
    with pytest.raises(ValueError, match="mask"):
        scene_metrics(np.zeros((2, 3)), np.zeros((2, 3)), mask=np.ones(3, bool))
    with pytest.raises(ValueError, match="no scenes"):
        aggregate([])
