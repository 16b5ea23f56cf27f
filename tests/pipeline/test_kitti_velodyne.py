"""Velodyne .bin reader/writer on the real object-benchmark scan 000008, projected with its calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import InputError
from pipeline.kitti.calib import read_object_calib
from pipeline.kitti.velodyne import read_velodyne_bin, write_velodyne_bin

SCAN = "kitti_object_000008/000008.bin"


def test_read_scan_000008(shared_data: Path):
    pts = read_velodyne_bin(shared_data / SCAN)
    assert pts.shape == (17238, 4) and pts.dtype == np.float32
    assert 0.0 <= pts[:, 3].min() and pts[:, 3].max() <= 1.0  # reflectance
    assert np.all(pts[:, 0] > 0)  # the camera-FOV-reduced cloud: everything lies ahead (velodyne x forward)


def test_scan_projects_into_the_image_with_p2_r0_tr(shared_data: Path):
    pts = read_velodyne_bin(shared_data / SCAN).astype(np.float64)
    calib = read_object_calib(shared_data / "kitti_object_000008/calib_000008.txt")
    hom = np.c_[pts[:, :3], np.ones(len(pts))]
    uvw = hom @ calib.velo_to_image(2).T
    z = uvw[:, 2]
    assert np.all(z > 0)
    u, v = uvw[:, 0] / z, uvw[:, 1] / z
    inside = (u >= 0) & (u <= 1241) & (v >= 0) & (v <= 374)
    assert inside.mean() > 0.99
    cam = hom @ calib.velo_to_cam_rect().T
    np.testing.assert_allclose(cam[:, 2], z - calib.P["P2"][2, 3], atol=1e-9)  # P2 adds t_z to the depth
    # camera y points down: the road, ~1.65 m below the camera, dominates the lowest near points
    near = cam[:, 2] < 15
    assert 1.5 < np.percentile(cam[near, 1], 80) < 1.8


def test_write_read_round_trip(tmp_path: Path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100, 4)).astype(np.float32)
    write_velodyne_bin(tmp_path / "v" / "000000.bin", pts)
    assert (tmp_path / "v" / "000000.bin").stat().st_size == 100 * 16
    np.testing.assert_array_equal(read_velodyne_bin(tmp_path / "v" / "000000.bin"), pts)
    write_velodyne_bin(tmp_path / "xyz.bin", pts[:, :3].astype(np.float64))
    back = read_velodyne_bin(tmp_path / "xyz.bin")
    np.testing.assert_array_equal(back[:, :3], pts[:, :3])
    np.testing.assert_array_equal(back[:, 3], 0)
    write_velodyne_bin(tmp_path / "empty.bin", np.zeros((0, 4)))
    assert read_velodyne_bin(tmp_path / "empty.bin").shape == (0, 4)


def test_truncated_or_missing_scan_is_an_input_error(shared_data: Path, tmp_path: Path):
    f = tmp_path / "000008.bin"
    f.write_bytes((shared_data / SCAN).read_bytes()[:-5])
    with pytest.raises(InputError) as e:
        read_velodyne_bin(f)
    assert str(f) in str(e.value) and "multiple of 16" in str(e.value)
    with pytest.raises(InputError, match="file not found"):
        read_velodyne_bin(tmp_path / "none.bin")
