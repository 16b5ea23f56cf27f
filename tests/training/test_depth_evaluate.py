"""Depth and pose metrics of the depth/pose evaluation: hand-computed values and invariances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.geometry import euler_to_matrix, pose_vec_to_mat, se3_inverse
from training.depth.config import DepthEvalConfig
from training.depth.evaluate import (
    ate_snippets,
    chain_poses,
    depth_errors,
    garg_crop,
    kitti_segment_errors,
    relative_errors,
    score_depth,
    snippet_errors,
    spread,
    to_first,
)


def test_depth_errors_by_hand():
    gt = np.array([1.0, 2.0, 4.0])
    pred = np.array([1.0, 2.0, 2.0])
    e = depth_errors(gt, pred)
    assert e["abs_rel"] == pytest.approx((0 + 0 + 0.5) / 3)
    assert e["sq_rel"] == pytest.approx((0 + 0 + 4 / 4) / 3)
    assert e["rmse"] == pytest.approx(math.sqrt(4 / 3))
    assert e["rmse_log"] == pytest.approx(math.sqrt(math.log(2) ** 2 / 3))
    assert (e["a1"], e["a2"], e["a3"]) == pytest.approx((2 / 3, 2 / 3, 2 / 3))  # ratio 2 > 1.25³ = 1.95


def test_score_depth_is_median_scaled_and_resizes_the_prediction():
    rng = np.random.default_rng(0)
    gt = rng.uniform(2, 60, size=(8, 12)).astype(np.float32)
    gt[0, 0] = 0.0  # no ground truth here
    gt[1, 1] = 95.0  # beyond max_depth: ignored
    cfg = DepthEvalConfig()
    e = score_depth(gt * 0.125, gt, cfg)  # right up to scale
    assert e["abs_rel"] == pytest.approx(0.0, abs=1e-6) and e["a1"] == 1.0 and e["scale"] == pytest.approx(8.0)
    small = np.full((4, 6), 3.0, np.float32)  # constant prediction at half the size
    e = score_depth(small, gt, cfg)
    ok = (gt > 0) & (gt < 80)
    med = np.median(gt[ok])
    assert e["abs_rel"] == pytest.approx(np.mean(np.abs(gt[ok] - med) / gt[ok]), rel=1e-5)
    assert score_depth(small, np.zeros_like(gt), cfg) is None


def test_garg_crop_rows_and_columns():
    m = garg_crop(370, 1226)
    rows, cols = np.nonzero(m.any(axis=1))[0], np.nonzero(m.any(axis=0))[0]
    assert (rows[0], rows[-1]) == (int(0.40810811 * 370), int(0.99189189 * 370) - 1)
    assert (cols[0], cols[-1]) == (int(0.03594771 * 1226), int(0.96405229 * 1226) - 1)


def test_spread():
    assert spread(5, 10) == [0, 1, 2, 3, 4]
    assert spread(11, 3) == [0, 5, 10]


def forward_trajectory(n: int, step: float = 1.0, yaw_deg: float = 0.0) -> np.ndarray:
    """Camera-to-world poses of a camera driving along +z, ``step`` metres per frame, turning by yaw."""
    T_rel = pose_vec_to_mat(np.array([0.0, 0.0, -step, 0.0, math.radians(yaw_deg), 0.0]))  # T_{k→k+1}
    return chain_poses(np.repeat(T_rel[None], n - 1, axis=0))


def test_chain_poses_accumulates_camera_positions():
    poses = forward_trajectory(4, step=1.5)
    np.testing.assert_allclose(poses[:, :3, 3], [[0, 0, 0], [0, 0, 1.5], [0, 0, 3.0], [0, 0, 4.5]], atol=1e-12)
    np.testing.assert_allclose(to_first(poses[1:])[:, :3, 3], [[0, 0, 0], [0, 0, 1.5], [0, 0, 3.0]], atol=1e-12)


def test_snippet_errors_ignore_scale_and_see_rotation():
    gt = forward_trajectory(5, yaw_deg=2.0)
    pred = gt.copy()
    pred[:, :3, 3] *= 0.01  # right up to scale
    ate, re = snippet_errors(gt, pred)
    assert ate == pytest.approx(0.0, abs=1e-12) and re == pytest.approx(0.0, abs=1e-6)
    tilted = pred.copy()
    tilted[:, :3, :3] = tilted[:, :3, :3] @ euler_to_matrix(np.array([math.radians(1.0), 0, 0]))
    _, re = snippet_errors(gt, tilted)
    assert math.degrees(re) == pytest.approx(1.0, rel=1e-6)
    # prediction standing still: least-squares scale 1 on zeros, ATE = |positions| / n
    still = np.repeat(np.eye(4)[None], 5, axis=0)
    ate, _ = snippet_errors(forward_trajectory(5), still)
    assert ate == pytest.approx(math.sqrt(1 + 4 + 9 + 16) / 5)


def test_ate_snippets_of_an_exact_prediction_and_a_constant_offset():
    gt = forward_trajectory(9)
    rel = np.stack([se3_inverse(gt[k + 1]) @ gt[k] for k in range(8)])  # T_{k→k+1}
    out = ate_snippets(gt, rel * np.array([1, 1, 1, 1.0]), 5)
    assert out["ate_snippets"] == 5 and out["ate"] == pytest.approx(0.0, abs=1e-12)


def test_relative_errors_rotation_direction_and_scale():
    n = 6
    gt = np.repeat(pose_vec_to_mat(np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0]))[None], n, axis=0)
    pred = np.repeat(pose_vec_to_mat(np.array([0.0, 0.0, -0.1, 0.0, math.radians(0.5), 0.0]))[None], n, axis=0)
    e = relative_errors(gt, pred)
    assert e["rot_err_deg"] == pytest.approx(0.5, rel=1e-6) and e["rot_mag_gt_deg"] == pytest.approx(0.0, abs=1e-9)
    assert e["trans_dir_err_deg"] == pytest.approx(0.0, abs=1e-6) and e["trans_err"] == pytest.approx(0.0, abs=1e-12)
    sideways = np.repeat(pose_vec_to_mat(np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0]))[None], n, axis=0)
    e = relative_errors(gt, sideways)
    assert e["trans_dir_err_deg"] == pytest.approx(90.0) and e["trans_err"] == pytest.approx(1.0)  # best scale 0
    one_reversed = pred.copy()
    one_reversed[2, :3, 3] *= -1  # one of six pairs backwards: the mean is 30°, the median stays 0°
    e = relative_errors(gt, one_reversed)
    assert e["trans_dir_err_deg"] == pytest.approx(30.0) and e["trans_dir_err_median_deg"] == pytest.approx(0.0, abs=1e-6)


def test_kitti_segment_errors_of_a_lateral_drift():
    """Prediction drifts sideways by 10 % of the distance: after the least-squares scale s = 1/1.01 a segment
    that spans D metres is off by D·√(0.1² + 0.01²)/1.01. As in the devkit the segment ends at the first frame
    *beyond* first + L (D = L + 1 at 1 m per frame) and the error is divided by the nominal L."""
    gt = forward_trajectory(301)
    pred = gt.copy()
    pred[:, 0, 3] = 0.1 * pred[:, 2, 3]
    e = kitti_segment_errors(gt, pred, (100.0, 200.0))
    per_metre = math.sqrt(0.0101) / 1.01
    expect = (20 * per_metre * 101 / 100 + 10 * per_metre * 201 / 200) / 30
    assert e["t_rel_pct"] == pytest.approx(100 * expect, rel=1e-6)
    assert e["r_rel_deg_per_100m"] == pytest.approx(0.0, abs=1e-9)
    # segments start every 10 frames and need a frame *beyond* first + L: 20 of length 100, 10 of length 200
    assert e["segments"] == 20 + 10
    assert kitti_segment_errors(gt, gt * 1.0, (100.0,))["t_rel_pct"] == pytest.approx(0.0, abs=1e-9)
    assert kitti_segment_errors(gt[:50], gt[:50], (100.0,)) == {}
