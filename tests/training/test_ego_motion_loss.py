"""The ego-motion term (training/losses/ego_motion.py): its value, its place in the multi-level loss (off by
default = the paper), the rigid flows the ego head reports for it, and that it trains the head's motion."""

from __future__ import annotations

import pytest
import torch

from core.errors import ConfigError
from _loss_levels import check_enters_every_level
from training.losses import LevelInputs, LossWeights, multi_level_loss
from training.losses.ego_motion import ego_motion_term
from training.model.ego_motion import weighted_rigid_fit

K = torch.tensor([[[40.0, 0.0, 23.5], [0.0, 40.0, 15.5], [0.0, 0.0, 1.0]]])
SF_S = torch.tensor([0.1, 0.0, -0.8])


def test_term_is_the_mean_distance_between_the_fitted_and_the_static_flow():
    sf = SF_S.expand(2, 50, 3).clone()
    assert ego_motion_term(sf, sf).item() == pytest.approx(0.0, abs=1e-6)
    rigid = sf + torch.tensor([0.0, 0.3, 0.4])  # 0.5 m off at every point
    assert ego_motion_term(rigid, sf).item() == pytest.approx(0.5, abs=2e-3)
    rigid[1] += torch.tensor([0.0, 0.9, 1.2])  # the second element 2 m off: the mean over both
    assert ego_motion_term(rigid, sf).item() == pytest.approx(1.25, abs=2e-3)
    rigid.requires_grad_(True)
    ego_motion_term(rigid, sf).backward()
    assert torch.isfinite(rigid.grad).all() and rigid.grad.abs().sum() > 0


def _levels(with_rigid: bool = True, with_gaps: bool = False) -> list[LevelInputs]:
    levels = []
    for n, seed in ((60, 0), (30, 1)):
        g = torch.Generator().manual_seed(seed)
        pc1 = torch.rand(1, n, 3, generator=g) * 10 + torch.tensor([-5.0, -1.0, 5.0])
        sf = SF_S.expand(1, n, 3).clone()
        flow_o = sf + 0.2 * torch.randn(1, n, 3, generator=g)
        levels.append(LevelInputs(pc1=pc1, pc2=pc1 + sf, flow_o=flow_o, flow_d=torch.zeros_like(flow_o),
                                  static_flow=sf, K=K, depth2=torch.full((1, 32, 48), 10.0),
                                  rigid_o=(sf + torch.tensor([0.0, 0.0, 0.3])) if with_rigid else None,
                                  gap_o=torch.full((1, n), 0.04) if with_gaps else None,
                                  gap_d=torch.full((1, n), 0.02) if with_gaps else None))
    return levels


def test_the_term_enters_every_level_with_its_weight_and_is_off_by_default():
    terms = check_enters_every_level(_levels, "ego_motion", "ego", 2.0, alpha=(0.02, 0.04))
    for k in range(2):
        assert terms[f"l{k}/ego"] == pytest.approx(0.3, abs=2e-3)
    with pytest.raises(ConfigError, match="ego_head"):
        multi_level_loss(_levels(with_rigid=False), LossWeights(ego_motion=1.0, alpha=(0.02, 0.04)))
    with pytest.raises(ConfigError, match="ego_motion"):
        LossWeights(ego_motion=-0.5)


def test_the_gate_pull_enters_every_level_with_its_weight_and_is_off_by_default():
    """The gate pull (training/losses/gate_pull.py; more in tests/training/test_gate_pull.py): the mean gap
    of both passes, α_k · gate_pull at every level."""
    terms = check_enters_every_level(lambda: _levels(with_gaps=True), "gate_pull", "pull", 2.0, alpha=(0.02, 0.04))
    for k in range(2):
        assert terms[f"l{k}/pull"] == pytest.approx(0.06, rel=1e-6)  # both passes: 0.04 + 0.02 m²
    with pytest.raises(ConfigError, match="ego_head"):
        multi_level_loss(_levels(), LossWeights(gate_pull=1.0, alpha=(0.02, 0.04)))
    with pytest.raises(ConfigError, match="gate_pull"):
        LossWeights(gate_pull=-1.0)


def test_the_ego_head_reports_a_rigid_flow_per_level_and_the_term_trains_it():
    from training.config import level_points_for
    from training.model.halflownet import HALFlowConfig, HALFlowNet

    torch.manual_seed(0)
    torch.set_num_threads(1)
    lp = level_points_for(512)
    g = torch.Generator().manual_seed(3)
    pc1 = torch.rand(2, 512, 3, generator=g) * torch.tensor([20.0, 2.0, 30.0]) + torch.tensor([-10.0, -1.0, 3.0])
    sf = SF_S.expand(2, 512, 3)
    pc2 = (pc1 + sf)[:, torch.randperm(512, generator=g)]
    assert HALFlowNet(HALFlowConfig(n_points=512, level_points=lp, width_scale=0.25))(pc1, pc2).rigid_flows == []
    net = HALFlowNet(HALFlowConfig(n_points=512, level_points=lp, width_scale=0.25, ego_head=True))
    out = net(pc1, pc2)
    assert [tuple(r.shape) for r in out.rigid_flows] == [(2, n, 3) for n in lp[:4]]
    for r, pts in zip(out.rigid_flows, out.points):  # each is exactly one rigid motion's flow
        R, t = weighted_rigid_fit(pts.double(), (pts + r).double(), torch.ones(pts.shape[:2], dtype=torch.float64))
        moved = pts.double() @ R.transpose(1, 2) + t[:, None]
        assert (moved - (pts + r).double()).norm(dim=-1).max() < 1e-3
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    losses = []
    for _ in range(15):
        out = net(pc1, pc2)
        loss = sum(ego_motion_term(r, sf[:, : r.shape[1]]) for r in out.rigid_flows)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]  # the term reaches the weights through the head's fit


def test_finest_only_leaves_the_named_terms_out_of_the_coarser_levels():
    """``loss.finest_only`` (an ablation, twenty-second round): the named departure terms count at L0 and
    nowhere else; the rest of the loss is unchanged."""
    w = dict(ego_motion=1.0, gate_pull=2.0, alpha=(0.02, 0.04))
    full_total, full = multi_level_loss(_levels(with_gaps=True), LossWeights(**w))
    kept_total, kept = multi_level_loss(_levels(with_gaps=True), LossWeights(**w, finest_only=("ego", "pull")))
    # finest-first α under the released order: (0.04, 0.02); the coarse level loses α₁ (ego + 2 · pull)
    dropped = 0.02 * (full["l1/ego"] + 2.0 * full["l1/pull"])
    assert kept_total.item() == pytest.approx(full_total.item() - dropped, rel=1e-5)
    assert "l0/ego" in kept and "l0/pull" in kept and "l1/ego" not in kept and "l1/pull" not in kept
    assert kept["l0/weighted"] == pytest.approx(full["l0/weighted"], rel=1e-6)
    with pytest.raises(ConfigError, match="finest_only"):
        LossWeights(finest_only=("chamfer",))
