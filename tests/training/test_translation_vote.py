"""The translation vote (training/model/translation_vote.py) and HALFlowConfig.translation_vote."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from _street import walls_and_poles as _street
from core.errors import ConfigError
from training.config import level_points_for
from training.model.halflownet import HALFlowNet
from training.model.halflownet_config import HALFlowConfig
from training.model.translation_vote import VoteConfig, vote_translation


@pytest.mark.parametrize("shift", [(0.0, 0.0, -0.6), (0.05, 0.0, -1.2), (0.3, -0.1, -2.4)])
def test_a_shifted_cloud_is_found_at_every_speed(shift):
    pc1 = _street(600)
    t = torch.tensor(shift)
    pc2 = pc1[:, torch.randperm(600, generator=torch.Generator().manual_seed(1))] + t  # order does not matter
    assert torch.allclose(vote_translation(pc1, pc2)[0], t, atol=0.02)


def test_the_static_majority_wins_over_a_mover():
    pc1 = _street(900)
    t, t_car = torch.tensor([0.0, 0.0, -1.2]), torch.tensor([0.0, 0.0, 0.8])
    car = torch.rand(1, 300, 3, generator=torch.Generator().manual_seed(2)) * torch.tensor([2.0, 1.5, 4.0])
    car = car + torch.tensor([1.0, -0.5, 12.0])
    pc1_all = torch.cat([pc1, car], 1)
    pc2_all = torch.cat([pc1 + t, car + t_car], 1)
    assert torch.allclose(vote_translation(pc1_all, pc2_all)[0], t, atol=0.02)


def test_a_dense_car_ahead_at_the_cameras_speed_does_not_outvote_the_sparser_static_scene():
    """The back of a car 6 m ahead, 200 points in a 1.8 × 1.4 × 0.3 m box, moving 0.1 m less than the
    camera per frame, against 300 static street points spread over 30 m: the car's pairs fill the fullest
    histogram cell, so the fullest cell alone returns the car's motion; scoring the maxima by how many
    frame-1 points each explains returns the camera's."""
    pc1 = _street(300)
    t, t_car = torch.tensor([0.0, 0.0, -1.2]), torch.tensor([0.0, 0.0, -0.1])
    car = torch.rand(1, 200, 3, generator=torch.Generator().manual_seed(3)) * torch.tensor([1.8, 1.4, 0.3])
    car = car + torch.tensor([-0.9, -0.7, 6.0])
    pc1_all, pc2_all = torch.cat([pc1, car], 1), torch.cat([pc1 + t, car + t_car], 1)
    assert torch.allclose(vote_translation(pc1_all, pc2_all, VoteConfig(candidates=1))[0], t_car, atol=0.02)
    assert torch.allclose(vote_translation(pc1_all, pc2_all)[0], t, atol=0.02)


def test_offsets_outside_the_search_cube_give_zero():
    pc1 = torch.zeros(1, 4, 3)
    far = pc1 + torch.tensor([0.0, 0.0, 50.0])
    assert torch.equal(vote_translation(pc1, far, VoteConfig(max_translation_m=3.0)), torch.zeros(1, 3))


def test_the_histogram_counts_the_offsets_in_the_cube_and_nothing_else():
    """The CPU's range search hands the histogram exactly the offsets inside the cube: its counts equal a
    count over every pair (the search ball reaches the cube's corners), weighted or not."""
    from training.model.translation_vote import _pair_offsets

    g = torch.Generator().manual_seed(3)
    x1 = torch.rand(2, 300, 3, generator=g) * torch.tensor([30.0, 4.0, 40.0])
    x2 = x1[:, torch.randperm(300, generator=g)[:250]] + torch.tensor([0.4, 0.0, 1.3])
    R = 3.0
    which, first, d = _pair_offsets(x1, x2, R)
    every = (x2[:, None, :, :] - x1[:, :, None, :])  # (B, M, N, 3)
    inside = (every.abs() <= R).all(-1)
    got = (d.abs() <= R).all(-1)
    assert int(got.sum()) == int(inside.sum()) > 0  # no offset of the cube is missed, none counted twice
    assert int((~got).sum()) > 0  # the ball holds a few outside the cube (its corners), which the count drops
    for b in range(2):  # every frame-1 point of every cloud holds its own offsets in the cube
        sel = (which == b) & got
        assert torch.equal(torch.bincount(first[sel], minlength=300), inside[b].sum(1))


def test_nearest_groups_every_cloud_s_hypotheses_on_one_search():
    from training.model.translation_vote import gather_nearest, nearest, per_hypothesis

    g = torch.Generator().manual_seed(5)
    a = torch.rand(2, 40, 3, generator=g) * 10
    b = torch.rand(2, 60, 3, generator=g) * 10
    moved = per_hypothesis(a, 3) + torch.rand(6, 1, 3, generator=g)
    d2, idx = nearest(moved, b)
    d2c, idxc = nearest(moved, per_hypothesis(b, 3))  # every hypothesis with its own copy
    assert torch.equal(idx, idxc) and torch.allclose(d2, d2c)
    q = gather_nearest(b, idx)
    assert torch.allclose(((q - moved) ** 2).sum(-1), d2, atol=1e-5)
    brute = torch.cdist(moved.double(), per_hypothesis(b, 3).double()).min(dim=2)
    assert torch.equal(idx, brute.indices)


def test_a_bad_search_is_refused():
    with pytest.raises(ValueError):
        VoteConfig(cell_m=0.0)
    with pytest.raises(ValueError):
        VoteConfig(candidates=0)
    with pytest.raises(ConfigError):
        HALFlowConfig(translation_vote_max_m=-1.0)


def _cfg(**kw) -> HALFlowConfig:
    return HALFlowConfig(n_points=512, level_points=level_points_for(512), width_scale=0.25, feature_dim=0,
                         norm="layer", **kw)


def test_the_net_with_the_switch_follows_a_change_of_speed_exactly_and_trains():
    torch.manual_seed(0)
    net = HALFlowNet(_cfg(translation_vote=True)).eval()
    pc1 = _street(512)
    slow, fast = torch.tensor([0.0, 0.0, -0.6]), torch.tensor([0.0, 0.0, -1.8])
    with torch.no_grad():
        a, b = net(pc1, pc1 + slow), net(pc1, pc1 + fast)
    for fa, fb in zip(a.flows, b.flows):  # the same residual problem, so the flows differ by the shift
        assert torch.allclose(fb - fa, (fast - slow).expand_as(fa), atol=0.02)
    net.train()
    out = net(pc1, pc1 + fast)
    sum(f.abs().mean() for f in out.flows).backward()
    assert all(p.grad is not None for p in net.head3_coarse.parameters())


def test_with_zero_flow_heads_the_untrained_net_returns_the_voted_translation_and_trains():
    """``zero_flow_heads``: before any training every level's flow is the vote's translation exactly (the
    heads add nothing, the ego head fits no motion to zero flow); the heads still receive gradients."""
    torch.manual_seed(0)
    net = HALFlowNet(_cfg(translation_vote=True, zero_flow_heads=True, ego_head=True, l0_cost_volume=True))
    pc1 = _street(512)
    shift = torch.tensor([0.2, 0.0, -1.3])
    pc2 = pc1 + shift
    with torch.no_grad():
        out = net.eval()(pc1, pc2)
        voted = vote_translation(out.points[0], out.points2[0])[0]  # the vote runs on the L0 points
    # the ego head's fit to zero flow is the identity up to float64 round-off
    assert all(torch.allclose(f, voted.expand_as(f), atol=1e-5) for f in out.flows)
    assert torch.allclose(voted, shift, atol=0.05)
    out = net.train()(pc1, pc2)
    sum(f.square().mean() for f in out.flows).backward()
    assert all(h.linear.weight.grad.abs().sum() > 0 for h in (net.head3_coarse, net.head0_refine))
    # the default: PyTorch's initialisation, the first flows are not the vote's
    torch.manual_seed(0)
    with torch.no_grad():
        plain = HALFlowNet(_cfg(translation_vote=True)).eval()(pc1, pc2)
    assert not torch.allclose(plain.flows[0], voted.expand_as(plain.flows[0]), atol=1e-3)


def test_without_the_switch_the_net_is_the_papers_form(monkeypatch):
    def refuse(*_args, **_kw):
        raise AssertionError("the vote ran with the switch off")

    monkeypatch.setattr("training.model.halflownet.vote_translation", refuse)
    pc1 = _street(512)
    out = HALFlowNet(_cfg()).eval()(pc1, pc1 + torch.tensor([0.0, 0.0, -1.0]))
    assert out.flows[0].shape == (1, level_points_for(512)[0], 3)
    with pytest.raises(AssertionError, match="switch off"):
        HALFlowNet(_cfg(translation_vote=True)).eval()(pc1, pc1)


def test_the_tvote_baseline_gives_every_point_the_voted_translation():
    from evaluation.methods import make_baseline

    pc1 = _street(400).numpy()[0]
    t = np.array([0.1, 0.0, -1.5], np.float32)
    flow = make_baseline("tvote")(pc1, pc1[::-1] + t, None, None)
    assert flow.shape == pc1.shape and flow.dtype == np.float32
    np.testing.assert_allclose(flow, np.broadcast_to(t, pc1.shape), atol=0.02)


def test_the_tvote_baseline_votes_between_farthest_point_samples_so_a_dense_near_car_does_not_win():
    """A LiDAR-like scene: 1500 points on the back of a car 6 m ahead (dense, as near points are), 600 on
    the street. On every raw point the car is the majority and the vote returns its motion; on 512
    farthest-point samples (the default, as the net's L0) the car keeps a few and the camera's wins."""
    from evaluation.baselines.translation_vote import TranslationVoteBaseline

    street = _street(600)
    t, t_car = torch.tensor([0.0, 0.0, -1.2]), torch.tensor([0.0, 0.0, -0.1])
    car = torch.rand(1, 1500, 3, generator=torch.Generator().manual_seed(3)) * torch.tensor([1.8, 1.4, 0.3])
    car = car + torch.tensor([-0.9, -0.7, 6.0])
    pc1 = torch.cat([street, car], 1)[0].numpy()
    pc2 = torch.cat([street + t, car + t_car], 1)[0].numpy()
    raw = TranslationVoteBaseline(sample_points=0)(pc1, pc2)
    sampled = TranslationVoteBaseline()(pc1, pc2)
    # the car's 1.1 m slower motion, not the camera's (its x, y come from the car's box: within 0.2 m)
    assert np.linalg.norm(raw[0] - t_car.numpy()) < 0.2
    np.testing.assert_allclose(sampled[0], t.numpy(), atol=0.05)
