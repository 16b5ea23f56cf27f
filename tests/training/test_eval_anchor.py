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


def _anchored_twins(**switch) -> tuple[HALFlowNet, HALFlowNet]:
    """Two anchored nets with the same (seed-0) weights: one with the inference ``switch`` on, one without."""
    torch.manual_seed(0)
    on = HALFlowNet(_cfg(eval_anchor=True, **switch))
    off = HALFlowNet(_cfg(eval_anchor=True))
    off.load_state_dict(on.state_dict())
    return on, off


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


def _grid_scene() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A 40 × 40 wall of points 0.1 m apart, 10 m ahead (camera axes); frame 2 holds the same points, a 0.6 m
    patch of them (the mover) moved 1 m along x. Returns pc1, the whole frame 2, a sparse sample of it (every
    fourth row and column), the mover mask and flows: static points at zero but every tenth, which strays onto
    the sparse sample's point 0.6 m away; movers at their true 1 m."""
    u, v = torch.meshgrid(torch.arange(40.0), torch.arange(40.0), indexing="ij")
    pc1 = torch.stack([u.flatten() * 0.1, v.flatten() * 0.1, torch.full((1600,), 10.0)], -1)
    mover = (u.flatten() < 6) & (v.flatten() < 6)
    shift = torch.tensor([1.0, 0.0, 0.0])
    pc2 = torch.where(mover[:, None], pc1 + shift, pc1)
    sparse = pc2[(u.flatten() % 4 == 0) & (v.flatten() % 4 == 0)]
    flow = torch.zeros_like(pc1)
    flow[mover] = shift
    stray = (~mover) & (torch.arange(1600) % 10 == 5)
    flow[stray] = torch.tensor([0.0, 0.6, 0.0])
    return pc1[None], pc2[None], sparse[None], mover, flow[None], stray


def test_the_evidence_test_against_the_whole_frame_2_shuts_stray_static_flows_and_keeps_movers():
    """``eval_evidence_dense``'s reason (thirty-fourth round): with the camera's motion held (here: none), a
    static point's stray flow lands on a sample point, so against a sparse sample it counts as supported
    and passes; against the whole frame 2 the point's own rigid target is a frame-2 point and the stray flow
    is shut. A mover's true flow passes either way."""
    from training.model.ego_motion import rigid_plus_residual

    pc1, pc2, sparse, mover, flow, stray = _grid_scene()
    hold = (torch.eye(3)[None], torch.zeros(1, 3))
    gates = {}
    for name, frame2 in (("sparse", sparse), ("whole", pc2)):
        gates[name] = rigid_plus_residual(pc1, flow, 0.1, 4, 3.0, frame2=frame2, motion=hold, evidence=True).gate[0]
    assert (gates["whole"][mover] > 0.99).all() and (gates["sparse"][mover] > 0.99).all()
    assert (gates["whole"][stray] == 0).all()
    passed = gates["sparse"][stray] > 0.99
    assert passed.float().mean() > 0.2, passed.float().mean()  # the sparse sample cannot tell them apart


def test_eval_evidence_dense_gives_the_finest_levels_evidence_test_the_whole_frame_2(monkeypatch):
    """The switch's wiring: at inference the last call of the finest level (the hold) gets frame 2's whole
    input, aligned by the vote like its L0 sample; without it, or in training steps, the L0 sample."""
    import training.model.halflownet as halflownet

    seen: list[int] = []
    gaps: list[float] = []
    real = halflownet.rigid_plus_residual

    def spy(*args, **kwargs):
        seen.append(args[8].shape[1])  # frame2, as the net passes it
        gaps.append(torch.cdist(args[0], args[8]).min(-1).values.mean().item())  # its points to frame 2
        return real(*args, **kwargs)

    monkeypatch.setattr(halflownet, "rigid_plus_residual", spy)
    pc1, pc2 = _pair()
    dense, sample = _anchored_twins(eval_evidence_dense=True)
    level0 = dense.config.level_points[0]
    _flows(dense.eval(), pc1, pc2)
    assert seen[-1] == pc2.shape[1] and set(seen[:-1]) <= set(dense.config.level_points)
    assert gaps[-1] < 0.1, gaps[-1]  # aligned by the vote: frame 2 is frame 1 moved 1 m and turned 2°
    seen.clear()
    _flows(sample.eval(), pc1, pc2)
    assert seen[-1] == level0
    seen.clear()
    _flows(dense.train(), pc1, pc2)
    assert pc2.shape[1] not in seen


def test_eval_evidence_dense_needs_an_evidence_test_and_goes_with_the_anchor():
    with pytest.raises(ConfigError, match="eval_evidence_dense"):
        _cfg(eval_evidence_dense=True)
    assert _cfg(eval_anchor=True, eval_evidence_dense=True).without_anchor().eval_evidence_dense is False
    kept = _cfg(eval_anchor=True, eval_evidence_dense=True, ego_gate_evidence=True).without_anchor()
    assert kept.eval_evidence_dense is True  # an evidence test left: the option stays


def test_eval_own_departure_needs_the_hold_at_the_vote_and_goes_with_the_anchor():
    with pytest.raises(ConfigError, match="eval_own_departure"):
        _cfg(eval_own_departure=True)
    assert _cfg(eval_anchor=True, eval_own_departure=True).without_anchor().eval_own_departure is False
    kept = _cfg(eval_anchor=True, eval_own_departure=True, **ANCHORED).without_anchor()
    assert kept.eval_own_departure is True  # the hold at the vote's motion left: the option stays


def test_eval_own_departure_changes_inference_passes_only(monkeypatch):
    """The switch's wiring: at inference the finest level's hold reads the flow's departure from its own robust
    fit (an :func:`~training.model.ego_motion.own_departure` call, and a different output); training steps, and
    the net without it, never call it."""
    import training.model.halflownet as halflownet

    calls: list[int] = []
    real = halflownet.own_departure

    def spy(*args, **kwargs):
        calls.append(args[0].shape[1])
        return real(*args, **kwargs)

    monkeypatch.setattr(halflownet, "own_departure", spy)
    pc1, pc2 = _pair()
    own, plain = _anchored_twins(eval_own_departure=True)
    a = _flows(own.eval(), pc1, pc2)[0]
    assert calls == [own.config.level_points[0]]
    b = _flows(plain.eval(), pc1, pc2)[0]
    _flows(own.train(), pc1, pc2)
    assert calls == [own.config.level_points[0]]
    assert a.shape == b.shape and torch.isfinite(a).all() and not torch.equal(a, b)


def test_eval_view_hold_needs_the_hold_at_the_vote_and_goes_with_the_anchor():
    with pytest.raises(ConfigError, match="eval_view_hold"):
        _cfg(eval_view_hold=True)
    assert _cfg(eval_anchor=True, eval_view_hold=True).without_anchor().eval_view_hold is False
    assert _cfg(eval_anchor=True, eval_view_hold=True, **ANCHORED).without_anchor().eval_view_hold is True


def test_eval_level_departure_needs_the_hold_at_the_vote_and_goes_with_the_anchor():
    with pytest.raises(ConfigError, match="eval_level_departure"):
        _cfg(eval_level_departure=True)
    assert _cfg(eval_anchor=True, eval_level_departure=True).without_anchor().eval_level_departure is False
    assert _cfg(eval_anchor=True, eval_level_departure=True, **ANCHORED).without_anchor().eval_level_departure is True


def test_level_departure_drops_the_vertical_part_only():
    from training.model.ego_motion import level_departure

    d = torch.tensor([[[0.3, -0.2, 1.1], [0.0, 0.5, -0.4]]], requires_grad=True)
    out = level_departure(d)
    assert torch.equal(out, torch.tensor([[[0.3, 0.0, 1.1], [0.0, 0.0, -0.4]]]))
    assert d[0, 0, 1].item() == pytest.approx(-0.2)  # a copy: the input keeps its vertical part
    out.sum().backward()
    assert torch.equal(d.grad, torch.tensor([[[1.0, 0.0, 1.0], [1.0, 0.0, 1.0]]]))


def test_eval_level_departure_changes_inference_passes_only(monkeypatch):
    """The switch's wiring: an inference pass hands the finest level's departures (the vote-aligned flow, one per L0
    point) to :func:`~training.model.ego_motion.level_departure`, and the gate reads what it returns — with no
    departure left, every point takes the vote's rigid flow; training steps, and the net without it, never call it."""
    import training.model.halflownet as halflownet

    calls: list[tuple] = []

    def spy(departure):
        calls.append(tuple(departure.shape))
        return torch.zeros_like(departure)  # a mark the output must carry: no point departs

    monkeypatch.setattr(halflownet, "level_departure", spy)
    pc1, pc2 = _pair()
    on, off = _anchored_twins(eval_level_departure=True)
    with torch.no_grad():
        out = on.eval()(pc1, pc2)
    assert calls == [(1, on.config.level_points[0], 3)]
    assert torch.allclose(out.flows[0], out.rigid_flows[0], atol=1e-5)
    _flows(off.eval(), pc1, pc2)
    _flows(on.train(), pc1, pc2)
    assert len(calls) == 1


def test_eval_view_hold_changes_inference_passes_only(monkeypatch):
    """The switch's wiring: an inference pass hands the finest level's points (camera 1), flow, the vote's rigid flow
    and frame 2's whole input to :func:`~training.model.ego_motion.hold_out_of_view` and returns what it gives;
    training steps, and the net without it, never call it."""
    import training.model.halflownet as halflownet

    calls: list[tuple] = []

    def spy(points, flow, rigid, frame2, k=0, agree=0.1):
        calls.append((points.shape[1], frame2.shape[1], k, agree))
        assert points.shape == flow.shape == rigid.shape and frame2.shape[-1] == 3
        return flow + 1.0, torch.zeros(flow.shape[:2], dtype=torch.bool)  # a mark the output must carry; none held

    monkeypatch.setattr(halflownet, "hold_out_of_view", spy)
    pc1, pc2 = _pair()
    on, off = _anchored_twins(eval_view_hold=True)
    a = _flows(on.eval(), pc1, pc2)[0]
    level0 = on.config.level_points[0]
    inference = on.config.at_inference()
    assert calls == [(level0, pc2.shape[1], inference.ego_gate_k, inference.ego_sigma)]  # the pass's gate and scale
    b = _flows(off.eval(), pc1, pc2)[0]
    _flows(on.train(), pc1, pc2)
    assert len(calls) == 1
    assert torch.isfinite(a).all() and torch.allclose(a, b + 1.0, atol=1e-5)
    monkeypatch.setattr(halflownet, "hold_out_of_view",
                        lambda points, flow, rigid, frame2, k=0, agree=0.1: (rigid, torch.ones(flow.shape[:2], dtype=torch.bool)))
    with torch.no_grad():
        every = on.eval()(pc1, pc2)
    assert torch.equal(every.gates[0], torch.zeros_like(every.gates[0]))  # every point held: no gate left open


def test_eval_evidence_surface_needs_the_evidence_test_and_goes_with_it():
    with pytest.raises(ConfigError, match="eval_evidence_surface"):
        _cfg(eval_evidence_surface=1.5)
    with pytest.raises(ConfigError, match="eval_evidence_surface"):
        _cfg(eval_anchor=True, eval_evidence_surface=-1.0)
    assert _cfg(eval_anchor=True, eval_evidence_surface=1.5).without_anchor().eval_evidence_surface == 0.0
    assert _cfg(eval_anchor=True, eval_evidence_surface=1.5, **ANCHORED).without_anchor().eval_evidence_surface == 1.5


def test_eval_evidence_surface_changes_the_finest_level_of_inference_passes_only(monkeypatch):
    """The switch's wiring: an inference pass hands the finest level's points, their rigid targets, frame 2's whole
    input (with ``eval_evidence_dense``) and the anchor's gate neighbourhood to
    :func:`~training.model.ego_motion.off_surface` once (where it finds every neighbourhood off the surface, the pass
    is the net's without the switch; what the gate does with its answer is pinned in tests/training/test_ego_motion.py);
    coarser levels, training steps and the net without it never call it."""
    import training.model.ego_motion as ego_motion

    calls: list[tuple] = []

    def spy(points, targets, frame2, kappa, k=0, nearest=None, neighbours=None):
        calls.append((points.shape[1], frame2.shape[1], kappa, k))
        return torch.ones(points.shape[:2], dtype=torch.bool, device=points.device)  # everything off the surface

    monkeypatch.setattr(ego_motion, "off_surface", spy)
    pc1, pc2 = _pair()
    on, off = _anchored_twins(eval_evidence_surface=1.5, eval_evidence_dense=True, eval_gate_k=16)
    off.config = dataclasses.replace(off.config, eval_evidence_dense=True, eval_gate_k=16)
    with torch.no_grad():
        out = on.eval()(pc1, pc2)
    assert calls == [(on.config.level_points[0], pc2.shape[1], 1.5, 16)]
    assert torch.equal(out.flows[0], _flows(off.eval(), pc1, pc2)[0])
    _flows(on.train(), pc1, pc2)
    assert len(calls) == 1


def test_eval_neighbourhood_scale_needs_the_anchor_and_changes_the_finest_level_of_inference_passes_only(monkeypatch):
    """``eval_neighbourhood_scale``: refused without the anchor, dropped with it; an inference pass hands it to the
    finest level's gate only (the one call held at the vote's motion), training steps and the net without it never."""
    import training.model.halflownet as halflownet

    with pytest.raises(ConfigError, match="eval_neighbourhood_scale"):
        _cfg(eval_neighbourhood_scale=True)
    assert _cfg(eval_anchor=True, eval_neighbourhood_scale=True).without_anchor().eval_neighbourhood_scale is False
    seen: list[bool] = []
    real = halflownet.rigid_plus_residual

    def spy(*args, **kwargs):
        seen.append(bool(args[14]) if len(args) > 14 else bool(kwargs.get("neighbourhood_scale", False)))
        return real(*args, **kwargs)

    monkeypatch.setattr(halflownet, "rigid_plus_residual", spy)
    pc1, pc2 = _pair()
    on, off = _anchored_twins(eval_neighbourhood_scale=True, eval_gate_k=16)
    _flows(on.eval(), pc1, pc2)
    assert seen[-1] and not any(seen[:-1])  # the last gate call, the finest level's, and none before it
    seen.clear()
    _flows(off.eval(), pc1, pc2)
    _flows(on.train(), pc1, pc2)
    assert seen and not any(seen)
