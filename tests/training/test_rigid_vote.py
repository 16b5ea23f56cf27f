"""The rigid vote (training/model/rigid_vote.py), HALFlowConfig.rigid_vote and the ``rvote`` baseline."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from _street import walls_and_poles
from core.errors import ConfigError
from training.config import level_points_for
from training.model.halflownet import HALFlowNet
from training.model.halflownet_config import HALFlowConfig
from training.model.rigid_vote import RigidVoteConfig, density_weights, trimmed_rounds, turn_scan, vote_rigid
from training.model.translation_vote import vote_translation


def _street(n: int, seed: int = 0) -> torch.Tensor:
    """The vote tests' street with a facade 20 m wide, so that a turn shows across it."""
    return walls_and_poles(n, seed, facade_half_width_m=10.0)


def _turn(deg_yaw: float, deg_pitch: float = 0.0) -> torch.Tensor:
    """R = R_y(yaw) · R_x(pitch): a turn about the camera's y axis (down) after a small pitch."""
    a, b = math.radians(deg_yaw), math.radians(deg_pitch)
    ry = torch.tensor([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rx = torch.tensor([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    return ry @ rx


def _static_error(R: torch.Tensor, t: torch.Tensor, pts: torch.Tensor, R_true, t_true) -> float:
    """Mean ‖(R p + t) − (R* p + t*)‖ over ``pts`` (N, 3), metres."""
    return float((pts @ R.T + t - (pts @ R_true.T + t_true)).norm(dim=-1).mean())


@pytest.mark.parametrize("yaw, pitch", [(0.8, 0.0), (2.6, 0.3), (-4.0, -0.2)])
def test_a_turned_and_moved_street_is_registered_where_the_translation_alone_is_metres_off(yaw, pitch):
    """Turns up to KITTI's largest per frame (4.8°): the translation vote leaves θ·ρ at the facade 30 m
    ahead, the rigid rounds recover the motion to a few centimetres. Frame 2 is another sample of the
    same surfaces (seed 1), so no point has an exact counterpart."""
    R_true, t_true = _turn(yaw, pitch), torch.tensor([0.05, 0.02, 1.2])
    pc1 = _street(900)
    pc2 = _street(900, seed=1) @ R_true.T + t_true
    R, t = vote_rigid(pc1, pc2)
    err = _static_error(R[0], t[0], pc1[0], R_true, t_true)
    voted = vote_translation(pc1, pc2)[0]
    err_vote = _static_error(torch.eye(3), voted, pc1[0], R_true, t_true)
    assert err < 0.08, (err, err_vote)
    assert err < err_vote / 3


def test_a_mover_does_not_pull_the_camera_motion():
    R_true, t_true = _turn(2.0), torch.tensor([0.0, 0.0, 1.2])
    pc1 = _street(900)
    car = torch.rand(1, 300, 3, generator=torch.Generator().manual_seed(2)) * torch.tensor([2.0, 1.5, 4.0])
    car = car + torch.tensor([1.0, -0.5, 12.0])
    pc1_all = torch.cat([pc1, car], 1)
    pc2_all = torch.cat([pc1 @ R_true.T + t_true, car + torch.tensor([0.0, 0.0, -1.5])], 1)
    R, t = vote_rigid(pc1_all, pc2_all)
    assert _static_error(R[0], t[0], pc1[0], R_true, t_true) < 0.05


def test_range_weighting_picks_the_far_static_scene_over_a_near_mover_as_dense():
    """A car 4–10 m ahead with as many points as the whole street (the street 5–35 m away), driving away
    while the camera drives on: counted alike, its motion explains as many points as the camera's and wins;
    weighted by range (``range_weighted``), the static scene's far points carry the choice."""
    t_true = torch.tensor([0.0, 0.0, -1.2])
    pc1 = _street(300)
    car = torch.rand(1, 300, 3, generator=torch.Generator().manual_seed(2)) * torch.tensor([4.0, 1.5, 6.0])
    car = car + torch.tensor([-1.0, -0.5, 4.0])
    pc1_all = torch.cat([pc1, car], 1)
    pc2_all = torch.cat([_street(300, seed=1) + t_true, car + torch.tensor([0.0, 0.0, 0.3])], 1)
    R, t = vote_rigid(pc1_all, pc2_all)
    assert _static_error(R[0], t[0], pc1[0], torch.eye(3), t_true) > 1.0  # the car's motion
    R, t = vote_rigid(pc1_all, pc2_all, RigidVoteConfig(range_weighted=True))
    assert _static_error(R[0], t[0], pc1[0], torch.eye(3), t_true) < 0.1
    # the range is measured from the given camera position: the same clouds shifted, with that origin
    shift = torch.tensor([[3.0, -1.0, 20.0]])
    R2, t2 = vote_rigid(pc1_all - shift, pc2_all - shift, RigidVoteConfig(range_weighted=True), origin=-shift)
    assert _static_error(R2[0], t2[0] + shift[0] - shift[0] @ R2[0].T, pc1[0], torch.eye(3), t_true) < 0.1


def test_by_its_gap_the_vote_picks_the_motion_that_brings_frame_one_nearest_frame_two(monkeypatch):
    """``choose_gap_m``: the hypotheses are weighed by the mean (truncated) gap from frame 1 moved to frame 2, not by
    the points each explains within a sample spacing. Here the count is made to prefer the least explaining
    hypothesis (the car's motion or a stray peak): counted, the camera motion is lost; by the gap, it is found."""
    import training.model.rigid_vote as rv

    real = rv.explained
    monkeypatch.setattr(rv, "explained", lambda *a, **k: -real(*a, **k))
    R_true, t_true = _turn(2.0), torch.tensor([0.0, 0.0, 1.2])
    pc1 = _street(900)
    car = torch.rand(1, 300, 3, generator=torch.Generator().manual_seed(2)) * torch.tensor([2.0, 1.5, 4.0])
    car = car + torch.tensor([1.0, -0.5, 12.0])
    pc1_all = torch.cat([pc1, car], 1)
    pc2_all = torch.cat([_street(900, seed=1) @ R_true.T + t_true, car + torch.tensor([0.0, 0.0, -1.5])], 1)
    R, t = vote_rigid(pc1_all, pc2_all)
    assert _static_error(R[0], t[0], pc1[0], R_true, t_true) > 0.5
    for weighted in (False, True):
        R, t = vote_rigid(pc1_all, pc2_all, RigidVoteConfig(choose_gap_m=0.3, range_weighted=weighted))
        assert _static_error(R[0], t[0], pc1[0], R_true, t_true) < 0.08


@pytest.mark.parametrize("gap", [0.0, 0.3])
def test_forward_starts_reach_the_camera_motion_when_every_peak_lies_to_the_side(monkeypatch, gap):
    """``forward_starts``: each hypothesis is also started with its translation along the optical axis alone. Here
    every histogram maximum is made to lie 2.5 m to the side and 1.5 m above the camera's translation (beyond the
    rounds' widest radius): from the vote's own starts the camera motion is lost; with the forward starts added it
    is found, whether the choice counts the points each motion explains or weighs its gap."""
    import training.model.rigid_vote as rv

    real = rv.vote_hypotheses
    aside = torch.tensor([2.5, -1.5, 0.0])

    def voted_aside(*args, **kwargs):
        h = real(*args, **kwargs)
        return h._replace(t=h.t + aside)

    monkeypatch.setattr(rv, "vote_hypotheses", voted_aside)
    R_true, t_true = _turn(1.0), torch.tensor([0.0, 0.0, 1.2])
    pc1 = _street(900)
    pc2 = _street(900, seed=1) @ R_true.T + t_true
    cfg = RigidVoteConfig(range_weighted=True, yaw_search_deg=6.0, choose_gap_m=gap)
    R, t = vote_rigid(pc1, pc2, cfg)
    assert _static_error(R[0], t[0], pc1[0], R_true, t_true) > 0.5
    R, t = vote_rigid(pc1, pc2, replace(cfg, forward_starts=True))
    assert _static_error(R[0], t[0], pc1[0], R_true, t_true) < 0.08


def test_forward_starts_are_only_added_a_camera_moving_sideways_keeps_its_motion():
    """A camera whose translation is mostly sideways (1 m across, 0.4 m along its axis): the forward starts are
    wrong for it, and the choice keeps the vote's own hypothesis, as without them."""
    R_true, t_true = _turn(-1.5), torch.tensor([1.0, 0.0, 0.4])
    pc1 = _street(900)
    pc2 = _street(900, seed=1) @ R_true.T + t_true
    for gap in (0.0, 0.3):
        cfg = RigidVoteConfig(range_weighted=True, yaw_search_deg=6.0, choose_gap_m=gap)
        for forward in (False, True):
            R, t = vote_rigid(pc1, pc2, replace(cfg, forward_starts=forward))
            assert _static_error(R[0], t[0], pc1[0], R_true, t_true) < 0.08, (gap, forward)


def _street_behind_a_car(seed: int, car_points: int = 800, poles: int = 400) -> tuple[torch.Tensor, torch.Tensor]:
    """(walls and poles (K, 3), a car's rear face (car_points, 3)): two walls along the camera's path (x = ±6 m,
    z 5–35 m, which hold no motion along z), thin poles beside them every 4.5 m from 8 to 30.5 m (which do), and
    the rear face of a car 10 m ahead, 2 m wide, sampled twice as densely as the poles; camera frame, metres.
    ``seed`` draws another sample of the same surfaces."""
    g = torch.Generator().manual_seed(seed)
    u, v, w = torch.rand(300, 3, generator=g), torch.rand(poles, 3, generator=g), torch.rand(car_points, 3, generator=g)
    side = torch.where(torch.arange(300) % 2 == 0, -6.0, 6.0)
    walls = torch.stack([side, 2 * u[:, 1] - 1, 5 + 30 * u[:, 2]], -1)
    k = (v[:, 2] * 6).floor()
    pole = torch.stack([torch.where(k % 2 == 0, -5.0, 5.0) + 0.1 * v[:, 0], 2 * v[:, 1] - 1, 8 + 4.5 * k], -1)
    car = torch.stack([2 * w[:, 0] - 1, 1.5 * w[:, 1] - 0.5, torch.full_like(w[:, 2], 10.0)], -1)
    return torch.cat([walls, pole]), car


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_density_rounds_keep_the_camera_motion_where_a_dense_car_ahead_pulls_the_uniform_rounds(seed):
    """``density_rounds_m``: a car 10 m ahead drives 0.2 m a frame faster than the camera (1.2 m) along a street
    whose walls hold no motion along it; its rear face holds twice the poles' points. The uniform rounds, even
    started at the true motion, settle at the car's; with the starts also refined with each point weighed by one
    over its neighbours within 0.62 m, the poles fix the motion and the choice takes it."""
    t_true, car_own = torch.tensor([0.0, 0.0, -1.2]), torch.tensor([0.0, 0.0, 0.2])
    static1, car1 = _street_behind_a_car(2 * seed)
    static2, car2 = _street_behind_a_car(2 * seed + 1)
    pc1 = torch.cat([static1, car1])[None]
    pc2 = torch.cat([static2 + t_true, car2 + t_true + car_own])[None]
    cfg = RigidVoteConfig(range_weighted=True, choose_gap_m=0.3)
    R, t, _ = trimmed_rounds(pc1.double(), pc2.double(), torch.eye(3, dtype=torch.float64)[None],
                             t_true.double()[None], cfg)
    assert _static_error(R[0].float(), t[0].float(), static1, torch.eye(3), t_true) > 0.15  # from the truth
    R, t = vote_rigid(pc1, pc2, cfg)
    assert _static_error(R[0], t[0], static1, torch.eye(3), t_true) > 0.15
    R, t = vote_rigid(pc1, pc2, replace(cfg, density_rounds_m=0.62))
    assert _static_error(R[0], t[0], static1, torch.eye(3), t_true) < 0.1


def test_density_rounds_are_only_added_a_street_without_movers_keeps_its_motion():
    """With nothing moving, the rounds weighed by density are offered beside the uniform ones and the motion stays
    as found without them (a turned street, frame 2 another sample of its surfaces)."""
    R_true, t_true = _turn(-1.5), torch.tensor([0.05, 0.0, 1.2])
    pc1 = _street(900)
    pc2 = _street(900, seed=1) @ R_true.T + t_true
    cfg = RigidVoteConfig(range_weighted=True, yaw_search_deg=6.0, choose_gap_m=0.3, forward_starts=True)
    for density in (0.0, 0.62):
        R, t = vote_rigid(pc1, pc2, replace(cfg, density_rounds_m=density))
        assert _static_error(R[0], t[0], pc1[0], R_true, t_true) < 0.08, density


def test_density_weights_give_every_occupied_neighbourhood_about_one():
    """Each point weighs one over its cloud's points within the radius (itself included): 50 points in one spot
    weigh 1/50 each, a lone point 1; each cloud of a batch on its own."""
    spot = torch.zeros(50, 3) + torch.linspace(0, 0.1, 50)[:, None]
    lone = torch.tensor([[5.0, 0.0, 0.0]])
    cloud = torch.cat([spot, lone])
    w = density_weights(torch.stack([cloud, cloud * 10]), 0.62)
    assert w.shape == (2, 51)
    torch.testing.assert_close(w[0], torch.cat([torch.full((50,), 1 / 50), torch.ones(1)]))
    assert float(w[1, :50].sum()) > 1.0 and float(w[1, 50]) == 1.0  # spread ten times wider: fewer neighbours each


def test_the_mean_gap_truncates_and_weighs():
    from training.model.rigid_vote import mean_gap

    moved = torch.tensor([[[0.0, 0.0, 0.0], [0.0, 0.0, 10.0]]], dtype=torch.float64)
    frame2 = torch.tensor([[[0.0, 0.0, 0.1], [0.0, 0.0, 12.0]]], dtype=torch.float64)
    assert torch.allclose(mean_gap(moved, frame2, 0.5), torch.tensor([0.3], dtype=torch.float64))  # (0.1 + 0.5) / 2
    w = torch.tensor([[1.0, 3.0]], dtype=torch.float64)
    assert torch.allclose(mean_gap(moved, frame2, 0.5, w), torch.tensor([0.4], dtype=torch.float64))  # (0.1 + 1.5) / 4


def test_planar_fits_a_turn_about_y_and_no_vertical_motion():
    R_true, t_true = _turn(3.0), torch.tensor([0.1, 0.0, 1.0])
    pc1 = _street(900)
    R, t = vote_rigid(pc1, _street(900, seed=1) @ R_true.T + t_true, RigidVoteConfig(planar=True))
    assert t[0, 1] == 0 and torch.allclose(R[0, 1], torch.tensor([0.0, 1.0, 0.0]))
    assert _static_error(R[0], t[0], pc1[0], R_true, t_true) < 0.08


def test_clouds_that_never_match_keep_the_votes_translation_and_no_turn():
    """Too few pairs within the radii (frame 2 is 50 m away, outside the vote's cube): identity and the
    vote's zero translation, not a fit to a handful of accidental pairs."""
    pc1 = _street(200)
    R, t = vote_rigid(pc1, pc1 + torch.tensor([0.0, 0.0, 50.0]))
    assert torch.equal(R[0], torch.eye(3)) and torch.equal(t, torch.zeros(1, 3))


def test_each_cloud_of_a_batch_gets_its_own_motion():
    pc1 = _street(600)
    motions = [(_turn(1.0), torch.tensor([0.0, 0.0, 0.6])), (_turn(-3.0), torch.tensor([0.2, 0.0, 1.8]))]
    pc2 = torch.cat([_street(600, seed=1) @ R.T + t for R, t in motions])
    R, t = vote_rigid(pc1.expand(2, -1, -1), pc2)
    for b, (R_true, t_true) in enumerate(motions):
        assert _static_error(R[b], t[b], pc1[0], R_true, t_true) < 0.08


def test_bad_settings_are_refused():
    for kw in ({"radii_m": ()}, {"radii_m": (1.0, 0.0)}, {"rounds": 0}, {"min_inliers": 2}):
        with pytest.raises(ValueError):
            RigidVoteConfig(**kw)
    with pytest.raises(ConfigError, match="translation_vote"):
        HALFlowConfig(rigid_vote=True)
    for name in ("rigid_vote_dense", "rigid_vote_far"):
        with pytest.raises(ConfigError, match=name):
            HALFlowConfig(translation_vote=True, **{name: True})
    for kw in ({"yaw_search_deg": -1.0}, {"yaw_search_deg": 90.0}, {"yaw_step_deg": 0.0}, {"yaw_resolution_deg": 0.0}):
        with pytest.raises(ValueError):
            RigidVoteConfig(**kw)
    with pytest.raises(ConfigError, match="rigid_vote_yaw_deg"):
        HALFlowConfig(translation_vote=True, rigid_vote_yaw_deg=6.0)
    with pytest.raises(ConfigError, match="rigid_vote_yaw_deg"):
        HALFlowConfig(translation_vote=True, rigid_vote=True, rigid_vote_yaw_deg=-1.0)
    # the vote's options in metres: refused below zero, and without a rigid vote to change; dropped with the anchor
    for vote_field, model_field in (("choose_gap_m", "rigid_vote_gap_m"), ("density_rounds_m", "rigid_vote_density_m")):
        with pytest.raises(ValueError):
            RigidVoteConfig(**{vote_field: -0.1})
        with pytest.raises(ConfigError, match=model_field):
            HALFlowConfig(translation_vote=True, **{model_field: 0.3})
        with pytest.raises(ConfigError, match=model_field):
            HALFlowConfig(translation_vote=True, rigid_vote=True, **{model_field: -0.3})
        anchored = HALFlowConfig(translation_vote=True, ego_head=True, l0_cost_volume=True, eval_anchor=True,
                                 **{model_field: 0.3})
        assert getattr(anchored.without_anchor(), model_field) == 0  # no vote left to change
    with pytest.raises(ConfigError, match="rigid_vote_forward"):
        HALFlowConfig(translation_vote=True, rigid_vote_forward=True)
    forward = HALFlowConfig(translation_vote=True, ego_head=True, l0_cost_volume=True, eval_anchor=True,
                            rigid_vote_forward=True)
    assert not forward.without_anchor().rigid_vote_forward  # no vote left to start


ORIGIN = torch.zeros(1, 3, dtype=torch.float64)


@pytest.mark.parametrize("yaw", [0.0, 3.0, -5.0, 6.0])
def test_the_turn_scan_finds_the_turn_to_its_resolution(yaw):
    """Step 0: the turn under which the most points agree on one translation is the camera's, to the scan's
    finest step (1°); with no turn it picks none (ties keep the smaller turn)."""
    R_true, t_true = _turn(yaw), torch.tensor([0.05, 0.02, 1.2])
    pc1, pc2 = _street(900), _street(900, seed=1) @ R_true.T + t_true
    found = math.degrees(float(turn_scan(pc1, pc2, RigidVoteConfig(yaw_search_deg=6.0), ORIGIN)[0]))
    assert abs(found - yaw) <= 0.5 + 1e-9, found
    assert RigidVoteConfig(yaw_search_deg=3.0, yaw_step_deg=1.0).turns_deg == (0.0, 1.0, -1.0, 2.0, -2.0, 3.0, -3.0)


@pytest.mark.parametrize("yaw", [6.0, -6.0])
def test_a_sharp_turn_is_registered_from_the_scanned_turn_where_the_rounds_from_none_get_lost(yaw):
    """A turn of 6° moves the facade 30 m ahead by 3 m sideways, past the rounds' widest radius: from no turn
    they end decimetres off; started at the scanned turn, centimetres."""
    R_true, t_true = _turn(yaw), torch.tensor([0.05, 0.02, 1.2])
    pc1, pc2 = _street(900), _street(900, seed=1) @ R_true.T + t_true
    err = {}
    for scan in (0.0, 6.0):
        R, t = vote_rigid(pc1, pc2, RigidVoteConfig(yaw_search_deg=scan))
        err[scan] = _static_error(R[0], t[0], pc1[0], R_true, t_true)
    assert err[6.0] < 0.08, err
    assert err[6.0] < err[0.0] / 5, err


def test_a_scan_that_finds_no_turn_leaves_the_vote_as_it_was():
    """Where the scan picks no turn, every later step runs on the same numbers: the same motion to the bit."""
    R_true, t_true = _turn(0.0), torch.tensor([0.05, 0.02, 1.2])
    pc1, pc2 = _street(900), _street(900, seed=1) @ R_true.T + t_true
    cfg = RigidVoteConfig(range_weighted=True, yaw_search_deg=6.0)
    assert float(turn_scan(pc1, pc2, cfg, ORIGIN)[0]) == 0.0
    plain = vote_rigid(pc1, pc2, RigidVoteConfig(range_weighted=True))
    scanned = vote_rigid(pc1, pc2, cfg)
    assert all(torch.equal(a, b) for a, b in zip(plain, scanned))


def test_the_turn_pivots_on_the_camera_given_as_origin():
    """The net votes in a frame centred on frame 1's points and passes the camera's position there: the same
    motion comes out, moved into that frame, for a turn the scan has to find."""
    R_true, t_true = _turn(-4.0), torch.tensor([0.05, 0.02, 1.2])
    pc1, pc2 = _street(900), _street(900, seed=1) @ R_true.T + t_true
    cfg = RigidVoteConfig(yaw_search_deg=6.0)
    centre = pc1.mean(dim=1)
    R, t = vote_rigid(pc1 - centre[:, None], pc2 - centre[:, None], cfg, origin=-centre.double())
    # in the centred frame q − c = R (p − c) + t', so t' = t + R c − c: the same R, and t = t' − R c + c
    t_back = t[0] - R[0] @ centre[0] + centre[0]
    assert _static_error(R[0], t_back, pc1[0], R_true, t_true) < 0.08


def test_a_dense_target_holding_each_points_counterpart_gives_the_exact_motion():
    """``target``: the rigid rounds match frame 1's sample against a denser cloud of frame 2. When that cloud
    holds every frame-1 point's true counterpart, the last rounds pair each point with it and the fit is
    exact; between two independent sparse samples it is off by a share of their spacing."""
    R_true, t_true = _turn(2.0, 0.3), torch.tensor([0.05, 0.02, 1.2])
    pc1 = _street(300)
    sparse = _street(300, seed=1) @ R_true.T + t_true  # another sample of the same surfaces
    dense = torch.cat([pc1 @ R_true.T + t_true, _street(1700, seed=2) @ R_true.T + t_true], 1)
    R, t = vote_rigid(pc1, sparse)
    err_sparse = _static_error(R[0], t[0], pc1[0], R_true, t_true)
    R, t = vote_rigid(pc1, sparse, target=dense)
    err_dense = _static_error(R[0], t[0], pc1[0], R_true, t_true)
    assert err_dense < 1e-3 < err_sparse, (err_dense, err_sparse)


def _cfg(**kw) -> HALFlowConfig:
    return HALFlowConfig(n_points=512, level_points=level_points_for(512), width_scale=0.25, feature_dim=0,
                         norm="layer", translation_vote=True, **kw)


def test_the_untrained_net_with_zero_heads_returns_the_rigid_motion_and_trains():
    """With ``rigid_vote`` and zero flow heads, every level's flow is the pre-alignment's ``R p + t − p``
    (the heads add nothing, the ego head fits the identity to zero flow): the net starts at the camera's
    whole motion, turn included, and learns departures from it; the heads still receive gradients."""
    torch.manual_seed(0)
    net = HALFlowNet(_cfg(rigid_vote=True, zero_flow_heads=True, ego_head=True, l0_cost_volume=True))
    R_true, t_true = _turn(2.5, 0.2), torch.tensor([0.1, 0.0, 1.3])
    pc1 = _street(512)
    pc2 = pc1[:, torch.randperm(512, generator=torch.Generator().manual_seed(4))] @ R_true.T + t_true
    with torch.no_grad():
        out = net.eval()(pc1, pc2)
    for f, p in zip(out.flows, out.points):  # the fit pairs different L0 samples of one surface: mm, not exact
        assert torch.allclose(f, p @ R_true.T + t_true - p, atol=0.01)
    with torch.no_grad():  # the translation vote alone misses the turn by θ·ρ
        plain = HALFlowNet(_cfg(zero_flow_heads=True)).eval()(pc1, pc2)
    p = plain.points[0]
    assert float((plain.flows[0] - (p @ R_true.T + t_true - p)).norm(dim=-1).mean()) > 0.2
    out = net.train()(pc1, pc2)
    sum(f.square().mean() for f in out.flows).backward()
    assert all(h.linear.weight.grad.abs().sum() > 0 for h in (net.head3_coarse, net.head0_refine))


def test_the_rvote_baseline_gives_every_point_the_rigid_flow():
    from evaluation.methods import make_baseline

    R_true, t_true = _turn(2.0), torch.tensor([0.1, 0.0, -1.5])
    pc1 = _street(900)[0]
    pc2 = (_street(900, seed=1)[0] @ R_true.T + t_true).numpy()
    flow = make_baseline("rvote")(pc1.numpy(), pc2, None, None)
    assert flow.shape == pc1.shape and flow.dtype == np.float32
    truth = (pc1 @ R_true.T + t_true - pc1).numpy()
    assert np.linalg.norm(flow - truth, axis=1).mean() < 0.08


def test_holding_the_l0_ego_head_keeps_a_uniform_pull_of_the_finest_level_out_of_the_camera_motion():
    """``ego_l0_hold``: a refinement at L0 that pushes every point 0.5 m forward (the L0 cost volume's
    forward pull on real clouds, eighteenth round, made exact) moves the refitted camera motion with it; held
    at the motion fitted before that cost volume, the camera's rigid flow does not move, and the points it holds
    keep it (the push is within the gate's robust scale, three robust standard deviations of the residuals)."""
    R_true, t_true = _turn(1.0), torch.tensor([0.0, 0.0, 1.0])
    pc1 = _street(512)
    pc2 = pc1[:, torch.randperm(512, generator=torch.Generator().manual_seed(4))] @ R_true.T + t_true
    outs = {}
    for hold in (False, True):
        for push in (0.0, 0.5):
            torch.manual_seed(0)
            net = HALFlowNet(_cfg(rigid_vote=True, zero_flow_heads=True, ego_head=True, l0_cost_volume=True,
                                  ego_l0_hold=hold)).eval()
            with torch.no_grad():
                net.head0_refine.linear.bias.copy_(torch.tensor([0.0, 0.0, push]))
                outs[hold, push] = net(pc1, pc2)
    moved = (outs[False, 0.5].rigid_flows[0] - outs[False, 0.0].rigid_flows[0]).norm(dim=-1).mean()
    held = (outs[True, 0.5].rigid_flows[0] - outs[True, 0.0].rigid_flows[0]).norm(dim=-1).mean()
    assert moved > 0.4 and held < 1e-4, (moved, held)
    # the held points leak the gate's share of the push: m = r⁴ / (s⁴ + r⁴) with s = 3 · 1.4826 · r, 1/393 of 0.5 m
    assert torch.allclose(outs[True, 0.5].flows[0], outs[True, 0.0].flows[0], atol=2e-3)
    p = outs[True, 0.0].points[0]
    assert torch.allclose(outs[True, 0.0].flows[0], p @ R_true.T + t_true - p, atol=0.01)
    with pytest.raises(ConfigError, match="ego_l0_hold"):
        _cfg(ego_l0_hold=True, ego_head=True)


def test_holding_l0_at_l1s_motion_keeps_the_whole_finest_level_out_of_the_camera_motion():
    """``ego_l0_hold_from="l1"``: a push from L0's feature-propagation head (before the L0 cost volume) moves
    the motion the ``"l0"`` hold keeps, but not L1's: held at L1's motion, the L0 level's rigid flow is L1's
    camera motion at the L0 points, push or not (nineteenth round: the pull was already in that head)."""
    R_true, t_true = _turn(1.0), torch.tensor([0.0, 0.0, 1.0])
    pc1 = _street(512)
    pc2 = pc1[:, torch.randperm(512, generator=torch.Generator().manual_seed(4))] @ R_true.T + t_true
    outs = {}
    for source in ("l0", "l1"):
        for push in (0.0, 0.5):
            torch.manual_seed(0)
            net = HALFlowNet(_cfg(rigid_vote=True, zero_flow_heads=True, ego_head=True, l0_cost_volume=True,
                                  ego_l0_hold=True, ego_l0_hold_from=source)).eval()
            with torch.no_grad():
                net.head0.linear.bias.copy_(torch.tensor([0.0, 0.0, push]))
                outs[source, push] = net(pc1, pc2)
    moved = (outs["l0", 0.5].rigid_flows[0] - outs["l0", 0.0].rigid_flows[0]).norm(dim=-1).mean()
    held = (outs["l1", 0.5].rigid_flows[0] - outs["l1", 0.0].rigid_flows[0]).norm(dim=-1).mean()
    assert moved > 0.4 and held < 1e-4, (moved, held)
    p = outs["l1", 0.5].points[0]
    assert torch.allclose(outs["l1", 0.5].rigid_flows[0], p @ R_true.T + t_true - p, atol=0.01)
    with pytest.raises(ConfigError, match="ego_l0_hold_from"):
        _cfg(ego_l0_hold=True, ego_head=True, l0_cost_volume=True, ego_l0_hold_from="l2")


def test_holding_l0_at_the_votes_motion_keeps_every_level_out_of_the_camera_motion():
    """``ego_l0_hold_from="vote"``: pushes from the L1 and the L0 flow heads move L1's fitted motion, but the
    finest level's rigid flow stays the vote's (frame 2 is pre-aligned by it, so it is the identity inside the
    net), and that is the true motion here (twentieth round)."""
    R_true, t_true = _turn(1.0), torch.tensor([0.0, 0.0, 1.0])
    pc1 = _street(512)
    pc2 = pc1[:, torch.randperm(512, generator=torch.Generator().manual_seed(4))] @ R_true.T + t_true
    outs = {}
    for push in (0.0, 0.5):
        torch.manual_seed(0)
        net = HALFlowNet(_cfg(rigid_vote=True, zero_flow_heads=True, ego_head=True, l0_cost_volume=True,
                              ego_l0_hold=True, ego_l0_hold_from="vote")).eval()
        with torch.no_grad():
            net.head0.linear.bias.copy_(torch.tensor([0.0, 0.0, push]))
            net.head1.linear.bias.copy_(torch.tensor([push, 0.0, 0.0]))
            outs[push] = net(pc1, pc2)
    assert (outs[0.5].rigid_flows[1] - outs[0.0].rigid_flows[1]).norm(dim=-1).mean() > 0.4  # L1's fit moved
    assert (outs[0.5].rigid_flows[0] - outs[0.0].rigid_flows[0]).norm(dim=-1).max() < 1e-4  # L0's did not
    p = outs[0.5].points[0]
    assert torch.allclose(outs[0.5].rigid_flows[0], p @ R_true.T + t_true - p, atol=0.01)
    with pytest.raises(ConfigError, match="needs model.translation_vote"):
        HALFlowConfig(ego_head=True, l0_cost_volume=True, ego_l0_hold=True, ego_l0_hold_from="vote")


def test_rigid_vote_dense_hands_the_vote_frame_2s_whole_input(monkeypatch):
    """``model.rigid_vote_dense``: the net's rigid vote matches against frame 2's input cloud (centred as the
    L0 points are), not only its L0 samples; without it, against the L0 samples alone. The camera's position
    in that centred frame goes with it (for ``model.rigid_vote_far``)."""
    import training.model.halflownet as halflownet

    seen, origins = [], []

    def spy(xyz1, xyz2, config=None, target=None, origin=None):
        seen.append((xyz1.shape[1], xyz2.shape[1], None if target is None else target.shape[1]))
        origins.append(origin)
        return vote_rigid(xyz1, xyz2, config, target, origin)

    monkeypatch.setattr(halflownet, "vote_rigid", spy)
    pc1 = _street(512)
    pc2 = _street(512, seed=1) + torch.tensor([0.0, 0.0, 1.0])
    n0 = level_points_for(512)[0]
    for dense, want in ((True, 512), (False, None)):
        net = HALFlowNet(_cfg(rigid_vote=True, rigid_vote_dense=dense, rigid_vote_far=dense)).eval()
        with torch.no_grad():
            out = net(pc1, pc2)
        assert all(torch.isfinite(f).all() for f in out.flows)
        assert seen.pop() == (n0, n0, want)
        assert torch.allclose(origins.pop(), -pc1.mean(dim=1))  # the camera, in the net's centred frame


def test_a_turn_that_fills_the_histogram_hardly_more_than_none_is_not_taken(monkeypatch):
    """``yaw_margin``: at no turn a 1° neighbour can fill the fullest cell a few per cent more by chance, and a
    start 1° off can leave the rounds off; a turn is taken only when it fills it clearly more."""
    import training.model.rigid_vote as rigid_vote

    R_true, t_true = _turn(3.0), torch.tensor([0.05, 0.02, 1.2])
    pc1, pc2 = _street(900), _street(900, seed=1) @ R_true.T + t_true
    full = {}
    real = rigid_vote._fullest

    def spy(xyz1, xyz2, cfg, origin, angle):
        f = real(xyz1, xyz2, cfg, origin, angle)
        full[round(math.degrees(float(angle[0])), 6)] = float(f[0])
        return f

    monkeypatch.setattr(rigid_vote, "_fullest", spy)
    taken = math.degrees(float(turn_scan(pc1, pc2, RigidVoteConfig(yaw_search_deg=6.0), ORIGIN)[0]))
    assert abs(taken - 3.0) <= 0.5 and max(full.values()) > 1.05 * full[0.0]
    ratio = max(full.values()) / full[0.0]
    refused = turn_scan(pc1, pc2, RigidVoteConfig(yaw_search_deg=6.0, yaw_margin=ratio), ORIGIN)
    assert float(refused[0]) == 0.0  # the same scan with a margin above what the turn gains: no turn
