"""Camera-cloud to LiDAR-cloud augmentations (training/augment.py)."""

from __future__ import annotations

import numpy as np

from training.augment import augment_masks, ring_mask


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
