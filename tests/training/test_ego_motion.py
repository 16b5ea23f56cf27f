"""The rigid ego-motion + residual head (training/model/ego_motion.py, HALFlowConfig.ego_head)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.geometry import pose_vec_to_mat
from training.model.ego_motion import (hold_out_of_view, off_surface, own_departure, rigid_plus_residual,
                                      weighted_rigid_fit)


def _scene(seed: int = 0, n: int = 600, movers: int = 60, noise: float = 0.1):
    g = torch.Generator().manual_seed(seed)
    p = torch.randn(2, n, 3, generator=g, dtype=torch.float64) * 6.0
    T = torch.tensor(pose_vec_to_mat(np.array([0.1, -0.02, 0.9, 0.01, 0.03, -0.02])))
    gt = p @ T[:3, :3].T + T[:3, 3] - p
    gt[:, :movers] += torch.tensor([2.0, 0.0, 1.0], dtype=torch.float64)
    noisy = gt + noise * torch.randn(gt.shape, generator=g, dtype=torch.float64)
    return p, gt, noisy, T


def test_weighted_fit_is_exact_on_a_rigid_motion_and_ignores_zero_weights():
    p, gt, _, T = _scene(noise=0.0)
    w = torch.ones(p.shape[:2], dtype=p.dtype)
    w[:, :60] = 0.0  # the movers
    R, t = weighted_rigid_fit(p, p + gt, w)
    # float64 Kabsch on exact correspondences: errors at the level of the float64 arithmetic
    assert torch.allclose(R, T[:3, :3].expand(2, 3, 3), atol=1e-9)
    assert torch.allclose(t, T[:3, 3].expand(2, 3), atol=1e-8)


def test_head_removes_static_noise_and_keeps_movers():
    p, gt, noisy, _ = _scene()
    out, R, t, w, _ = rigid_plus_residual(p, noisy, sigma=0.25, iterations=4)
    err_in = (noisy - gt).norm(dim=-1)
    err_out = (out - gt).norm(dim=-1)
    # static points: the rigid fit over ~1000 points averages the 0.1 m/axis noise away (only the gate leaks)
    assert err_out[:, 60:].mean() < 0.5 * err_in[:, 60:].mean()
    # movers (2.2 m off the ego-motion) keep their own flow: same error as their input
    assert torch.allclose(err_out[:, :60].mean(), err_in[:, :60].mean(), rtol=0.05)
    assert (w[:, :60] < 0.05).all() and (w[:, 60:].mean() > 0.6)


def test_head_is_differentiable_in_the_flow():
    p, _, noisy, _ = _scene()
    f = noisy.clone().requires_grad_()
    out, *_ = rigid_plus_residual(p, f)
    out.square().sum().backward()
    assert torch.isfinite(f.grad).all() and f.grad[:, 60:].abs().sum() > 0


def test_net_with_ego_head_trains_and_can_be_switched_off():
    from training.config import level_points_for
    from training.model.halflownet import HALFlowConfig, HALFlowNet

    torch.manual_seed(0)
    lp = level_points_for(512)
    pc1 = torch.randn(2, 512, 3) * 4 + torch.tensor([0.0, 0.0, 10.0])
    pc2 = pc1 + torch.tensor([0.0, 0.0, -0.8])
    for ego in (True, False):
        net = HALFlowNet(HALFlowConfig(n_points=512, level_points=lp, width_scale=0.25, ego_head=ego))
        out = net(pc1, pc2)
        loss = sum(f.square().mean() for f in out.flows)
        loss.backward()
        assert all(torch.isfinite(p.grad).all() for p in net.parameters() if p.grad is not None)
        assert [f.shape[1] for f in out.flows] == list(lp[:4])
    with pytest.raises(Exception, match="ego_sigma"):
        HALFlowConfig(ego_sigma=0.0)


def test_robust_scale_follows_the_noise_of_the_flow():
    """With 0.3 m/axis noise a fixed 0.1 m scale calls most static points moving (they keep their noise);
    the MAD scale (3 × 1.4826 × median residual) recognises them and hands them the rigid flow."""
    p, gt, noisy, _ = _scene(noise=0.3)
    fixed, *_, w_fixed, _ = rigid_plus_residual(p, noisy, sigma=0.1, iterations=4, mad_factor=0.0)
    robust, *_, w_robust, _ = rigid_plus_residual(p, noisy, sigma=0.1, iterations=4, mad_factor=3.0)
    static = slice(60, None)
    assert w_fixed[:, static].mean() < 0.3 < 0.7 < w_robust[:, static].mean()
    err_fixed = (fixed - gt).norm(dim=-1)[:, static].mean()
    err_robust = (robust - gt).norm(dim=-1)[:, static].mean()
    assert err_robust < 0.5 * err_fixed


def _street(seed: int = 0, n: int = 400):
    """Ground (normal y), two side walls (normal x) and a facade ahead (normal z), camera frame, metres;
    the camera drives 1 m forward and turns 1°. Returns points, the true flow and T."""
    g = torch.Generator().manual_seed(seed)
    u = lambda *s: torch.rand(*s, generator=g, dtype=torch.float64)  # noqa: E731
    ground = torch.stack([u(n) * 12 - 6, torch.full((n,), 1.6, dtype=torch.float64), u(n) * 30 + 3], -1)
    left = torch.stack([torch.full((n,), -6.0, dtype=torch.float64), u(n) * 4 - 2.4, u(n) * 30 + 3], -1)
    right = torch.stack([torch.full((n,), 6.0, dtype=torch.float64), u(n) * 4 - 2.4, u(n) * 30 + 3], -1)
    facade = torch.stack([u(n // 4) * 12 - 6, u(n // 4) * 4 - 2.4, torch.full((n // 4,), 33.0, dtype=torch.float64)], -1)
    p = torch.cat([ground, left, right, facade])[None]
    T = torch.tensor(pose_vec_to_mat(np.array([0.0, 0.0, -1.0, 0.0, 0.0175, 0.0])))
    gt = p @ T[:3, :3].T + T[:3, 3] - p
    return p, gt, T


def test_planar_fit_is_exact_on_a_turn_and_drops_pitch_and_vertical_motion():
    from training.model.ego_motion import weighted_planar_fit

    p, gt, T = _street()  # a 1° turn about y and 1 m forward: a planar motion
    w = torch.ones(p.shape[:2], dtype=p.dtype)
    R, t = weighted_planar_fit(p, p + gt, w)
    assert torch.allclose(R, T[None, :3, :3], atol=1e-9) and torch.allclose(t, T[None, :3, 3], atol=1e-8)
    # flows that add a 0.3 m vertical drift and a 0.5° pitch: the planar fit keeps the turn and the forward
    # motion, its vertical flow is exactly zero
    T2 = torch.tensor(pose_vec_to_mat(np.array([0.0, 0.3, -1.0, 0.0087, 0.0175, 0.0])))
    tilted = p @ T2[:3, :3].T + T2[:3, 3] - p
    R, t = weighted_planar_fit(p, p + tilted, w)
    flow = p @ R.transpose(1, 2) + t[:, None] - p
    assert flow[..., 1].abs().max() == 0
    assert abs(t[0, 1].item()) == 0 and abs(t[0, 2].item() + 1.0) < 0.05
    yaw = torch.atan2(R[0, 0, 2], R[0, 0, 0]).item()
    assert abs(yaw - 0.0175) < 0.002
    out, *_ = rigid_plus_residual(p, gt, sigma=0.1, planar=True)
    assert (out - gt).norm(dim=-1).max() < 1e-6
    from training.config import level_points_for
    from training.model.halflownet import HALFlowConfig, HALFlowNet

    torch.manual_seed(0)
    lp = level_points_for(512)
    pc1 = torch.randn(2, 512, 3) * 4 + torch.tensor([0.0, 0.0, 10.0])
    net = HALFlowNet(HALFlowConfig(n_points=512, level_points=lp, width_scale=0.25, ego_head=True, ego_planar=True))
    out = net(pc1, pc1 + torch.tensor([0.0, 0.0, -0.8]))
    assert all(r[..., 1].abs().max() == 0 for r in out.rigid_flows)  # no vertical camera motion at any level
    sum(f.square().mean() for f in out.flows).backward()
    assert all(torch.isfinite(q.grad).all() for q in net.parameters() if q.grad is not None)


def test_open_gradient_keeps_the_output_and_reaches_the_own_flow_of_a_gated_point():
    """``open_gradient``: the same output, and a point whose flow agrees with the ego-motion (gate ≈ 0) gets
    the output's gradient in full on its own flow, where the gate alone passes almost none of it."""
    p, gt, _, _ = _scene(noise=0.0, movers=0)
    flow = gt.clone().requires_grad_(True)
    gated, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4)
    (g_gated,) = torch.autograd.grad(gated[0, 0, 0], flow)
    opened, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, open_gradient=True)
    (g_open,) = torch.autograd.grad(opened[0, 0, 0], flow)
    assert torch.equal(gated, opened)
    # gated: the point's own x flow enters only through the rigid fit over 600 points (about 1/600 of it)
    assert abs(g_gated[0, 0, 0].item()) < 0.05
    # opened: the straight-through adds (1 − m) ≈ 1 to it
    assert g_open[0, 0, 0].item() > 0.95


def test_a_shared_straight_through_passes_a_cluster_s_common_pull_and_thins_scattered_ones():
    """``open_k``: every point is held at the camera's motion (gate 0). 30 points of a tight cluster (a mover
    not yet departed) receive one common pull, 300 scattered static points pulls in random directions (their
    nearest samples lie every way). Shared over 10 neighbours, the cluster's pull reaches its own flows
    whole (as a sum) and the scattered ones shrink to about 1/√10 of their size; values are unchanged."""
    g = torch.Generator().manual_seed(4)
    scattered = torch.rand(1, 300, 3, generator=g, dtype=torch.float64) * 30.0 + torch.tensor([-15.0, -3.0, 5.0],
                                                                                           dtype=torch.float64)
    cluster = torch.randn(1, 30, 3, generator=g, dtype=torch.float64) * 0.3 + torch.tensor([4.0, 0.0, 12.0],
                                                                                         dtype=torch.float64)
    p = torch.cat([scattered, cluster], 1)
    T = torch.tensor(pose_vec_to_mat(np.array([0.05, 0.0, 0.9, 0.0, 0.01, 0.0])))
    ego = p @ T[:3, :3].T + T[:3, 3] - p
    pull = torch.randn(1, 330, 3, generator=g, dtype=torch.float64)
    pull = pull / pull.norm(dim=-1, keepdim=True)
    common = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    pull[:, 300:] = common

    def grads(k: int) -> tuple[torch.Tensor, torch.Tensor]:
        flow = ego.clone().requires_grad_(True)
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, open_gradient=True, open_k=k)
        (grad,) = torch.autograd.grad((out * pull).sum(), flow)
        return out.detach(), grad[0]

    out_own, own = grads(0)
    out_shared, shared = grads(10)
    assert torch.equal(out_own, out_shared)
    # the rigid fit adds the same small term to both (the mean pull over 330 points, ≤ 30/330 + noise);
    # shared, a point gets 1/k of each pull of the points whose neighbourhood holds it: as a whole the cluster
    # keeps its pull, a point in its middle (in more neighbourhoods) more than one at its edge
    assert (own[300:] @ common).min() > 0.8
    assert (shared[300:] @ common).mean() > 0.8 and (shared[300:] @ common).min() > 0.2
    own_size, shared_size = own[:300].norm(dim=-1).mean(), shared[:300].norm(dim=-1).mean()
    assert own_size > 0.9
    assert shared_size < 0.5  # 1/√10 ≈ 0.32 for independent directions


def test_neighbourhood_gate_keeps_a_moving_cluster_and_returns_isolated_strays_to_the_ego_motion():
    """``gate_k``: 60 points of a car (a 1 m ball) move 2 m on their own; 10 scattered static points have a
    wrong flow of their own (1 m off, as a wrong Chamfer match leaves them). Each point's own residual keeps
    both; the median over 8 neighbours keeps the car's and gives the strays the ego-motion."""
    g = torch.Generator().manual_seed(1)
    static = (torch.rand(1, 500, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([40.0, 4.0, 40.0])
    car = torch.randn(1, 60, 3, generator=g, dtype=torch.float64) * 0.4 + torch.tensor([3.0, 0.0, 12.0])
    p = torch.cat([static, car], 1)
    T = torch.tensor(pose_vec_to_mat(np.array([0.05, 0.0, 1.0, 0.0, 0.02, 0.0])))
    flow = p @ T[:3, :3].T + T[:3, 3] - p
    flow[:, 500:] += torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
    strays = torch.arange(0, 500, 50)
    flow[:, strays] += torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    rigid = p @ T[:3, :3].T + T[:3, 3] - p
    for k, strays_kept in ((0, True), (8, False)):
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, mad_factor=3.0, gate_k=k)
        assert torch.allclose(out[:, 500:], flow[:, 500:], atol=0.05)  # the car keeps its own flow
        stray_err = (out[:, strays] - rigid[:, strays]).norm(dim=-1)
        assert (stray_err > 0.9).all() if strays_kept else (stray_err < 0.05).all()


def test_spacing_gate_holds_offsets_within_frame_twos_sample_spacing_and_keeps_larger_ones():
    """``gate_spacing``: frame 2 is a 2 m grid in x–z on two layers (y = ±0.5 m; a sparse sample); every
    point's rigid target is a cell centre of its layer, 1.41 m from the nearest node. 23 static points carry an own flow 0.5 m off
    (what a Chamfer match to a node gives), 40 points of a car move 6 m. By the scale alone (0.1 m: the
    median residual is 0) both pass the gate; with κ = 1 the scale there is 1.41 m: the strays' gate is
    0.5⁴ / (1.41⁴ + 0.5⁴) ≈ 0.016, the car's 6⁴ / (1.41⁴ + 6⁴) ≈ 0.997."""
    odd = torch.arange(-15.0, 16.0, 2.0, dtype=torch.float64)
    layers = torch.tensor([-0.5, 0.5], dtype=torch.float64)
    targets = torch.stack(torch.meshgrid(odd, layers, odd, indexing="ij"), -1).reshape(1, -1, 3)  # 512 centres
    t = torch.tensor([0.2, 0.0, 1.0], dtype=torch.float64)
    p = targets - t
    rigid = t.expand_as(p)
    flow = rigid.clone()
    flow[:, :40] += torch.tensor([0.0, 0.0, 6.0], dtype=torch.float64)  # the car
    strays = torch.arange(50, 500, 20)
    flow[:, strays] += torch.tensor([0.3, 0.0, 0.4], dtype=torch.float64)
    even = torch.arange(-16.0, 17.0, 2.0, dtype=torch.float64)
    frame2 = torch.stack(torch.meshgrid(even, layers, even, indexing="ij"), -1).reshape(1, -1, 3)
    for spacing, strays_kept in ((0.0, True), (1.0, False)):
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, mad_factor=3.0, frame2=frame2,
                                      gate_spacing=spacing)
        assert torch.allclose(out[:, :40], flow[:, :40], atol=0.05)  # (1 − 0.997) × 6 m ≈ 0.02 m at most
        stray_err = (out[:, strays] - rigid[:, strays]).norm(dim=-1)
        assert (stray_err > 0.45).all() if strays_kept else (stray_err < 0.05).all()


def test_evidence_gate_keeps_departures_frame_two_supports_and_shuts_the_rest():
    """``evidence``: frame 2 holds every static point at its rigid target and the car's 40 points 2 m further
    on. The car's own flow lands on its frame-2 points, nearer than its rigid target (2 m from any): kept.
    23 static points carry a spurious 0.6 m departure (a static point the net calls moving) that lands
    where frame 2 has nothing, farther than their rigid target (on a frame-2 point): shut. Without evidence
    the residual alone passes both."""
    g = torch.Generator().manual_seed(2)
    p = (torch.rand(1, 500, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([40.0, 4.0, 40.0])
    T = torch.tensor(pose_vec_to_mat(np.array([0.02, 0.0, 0.9, 0.0, 0.01, 0.0])))
    rigid = p @ T[:3, :3].T + T[:3, 3] - p
    car = torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
    frame2 = p + rigid
    frame2[:, :40] += car
    flow = rigid.clone()
    flow[:, :40] += car
    strays = torch.arange(50, 500, 20)
    flow[:, strays] += torch.tensor([0.0, 0.0, -0.6], dtype=torch.float64)
    for evidence, strays_kept in ((False, True), (True, False)):
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, mad_factor=3.0, frame2=frame2,
                                      evidence=evidence)
        assert torch.allclose(out[:, :40], flow[:, :40], atol=0.05)  # the car keeps its own flow
        stray_err = (out[:, strays] - rigid[:, strays]).norm(dim=-1)
        assert (stray_err > 0.5).all() if strays_kept else (stray_err < 0.01).all(), stray_err.max()


def _wall_and_car() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A wall 20 m ahead whose frame-2 points lie on a 0.5 m grid, frame 1's on the same wall between them (their
    rigid targets at the grid cells' centres, 0.35 m = 0.71 spacings from the nearest sample: the worst a right rigid
    target gets), and a car's rear 12 m ahead, on a 0.25 m grid, that drives 2 m on. The camera turns 1° and moves
    0.9 m forward. Returns frame-1 points (camera 1), frame 2 (camera 2), the rigid flow, the true flow, the car's
    mask and the camera's motion (R (1, 3, 3), t (1, 3)); metres, float64."""
    T = torch.tensor(pose_vec_to_mat(np.array([0.02, 0.0, 0.9, 0.0, np.radians(1.0), 0.0])))
    xs, ys = torch.arange(-10.0, 10.01, 0.5, dtype=torch.float64), torch.arange(-2.0, 1.51, 0.5, dtype=torch.float64)
    grid = torch.stack(torch.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    wall2 = torch.cat([grid, torch.full((len(grid), 1), 20.0, dtype=torch.float64)], 1)
    inv = torch.linalg.inv(T)
    wall1 = (wall2 + torch.tensor([0.25, 0.25, 0.0], dtype=torch.float64)) @ inv[:3, :3].T + inv[:3, 3]
    cx, cy = torch.arange(2.0, 4.01, 0.25, dtype=torch.float64), torch.arange(-0.5, 1.01, 0.25, dtype=torch.float64)
    face = torch.stack(torch.meshgrid(cx, cy, indexing="ij"), -1).reshape(-1, 2)
    car1 = torch.cat([face, torch.full((len(face), 1), 12.0, dtype=torch.float64)], 1)
    p = torch.cat([wall1, car1])[None]
    rigid = p @ T[:3, :3].T + T[:3, 3] - p
    car = torch.zeros(p.shape[1], dtype=torch.bool)
    car[len(wall1):] = True
    truth = rigid.clone()
    truth[0, car] += torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
    frame2 = torch.cat([wall2[None], (p + truth)[:, car]], 1)
    return p, frame2, rigid, truth, car, (T[None, :3, :3], T[None, :3, 3])


def test_off_surface_tells_a_mover_s_rigid_targets_from_a_sampled_surface_s():
    """Rigid targets on the wall, however they fall between its samples (0.71 spacings at most here), lie on frame
    2's surface; the car's, 2 m in front of its frame-2 points (8 of its 0.25 m spacings), lie off it — point by point
    and by the quarter rule over 16 neighbours."""
    p, frame2, rigid, _, car, _ = _wall_and_car()
    for k in (0, 16):
        off = off_surface(p, p + rigid, frame2, 1.5, k)[0]
        assert off[car].all() and not off[~car].any()
    gap_on_wall = off_surface(p, p + rigid, frame2, 0.70, 0)[0]  # the wall's targets sit at 0.71 spacings
    assert gap_on_wall[~car].all()


def test_surface_evidence_shuts_a_departure_that_snaps_onto_frame_two_s_own_surface():
    """A patch of the wall whose flow snaps onto the nearest frame-2 sample (a coherent 0.35 m departure along the
    wall, as a Chamfer match gives) lands nearer to frame 2 than its rigid target: the evidence test alone takes it.
    With ``surface`` 1.5 the camera's motion leaves that patch on frame 2's surface, so it is held at the rigid
    flow; the car, whose rigid targets lie off the surface, keeps its own flow either way. Held at the camera's
    motion, as the anchor holds the finest level at the vote's."""
    p, frame2, rigid, truth, car, motion = _wall_and_car()
    flow = truth.clone()
    patch = (p[0, :, 0] < -6.0) & ~car
    flow[0, patch] -= torch.tensor([0.25, 0.25, 0.0], dtype=torch.float64)  # onto the grid's samples
    for surface, patch_kept in ((0.0, True), (1.5, False)):
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, mad_factor=3.0, gate_k=16, frame2=frame2,
                                      motion=motion, evidence=True, surface=surface)
        assert torch.allclose(out[0, car], truth[0, car], atol=0.05)  # the car keeps its own flow
        patch_dep = (out[0, patch] - rigid[0, patch]).norm(dim=-1)
        inner = p[0, patch, 0] < -7.0  # the patch's points away from its edge, whose neighbourhoods lie inside it
        assert (patch_dep[inner] > 0.3).all() if patch_kept else (patch_dep < 1e-6).all(), patch_dep.max()


def test_the_neighbourhood_scale_lets_a_mover_through_a_noisy_net_s_gate():
    """A net whose static flows carry 0.1 m of noise per axis: the points' own departures put the gate's robust scale
    near 0.7 m, and a car that departs by 0.5 m (40 points, one cluster) stays mostly shut. The gate tests each point's
    16-neighbour median departure, whose noise is a few times smaller; scaled by those medians the car passes while
    the static points stay held. Held at the true camera motion, as the anchor holds the finest level."""
    g = torch.Generator().manual_seed(3)
    p = (torch.rand(1, 600, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([40.0, 4.0, 40.0])
    p[0, :40] = torch.tensor([5.0, 0.0, 12.0], dtype=torch.float64) + 0.8 * torch.randn(40, 3, generator=g,
                                                                                           dtype=torch.float64)
    T = torch.tensor(pose_vec_to_mat(np.array([0.02, 0.0, 0.9, 0.0, 0.01, 0.0])))
    rigid = p @ T[:3, :3].T + T[:3, 3] - p
    flow = rigid + 0.1 * torch.randn(p.shape, generator=g, dtype=torch.float64)
    flow[:, :40] = rigid[:, :40] + torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64)
    motion = (T[None, :3, :3], T[None, :3, 3])
    kept = {}
    for scaled in (False, True):
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, mad_factor=3.0, gate_k=16, motion=motion,
                                      neighbourhood_scale=scaled)
        kept[scaled] = (out[0, :40] - rigid[0, :40]).norm(dim=-1).median()
        static_left = (out[0, 40:] - rigid[0, 40:]).norm(dim=-1).median()
        assert static_left < 0.05, static_left  # the static noise is held either way
    assert kept[False] < 0.2 and kept[True] > 0.4, kept


def test_a_negative_gate_neighbourhood_or_spacing_is_refused():
    from core.errors import ConfigError
    from training.model.halflownet import HALFlowConfig

    with pytest.raises(ConfigError, match="ego_gate_k"):
        HALFlowConfig(ego_gate_k=-1)
    with pytest.raises(ConfigError, match="ego_gate_spacing"):
        HALFlowConfig(ego_gate_spacing=-0.5)
    with pytest.raises(ConfigError, match="ego_open_gradient_k"):
        HALFlowConfig(ego_open_gradient_k=-1)


def test_own_departure_removes_the_flows_camera_error_so_the_held_gate_keeps_the_movers():
    """HALFlowConfig.eval_own_departure: a net whose flow follows a camera motion 0.4 m and 1° off the vote's
    (here the identity, as in the vote-aligned frame), with 60 movers departing 0.8 m from it. Held at the vote's
    motion, every static point departs by ~0.4 m, the gate's robust scale (3 × 1.4826 × the median residual ≈ 1.8 m)
    grows past the movers and holds them; their departure from the net's own motion leaves the static points at
    ~0 (the scale falls to σ) and hands the movers their 0.8 m."""
    g = torch.Generator().manual_seed(3)
    p = torch.randn(1, 600, 3, generator=g, dtype=torch.float64) * 6.0
    off = torch.tensor(pose_vec_to_mat(np.array([0.3, 0.0, 0.26, 0.0, np.radians(1.0), 0.0])))
    d = torch.tensor([0.0, 0.0, 0.8], dtype=torch.float64)
    flow = p @ off[:3, :3].T + off[:3, 3] - p
    flow[:, :60] += d
    hold = (torch.eye(3, dtype=torch.float64)[None], torch.zeros(1, 3, dtype=torch.float64))
    kw = dict(sigma=0.1, iterations=4, mad_factor=3.0)
    dep = own_departure(p, flow, **kw)
    # the movers keep a Cauchy weight of σ² / (σ² + 0.8²) ≈ 0.015 each in the fit: together ~0.2 % of its weight,
    # so the fitted motion leans ~1.5 mm their way (measured 1.1–1.8 mm)
    assert dep[:, 60:].norm(dim=-1).max() < 0.005 and (dep[:, :60] - d).norm(dim=-1).max() < 0.005
    kept = rigid_plus_residual(p, dep, motion=hold, **kw).flow
    held = rigid_plus_residual(p, flow, motion=hold, **kw).flow
    assert (kept[:, :60] - d).norm(dim=-1).max() < 0.01 and kept[:, 60:].norm(dim=-1).max() < 1e-4
    assert ((held[:, :60] * d).sum(-1) / 0.64).mean() < 0.5  # held: less than half of their departure along it


def _view_scene() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Frame 1: a street in front of the camera (x in ±8 m, y ±1 m, z 5–30 m) and a wall beside it from x = 4 to
    20 m at z 4–6 m; the camera moves 1.5 m forward (rigid flow −1.5 m along z). Frame 2: the street re-seen a
    little wider (x ±9 m, y ±1.2 m, z 3–30 m in camera 2), so its azimuth range reaches ~71.6° (less the 0.5°
    margin): every street target lies inside (at most 66°), the wall's far part (x beyond ~9.5 m at z 3–4.5 m) outside.
    Returns (points (1, N, 3), rigid (1, N, 3), frame 2 (1, M, 3)), metres, camera frames."""
    g = torch.Generator().manual_seed(5)

    def box(n, half_x, half_y, z0, z1):
        return torch.stack([(torch.rand(n, generator=g) * 2 - 1) * half_x, (torch.rand(n, generator=g) * 2 - 1) * half_y,
                            torch.rand(n, generator=g) * (z1 - z0) + z0], -1)

    wall = torch.stack([torch.linspace(4, 20, 60), torch.zeros(60), torch.linspace(4, 6, 60)], -1)
    points = torch.cat([box(400, 8.0, 1.0, 5.0, 30.0), wall])[None].double()
    rigid = torch.zeros_like(points)
    rigid[..., 2] = -1.5
    corners = torch.tensor([[9.0, 0.0, 3.0], [-9.0, 0.0, 3.0], [0.0, 1.2, 3.0], [0.0, -1.2, 3.0], [0.0, 0.0, 30.0]])
    frame2 = torch.cat([box(600, 9.0, 1.2, 3.0, 30.0), corners])[None].double()
    return points, rigid, frame2


def test_points_that_leave_the_view_are_held_at_the_camera_motion_unless_they_depart_with_their_in_view_neighbours():
    """HALFlowConfig.eval_view_hold: a point whose rigid target frame 2 could not have seen gives up its own departure,
    unless it departs as its k nearest points in view do (within ``agree`` metres of their median departure): then
    it takes theirs."""
    from core.view import ViewExtent

    points, rigid, frame2 = _view_scene()
    out = ~torch.from_numpy(ViewExtent.of(frame2[0].numpy()).contains((points + rigid)[0].numpy()))
    assert not out[:400].any() and 0 < int(out[400:].sum()) < 60  # the wall's far end only
    flow = rigid.clone()
    flow[:, 400:, 0] += 0.9  # the whole wall departs 0.9 m: its far part with its near part
    held, marked = hold_out_of_view(points, flow, rigid, frame2)
    assert torch.equal(marked[0], out)
    assert torch.equal(held[0, ~out], flow[0, ~out]) and torch.equal(held[0, out], rigid[0, out])  # k = 0: held
    moved, marked = hold_out_of_view(points, flow, rigid, frame2, k=8)
    assert torch.allclose(moved[0, out], flow[0, out])  # departs with its in-view neighbours: theirs
    assert not marked.any()
    alone = flow.clone()
    alone[0, out, 0] += 0.5  # 0.5 m beyond its neighbours' departure: not with them
    kept, marked = hold_out_of_view(points, alone, rigid, frame2, k=8)
    assert torch.allclose(kept[0, out], rigid[0, out]) and torch.equal(marked[0], out)
    near = flow.clone()
    near[0, out, 0] += 0.05  # within 0.1 m of their departure: with them, and it takes their median
    close, _ = hold_out_of_view(points, near, rigid, frame2, k=8, agree=0.1)
    assert torch.allclose(close[0, out], flow[0, out])
    still = rigid.clone()
    still[0, out, 0] += 0.9  # only the part out of view departs (a false match): its neighbours do not
    stay, _ = hold_out_of_view(points, still, rigid, frame2, k=8)
    assert torch.allclose(stay[0, out], rigid[0, out])
    few, _ = hold_out_of_view(points[:, 380:], flow[:, 380:], rigid[:, 380:], frame2, k=500)  # fewer than k in view
    assert torch.equal(few[0, out[380:]], rigid[0, 380:][out[380:]])
