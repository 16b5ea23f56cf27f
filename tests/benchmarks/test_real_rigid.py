"""benchmarks/real_rigid.py: a rigid split from the real KITTI scan 000008, read back by the evaluation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from benchmarks.real_rigid import RealRigidConfig, build_split, main
from benchmarks.sensor_gap import static_motion
from evaluation.readers import load_split

SCAN = "kitti_object_000008/000008.bin"
CALIB = "kitti_object_000008/calib_000008.txt"


def _cfg(shared_data: Path, out: Path, **kw) -> RealRigidConfig:
    return RealRigidConfig(scan=str(shared_data / SCAN), calib=str(shared_data / CALIB), out=str(out), **kw)


def test_the_true_flow_carries_frame_t_onto_frame_t1s_surfaces(shared_data: Path, tmp_path: Path):
    cfg = _cfg(shared_data, tmp_path / "split", pairs=3)
    n = build_split(cfg)
    split = load_split(str(tmp_path / "split"), "auto")
    assert len(split) == 3
    for i in range(3):
        s = split[i]
        assert len(s.pc1) == n and len(s.pc2) >= n and not s.moving.any()
        assert s.pc1[:, 2].min() > 0 and s.pc1[:, 2].max() < cfg.max_depth and s.pc1[:, 1].max() < cfg.ground_y
        # the camera moves forward 0.5-1.5 m: every static point comes that much closer (camera z)
        assert -1.6 < np.median(s.flow[:, 2]) < -0.4
        tree = cKDTree(s.pc2)
        moved, still = tree.query(s.pc1 + s.flow)[0], tree.query(s.pc1)[0]
        # the halves are disjoint, so the truth leaves a sampling gap, but far below the zero flow's
        assert np.median(moved) < 0.5 * np.median(still)
        assert np.mean(moved > 1e-3) > 0.99  # no frame-t point has its own copy in frame t+1
        # the flow is one rigid motion of frame t's points (static scene, eq. 11)
        a = s.pc1.astype(np.float64)
        R, t = static_motion(a, s.flow.astype(np.float64))
        np.testing.assert_allclose(a @ R.T + t, a + s.flow, atol=1e-4)


def test_the_same_seed_writes_the_same_split(shared_data: Path, tmp_path: Path):
    for name in ("a", "b"):
        build_split(_cfg(shared_data, tmp_path / name, pairs=2, seed=5))
    for f in ("000000.npz", "000001.npz"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()


def test_bad_input_is_one_line_and_writes_nothing(shared_data: Path, tmp_path: Path, capsys):
    (tmp_path / "taken").mkdir()
    assert main(["--scan", str(shared_data / SCAN), "--calib", str(shared_data / CALIB),
                 "--out", str(tmp_path / "taken")]) == 2
    bad = tmp_path / "bad.bin"
    bad.write_bytes(b"\0" * 15)
    assert main(["--scan", str(bad), "--calib", str(shared_data / CALIB), "--out", str(tmp_path / "new")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "taken" in err[0] and "bad.bin" in err[1] and "multiple of 16" in err[1]
    assert not (tmp_path / "new").exists() and not (tmp_path / "new.partial").exists()


def test_motions_drawn_from_kitti_poses_are_kittis(shared_data: Path, tmp_path: Path):
    from benchmarks.real_rigid import kitti_motions

    poses = shared_data / "kitti_odometry_gt_poses"
    motions = kitti_motions(poses / "06.txt")
    assert motions.shape == (1100, 4, 4)  # 1101 poses in sequence 06
    build_split(_cfg(shared_data, tmp_path / "split", pairs=2, poses=str(poses / "06.txt")))
    split = load_split(str(tmp_path / "split"), "auto")
    for i in range(2):
        s = split[i]
        # frame t's points moved by the flow are T p for one of sequence 06's frame-to-frame motions
        errs = [np.abs(s.pc1 @ T[:3, :3].T + T[:3, 3] - (s.pc1 + s.flow)).max() for T in motions]
        assert min(errs) < 1e-4


def test_a_folder_without_pose_files_is_refused_in_one_line(shared_data: Path, tmp_path: Path, capsys):
    assert main(["--scan", str(shared_data / SCAN), "--calib", str(shared_data / CALIB), "--poses", str(tmp_path),
                 "--out", str(tmp_path / "new")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no KITTI pose files" in err[0]
    assert not (tmp_path / "new").exists() and not (tmp_path / "new.partial").exists()


def test_rescan_gives_each_frame_its_own_sensors_rings_and_the_same_motions(shared_data: Path, tmp_path: Path):
    from benchmarks.real_rigid import scan_points

    halves = _cfg(shared_data, tmp_path / "halves", pairs=2)
    rescan = _cfg(shared_data, tmp_path / "rescan", pairs=2, rescan=True)
    build_split(halves)
    build_split(rescan)
    _, sensor = scan_points(rescan.scan, rescan.calib)
    for i in range(2):
        h, r = load_split(str(tmp_path / "halves"), "auto")[i], load_split(str(tmp_path / "rescan"), "auto")[i]
        a = r.pc1.astype(np.float64)
        R, t = static_motion(a, r.flow.astype(np.float64))
        b = h.pc1.astype(np.float64)
        np.testing.assert_allclose(b @ R.T + t, b + h.flow, atol=1e-3)  # the same camera motion as the halves
        for cloud in (r.pc1, r.pc2):  # every point on a ring of its own frame's sensor, at a cell's centre
            d = cloud.astype(np.float64) - sensor  # the reader gives camera axes
            elev = np.degrees(np.arctan2(-d[:, 1], np.hypot(d[:, 0], d[:, 2]))) / rescan.ring_deg - 0.5
            assert np.abs(elev - np.round(elev)).max() < 0.01
        tree = cKDTree(r.pc2)
        moved, still = tree.query(r.pc1 + r.flow)[0], tree.query(r.pc1)[0]
        assert np.median(moved) < 0.5 * np.median(still)  # the truth lands on frame t+1's surfaces
        assert np.mean(moved > 1e-3) > 0.99  # re-scanned: no copies of frame t's points


@pytest.mark.parametrize("rescan", [True, False])
def test_movers_carry_their_own_motion_onto_frame_t1_and_leave_the_rest_static(shared_data: Path, tmp_path: Path,
                                                                              rescan: bool):
    from benchmarks.real_rigid import mover_clusters, scan_points, split_keep

    cfg = _cfg(shared_data, tmp_path / "movers", pairs=3, rescan=rescan, movers=2, seed=3)
    build_split(cfg)
    whole, _ = scan_points(cfg.scan, cfg.calib)
    clusters = mover_clusters(whole, np.flatnonzero(split_keep(whole, cfg.ground_y, cfg.max_depth)),
                              cfg.mover_min_points)
    assert len(clusters) >= 2  # the scan's cars and posts: there is something to move
    split = load_split(str(tmp_path / "movers"), "auto")
    for i in range(3):
        s = split[i]
        assert 0 < s.moving.mean() < 0.5
        assert set(np.unique(s.instance[s.moving])) <= {0, 1} and (s.instance[~s.moving] == -1).all()
        a = s.pc1.astype(np.float64)
        R, t = static_motion(a[~s.moving], s.flow[~s.moving].astype(np.float64))
        still = a[~s.moving]
        np.testing.assert_allclose(still @ R.T + t, still + s.flow[~s.moving], atol=1e-3)  # one camera motion
        # a mover departs from that motion by at least the smallest distance it is moved (0.3 m), less what a
        # turn of 2 degrees about its centre can take back over a 6 m object (0.1 m)
        departure = np.linalg.norm(a[s.moving] @ R.T + t - (a[s.moving] + s.flow[s.moving]), axis=1)
        assert departure.min() > 0.2
        # and its true flow lands on frame t+1's surfaces, nearer than the camera's motion alone takes it (both
        # leave a sampling gap, wide on a small far cluster: 30 points of a post)
        tree = cKDTree(s.pc2)
        landed = tree.query(a[s.moving] + s.flow[s.moving])[0]
        left = tree.query(a[s.moving] @ R.T + t)[0]
        assert np.median(landed) < 0.5 * np.median(left)


def test_without_movers_the_split_is_what_it_was(shared_data: Path, tmp_path: Path):
    """Movers draw their randomness after the camera's, so a split without them is unchanged by the option."""
    build_split(_cfg(shared_data, tmp_path / "none", pairs=2, seed=4))
    build_split(_cfg(shared_data, tmp_path / "zero", pairs=2, seed=4, movers=0, mover_m=(1.0, 2.0)))
    for f in ("000000.npz", "000001.npz"):
        assert (tmp_path / "none" / f).read_bytes() == (tmp_path / "zero" / f).read_bytes()
