"""The flow smoothness term (training/losses/flow_smooth.py): zero for one shared departure, a pull that
brings a stray point back to its neighbours, measured on the departure from the camera's motion, and its
place in the multi-level loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.errors import ConfigError
from _loss_levels import check_enters_every_level
from training.losses import LevelInputs, LossWeights
from training.losses.flow_smooth import flow_smoothness


def _grid(n_side: int = 8, spacing: float = 0.5) -> torch.Tensor:
    """A flat wall of n_side² points at z = 10 m, ``spacing`` metres apart."""
    u = torch.arange(n_side, dtype=torch.float64) * spacing
    x, y = torch.meshgrid(u, u, indexing="ij")
    return torch.stack([x.reshape(-1), y.reshape(-1), torch.full((n_side * n_side,), 10.0, dtype=torch.float64)],
                       -1)[None]


def test_one_shared_motion_costs_nothing_and_a_stray_point_costs_its_departure():
    pc1 = _grid()
    flow = torch.tensor([0.3, 0.0, -1.2], dtype=torch.float64).expand_as(pc1).clone()
    assert flow_smoothness(pc1, flow, k=4).item() == pytest.approx(0.0, abs=1e-9)
    stray = 27  # an interior point: its 4 nearest points are its grid neighbours, and it is theirs
    flow[0, stray] += torch.tensor([0.0, 0.4, 0.0], dtype=torch.float64)
    n, k = pc1.shape[1], 4
    # its own 4 pairs and the 4 pairs in which it is a neighbour, each 0.4 m (the length smoothed at 1 mm)
    expected = 8 * (np.sqrt(0.16 + 1e-6) - 1e-3) / (n * k)
    assert flow_smoothness(pc1, flow, k=4).item() == pytest.approx(expected, rel=1e-9)


def test_descent_brings_a_stray_point_back_and_leaves_a_shared_motion_alone():
    pc1 = _grid()
    base = torch.tensor([0.3, 0.0, -1.2], dtype=torch.float64)
    flow = base.expand_as(pc1).clone()
    flow[0, 27] += torch.tensor([0.0, 0.4, 0.0], dtype=torch.float64)
    flow.requires_grad_(True)
    opt = torch.optim.SGD([flow], lr=0.5)
    for _ in range(400):
        opt.zero_grad()
        flow_smoothness(pc1, flow, k=4).backward()
        opt.step()
    flow = flow.detach()
    assert (flow[0, 27] - base).norm() < 0.05  # back within 5 cm of its neighbours' motion
    others = torch.cat([flow[0, :27], flow[0, 28:]])
    # the neighbours moved towards it by as much as it moved back (the term is symmetric), spread over many points
    assert (others - base).norm(dim=-1).max() < 0.1


def test_two_rigid_bodies_apart_cost_nothing_and_the_term_is_zero_for_one_point():
    a, b = _grid(4), _grid(4) + torch.tensor([20.0, 0.0, 0.0], dtype=torch.float64)
    pc1 = torch.cat([a, b], 1)
    flow = torch.cat([torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64).expand_as(a),
                      torch.tensor([1.5, 0.0, 0.5], dtype=torch.float64).expand_as(b)], 1)
    assert flow_smoothness(pc1, flow, k=5).item() == pytest.approx(0.0, abs=1e-9)  # no neighbourhood spans both
    one = torch.zeros(1, 1, 3, requires_grad=True)
    value = flow_smoothness(torch.zeros(1, 1, 3), one)
    value.backward()
    assert value.item() == 0.0 and one.grad is not None and one.grad.abs().sum() == 0


def _levels() -> list[LevelInputs]:
    K = torch.tensor([[[40.0, 0.0, 23.5], [0.0, 40.0, 15.5], [0.0, 0.0, 1.0]]])
    levels = []
    for n, seed in ((60, 0), (30, 1)):
        g = torch.Generator().manual_seed(seed)
        pc1 = torch.rand(1, n, 3, generator=g) * 10 + torch.tensor([-5.0, -1.0, 5.0])
        sf = torch.tensor([0.1, 0.0, -0.8]).expand(1, n, 3).clone()
        flow_o = sf + 0.2 * torch.randn(1, n, 3, generator=g)
        levels.append(LevelInputs(pc1=pc1, pc2=pc1 + sf, flow_o=flow_o, flow_d=torch.zeros_like(flow_o),
                                  static_flow=sf, K=K, depth2=torch.full((1, 32, 48), 10.0)))
    return levels


def test_the_term_enters_every_level_with_its_weight_and_is_off_by_default():
    terms = check_enters_every_level(_levels, "flow_smooth", "smooth", 0.5, alpha=(0.02, 0.04))
    for k, level in enumerate(_levels()):
        departure = level.flow_o - level.static_flow
        assert terms[f"l{k}/smooth"] == pytest.approx(flow_smoothness(level.pc1, departure).item(), rel=1e-6)
        assert terms[f"l{k}/smooth"] > 0.1  # 0.2 m noise per component: neighbours differ by ≈ 0.45 m
    with pytest.raises(ConfigError, match="flow_smooth"):
        LossWeights(flow_smooth=-1.0)


def test_a_turning_cameras_flow_costs_nothing_in_the_loss():
    """The loss measures the departure from stage one's static flow: a camera turning by 2° gives a flow
    that differs between neighbours by 1.7 cm at 0.5 m, which the plain flow's length would count on
    every point; the departure is zero."""
    pc1 = _grid()
    a = np.deg2rad(2.0)
    R = torch.tensor([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]], dtype=torch.float64)
    sf = pc1 @ R.T + torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64) - pc1
    assert flow_smoothness(pc1, sf, k=4).item() > 0.005  # the flow itself is not: 1.7 cm on the x pairs, half of them
    K = torch.tensor([[[40.0, 0.0, 23.5], [0.0, 40.0, 15.5], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    level = LevelInputs(pc1=pc1, pc2=pc1 + sf, flow_o=sf.clone().requires_grad_(True), flow_d=torch.zeros_like(sf),
                        static_flow=sf, K=K, depth2=torch.full((1, 32, 48), 10.0, dtype=torch.float64))
    from training.losses.total import level_terms
    terms = level_terms(level, LossWeights(flow_smooth=1.0, use_depth=False, use_ds=False, use_chamfer=False,
                                           use_laplacian=False))
    assert terms["smooth"].item() == pytest.approx(0.0, abs=1e-9)
    grad, = torch.autograd.grad(terms["smooth"], level.flow_o)
    assert grad.abs().max() < 1e-9
