"""HALFlowConfig.coarse_match: the coarse translation measured by soft matching (training/model/coarse_match.py)."""

from __future__ import annotations

import pytest
import torch

from core.errors import ConfigError
from training.model.coarse_match import SoftTranslation
from training.model.halflownet import HALFlowNet
from training.model.halflownet_config import HALFlowConfig
from training.config import level_points_for


def _matcher(channels: int) -> SoftTranslation:
    m = SoftTranslation(channels, width=channels, sigma_m=5.0)
    with torch.no_grad():  # identity embedding, sharp: each point's own feature wins by a wide margin
        m.embed.weight.copy_(torch.eye(channels) * 30.0)
        m.embed.bias.zero_()
    return m


@pytest.mark.parametrize("shift", [(0.0, 0.0, -0.8), (0.1, 0.0, -1.6), (0.3, -0.1, -2.4)])
def test_a_shift_of_frame_two_is_measured_with_gain_one(shift):
    g = torch.Generator().manual_seed(0)
    xyz1 = torch.rand(2, 64, 3, generator=g) * torch.tensor([20.0, 3.0, 30.0])
    feat = torch.nn.functional.normalize(torch.randn(2, 64, 64, generator=g), dim=-1)
    t = torch.tensor(shift)
    out = _matcher(64)(xyz1, feat, xyz1 + t, feat)
    assert torch.allclose(out, t.expand(2, 3), atol=1e-3)


def test_the_distance_prior_keeps_matches_local_when_features_say_nothing():
    xyz1 = torch.rand(1, 50, 3) * 30.0
    feat = torch.zeros(1, 50, 8)  # no feature information: the prior alone
    m = SoftTranslation(8, sigma_m=1e-2)
    assert torch.allclose(m(xyz1, feat, xyz1, feat), torch.zeros(1, 3), atol=1e-4)


def test_the_net_with_the_switch_runs_and_trains_the_matcher():
    cfg = dict(n_points=512, level_points=level_points_for(512), width_scale=0.25, feature_dim=0, norm="layer")
    torch.manual_seed(0)
    net = HALFlowNet(HALFlowConfig(**cfg, coarse_match=True))
    pc1 = torch.randn(2, 512, 3) * 5.0
    out = net(pc1, pc1 + torch.tensor([0.0, 0.0, -1.0]))
    assert [f.shape[1] for f in out.flows] == list(level_points_for(512)[:4])
    sum(f.abs().mean() for f in out.flows).backward()
    assert net.coarse_translation.embed.weight.grad.abs().sum() > 0
    assert not hasattr(HALFlowNet(HALFlowConfig(**cfg)), "coarse_translation")  # off: the paper's form


def test_a_non_positive_prior_is_refused():
    with pytest.raises(ConfigError):
        HALFlowConfig(coarse_match_sigma_m=0.0)
