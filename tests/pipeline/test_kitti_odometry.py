"""OdometrySequence / find_sequences on KITTI-layout trees assembled in tmp_path from the real seq-06 files."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from core.errors import ConfigError, InputError
from core.geometry import relative_pose, se3_inverse
from pipeline.kitti.calib import read_object_calib, read_odometry_calib, write_odometry_calib
from pipeline.kitti.odometry import OdometrySequence, find_sequences
from pipeline.kitti.poses import read_poses, write_poses

GRAY = "kitti_odometry_06_gray"
COLOR = "kitti_odometry_06_color"
TRANSCRIBED = f"{COLOR}/calib_odometry_seq04-12_TRANSCRIBED.txt"
POSES_06 = "kitti_odometry_gt_poses/06.txt"


def _gray_tree(data: Path, root: Path, poses: Path | None = None) -> Path:
    """root/sequences/06/{image_0 → image_l, calib.txt}, root/poses/06.txt (default: the 51-line poses.txt)."""
    seq = root / "sequences" / "06"
    seq.mkdir(parents=True)
    (seq / "image_0").symlink_to(data / GRAY / "image_l", target_is_directory=True)
    (seq / "calib.txt").symlink_to(data / GRAY / "calib.txt")
    (root / "poses").mkdir()
    (root / "poses" / "06.txt").symlink_to(poses or data / GRAY / "poses.txt")
    return root


def _color_tree(data: Path, root: Path, frames=(12, 13, 14), calib: Path | None = None, poses: Path | None = None):
    """image_2/0000{12,13,14}.png, the TRANSCRIBED calib, the full 06.txt poses and times."""
    seq = root / "sequences" / "06"
    (seq / "image_2").mkdir(parents=True)
    for f in frames:
        (seq / "image_2" / f"{f:06d}.png").symlink_to(data / COLOR / "test_data" / f"kitti06-{f}-color.png")
    (seq / "calib.txt").symlink_to(calib or data / TRANSCRIBED)
    (seq / "times.txt").symlink_to(data / COLOR / "videos_kitti06" / "times.txt")
    (root / "poses").mkdir()
    (root / "poses" / "06.txt").symlink_to(poses or data / POSES_06)
    return root


def test_gray_sequence(shared_data: Path, tmp_path: Path):
    seq = OdometrySequence(_gray_tree(shared_data, tmp_path), "06", camera="image_0")
    assert len(seq) == 51 and seq.frames == list(range(51))
    assert seq.image_path(7).name == "000007.png"
    assert seq.image_size == seq.image_shape == (370, 1226) and (seq.height, seq.width) == (370, 1226)
    img = seq.read_image(50)
    assert img.shape == (370, 1226, 3) and np.array_equal(img[..., 0], img[..., 2])
    np.testing.assert_array_equal(seq.K, [[707.0912, 0, 601.8873], [0, 707.0912, 183.1104], [0, 0, 1]])
    np.testing.assert_array_equal(seq.T_cam0_to_cam, np.eye(4))
    gt = read_poses(shared_data / POSES_06)[:51]
    np.testing.assert_array_equal(seq.poses_cam0, gt)
    np.testing.assert_allclose(seq.poses, gt, atol=1e-15)
    np.testing.assert_allclose(seq.relative_pose(3, 4), se3_inverse(gt[4]) @ gt[3], atol=1e-12)
    np.testing.assert_allclose(seq.relative_pose(4, 4), np.eye(4), atol=1e-6)  # KITTI R: orthonormal to ~1e-7
    assert seq.Tr is None and seq.T_velo_to_cam is None and seq.times is None
    with pytest.raises(IndexError):
        seq.image_path(51)
    assert find_sequences(tmp_path) == ["06"]


def test_gray_sequence_with_a_missing_pose_is_an_input_error(shared_data: Path, tmp_path: Path):
    short = tmp_path / "50.txt"
    write_poses(short, read_poses(shared_data / GRAY / "poses.txt")[:50])
    _gray_tree(shared_data, tmp_path / "t", poses=short)
    with pytest.raises(InputError) as e:
        OdometrySequence(tmp_path / "t", "06", camera="image_0")
    msg = str(e.value)
    assert str(tmp_path / "t" / "poses" / "06.txt") in msg and "50 poses" in msg and "51 images" in msg


def test_complete_sequence_beside_a_longer_pose_file(shared_data: Path, tmp_path: Path):
    root = _gray_tree(shared_data, tmp_path, poses=shared_data / POSES_06)
    with pytest.raises(InputError) as e:
        OdometrySequence(root, "06", camera="image_0")
    assert "1101 poses" in str(e.value) and "51 images" in str(e.value) and "counts differ" in str(e.value)
    seq = OdometrySequence(root, 6, camera="image_0", strict_pose_count=False)
    np.testing.assert_array_equal(seq.poses_cam0, read_poses(shared_data / GRAY / "poses.txt"))


def test_colour_subset_frames_index_the_full_pose_file(shared_data: Path, tmp_path: Path):
    seq = OdometrySequence(_color_tree(shared_data, tmp_path), "06")  # image_2 is the default
    assert seq.frames == [12, 13, 14] and len(seq) == 3 and seq.index_of(13) == 1
    assert seq.image_path(0).name == "000012.png"
    assert seq.read_image(2).shape == (370, 1226, 3)
    P2 = read_odometry_calib(shared_data / TRANSCRIBED).P["P2"]
    np.testing.assert_array_equal(seq.P, P2)
    np.testing.assert_array_equal(seq.K, P2[:, :3])
    # offset of cam2 from cam0: K⁻¹ P2[:, 3], by hand
    tz = 6.203223e-03
    ty = (1.178601e-01 - 183.1104 * tz) / 707.0912
    tx = (4.688783e01 - 601.8873 * tz) / 707.0912
    np.testing.assert_allclose(seq.T_cam0_to_cam[:3, 3], [tx, ty, tz], rtol=1e-12)
    np.testing.assert_array_equal(seq.T_cam0_to_cam[:3, :3], np.eye(3))
    assert 0.05 < tx < 0.07  # ≈ P2[0,3] / P2[0,0] (docs/design.md §2)

    gt = read_poses(shared_data / POSES_06)
    np.testing.assert_array_equal(seq.poses_cam0, gt[12:15])  # frame id i ↔ line i
    off = seq.T_cam0_to_cam
    np.testing.assert_allclose(seq.poses, gt[12:15] @ se3_inverse(off), atol=1e-12)
    # image_2's centre is cam0's centre moved by −t_off (in cam0's axes at frame 12)
    np.testing.assert_allclose(seq.poses[0][:3, 3], gt[12][:3, 3] - gt[12][:3, :3] @ off[:3, 3], atol=1e-12)
    # T_{i→j} of cam2 = off · T_{i→j}(cam0) · off⁻¹: same rotation, translation t0 + (I − R0) t_off
    T0 = relative_pose(gt[12], gt[13])
    T2 = seq.relative_pose(0, 1)
    np.testing.assert_allclose(T2[:3, :3], T0[:3, :3], atol=1e-12)
    # (atol 1e-8: KITTI's rotations are orthonormal to ~1e-7 only)
    np.testing.assert_allclose(T2[:3, 3], T0[:3, 3] + (np.eye(3) - T0[:3, :3]) @ off[:3, 3], atol=1e-8)
    assert -1.5 < T2[2, 3] < -0.5  # driving forward ≈ 1 m per frame

    times = seq.times
    assert times.shape == (3,) and times[0] == pytest.approx(12 * 0.1036, abs=0.02)
    assert seq.Tr is None and seq.T_velo_to_cam is None


def test_colour_subset_needs_a_pose_line_for_every_frame(shared_data: Path, tmp_path: Path):
    p13 = tmp_path / "13.txt"
    write_poses(p13, read_poses(shared_data / POSES_06)[:13])  # lines 0..12: frame 13, 14 have none
    root = _color_tree(shared_data, tmp_path / "t", poses=p13)
    with pytest.raises(InputError) as e:
        OdometrySequence(root, "06")
    assert str(root / "poses" / "06.txt") in str(e.value) and "13 poses" in str(e.value)
    assert "frame id 14" in str(e.value)


def test_velodyne_and_tr(shared_data: Path, tmp_path: Path):
    calib = read_odometry_calib(shared_data / TRANSCRIBED)
    Tr = read_object_calib(shared_data / "kitti_object_000008/calib_000008.txt").velo_to_cam_rect()
    cfile = tmp_path / "calib_tr.txt"
    write_odometry_calib(cfile, calib.P, Tr)
    root = _color_tree(shared_data, tmp_path / "t", calib=cfile)
    velo = root / "sequences" / "06" / "velodyne"
    velo.mkdir()
    shutil.copy(shared_data / "kitti_object_000008/000008.bin", velo / "000013.bin")
    seq = OdometrySequence(root, "06")
    np.testing.assert_allclose(seq.Tr, Tr, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(seq.T_velo_to_cam, seq.T_cam0_to_cam @ Tr, rtol=1e-12)
    np.testing.assert_allclose(seq.T_velo_to_cam[:3, 3], Tr[:3, 3] + seq.T_cam0_to_cam[:3, 3], rtol=1e-12)
    assert seq.velodyne_path(1) == velo / "000013.bin" and seq.has_velodyne(1) and not seq.has_velodyne(0)
    assert seq.read_velodyne(1).shape == (17238, 4)
    with pytest.raises(InputError, match="file not found"):
        seq.read_velodyne(0)


def test_test_sequence_without_poses(shared_data: Path, tmp_path: Path):
    root = _color_tree(shared_data, tmp_path)
    (root / "poses" / "06.txt").unlink()
    seq = OdometrySequence(root, "06")
    assert seq.poses is None and seq.poses_cam0 is None and not seq.has_poses
    with pytest.raises(InputError, match="no poses"):
        seq.relative_pose(0, 1)


def test_construction_errors_name_the_path(shared_data: Path, tmp_path: Path):
    with pytest.raises(InputError) as e:
        OdometrySequence(tmp_path / "nowhere", "06")
    assert str(tmp_path / "nowhere" / "sequences") in str(e.value)
    root = _gray_tree(shared_data, tmp_path / "g")
    with pytest.raises(InputError) as e:
        OdometrySequence(root, "07", camera="image_0")
    assert str(root / "sequences" / "07") in str(e.value)
    with pytest.raises(InputError) as e:
        OdometrySequence(root, "06")  # image_2 absent
    assert str(root / "sequences" / "06" / "image_2") in str(e.value)
    with pytest.raises(ConfigError):
        OdometrySequence(root, "06", camera="image_5")
    # colour frames beside the gray 2-line calib: no P2
    croot = _color_tree(shared_data, tmp_path / "c", calib=shared_data / GRAY / "calib.txt")
    with pytest.raises(InputError) as e:
        OdometrySequence(croot, "06")
    assert str(croot / "sequences" / "06" / "calib.txt") in str(e.value) and "'P2'" in str(e.value)
    # no calib at all
    (croot / "sequences" / "06" / "calib.txt").unlink()
    with pytest.raises(InputError) as e:
        OdometrySequence(croot, "06")
    assert str(croot / "sequences" / "06" / "calib.txt") in str(e.value) and "not found" in str(e.value)
    # an image folder without frames
    (root / "sequences" / "06" / "image_1").mkdir()
    with pytest.raises(InputError) as e:
        OdometrySequence(root, "06", camera="image_1")
    assert str(root / "sequences" / "06" / "image_1") in str(e.value) and "no images" in str(e.value)


def test_find_sequences_lists_only_folders_with_a_calib(shared_data: Path, tmp_path: Path):
    root = _gray_tree(shared_data, tmp_path)
    (root / "sequences" / "07").mkdir()
    (root / "sequences" / "00").mkdir()
    (root / "sequences" / "00" / "calib.txt").write_text("P0: " + " ".join(["1"] * 12) + "\n")
    assert find_sequences(root) == ["00", "06"]
    with pytest.raises(InputError):
        find_sequences(tmp_path / "empty")
