"""Scale recovery: LiDAR median ratio, camera-height road-plane fit, fixed / none, block combination."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.errors import ConfigError
from core.geometry import pixel_grid
from pipeline.scale import (
    ScaleConfig,
    ScaleError,
    camera_height_scale,
    combine_factors,
    fit_road_plane,
    frame_factor,
    lidar_scale,
    road_region_points,
)

SYNTH = dict(seed=0, width=208, height=64, n_sequences=1, frames=9, test_frames=0)
K = np.array([[120.0, 0.0, 103.5], [0.0, 120.0, 31.5], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="session")
def synth_root(tmp_path_factory):
    from pipeline.synth import SynthConfig, generate

    root = tmp_path_factory.getbasetemp() / "synth_w208_h64_s0_f9"
    generate(SynthConfig(**SYNTH), root)
    return root


def road_depth(height_m: float, pitch_deg: float = 0.0, H: int = 64, W: int = 208) -> np.ndarray:
    """Depth of a flat road ``height_m`` below a camera pitched down by ``pitch_deg``; a wall at 30 m elsewhere."""
    a = math.radians(pitch_deg)
    n = np.array([0.0, math.cos(a), -math.sin(a)])  # road normal (down) in camera coordinates
    uv = pixel_grid(H, W)
    rays = np.stack([(uv[..., 0] - K[0, 2]) / K[0, 0], (uv[..., 1] - K[1, 2]) / K[1, 1], np.ones((H, W))], -1)
    denom = rays @ n
    depth = np.full((H, W), 30.0)
    road = denom > 1e-3
    depth[road] = np.minimum(height_m / denom[road], 30.0)
    return depth.astype(np.float32)


def test_lidar_scale_is_the_median_ratio():
    depth = np.array([[1.0, 2.0, 4.0], [0.0, 5.0, 1.0]], dtype=np.float32)
    lidar = np.array([[3.0, 0.0, 10.0], [7.0, 10.0, 100.0]], dtype=np.float32)
    # Both valid at (0,0) 3, (0,2) 2.5, (1,1) 2, (1,2) 100 → median 2.75.
    assert lidar_scale(depth, lidar) == pytest.approx(2.75)
    with pytest.raises(ScaleError):
        lidar_scale(depth, np.zeros_like(lidar))


@pytest.mark.parametrize("pitch", [0.0, 3.0])
@pytest.mark.parametrize("factor", [0.3, 1.0, 4.0])
def test_camera_height_recovers_scale_of_a_flat_road(pitch, factor):
    depth = road_depth(1.65, pitch) * factor  # a monocular net's depth: metric × unknown factor
    depth[40:52, 90:120] = 6.0 * factor  # a car's back in the road region
    s = camera_height_scale(depth, K)
    assert s == pytest.approx(1.0 / factor, rel=0.01)


def test_camera_height_plane_is_level_and_below():
    cfg = ScaleConfig(mode="camera-height")
    plane = fit_road_plane(road_region_points(road_depth(2.0), K, cfg), cfg)
    assert plane.d == pytest.approx(2.0, rel=1e-3)
    assert np.allclose(plane.normal, [0, 1, 0], atol=1e-3)


def test_camera_height_fails_cleanly_without_a_road():
    wall = np.full((64, 208), 10.0, dtype=np.float32)  # a fronto-parallel wall: no level plane below
    with pytest.raises(ScaleError):
        camera_height_scale(wall, K)


def test_modes_none_fixed_and_config_checks():
    d = road_depth(1.65)
    assert frame_factor(ScaleConfig(mode="none"), d, K) == 1.0
    assert frame_factor(ScaleConfig(mode="fixed", factor=2.5), d, K) == 2.5
    with pytest.raises(ConfigError):
        frame_factor(ScaleConfig(mode="lidar"), d, K)  # no LiDAR depth given
    with pytest.raises(ConfigError):
        ScaleConfig(mode="stereo")
    with pytest.raises(ConfigError):
        ScaleConfig(mode="fixed", factor=-1.0)


def test_combine_factors_median_skips_failed_frames():
    assert combine_factors([2.0, float("nan"), 3.0, 10.0]) == 3.0
    with pytest.raises(ScaleError):
        combine_factors([float("nan")])


@pytest.mark.parametrize("factor", [0.37, 2.9])
def test_camera_height_on_synthetic_ground_truth_depth(synth_root, factor):
    from pipeline.kitti.odometry import OdometrySequence
    from pipeline.sources import GroundTruthDepth

    seq = OdometrySequence(synth_root, "00")
    H, W = seq.image_shape
    depths = GroundTruthDepth().depths(seq, [0, 3, 6], np.zeros((3, H, W, 3), np.uint8), seq.K)
    for d in depths:
        s = camera_height_scale(d * np.float32(factor), seq.K)
        assert s * factor == pytest.approx(1.0, rel=0.05)


def test_lidar_mode_on_real_kitti_object_scan(shared_data):
    """KITTI object frame 000008: a dense depth made from its scan, × an unknown factor, at 832×256;
    the LiDAR projected straight at that size gives the factor back (median ratio)."""
    import cv2
    from scipy import ndimage

    from core.geometry import camera_offset_from_projection, scale_intrinsics
    from pipeline.kitti.calib import read_object_calib
    from pipeline.kitti.images import image_size
    from pipeline.kitti.velodyne import read_velodyne_bin
    from pipeline.sources import project_lidar

    folder = shared_data / "kitti_object_000008"
    calib = read_object_calib(folder / "calib_000008.txt")
    scan = read_velodyne_bin(folder / "000008.bin")
    H0, W0 = image_size(folder / "000008.png")
    T = camera_offset_from_projection(calib.P["P2"]) @ calib.velo_to_cam_rect()
    K0 = calib.P["P2"][:, :3]
    native = project_lidar(scan, T, K0, (H0, W0))
    assert np.count_nonzero(native) > 10_000  # the camera-FOV cloud lands in the image
    # Dense "net" depth: nearest LiDAR return everywhere below the top return, resized to the working size.
    _, (ri, ci) = ndimage.distance_transform_edt(native == 0, return_indices=True)
    dense = native[ri, ci]
    dense[: np.flatnonzero(native.any(axis=1))[0]] = 0.0
    work = (256, 832)
    Kw = scale_intrinsics(K0, work[1] / W0, work[0] / H0)
    factor = 0.23
    depth = cv2.resize(dense, (work[1], work[0]), interpolation=cv2.INTER_LINEAR) * np.float32(factor)
    lidar = project_lidar(scan, T, Kw, work)
    s = frame_factor(ScaleConfig(mode="lidar"), depth, Kw, lidar)
    assert s * factor == pytest.approx(1.0, rel=0.03)
