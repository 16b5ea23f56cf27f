"""HALFlowConfig.eval_anchor: the rigid vote, the finest level held at the vote's motion and the evidence gate
at inference only; ``ego_l0_hold_from="vote"`` (docs/learned-flow.md, twentieth round)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from _street import walls_and_poles
from core.errors import ConfigError
from training.config import level_points_for
from training.model.halflownet import HALFlowNet
from training.model.halflownet_config import HALFlowConfig

ANCHORED = dict(rigid_vote=True, ego_l0_hold=True, ego_l0_hold_from="vote", ego_gate_evidence=True)


def _cfg(**kw) -> HALFlowConfig:
    parts = dict(translation_vote=True, ego_head=True, l0_cost_volume=True)
    return HALFlowConfig(n_points=512, level_points=level_points_for(512), width_scale=0.25, feature_dim=0,
                         norm="layer", **{**parts, **kw})


def _pair() -> tuple[torch.Tensor, torch.Tensor]:
    """A street turned by 2° and moved 1 m forward, frame 2 re-ordered."""
    a = math.radians(2.0)
    R = torch.tensor([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    pc1 = walls_and_poles(512, 0, facade_half_width_m=10.0)
    pc2 = pc1[:, torch.randperm(512, generator=torch.Generator().manual_seed(1))] @ R.T + torch.tensor([0.0, 0.0, 1.0])
    return pc1, pc2


def _flows(net: HALFlowNet, pc1: torch.Tensor, pc2: torch.Tensor) -> list[torch.Tensor]:
    with torch.no_grad():
        return net(pc1, pc2).flows


def test_inference_runs_the_anchored_switches_and_training_steps_run_the_config_as_set():
    pc1, pc2 = _pair()
    torch.manual_seed(0)
    anchored = HALFlowNet(_cfg(eval_anchor=True))
    with torch.no_grad():  # a finest-level push, so the hold and the evidence gate have something to change
        anchored.head0.linear.bias.copy_(torch.tensor([0.0, 0.0, 0.4]))
    plain = HALFlowNet(_cfg())
    switched = HALFlowNet(_cfg(**ANCHORED))
    plain.load_state_dict(anchored.state_dict())
    switched.load_state_dict(anchored.state_dict())

    for a, b in zip(_flows(anchored.eval(), pc1, pc2), _flows(switched.eval(), pc1, pc2)):
        assert torch.allclose(a, b, atol=1e-6)
    for a, b in zip(_flows(anchored.train(), pc1, pc2), _flows(plain.train(), pc1, pc2)):
        assert torch.allclose(a, b, atol=1e-6)
    # and the two passes differ: the anchor changes what inference returns
    gap = (_flows(anchored.eval(), pc1, pc2)[0] - _flows(plain.eval(), pc1, pc2)[0]).norm(dim=-1).mean()
    assert gap > 0.05, gap
    assert anchored.config.rigid_vote is False  # the stored config is not changed by an inference pass


def test_the_config_names_its_inference_switches_and_refuses_an_anchor_without_its_parts():
    cfg = _cfg(eval_anchor=True)
    inf = cfg.at_inference()
    assert {k: getattr(inf, k) for k in ANCHORED} == ANCHORED
    assert dataclasses.replace(inf, **{k: getattr(cfg, k) for k in ANCHORED}) == cfg
    assert _cfg().at_inference() == _cfg()
    for off in ("translation_vote", "ego_head", "l0_cost_volume"):
        with pytest.raises(ConfigError, match="eval_anchor"):
            _cfg(eval_anchor=True, **{off: False})


def test_eval_gate_k_sets_the_gates_neighbourhood_for_inference_passes_only(monkeypatch):
    """``eval_gate_k`` (twenty-second round) is ``ego_gate_k`` for the anchored inference pass; training
    steps keep the gate as configured (``ego_gate_k``'s rule itself: tests/training/test_ego_motion.py)."""
    cfg = _cfg(eval_anchor=True, eval_gate_k=8)
    assert cfg.at_inference().ego_gate_k == 8 and cfg.ego_gate_k == 0
    assert _cfg(eval_anchor=True, ego_gate_k=4).at_inference().ego_gate_k == 4  # 0: the gate as trained
    import training.model.halflownet as halflownet

    seen: list[int] = []
    real = halflownet.rigid_plus_residual

    def spy(*args, **kwargs):
        seen.append(args[7])  # gate_k, as the net passes it
        return real(*args, **kwargs)

    monkeypatch.setattr(halflownet, "rigid_plus_residual", spy)
    pc1, pc2 = _pair()
    torch.manual_seed(0)
    net = HALFlowNet(cfg)
    switched = HALFlowNet(_cfg(**ANCHORED, ego_gate_k=8))
    plain = HALFlowNet(_cfg())
    for other in (switched, plain):
        other.load_state_dict(net.state_dict())
    for a, b in zip(_flows(net.eval(), pc1, pc2), _flows(switched.eval(), pc1, pc2)):
        assert torch.allclose(a, b, atol=1e-6)
    assert seen and set(seen) == {8}
    seen.clear()
    for a, b in zip(_flows(net.train(), pc1, pc2), _flows(plain.train(), pc1, pc2)):
        assert torch.allclose(a, b, atol=1e-6)
    assert seen and set(seen) == {0}


def test_eval_gate_k_needs_the_anchor_and_goes_with_it():
    with pytest.raises(ConfigError, match="eval_gate_k"):
        _cfg(eval_gate_k=8)
    with pytest.raises(ConfigError, match="eval_gate_k"):
        _cfg(eval_anchor=True, eval_gate_k=-1)
    full = _cfg(eval_anchor=True, eval_gate_k=8, rigid_vote_dense=True, rigid_vote_far=True, rigid_vote_yaw_deg=6.0)
    off = full.without_anchor()
    assert not (off.eval_anchor or off.eval_gate_k or off.rigid_vote_dense or off.rigid_vote_far
                or off.rigid_vote_yaw_deg)
    kept = dataclasses.replace(full, rigid_vote=True).without_anchor()  # a vote left: its options stay
    assert kept.rigid_vote_dense and kept.rigid_vote_far and kept.rigid_vote_yaw_deg == 6.0 and not kept.eval_gate_k
