"""The synthetic world's ground truth, checked from the WRITTEN files (as a user reads them).

One tiny world (160×48, a 4-frame training sequence and a 3-frame test sequence) is generated once.
"""

from __future__ import annotations

import numpy as np
import pytest

from core import geometry as g
from core.axes import HPLFLOWNET, LIDAR
from pipeline.kitti import OdometrySequence, read_depth_png, read_velodyne_bin
from pipeline.synth import SynthConfig, generate

CFG = SynthConfig(seed=3, width=160, height=48, n_sequences=1, frames=4, test_frames=3, parked_cars=8,
                  moving_cars=5, lidar_azimuth_step_deg=0.8, test_lidar_azimuth_step_deg=0.6)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth") / "world"
    summary = generate(CFG, root)
    assert summary.frames == 7 and summary.flow_pairs == 5 and summary.test_pairs == 2
    return root


def _pair(root, seq: str, t: int):
    d = root / "sequences" / seq
    f = np.load(d / "flow3d_2" / f"{t:06d}.npz")
    return (read_depth_png(d / "depth_2" / f"{t:06d}.png"), read_depth_png(d / "depth_2" / f"{t + 1:06d}.png"),
            {k: f[k] for k in f.files})


def _sample_inverse_depth(depth: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation of 1/depth (exact on planes) at sub-pixel uv; ok = all 4 neighbours valid."""
    H, W = depth.shape
    u0 = np.clip(np.floor(uv[:, 0]).astype(int), 0, W - 2)
    v0 = np.clip(np.floor(uv[:, 1]).astype(int), 0, H - 2)
    a, b = uv[:, 0] - u0, uv[:, 1] - v0
    n = [depth[v0, u0], depth[v0, u0 + 1], depth[v0 + 1, u0], depth[v0 + 1, u0 + 1]]
    ok = np.all([x > 0 for x in n], axis=0)
    inv = [np.where(x > 0, 1.0 / np.maximum(x, 1e-6), 0.0) for x in n]
    i = (1 - a) * (1 - b) * inv[0] + a * (1 - b) * inv[1] + (1 - a) * b * inv[2] + a * b * inv[3]
    return np.where(ok, 1.0 / np.maximum(i, 1e-9), 0.0), ok


def _planar(depth: np.ndarray, uv: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    """Whether 1/depth over the 4×4 pixels around each uv is affine (one plane: interpolation is exact)
    within ``tol`` relative — i.e. uv does not straddle a depth edge."""
    H, W = depth.shape
    u0, v0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    inside = (u0 >= 1) & (u0 <= W - 3) & (v0 >= 1) & (v0 <= H - 3)
    du, dv = (a.ravel() for a in np.meshgrid(np.arange(-1, 3), np.arange(-1, 3)))
    A = np.stack([np.ones(16), du, dv], 1)
    win = depth[np.clip(v0, 1, H - 3)[:, None] + dv, np.clip(u0, 1, W - 3)[:, None] + du].astype(np.float64)
    inv = 1.0 / np.maximum(win, 1e-6)
    res = np.abs(inv - inv @ np.linalg.pinv(A).T @ A.T).max(1) / inv.mean(1)
    return inside & np.all(win > 0, axis=1) & (res < tol)


def test_reader_reads_the_world_unchanged(world):
    seq = OdometrySequence(world, "00")
    assert len(seq) == CFG.frames and seq.image_shape == (CFG.height, CFG.width)
    assert seq.read_image(0).shape == (48, 160, 3)
    K = seq.K
    assert K[0, 0] == pytest.approx(707.0912 * 160 / 1226) and K[1, 2] == pytest.approx(183.1104 * 48 / 370)
    np.testing.assert_allclose(seq.T_cam0_to_cam[:3, 3], [0.06, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(seq.poses_cam0[0], np.eye(4), atol=1e-15)
    # image_2 pose = cam0 pose · inv(T_cam0_to_cam2): its centre is 6 cm to the left of cam0 (x = −0.06)
    np.testing.assert_allclose(seq.poses[0][:3, 3], [-0.06, 0.0, 0.0], atol=1e-12)
    # velodyne 0.27 m behind and 0.08 m above cam0, axes x fwd / y left / z up
    Tr = seq.Tr
    np.testing.assert_allclose(Tr[:3, :3] @ [1, 0, 0], [0, 0, 1])
    np.testing.assert_allclose(Tr[:3, :3] @ [0, 0, 1], [0, -1, 0])
    np.testing.assert_allclose(Tr[:3, 3], [0.0, -0.08, -0.27])
    assert np.all(np.diff(seq.times) == pytest.approx(0.1))
    step = np.linalg.norm(np.diff(seq.poses_cam0[:, :3, 3], axis=0), axis=1)
    assert np.all((step > 0.7) & (step < 1.35))  # KITTI-like ≈ 1 m per frame


def test_flow_moves_pixels_onto_next_depth_where_visible(world):
    K = OdometrySequence(world, "00").K
    for t in range(CFG.frames - 1):
        d0, d1, f = _pair(world, "00", t)
        np.testing.assert_array_equal(f["valid"], d0 > 0)
        assert f["valid"].mean() > 0.5 and not np.any(f["visible_next"] & ~f["valid"])
        p = g.backproject(d0.astype(np.float64), K)
        m = f["visible_next"]
        q = p[m] + f["flow"][m]
        uv, z = g.project(q, K)
        assert np.all(g.in_image(uv, *d1.shape)) and np.all(z > 0)
        zi, ok = _sample_inverse_depth(d1, uv)
        assert ok.mean() > 0.9
        # where t+1's depth around the landing point is one plane, interpolating it is exact: the moved
        # point lies on it within 1 cm (depth PNGs are quantised to 1/256 m)
        flat = ok & _planar(d1, uv)
        assert flat.mean() > 0.35
        err = np.abs(z - zi)[flat]
        assert np.median(err) < 0.003 and err.max() < 0.01, (t, np.median(err), err.max())
        # the mask is informative: valid pixels landing in the image but marked not visible mostly disagree
        nv = f["valid"] & ~m
        uv2, z2 = g.project(p[nv] + f["flow"][nv], K)
        inside = g.in_image(uv2, *d1.shape) & (z2 > 0)
        if inside.sum() >= 10:
            zi2, ok2 = _sample_inverse_depth(d1, uv2[inside])
            assert (np.abs(z2[inside] - zi2) > 0.05).mean() > 0.5


def test_static_flow_equals_pose_flow_from_written_files(world):
    seq = OdometrySequence(world, "00")
    for t in range(CFG.frames - 1):
        d0, _, f = _pair(world, "00", t)
        T = seq.relative_pose(t, t + 1)
        assert np.linalg.norm(T[:3, 3]) > 0.5
        static = f["valid"] & ~f["moving"]
        p = g.backproject(d0.astype(np.float64), seq.K)[static]
        err = np.abs(f["flow"][static] - g.static_flow(p, T)).max()
        assert err < 1e-3, err


def test_moving_cars_really_move(world):
    seq = OdometrySequence(world, "00")
    moved = 0
    for t in range(CFG.frames - 1):
        d0, _, f = _pair(world, "00", t)
        mv = f["moving"] & f["valid"]
        p = g.backproject(d0.astype(np.float64), seq.K)[mv]
        diff = np.linalg.norm(f["flow"][mv] - g.static_flow(p, seq.relative_pose(t, t + 1)), axis=-1)
        moved += int((diff > 0.1).sum())
        assert np.all(diff > 0.1)  # every mover drives at ≥ 3 m/s = 0.3 m per frame
    assert moved > 20


def test_warping_next_image_with_gt_lowers_photometric_error(world):
    import cv2

    seq = OdometrySequence(world, "00")
    for t in range(CFG.frames - 1):
        d0, _, f = _pair(world, "00", t)
        I0, I1 = seq.read_image(t).astype(np.float32), seq.read_image(t + 1).astype(np.float32)
        m = f["visible_next"]
        p = g.backproject(d0.astype(np.float64), seq.K)
        uv, _ = g.project((p + f["flow"]).reshape(-1, 3), seq.K)
        uv = uv.reshape(*d0.shape, 2).astype(np.float32)
        warped = cv2.remap(I1, uv[..., 0], uv[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        e_warp = np.abs(warped - I0)[m].mean()
        e_id = np.abs(I1 - I0)[m].mean()
        assert e_warp < 0.75 * e_id, (e_warp, e_id)  # the rest: hard pattern edges at 160×48


def test_lidar_scan_agrees_with_gt_depth(world):
    seq = OdometrySequence(world, "00")
    for t in (0, CFG.frames - 1):
        pts = read_velodyne_bin(seq.velodyne_path(t))
        assert pts.shape[1] == 4 and np.all((pts[:, 3] >= 0) & (pts[:, 3] <= 1))
        r = np.linalg.norm(pts[:, :3], axis=1)
        assert r.max() <= CFG.lidar_range + 1e-3
        elev = np.degrees(np.arcsin(pts[:, 2] / r))
        assert elev.max() <= 2.0 + 1e-3 and elev.min() >= -24.8 - 1e-3
        pc = g.transform_points(seq.T_velo_to_cam, pts[:, :3].astype(np.float64))
        uv, z = g.project(pc, seq.K)
        inside = g.in_image(uv, seq.height, seq.width) & (z > 0)
        assert inside.sum() > 500
        depth = read_depth_png(seq.seq_dir / "depth_2" / f"{t:06d}.png")
        zi, ok = _sample_inverse_depth(depth, uv[inside])
        flat = ok & _planar(depth, uv[inside])
        err = np.abs(zi - z[inside])[flat]
        assert flat.mean() > 0.35 and np.median(err) < 0.003
        assert (err < 0.01).mean() > 0.95, (err < 0.01).mean()  # the rest: seen by the LiDAR, hidden from the camera


def test_sceneflow_files_round_trip_through_their_axes(world):
    seq = OdometrySequence(world, "01")  # the test sequence
    readme = (world / "sceneflow" / "README.txt").read_text()
    assert "(cam_z, -cam_x, -cam_y)" in readme and "(-cam_x, -cam_y, cam_z)" in readme
    for t in range(CFG.test_frames - 1):
        T = seq.relative_pose(t, t + 1)
        fn = np.load(world / "sceneflow" / "flownet3d" / f"{t:06d}.npz")
        pos1 = LIDAR.to_camera(fn["pos1"].astype(np.float64))
        pos2 = LIDAR.to_camera(fn["pos2"].astype(np.float64))
        gt = LIDAR.to_camera(fn["gt"].astype(np.float64))
        moving = fn["moving"]
        assert len(pos1) > 100 and len(pos2) > 100 and moving.shape == (len(pos1),)
        assert pos1[:, 2].max() < 35.0 and pos2[:, 2].max() < 35.0
        # pos1 are scan-t returns seen by image_2 at t; pos2 scan-(t+1) returns in camera t+1
        for cloud, k in ((pos1, t), (pos2, t + 1)):
            scan = g.transform_points(seq.T_velo_to_cam, read_velodyne_bin(seq.velodyne_path(k))[:, :3].astype(np.float64))
            d = np.sqrt(((cloud[:200, None, :] - scan[None, :, :]) ** 2).sum(-1)).min(1)
            assert d.max() < 1e-3
            uv, z = g.project(cloud, seq.K)
            assert np.all(g.in_image(uv, seq.height, seq.width) & (z > 0))
        # gt in camera axes: static points move exactly with the camera
        st = ~moving
        np.testing.assert_allclose(gt[st], g.static_flow(pos1[st], T), atol=1e-4)
        if moving.any():
            assert np.linalg.norm(gt[moving] - g.static_flow(pos1[moving], T), axis=1).min() > 0.1
        # HPLFlowNet: (−x, −y, z) axes, pc2 = pc1 + flow, ground kept (the reader removes stored y < −1.4)
        hd = world / "sceneflow" / "hplflownet" / f"{t:06d}"
        pc1 = HPLFLOWNET.to_camera(np.load(hd / "pc1.npy").astype(np.float64))
        pc2 = HPLFLOWNET.to_camera(np.load(hd / "pc2.npy").astype(np.float64))
        hm = np.load(hd / "moving.npy")
        assert len(pc1) > len(pos1) and hm.shape == (len(pc1),)
        hs = ~hm
        np.testing.assert_allclose((pc2 - pc1)[hs], g.static_flow(pc1[hs], T), atol=1e-4)
        ground_like = np.load(hd / "pc1.npy")[:, 1] < -1.4
        assert ground_like.mean() > 0.2  # ground present here …
        assert (pos1[:, 1] > 1.4).mean() < ground_like.mean() / 4  # … and removed from FlowNet3D's pos1
        # the same points, the same flow, in both layouts
        keep = (pc1[:, 2] < 35.0) & (pc1[:, 1] < 1.4)
        j = np.sqrt(((pos1[:100, None, :] - pc1[None, keep, :]) ** 2).sum(-1)).argmin(1)
        np.testing.assert_allclose(pc1[keep][j], pos1[:100], atol=1e-5)
        np.testing.assert_allclose((pc2 - pc1)[keep][j], gt[:100], atol=1e-4)


def test_kitti_working_size_832x256(tmp_path):
    cfg = SynthConfig(seed=1, width=832, height=256, n_sequences=1, frames=2, test_frames=0, parked_cars=2,
                      moving_cars=1, lidar_azimuth_step_deg=2.0)
    generate(cfg, tmp_path / "w")
    seq = OdometrySequence(tmp_path / "w", "00")
    assert seq.image_shape == (256, 832) and seq.K[0, 0] == pytest.approx(707.0912 * 832 / 1226)
    d0, _, f = _pair(tmp_path / "w", "00", 0)
    assert f["flow"].shape == (256, 832, 3) and f["visible_next"].mean() > 0.5
    static = f["valid"] & ~f["moving"]
    p = g.backproject(d0.astype(np.float64), seq.K)[static]
    assert np.abs(f["flow"][static] - g.static_flow(p, seq.relative_pose(0, 1))).max() < 1e-3
    assert not (tmp_path / "w" / "sceneflow").exists()  # no test sequence asked for
