"""core.view.ViewExtent: the field of view a cloud itself shows, for a camera frustum and for a surround sweep."""

from __future__ import annotations

import numpy as np

from core.view import ViewExtent


def _ring(az_deg: np.ndarray, rng: np.random.Generator, r: tuple[float, float] = (3.0, 40.0)) -> np.ndarray:
    """Points at the given azimuths (camera frame: x right, y down, z forward), ranges in ``r`` metres, heights ±1 m."""
    a = np.radians(az_deg)
    dist = rng.uniform(*r, len(a))
    return np.stack([dist * np.sin(a), rng.uniform(-1.0, 1.0, len(a)), dist * np.cos(a)], -1)


def test_a_frustum_shows_its_sector_ahead_cut_at_its_farthest_depth():
    rng = np.random.default_rng(0)
    cloud = _ring(rng.uniform(-40.0, 40.0, 3000), rng)
    view = ViewExtent.of(cloud)
    assert view.ahead
    probe = np.array([[0.0, 0.0, 10.0],      # straight ahead
                      [0.0, 0.0, -10.0],     # behind the camera
                      [20.0, 0.0, 10.0],     # 63° to the right: beyond the sector
                      [0.0, 0.0, 45.0],      # beyond its farthest depth
                      [0.0, -30.0, 10.0]])   # far above its highest elevation
    assert view.contains(probe).tolist() == [True, False, False, False, False]


def test_a_surround_sweep_shows_the_whole_circle_but_the_sector_it_has_no_return_in():
    """A 360° LiDAR sweep in camera axes (the OpenSceneFlow reader's): points behind the camera are in view; a sector
    with no return (here 100°–140°, an occluder beside the car) is not; the far cut is the horizontal range."""
    rng = np.random.default_rng(1)
    az = rng.uniform(-180.0, 180.0, 6000)
    az = az[(az < 100.0) | (az > 140.0)]
    view = ViewExtent.of(_ring(az, rng))
    assert not view.ahead
    probe = _ring(np.array([0.0, 180.0, -90.0, 90.0, -170.0, 120.0]), np.random.default_rng(2), r=(10.0, 20.0))
    far = np.array([[0.0, 0.0, -45.0]])  # behind, beyond the sweep's reach
    assert view.contains(probe).tolist() == [True, True, True, True, True, False]
    assert not view.contains(far).any()
