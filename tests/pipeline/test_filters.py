"""The four stage-one filters: hand-computed cases, then each filter's claim on the synthetic world."""

from __future__ import annotations

import math

import numpy as np

from pipeline.cache.points import canonical_depth, points_from_depth
from pipeline.filters import (
    KITTI_DEFAULT_VELO_TO_CAM,
    FilterConfig,
    far_keep,
    ground_keep,
    lidar_keep,
    occlusion_keep,
    sample_depth,
)
from core.geometry import se3_inverse, transform_points
from pipeline.pairs import build_pair, valid_pixels



# --------------------------------------------------------------------------- ground / far


def test_ground_and_far_thresholds_are_strict():
    pts = np.array([[0, 1.14, 5], [0, 1.15, 5], [0, 2.0, 5], [0, -3.0, 34.99], [0, 0, 35.0], [0, 0, 80.0]])
    assert ground_keep(pts, 1.15).tolist() == [True, False, False, True, True, True]
    assert far_keep(pts, 35.0).tolist() == [True, True, True, True, False, False]
    assert ground_keep(pts, 2.5).all()  # threshold is an option


# --------------------------------------------------------------------------- LiDAR range


def _cam_point(elev_deg: float, dist: float, T=KITTI_DEFAULT_VELO_TO_CAM) -> np.ndarray:
    """Camera-frame point at ``dist`` metres straight ahead of the scanner, ``elev_deg`` above its horizon."""
    e = math.radians(elev_deg)
    velo = np.array([[dist * math.cos(e), 0.0, dist * math.sin(e)]])
    return transform_points(np.asarray(T), velo)


def test_lidar_keep_elevation_and_range_with_default_mount():
    # The default mount puts the scanner at (+0.06, -0.08, -0.27) in the image_2 frame, axes swapped.
    assert np.allclose(transform_points(KITTI_DEFAULT_VELO_TO_CAM, np.zeros((1, 3))), [[0.06, -0.08, -0.27]])
    cases = [(0.0, 10, True), (1.9, 10, True), (2.1, 10, False), (-24.7, 10, True), (-24.9, 10, False),
             (0.0, 119.9, True), (0.0, 120.1, False)]
    pts = np.concatenate([_cam_point(e, d) for e, d, _ in cases])
    assert lidar_keep(pts).tolist() == [k for _, _, k in cases]
    # Thresholds are options.
    assert lidar_keep(pts, max_elevation_deg=3.0, max_range=200.0).tolist() == [True, True, True, True, False, True, True]


def test_lidar_keep_uses_the_given_mount():
    T = KITTI_DEFAULT_VELO_TO_CAM.copy()
    T[1, 3] -= 1.0  # scanner 1 m higher
    p = _cam_point(1.0, 10.0, T)  # 1° above the horizon of the raised scanner
    assert lidar_keep(p, T).tolist() == [True]
    # Seen from the default (lower) mount the same point is ≈ 6.6° up: out of the fan.
    assert lidar_keep(p).tolist() == [False]


# --------------------------------------------------------------------------- occlusion


def test_sample_depth_bilinear_over_valid_neighbours():
    d = np.array([[2.0, 4.0, 0.0], [6.0, 8.0, 0.0]], dtype=np.float32)
    vals, ok = sample_depth(d, np.array([[0.5, 0.0], [0.5, 0.5], [1.5, 0.0], [2.0, 1.0], [-0.1, 0.0], [0.0, 1.2]]))
    assert ok.tolist() == [True, True, True, False, False, False]
    assert np.allclose(vals[:3], [3.0, 5.0, 4.0])  # (1.5, 0): only the valid left neighbour counts


def _plane(depth: float, H=20, W=30) -> np.ndarray:
    return np.full((H, W), depth, dtype=np.float32)


K_SMALL = np.array([[20.0, 0, 14.5], [0, 20.0, 9.5], [0, 0, 1]])


def test_occlusion_threshold_on_hand_computed_ratios():
    d_t = _plane(10.0)
    idx = valid_pixels(d_t)
    pts = points_from_depth(d_t, idx, K_SMALL)
    eye = np.eye(4)
    assert occlusion_keep(pts, eye, d_t, K_SMALL).all()  # same surface: |10-10|/20 = 0
    # An occluder at 4 m: |10-4|/14 = 0.43 < 0.5 kept; at 3 m: 7/13 = 0.54 removed; threshold configurable.
    assert occlusion_keep(pts, eye, _plane(4.0), K_SMALL).all()
    assert not occlusion_keep(pts, eye, _plane(3.0), K_SMALL).any()
    assert not occlusion_keep(pts, eye, _plane(4.0), K_SMALL, threshold=0.4).any()
    # A 0.5 m sideways camera motion at 10 m shifts pixels by 1 px: the first column leaves the image.
    T = np.eye(4)
    T[0, 3] = -0.5
    keep = occlusion_keep(pts, T, d_t, K_SMALL).reshape(20, 30)
    assert not keep[:, 0].any() and keep[:, 1:].all()
    # Moving 20 m forward puts everything behind the camera.
    T = np.eye(4)
    T[2, 3] = -20.0
    assert not occlusion_keep(pts, T, d_t, K_SMALL).any()


def test_occlusion_removes_a_half_hidden_patch():
    d_t = _plane(10.0)
    d_t1 = _plane(10.0)
    d_t1[5:10, 5:12] = 2.0  # something near the camera in frame t+1 hides these pixels
    pts = points_from_depth(d_t, valid_pixels(d_t), K_SMALL)
    keep = occlusion_keep(pts, np.eye(4), d_t1, K_SMALL).reshape(20, 30)
    assert not keep[5:10, 5:12].any()
    assert keep.sum() == 20 * 30 - 5 * 7


# --------------------------------------------------------------------------- on the synthetic world


def _pair(seq, i: int, filters: FilterConfig):
    from pipeline.sources import GroundTruthDepth, read_gt_flow

    H, W = seq.image_shape
    d = canonical_depth(GroundTruthDepth().depths(seq, [i, i + 1], np.zeros((2, H, W, 3), np.uint8), seq.K))
    T = seq.relative_pose(i, i + 1)
    gt = read_gt_flow(seq, i, (H, W))
    rec = build_pair(seq.frames[i], seq.frames[i + 1], d[0], d[1], T, seq.K, filters,
                     T_velo_to_cam=seq.T_velo_to_cam, gt=gt)
    return d, T, gt, rec


def test_each_filter_removes_what_it_claims_on_synthetic_world(synth_root):
    from pipeline.kitti.odometry import OdometrySequence

    seq = OdometrySequence(synth_root, "00")
    assert seq.T_velo_to_cam is not None
    Tvc_inv = se3_inverse(seq.T_velo_to_cam)
    for i in range(3):
        d, T, gt, rec = _pair(seq, i, FilterConfig())
        p1 = points_from_depth(d[0], rec.idx1, seq.K)
        p2 = points_from_depth(d[1], rec.idx2, seq.K)
        for p in (p1, p2):
            assert len(p) > 500
            assert p[:, 1].max() < 1.15 and p[:, 2].max() < 35.0
            v = transform_points(Tvc_inv, p.astype(np.float64))
            elev = np.degrees(np.arctan2(v[:, 2], np.hypot(v[:, 0], v[:, 1])))
            assert elev.max() <= 2.0 and elev.min() >= -24.8 and np.linalg.norm(v, axis=1).max() <= 120.0
        # Every stage removes something here, and the counts are monotone.
        names = ["valid", "ground", "far", "lidar", "occlusion"]
        c1 = [rec.stats[f"pc1_{n}"] for n in names]
        assert all(a > b for a, b in zip(c1[:-1], c1[1:])), c1
        assert rec.stats["pc1_occlusion"] == len(rec.idx1) and rec.stats["pc2_occlusion"] == len(rec.idx2)
        # Ground truth rides along with the kept points.
        assert rec.gt_flow.shape == (len(rec.idx1), 3) and rec.moving.shape == (len(rec.idx1),)


def test_switched_off_filters_keep_every_valid_pixel(synth_root):
    from pipeline.kitti.odometry import OdometrySequence

    seq = OdometrySequence(synth_root, "00")
    off = FilterConfig(ground=False, far=False, lidar=False, occlusion=False)
    d, _, _, rec = _pair(seq, 0, off)
    assert np.array_equal(rec.idx1, valid_pixels(d[0])) and np.array_equal(rec.idx2, valid_pixels(d[1]))
    only_ground = FilterConfig(far=False, lidar=False, occlusion=False)
    _, _, _, rec_g = _pair(seq, 0, only_ground)
    assert set(rec_g.stats) == {"pc1_valid", "pc1_ground", "pc1_gt", "pc2_valid", "pc2_ground"}


def test_occlusion_recall_on_ground_truth_visibility(synth_root):
    """Static points that the ground truth marks not visible at t+1 (occluded or out of view) are removed.

    With exact depth, a tight threshold (0.1) finds ≥ 90 % of them while removing < 2 % of visible ones.
    The paper's 0.5 only flags occluders nearer than a third of the depth (|a−b|/(a+b) ≥ 0.5 ⇔ a ≥ 3b),
    so its recall depends on the scene (0.86–0.97 over 5-frame synthetic worlds of seeds 0–5; 0.91 on this
    one): it is held to 0.85 here, and to removing < 0.1 % of the visible static points.
    """
    from pipeline.kitti.odometry import OdometrySequence

    seq = OdometrySequence(synth_root, "00")
    only_occ = dict(ground=False, far=False, lidar=False)
    for thr, min_recall, max_false in ((0.1, 0.9, 0.02), (0.5, 0.85, 0.001)):
        hidden = caught = visible = wrong = 0
        for i in range(len(seq) - 1):
            d, T, gt, rec = _pair(seq, i, FilterConfig(**only_occ, occlusion_threshold=thr))
            idx = valid_pixels(d[0])
            kept = np.isin(idx, rec.idx1)
            vis = gt.visible_next.reshape(-1)[idx]
            static = ~gt.moving.reshape(-1)[idx]
            hidden += np.count_nonzero(~vis & static)
            caught += np.count_nonzero(~vis & static & ~kept)
            visible += np.count_nonzero(vis & static)
            wrong += np.count_nonzero(vis & static & ~kept)
        assert hidden > 1000
        assert caught / hidden >= min_recall, (thr, caught / hidden)
        assert wrong / visible < max_false, (thr, wrong / visible)
