"""KITTI poses / times readers and writers on the real seq-06 files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import InputError
from core.geometry import relative_pose
from pipeline.kitti.poses import read_poses, read_times, write_poses, write_times

POSES_06 = "kitti_odometry_gt_poses/06.txt"
TIMES_06 = "kitti_odometry_06_color/videos_kitti06/times.txt"


def test_read_poses_06(shared_data: Path):
    P = read_poses(shared_data / POSES_06)
    assert P.shape == (1101, 4, 4) and P.dtype == np.float64
    np.testing.assert_array_equal(P[:, 3], np.broadcast_to([0, 0, 0, 1], (1101, 4)))
    np.testing.assert_allclose(P[0], np.eye(4), atol=1e-9)
    # line 2 of 06.txt, hand-copied
    np.testing.assert_array_equal(P[1, :3, 3], [-1.401751e-02, -2.820321e-02, 1.198998e00])
    assert P[1, 0, 1] == 7.196824e-04
    # T_{0→1} = inv(Pose_1)·Pose_0: the car drives forward (+z), so frame-0 points move by ≈ −1.2 m in z
    T01 = relative_pose(P[0], P[1])
    assert T01[2, 3] == pytest.approx(-1.198998, abs=2e-3)


def test_gray_poses_are_the_first_51_lines_of_06(shared_data: Path):
    gray = read_poses(shared_data / "kitti_odometry_06_gray/poses.txt")  # no newline at the end
    assert gray.shape == (51, 4, 4)
    np.testing.assert_array_equal(gray, read_poses(shared_data / POSES_06)[:51])


def test_read_times_06(shared_data: Path):
    t = read_times(shared_data / TIMES_06)
    assert t.shape == (1101,) and t.dtype == np.float64
    assert t[0] == 0.0 and t[1] == 1.044989e-01 and t[2] == 2.077935e-01
    dt = np.diff(t)
    assert np.all(dt > 0) and np.median(dt) == pytest.approx(0.1036, abs=2e-3)  # KITTI records at ≈ 10 Hz


def test_write_read_poses_round_trip_and_format(shared_data: Path, tmp_path: Path):
    P = read_poses(shared_data / POSES_06)[:20]
    out = tmp_path / "poses" / "06.txt"
    write_poses(out, P)
    lines = out.read_text().splitlines()
    assert len(lines) == 20 and all(len(ln.split()) == 12 for ln in lines)
    assert lines[1].split()[3] == "-1.401751000000e-02"
    np.testing.assert_array_equal(read_poses(out), P)
    write_poses(tmp_path / "b.txt", P[:, :3])  # 3x4 input too
    np.testing.assert_array_equal(read_poses(tmp_path / "b.txt"), P)


def test_write_read_times_round_trip(shared_data: Path, tmp_path: Path):
    t = read_times(shared_data / TIMES_06)
    out = tmp_path / "times.txt"
    write_times(out, t)
    assert out.read_text() == (shared_data / TIMES_06).read_text()
    np.testing.assert_array_equal(read_times(out), t)
    synth = np.arange(5) * 0.1
    write_times(tmp_path / "s.txt", synth)
    np.testing.assert_allclose(read_times(tmp_path / "s.txt"), synth, rtol=1e-6)


@pytest.mark.parametrize(
    "content, expect",
    [
        ("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n", "line 2: expected 12 numbers"),
        ("1 0 0 0 0 1 0 0 0 0 1 zz\n", "'zz' is not a number"),
        ("2 0 0 0 0 1 0 0 0 0 1 0\n", "line 1: the 3x3 rotation block is not orthonormal"),
        ("\n\n", "contains no poses"),
        ("0 1 2 3 4 5 6 7 8 9 10 11 12\n", "got 13"),
    ],
)
def test_read_poses_bad_input_names_file_and_line(tmp_path: Path, content: str, expect: str):
    f = tmp_path / "06.txt"
    f.write_text(content)
    with pytest.raises(InputError) as e:
        read_poses(f)
    assert str(f) in str(e.value) and expect in str(e.value)


def test_pyslam_groundtruth_format_is_rejected_as_poses(shared_data: Path):
    f = shared_data / "kitti_odometry_06_color/videos_kitti06/groundtruth.txt"  # timestamp x y z q… scale
    with pytest.raises(InputError) as e:
        read_poses(f)
    assert str(f) in str(e.value) and "line 1" in str(e.value)


def test_read_times_bad_input(tmp_path: Path):
    f = tmp_path / "times.txt"
    f.write_text("0.0\n0.1 0.2\n")
    with pytest.raises(InputError) as e:
        read_times(f)
    assert str(f) in str(e.value) and "line 2" in str(e.value)
    with pytest.raises(InputError, match="file not found"):
        read_times(tmp_path / "missing.txt")
