"""Baselines: zero and static flow by hand; ICP and FGR recover known rigid motions on a structured scene."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from evaluation.baselines import (
    Baseline,
    FGRBaseline,
    FGRConfig,
    ICPBaseline,
    ICPConfig,
    ZeroFlowBaseline,
    compute_fpfh,
    fast_global_registration,
    icp,
)
from evaluation.baselines.base import kabsch, rotation_from_vector, transform_error
from evaluation.baselines.fpfh import FEATURE_DIM, pair_features, point_spacing
from evaluation.baselines.icp import weakest_hold
from evaluation.baselines.normals import estimate_normals
from evaluation.methods import StaticPoseMethod
from core.geometry import static_flow
from testkit.rigid_scene import SMALL, YAW30, box_surface, motion, scene_pair, structured_scene


# ------------------------------------------------------------------------------------------------
# trivial baselines


def test_zero_and_static_flow_by_hand() -> None:
    pts = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 5.0]])
    zero = ZeroFlowBaseline()
    assert isinstance(zero, Baseline) and zero.name == "zero"
    np.testing.assert_array_equal(zero(pts, pts), np.zeros((2, 3), np.float32))
    # T: 90° about camera y (R maps x -> −z, z -> x), then t = (0, 0, 1)
    pose = np.array([[0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 1.0], [0, 0, 0, 1]])
    # p = (1, 0, 0): R p = (0, 0, −1), + t = (0, 0, 0), flow = (−1, 0, 0)
    # p = (0, 2, 5): R p = (5, 2, 0),  + t = (5, 2, 1), flow = (5, 0, −4)
    expected = np.array([[-1.0, 0.0, 0.0], [5.0, 0.0, -4.0]])
    np.testing.assert_allclose(static_flow(pts, pose, as_float32=True), expected, atol=1e-6)
    base = StaticPoseMethod()
    assert isinstance(base, Baseline)
    np.testing.assert_allclose(base(pts, np.zeros((7, 3)), pose=pose), expected, atol=1e-6)
    with pytest.raises(ValueError, match="pose"):
        base(pts, pts, pose=np.eye(3))


@pytest.mark.parametrize("seed", range(8))
def test_kabsch_exact(seed: int) -> None:
    """Exact correspondences: Kabsch returns the transform to rounding. The bound comes from the
    arithmetic: the rotation of an SVD of the covariance is perturbed by about eps times its condition
    (largest squared spread over the other two), the translation in proportion to the coordinates; 64 ulps
    of slack make it machine independent while still 10 orders below the old arccos-limited 1e-6°."""
    rng = np.random.default_rng(seed)
    src = rng.normal(size=(50, 3))
    dst = src @ YAW30[:3, :3].T + YAW30[:3, 3]
    est = kabsch(src, dst)
    spread = np.linalg.svd(src - src.mean(0), compute_uv=False)
    kappa = spread[0] ** 2 / (spread[1] ** 2 + spread[2] ** 2)
    size = 1.0 + np.abs(YAW30[:3, 3]).max() + np.abs(src).max()
    tol = 64 * np.finfo(np.float64).eps * (1.0 + kappa) * size
    assert np.abs(est - YAW30).max() <= tol
    rot_err, t_err = transform_error(est, YAW30)
    assert np.radians(rot_err) <= tol and t_err <= tol


def test_transform_error_angle_is_exact_near_zero_and_at_large_angles() -> None:
    for deg in (1e-9, 1e-3, 30.0, 179.0):
        a = np.radians(deg)
        rot = np.eye(4)
        rot[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        got, trans = transform_error(rot, np.eye(4))
        assert abs(got - deg) <= 8 * np.finfo(np.float64).eps * max(deg, 1.0) and trans == 0.0


# ------------------------------------------------------------------------------------------------
# ICP


@pytest.mark.parametrize("method", ["point_to_point", "point_to_plane"])
def test_icp_recovers_small_motion(method: str) -> None:
    pc1, pc2 = scene_pair(0, 3000, SMALL)
    result = icp(pc1, pc2, ICPConfig(method=method, max_correspondence_distance=1.0))
    rot_err, t_err = transform_error(result.transform, SMALL)
    assert rot_err < 0.5 and t_err < 0.02, (rot_err, t_err)
    assert result.converged and result.fitness > 0.8
    # the flow is the rigid flow of the estimate; its error against the true rigid flow is small
    flow = ICPBaseline(ICPConfig(method=method))(pc1, pc2)
    true_flow = pc1 @ SMALL[:3, :3].T + SMALL[:3, 3] - pc1
    assert np.linalg.norm(flow - true_flow, axis=1).mean() < 0.02


@pytest.mark.parametrize("method", ["point_to_point", "point_to_plane"])
def test_cauchy_kernel_ignores_a_car_that_moves_on_its_own(method: str) -> None:
    """A car (a seventh of the points) drives 0.4 m right and 0.5 m closer than the camera's motion says:
    with Cauchy weights ICP still finds the camera's motion to a few millimetres, unweighted it is pulled
    off by a centimetre (point-to-point) to several (point-to-plane)."""
    pc1, pc2 = scene_pair(3, 3000, SMALL)
    car = box_surface(np.random.default_rng(4), (-1.0, 0.8, 9.0), (1.8, 1.6, 4.2), 500)
    pc1 = np.concatenate([pc1, car])
    pc2 = np.concatenate([pc2, car @ SMALL[:3, :3].T + SMALL[:3, 3] + [0.4, 0.0, -0.5]])
    errors = {}
    for kernel in ("none", "cauchy"):
        cfg = ICPConfig(method=method, max_correspondence_distance=1.0, kernel=kernel)
        errors[kernel] = transform_error(icp(pc1, pc2, cfg).transform, SMALL)[1]
    assert errors["cauchy"] < 0.005, errors
    assert errors["none"] > 2 * errors["cauchy"], errors


def test_two_way_icp_step_also_pairs_each_near_target_point_with_its_nearest_source_point() -> None:
    """One iteration of ``two_way`` is the Kabsch fit over the forward pairs (each source point, its nearest
    target) and the reverse pairs (each target point within the limit, its nearest source point); the reverse
    pairs reach the target points that no source point chooses, here a car's new front end."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    src = box_surface(rng, (0.5, 0.8, 12.0), (1.8, 1.6, 4.2), 150)
    dst = box_surface(rng, (0.5, 0.8, 12.0), (1.8, 1.6, 4.2), 150) + [0.0, 0.0, 0.9]
    step = icp(src, dst, ICPConfig(max_correspondence_distance=1.0, max_iterations=1, two_way=True)).transform
    d_fwd, i_fwd = cKDTree(dst).query(src)
    d_back, i_back = cKDTree(src).query(dst)
    fwd, back = d_fwd < 1.0, d_back < 1.0
    expected = kabsch(np.concatenate([src[fwd], src[i_back[back]]]), np.concatenate([dst[i_fwd[fwd]], dst[back]]))
    np.testing.assert_allclose(step, expected, atol=1e-9)
    one_way = icp(src, dst, ICPConfig(max_correspondence_distance=1.0, max_iterations=1)).transform
    assert not np.allclose(step, one_way)
    assert (~np.isin(np.flatnonzero(back), i_fwd[fwd])).sum() > 10  # target points only the reverse pairs reach
    with pytest.raises(ValueError, match="two_way"):
        ICPConfig(method="point_to_plane", two_way=True)


def test_icp_holding_the_vertical_moves_the_points_in_the_ground_plane_only() -> None:
    """``hold_vertical``: every increment turns about camera y and shifts along x and z, so each point keeps the
    height the start gave it (the start's height, pitch and roll stay), while the yaw and the horizontal
    translation are still registered: started 1.5° and 0.3 m off in the ground plane (and 4 cm too high), the
    points land within a few millimetres of the truth along x and z and exactly 4 cm off along y."""
    truth = motion(1.0, (0.1, 1.0, 0.05), (0.2, 0.03, 0.9))
    pc1, pc2 = scene_pair(5, 3000, truth)
    start = motion(1.5, (0.0, 1.0, 0.0), (0.25, 0.0, -0.15)) @ truth
    start[1, 3] += 0.04
    cfg = ICPConfig(method="point_to_plane", max_correspondence_distance=1.0, kernel="cauchy", hold_vertical=2.0)
    held = icp(pc1, pc2, cfg, init=start).transform
    moved, at_start, true = (pc1 @ T[:3, :3].T + T[:3, 3] for T in (held, start, truth))
    np.testing.assert_allclose(moved[:, 1], at_start[:, 1], atol=1e-9)  # heights never change
    assert np.abs(at_start - true)[:, [0, 2]].mean() > 0.1  # the start was far off in the ground plane
    assert np.abs(moved - true)[:, [0, 2]].mean() < 0.005
    np.testing.assert_allclose(np.mean(moved[:, 1] - true[:, 1]), 0.04, atol=0.005)
    free = icp(pc1, pc2, dataclasses.replace(cfg, hold_vertical=0.0), init=start).transform
    assert transform_error(free, truth)[1] < 0.01  # this street has a road: six degrees find the height too
    with pytest.raises(ValueError, match="hold_vertical"):
        ICPConfig(method="point_to_point", hold_vertical=1.0)


def test_icp_holds_the_vertical_only_where_the_start_s_pairs_hold_a_direction_weakly() -> None:
    """The gate: the street with a road holds every direction well (its weakest eigenvalue per pair is far
    above 0.03), so ``hold_vertical`` 0.03 registers all six degrees as 0 does; the same street without its
    road and with walls only has a near-zero vertical and is held."""
    from scipy.spatial import cKDTree

    truth = motion(1.0, (0.1, 1.0, 0.05), (0.2, 0.03, 0.9))
    pc1, pc2 = scene_pair(5, 3000, truth)
    start = truth.copy()
    start[1, 3] += 0.04
    idx = cKDTree(pc2).query(pc1 @ start[:3, :3].T + start[:3, 3])[1]
    weakest = weakest_hold(pc1 @ start[:3, :3].T + start[:3, 3], estimate_normals(pc2, 20)[idx])
    assert weakest > 0.03
    cfg = ICPConfig(method="point_to_plane", max_correspondence_distance=1.0, kernel="cauchy")
    gated = icp(pc1, pc2, dataclasses.replace(cfg, hold_vertical=0.03), init=start).transform
    np.testing.assert_allclose(gated, icp(pc1, pc2, cfg, init=start).transform, atol=1e-12)
    assert transform_error(gated, truth)[1] < 0.01
    walls = np.abs(estimate_normals(pc1, 20)[:, 1]) < 0.5  # drop the road and the boxes' tops
    walls2 = np.abs(estimate_normals(pc2, 20)[:, 1]) < 0.5
    off = motion(1.0, (0.0, 1.0, 0.0), (0.15, 0.0, -0.1)) @ start  # also off in the ground plane
    src = pc1[walls] @ off[:3, :3].T + off[:3, 3]
    near = cKDTree(pc2[walls2]).query(src)[1]
    assert weakest_hold(src, estimate_normals(pc2[walls2], 20)[near]) < 0.03
    held = icp(pc1[walls], pc2[walls2], dataclasses.replace(cfg, hold_vertical=0.03), init=off).transform
    moved, at_start, true = (pc1[walls] @ T[:3, :3].T + T[:3, 3] for T in (held, off, truth))
    np.testing.assert_allclose(moved[:, 1], at_start[:, 1], atol=1e-9)  # held: heights as the start put them
    assert np.abs(moved - true)[:, [0, 2]].mean() < 0.01 < np.abs(at_start - true)[:, [0, 2]].mean()


def test_icp_config_rejects_unknown_method() -> None:
    with pytest.raises(ValueError, match="kernel"):
        ICPConfig(kernel="huber")
    with pytest.raises(ValueError, match="kernel_scale_min"):
        ICPConfig(kernel="cauchy", kernel_scale_min=0.0)
    with pytest.raises(ValueError, match="method"):
        ICPConfig(method="point_to_line")
    assert ICPBaseline(ICPConfig(method="point_to_plane")).name == "icp-p2l"


# ------------------------------------------------------------------------------------------------
# FPFH and FGR


def test_normals_of_a_plane_face_the_camera() -> None:
    rng = np.random.default_rng(1)
    road = np.stack([rng.uniform(-5, 5, 400), np.full(400, 1.6), rng.uniform(2, 12, 400)], 1)
    normals = estimate_normals(road, max_nn=20)
    np.testing.assert_allclose(normals, np.tile([0, -1.0, 0], (400, 1)), atol=1e-6)  # up, towards camera


def test_pair_features_by_hand() -> None:
    # source at origin with normal +z, target at (1, 0, 0) with normal +x:
    # d = (1, 0, 0), u = n_s = (0, 0, 1) (|u·d| = 0 < |n_t·d| = 1 -> the target becomes the source!)
    # after the swap: u = (1, 0, 0), d = (−1, 0, 0), other normal n = (0, 0, 1)
    # phi = u·d = −1; v = u × d = 0 -> degenerate pair, all features 0
    th, al, ph = pair_features(np.zeros((1, 3)), np.array([[0, 0, 1.0]]), np.array([[1.0, 0, 0]]), np.array([[1.0, 0, 0]]))
    assert (th[0], al[0], ph[0]) == (0.0, 0.0, 0.0)
    # source normal +z, target at (1, 0, 1)/√2 direction with normal +y: |u·d| = 0.707 > |n_t·d| = 0
    # d = (1, 0, 1)/√2, v = u × d = (0, 1, 0)·(1/√2) -> normalised (0, 1, 0); w = u × v = (−1, 0, 0)
    # alpha = v·n_t = 1; phi = u·d = 1/√2; theta = atan2(w·n_t, u·n_t) = atan2(0, 0) = 0
    th, al, ph = pair_features(np.zeros((1, 3)), np.array([[0, 0, 1.0]]), np.array([[1.0, 0, 1.0]]), np.array([[0, 1.0, 0]]))
    np.testing.assert_allclose([th[0], al[0], ph[0]], [0.0, 1.0, 1 / np.sqrt(2)], atol=1e-12)


def test_fpfh_is_rotation_invariant() -> None:
    rng = np.random.default_rng(2)
    pts = structured_scene(rng, 1500)
    rot = motion(20.0, (0.2, 1.0, 0.1), (0, 0, 0))  # about the camera centre: normals keep facing it
    spacing = point_spacing(pts)
    f1 = compute_fpfh(pts, spacing=spacing)
    f2 = compute_fpfh(pts @ rot[:3, :3].T, spacing=spacing)
    assert f1.shape == (1500, FEATURE_DIM)
    np.testing.assert_allclose(f1.reshape(-1, 3, 11).sum(2), 200.0, atol=1e-6)  # SPFH + neighbour term
    # identical up to round-off (ties between equal normals are broken without looking at round-off)
    np.testing.assert_allclose(f1, f2, atol=1e-6)
    # and not trivially so: the descriptors differ between points on a plane and on a box corner
    assert np.abs(f1[0] - f1[-1]).max() > 1.0


def test_fgr_recovers_small_motion() -> None:
    pc1, pc2 = scene_pair(0, 3000, SMALL)
    result = fast_global_registration(pc1, pc2)
    rot_err, t_err = transform_error(result.transform, SMALL)
    assert rot_err < 0.5 and t_err < 0.02, (rot_err, t_err)


def test_fgr_recovers_30_degrees_where_icp_fails() -> None:
    pc1, pc2 = scene_pair(1, 3000, YAW30)
    fgr = FGRBaseline()
    result = fgr.register(pc1, pc2)
    rot_err, t_err = transform_error(result.transform, YAW30)
    assert rot_err < 0.5 and t_err < 0.02, (rot_err, t_err)
    assert result.n_correspondences >= 300
    for method in ("point_to_point", "point_to_plane"):
        icp_rot, icp_t = transform_error(icp(pc1, pc2, ICPConfig(method=method)).transform, YAW30)
        assert icp_rot > 10.0 and icp_t > 0.5, (method, icp_rot, icp_t)  # stuck in a local minimum
    # the refined variant keeps the global answer
    refined = FGRBaseline(FGRConfig(refine_icp=ICPConfig(max_correspondence_distance=0.3)))
    assert refined.name == "fgr+icp"
    rr, rt = transform_error(refined.register(pc1, pc2).transform, YAW30)
    assert rr < 0.5 and rt < 0.02


def test_fgr_degenerate_inputs() -> None:
    res = fast_global_registration(np.zeros((2, 3)), np.zeros((2, 3)))
    np.testing.assert_array_equal(res.transform, np.eye(4))
    assert not res.converged
    with pytest.raises(ValueError, match="pc1"):
        FGRBaseline()(np.zeros((4, 2)), np.zeros((4, 3)))


def test_open3d_cross_check() -> None:
    o3d = pytest.importorskip("open3d", reason="open3d is not installed; the cross-check is optional")
    pc1, pc2 = scene_pair(0, 3000, SMALL)
    reg = o3d.pipelines.registration
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pc1))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pc2))
    theirs = reg.registration_icp(
        src, dst, 1.0, np.eye(4), reg.TransformationEstimationPointToPoint(),
        reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=50),
    ).transformation
    ours = icp(pc1, pc2, ICPConfig(max_correspondence_distance=1.0, max_iterations=50)).transform
    rot, trans = transform_error(ours, theirs)
    assert rot < 0.05 and trans < 0.005
