"""Camera-cloud to LiDAR-cloud augmentations (training/augment.py)."""

from __future__ import annotations

import numpy as np

from _street import street
from training.augment import augment_masks, ring_mask, synthetic_mover


def _cloud(n=20000, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-10, 10, n), rng.uniform(-3, 1.6, n), rng.uniform(3, 40, n)], 1)


def test_all_off_keeps_everything_and_draws_nothing():
    rng = np.random.default_rng(5)
    pc = _cloud()
    k1, k2 = augment_masks(rng, pc, pc)
    assert k1.all() and k2.all()
    assert rng.random() == np.random.default_rng(5).random()


def test_rings_keep_points_near_rings_in_both_frames():
    pc1, pc2 = _cloud(seed=1), _cloud(seed=2)
    k1, k2 = augment_masks(np.random.default_rng(0), pc1, pc2, lidar_rings=1.0, ring_band=0.3)
    # about the band's share survives; all kept points lie within the band of one ring spacing
    assert 0.2 < k1.mean() < 0.4 and 0.2 < k2.mean() < 0.4
    elev = np.degrees(np.arctan2(-pc1[:, 1], np.hypot(pc1[:, 0], pc1[:, 2])))
    kept = np.sort(elev[k1])
    # the kept elevations form separated bands: gaps of at least (1 - band) * 0.3° between rings
    gaps = np.diff(kept)
    assert gaps.max() >= 0.7 * 0.3 - 1e-9
    assert ring_mask(pc1, 0.4, 0.0, 1.0).all()


def test_density_drop_thins_frame_two_only_and_ground_jitter_cuts_low_points():
    pc1, pc2 = _cloud(seed=3), _cloud(seed=4)
    k1, k2 = augment_masks(np.random.default_rng(1), pc1, pc2, density_drop=0.9)
    assert k1.all() and k2.mean() < 1.0
    k1, k2 = augment_masks(np.random.default_rng(1), pc1, pc2, ground_jitter_m=0.5)
    cut = np.percentile(pc1[:, 1], 99.0)
    assert pc1[k1, 1].max() <= cut and pc2[k2, 1].max() <= cut and k1.mean() > 0.8


def test_an_augmentation_that_would_empty_a_cloud_is_skipped():
    tiny = _cloud(n=80)
    k1, k2 = augment_masks(np.random.default_rng(0), tiny, tiny, lidar_rings=1.0, ring_band=0.05)
    assert k1.all() and k2.all()


def test_speed_scaled_view_keeps_frame_t1_and_scales_the_motion():
    """A = T'^-1 T: moving frame t's points by A turns the ego-motion into T' = scale x T (angle and
    translation), and every static point still lands where T put it in frame t+1."""
    from core.geometry import pose_vec_to_mat, rotation_angle, transform_points
    from training.augment import speed_scaled_view

    T = pose_vec_to_mat(np.array([0.1, -0.02, 1.1, 0.004, 0.03, -0.002]))
    pts = np.random.default_rng(0).uniform(-10, 30, size=(50, 3))
    for scale in (0.5, 1.0, 1.7):
        A = speed_scaled_view(T, scale)
        T_new = T @ np.linalg.inv(A)  # the motion from the moved camera t to camera t+1
        assert np.allclose(T_new[:3, 3], scale * T[:3, 3], atol=1e-9)
        assert np.isclose(rotation_angle(T_new[:3, :3]), scale * rotation_angle(T[:3, :3]), atol=1e-9)
        moved = transform_points(A, pts)
        assert np.allclose(transform_points(T_new, moved), transform_points(T, pts), atol=1e-9)
    assert np.allclose(speed_scaled_view(T, 1.0), np.eye(4), atol=1e-12)


def test_draw_speed_scale_is_log_uniform_and_off_draws_nothing():
    from training.augment import draw_speed_scale

    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    assert draw_speed_scale(rng, 1.0, 1.0) == 1.0 and rng.bit_generator.state == state
    s = np.array([draw_speed_scale(rng, 0.5, 2.0) for _ in range(4000)])
    assert s.min() >= 0.5 and s.max() <= 2.0
    # log-uniform on [1/2, 2]: half the draws below 1 (binomial sd 0.008 at n=4000; 5 sd margin)
    assert abs((s < 1.0).mean() - 0.5) < 0.04


def test_synthetic_mover_moves_one_cluster_rigidly_along_the_ground():
    """The moved cluster is one of the objects, turned by at most 5° about the vertical through its centroid
    and shifted horizontally by a length in the drawn range; no cluster, no mover."""
    pts, boxes = street(np.random.default_rng(1))
    for seed in range(20):
        idx, at = synthetic_mover(np.random.default_rng(seed), pts, (0.5, 1.5))
        assert any(np.array_equal(np.sort(idx), b) for b in boxes)
        old = pts[idx]
        shift = at.mean(0) - old.mean(0)
        assert abs(shift[1]) < 1e-9 and 0.5 - 1e-9 <= np.linalg.norm(shift) <= 1.5 + 1e-9
        assert np.allclose(at[:, 1], old[:, 1])  # heights kept: a turn about y, a shift in x-z
        a, b = old - old.mean(0), at - at.mean(0)
        u, _, vt = np.linalg.svd(b.T @ a)
        R = u @ vt
        assert np.allclose(b, a @ R.T, atol=1e-9)  # rigid
        assert abs(np.degrees(np.arctan2(R[0, 2], R[0, 0]))) <= 5.0 + 1e-9
    assert synthetic_mover(np.random.default_rng(0), pts[270:2270], (0.5, 1.5)) is None  # the wall alone
