"""The gate pull (training/losses/gate_pull.py, LossWeights.gate_pull): it pulls the own flow that the ego
head's gate holds at the camera's motion back to it, leaves movers alone, and reaches every head through the
gaps the net reports (its place in the multi-level loss: tests/training/test_ego_motion_loss.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.errors import InputError
from core.geometry import pose_vec_to_mat
from training.losses.chamfer import chamfer
from training.losses.gate_pull import gate_pull
from training.model.ego_motion import rigid_plus_residual


def _gap(p: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    out, *_ = rigid_plus_residual(p, flow, sigma=0.25, iterations=4, open_gradient=True)
    return ((flow - out.detach()) ** 2).sum(-1)


def test_descending_the_pull_returns_gated_strays_to_the_camera_motion_and_leaves_movers_alone():
    """600 points move with the camera; 60 of them carry a stray own flow 0.15 m off (inside the gate's
    σ = 0.25 m, so the head outputs the rigid flow there), 60 are movers 2.2 m off. Gradient descent on the
    pull alone brings the strays' own flow back to the head's rigid flow and hardly moves the movers'.
    (The rigid flow itself may wander: the pull alone prefers no camera motion over another, and the
    movers' small Cauchy weights bias the fit towards them; in training the Chamfer and ego-motion terms
    hold it.)"""
    g = torch.Generator().manual_seed(0)
    p = torch.randn(1, 600, 3, generator=g, dtype=torch.float64) * 6.0
    T = torch.tensor(pose_vec_to_mat(np.array([0.1, -0.02, 0.9, 0.01, 0.03, -0.02])))
    ego = p @ T[:3, :3].T + T[:3, 3] - p
    start = ego.clone()
    start[:, :60] += torch.tensor([2.0, 0.0, 1.0], dtype=torch.float64)  # movers
    start[:, 60:120] += torch.tensor([0.0, 0.09, 0.12], dtype=torch.float64)  # strays, 0.15 m off
    flow = start.clone().requires_grad_(True)
    gap0 = _gap(p, flow).detach()
    assert gap0[:, :60].max() < 1e-6  # open gate: the output is the own flow
    assert gap0[:, 60:120].min() > 0.5 * 0.15 ** 2  # closed gate: the output is (nearly) the rigid flow
    opt = torch.optim.SGD([flow], lr=600 / 4)  # the mean over 600 points: each step halves a point's gap
    for _ in range(30):
        opt.zero_grad()
        gate_pull(_gap(p, flow)).backward()
        opt.step()
    with torch.no_grad():
        _, R, t, *_ = rigid_plus_residual(p, flow, sigma=0.25, iterations=4)
        rigid = p @ R.transpose(1, 2) + t[:, None] - p
        stray_gap = (flow[:, 60:120] - rigid[:, 60:120]).norm(dim=-1)
        mover_shift = (flow[:, :60] - start[:, :60]).norm(dim=-1)
    assert stray_gap.max() < 0.01  # from 0.15 m
    # a mover's gate is open to 1 − (σ/r)⁴ ≈ 1 − 2·10⁻⁴: each step moves it by at most half of that × 2.24 m
    assert mover_shift.max() < 30 * 0.5 * 2e-4 * 2.24 * 2


def _held_departure(weight: float) -> float:
    """Mean ‖f − f'‖ (m) at which descent on Chamfer (τ 2 m) + ``weight`` × the pull leaves the own flows of a
    static scene whose every frame-2 sample lies 0.3 m from its point's true target (see the test below)."""
    g = torch.Generator().manual_seed(3)
    n = 200
    p = torch.rand(1, n, 3, generator=g, dtype=torch.float64) * 20.0 + torch.tensor([-10.0, -10.0, 5.0],
                                                                                   dtype=torch.float64)
    T = torch.tensor(pose_vec_to_mat(np.array([0.05, 0.0, 0.8, 0.0, 0.02, 0.0])))
    ego = p @ T[:3, :3].T + T[:3, 3] - p
    jitter = torch.randn(1, n, 3, generator=g, dtype=torch.float64)
    pc2 = p + ego + 0.3 * jitter / jitter.norm(dim=-1, keepdim=True)  # points ~3 m apart: the match is unique
    flow = ego.clone().requires_grad_(True)
    opt = torch.optim.SGD([flow], lr=n / (4 * weight))  # the pull's stiffness is 2w/n: each step halves the gap
    for _ in range(40):
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, mad_factor=3.0, open_gradient=True)
        gap = ((flow - out.detach()) ** 2).sum(-1)
        loss = chamfer(p + out, pc2, "torch", truncate=2.0) + weight * gate_pull(gap)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        out, *_ = rigid_plus_residual(p, flow, sigma=0.1, iterations=4, mad_factor=3.0)
        return float((flow - out).norm(dim=-1).mean())


def test_the_pull_weight_sets_how_far_a_held_static_flow_strays_towards_its_chamfer_match():
    """The equilibrium behind ``loss.gate_pull`` 4 (docs/learned-flow.md, thirteenth round). Where the gate
    holds the output at the rigid flow, the output does not move with the own flow, so the Chamfer term's
    pull on it never fades: 4 (f' − q) / n from the two directions, q its match at distance d. The pull
    2 w (f − f') / n balances it at ‖f − f'‖ = 2 d / w. With w = 1 the own flow overshoots its match
    (0.6 m for d = 0.3 m) and a gate whose scale is fixed lets it through; with w = 4 it stays at half of d."""
    far, near = _held_departure(1.0), _held_departure(4.0)
    assert far > 0.3  # past the sample it is pulled to (2 d / w = 0.6 m)
    assert near < 0.5 * 0.3  # 2 d / w = 0.15 m
    assert 0.2 < near / far < 0.3  # ∝ 1 / w


def test_bad_gaps_are_refused():
    with pytest.raises(InputError, match="gap_sq"):
        gate_pull(torch.zeros(2, 10, 3))


def test_the_net_reports_its_gate_gaps_and_gates_per_level_and_the_gaps_reach_the_heads():
    from training.config import level_points_for
    from training.model.halflownet import HALFlowConfig, HALFlowNet

    torch.manual_seed(0)
    lp = level_points_for(512)
    pc1 = torch.randn(2, 512, 3) * 4 + torch.tensor([0.0, 0.0, 10.0])
    pc2 = pc1 + torch.tensor([0.0, 0.0, -0.8])
    small = dict(n_points=512, level_points=lp, width_scale=0.25)
    plain = HALFlowNet(HALFlowConfig(**small))(pc1, pc2)
    assert plain.gate_gaps == [] and plain.gates == []
    net = HALFlowNet(HALFlowConfig(**small, ego_head=True, ego_open_gradient=True, l0_cost_volume=True))
    out = net(pc1, pc2)
    assert [tuple(g.shape) for g in out.gate_gaps] == [(2, n) for n in lp[:4]]
    assert all(bool((g >= 0).all()) and g.sum() > 0 for g in out.gate_gaps)  # random heads: own flows stray
    # the gate itself (loss.plane_where_held), per level, without gradient
    assert [tuple(g.shape) for g in out.gates] == [(2, n) for n in lp[:4]]
    assert all(bool((g >= 0).all() and (g <= 1).all()) and not g.requires_grad for g in out.gates)
    sum(gate_pull(g) for g in out.gate_gaps).backward()
    heads = [net.head0, net.head1, net.head2, net.head3, net.head0_refine]
    assert all(q.grad is not None and q.grad.abs().sum() > 0 for h in heads for q in h.parameters())
