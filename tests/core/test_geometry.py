"""Camera geometry: projection round trips, SE(3) algebra, Euler convention, real seq-06 poses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core import geometry as g


def _K() -> np.ndarray:
    return np.array([[718.856, 0.0, 607.1928], [0.0, 718.856, 185.2157], [0.0, 0.0, 1.0]])


def _load_poses(path) -> np.ndarray:
    rows = np.loadtxt(path).reshape(-1, 3, 4)
    return g.to_homogeneous_3x4(rows)


def test_backproject_then_project_returns_pixels_numpy_and_torch():
    rng = np.random.default_rng(0)
    depth = rng.uniform(2, 50, size=(2, 5, 7))
    K = np.stack([_K(), g.scale_intrinsics(_K(), 0.5, 0.25)])
    pts = g.backproject(depth, K)
    assert pts.shape == (2, 5, 7, 3)
    np.testing.assert_allclose(pts[..., 2], depth)
    uv, z = g.project(pts.reshape(2, -1, 3), K)
    grid = g.pixel_grid(5, 7).reshape(-1, 2)
    np.testing.assert_allclose(uv, np.broadcast_to(grid, uv.shape), atol=1e-9)
    np.testing.assert_allclose(z, depth.reshape(2, -1))
    t_pts = g.backproject(torch.from_numpy(depth), torch.from_numpy(K))
    assert isinstance(t_pts, torch.Tensor)
    np.testing.assert_allclose(t_pts.numpy(), pts)


def test_backproject_principal_point_lies_on_optical_axis():
    K = _K()
    p = g.backproject(np.array([10.0]), K, uv=np.array([[K[0, 2], K[1, 2]]]))
    np.testing.assert_allclose(p, [[0.0, 0.0, 10.0]], atol=1e-12)
    # a pixel to the right and below the principal point is at +x, +y (x right, y down)
    p = g.backproject(np.array([10.0]), K, uv=np.array([[K[0, 2] + K[0, 0], K[1, 2] + K[1, 1]]]))
    np.testing.assert_allclose(p, [[10.0, 10.0, 10.0]], atol=1e-9)


def test_scale_and_crop_intrinsics():
    K = _K()
    Ks = g.scale_intrinsics(K, 0.5, 0.25)
    assert Ks[0, 0] == pytest.approx(K[0, 0] * 0.5) and Ks[0, 2] == pytest.approx(K[0, 2] * 0.5)
    assert Ks[1, 1] == pytest.approx(K[1, 1] * 0.25) and Ks[1, 2] == pytest.approx(K[1, 2] * 0.25)
    Kc = g.crop_intrinsics(K, 10, 20)
    assert Kc[0, 2] == pytest.approx(K[0, 2] - 10) and Kc[1, 2] == pytest.approx(K[1, 2] - 20)
    assert K[0, 2] == pytest.approx(607.1928)  # inputs untouched


def test_euler_matches_rx_ry_rz_product_and_inverts():
    a = np.array([0.1, -0.2, 0.3])
    cx, sx = np.cos(a[0]), np.sin(a[0])
    cy, sy = np.cos(a[1]), np.sin(a[1])
    cz, sz = np.cos(a[2]), np.sin(a[2])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    np.testing.assert_allclose(g.euler_to_matrix(a), Rx @ Ry @ Rz, atol=1e-12)
    np.testing.assert_allclose(g.matrix_to_euler(Rx @ Ry @ Rz), a, atol=1e-12)
    vec = torch.tensor([[0.5, -0.1, 2.0, 0.01, 0.02, -0.03]], dtype=torch.float64, requires_grad=True)
    T = g.pose_vec_to_mat(vec)
    assert T.shape == (1, 4, 4)
    np.testing.assert_allclose(g.mat_to_pose_vec(T).detach().numpy(), vec.detach().numpy(), atol=1e-12)
    T.sum().backward()
    assert torch.isfinite(vec.grad).all()


def test_se3_inverse_and_static_flow():
    T = g.pose_vec_to_mat(np.array([1.0, 2.0, -3.0, 0.2, -0.1, 0.4]))
    np.testing.assert_allclose(g.se3_inverse(T) @ T, np.eye(4), atol=1e-12)
    p = np.array([[1.0, 2.0, 3.0], [-4.0, 0.5, 10.0]])
    q = g.transform_points(T, p)
    np.testing.assert_allclose(g.transform_points(g.se3_inverse(T), q), p, atol=1e-12)
    np.testing.assert_allclose(g.static_flow(p, T), q - p, atol=1e-12)
    # pure translation: flow equals t for every point
    Tt = np.eye(4)
    Tt[:3, 3] = [0.1, 0.0, -1.2]
    np.testing.assert_allclose(g.static_flow(p, Tt), np.tile([0.1, 0.0, -1.2], (2, 1)))
    # as_float32: float64 arithmetic, one rounding to float32 (the cache's and the evaluation's precision)
    sf = g.static_flow(p.astype(np.float32), T, as_float32=True)
    p64 = p.astype(np.float32).astype(np.float64)
    assert sf.dtype == np.float32 and np.array_equal(sf, g.static_flow(p64, T).astype(np.float32))
    # torch, batched: the same flow
    pt = torch.tensor(np.stack([p, 2 * p]))
    Tb = torch.tensor(np.stack([T, Tt]))
    np.testing.assert_allclose(g.static_flow(pt, Tb).numpy()[1], g.static_flow(2 * p, Tt), atol=1e-12)


def test_rotation_angle_is_exact_near_zero_and_agrees_for_torch():
    for deg in (1e-9, 1e-3, 30.0, 179.0):
        a = np.radians(deg)
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        assert abs(g.rotation_angle(R) - a) <= 8 * np.finfo(np.float64).eps * max(a, 1.0)
        assert abs(float(g.rotation_angle(torch.tensor(R))) - a) <= 8 * np.finfo(np.float64).eps * max(a, 1.0)
    assert g.rotation_angle(np.eye(3)) == 0.0


def test_projection_offset_of_colour_camera(shared_data):
    lines = (shared_data / "kitti_odometry_06_color" / "calib_odometry_seq04-12_TRANSCRIBED.txt").read_text()
    P = {}
    for line in lines.splitlines():
        if line[:2] in ("P0", "P1", "P2", "P3") and ":" in line:
            key, vals = line.split(":", 1)
            P[key.strip()] = np.array(vals.split(), dtype=np.float64).reshape(3, 4)
    T02 = g.camera_offset_from_projection(P["P2"])
    # exact: K^-1 P2[:, 3]; the common shortcut P2[0,3]/fx ignores P2's small z offset (6 mm here)
    fx, cx, tz = P["P2"][0, 0], P["P2"][0, 2], P["P2"][2, 3]
    assert T02[0, 3] == pytest.approx((P["P2"][0, 3] - cx * tz) / fx, abs=1e-9)
    assert T02[2, 3] == pytest.approx(tz, abs=1e-12)
    assert T02[0, 3] == pytest.approx(P["P2"][0, 3] / fx, abs=0.01)
    assert 0.04 < T02[0, 3] < 0.08  # image_2 sits ~6 cm from cam0 along x
    assert np.allclose(g.camera_offset_from_projection(P["P0"]), np.eye(4))
    # cam1 (right grey) is the stereo baseline (~0.54 m) to the right: cam1 coords = cam0 coords - 0.54 x
    T01 = g.camera_offset_from_projection(P["P1"])
    assert T01[0, 3] == pytest.approx(-0.537, abs=0.01)


def test_real_seq06_relative_poses_chain_back_and_move_forward(shared_data):
    poses = _load_poses(shared_data / "kitti_odometry_gt_poses" / "06.txt")
    assert poses.shape[1:] == (4, 4)
    rel = g.relative_pose(poses[:-1], poses[1:])  # T_{i -> i+1}
    # chain: Pose_{i+1} = Pose_i · inv(T_{i -> i+1})
    chained = poses[0]
    for i in range(200):
        chained = chained @ g.se3_inverse(rel[i])
    # KITTI stores rotations to ~7 digits, so they are orthonormal only to ~1e-7 per step
    np.testing.assert_allclose(chained, poses[200], atol=1e-3)  # 1 mm over ~230 m
    # the car drives forward: a static point ahead comes closer, i.e. t_z of T_{i->i+1} is negative
    # (camera moves +z), and the camera centre of i+1 expressed in frame i has positive z.
    centre_next_in_i = g.se3_inverse(rel)[:, :3, 3]
    moving = np.linalg.norm(centre_next_in_i, axis=1) > 0.1
    assert moving.mean() > 0.9
    assert (centre_next_in_i[moving, 2] > 0.5 * np.linalg.norm(centre_next_in_i[moving], axis=1)).mean() > 0.99
    # rotations between consecutive frames are small
    assert np.degrees(g.rotation_angle(rel[:, :3, :3])).max() < 5.0
