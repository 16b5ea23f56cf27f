"""The net's normalisation: test-time batch norm with the input's own statistics
(HALFlowConfig.eval_norm_stats) and the per-point layer norm (HALFlowConfig.norm)."""

from __future__ import annotations

import pytest
import torch

from training.config import level_points_for
from core.errors import ConfigError
from training.model.halflownet import HALFlowConfig, HALFlowNet


def _net(mode: str) -> HALFlowNet:
    torch.manual_seed(0)
    net = HALFlowNet(HALFlowConfig(n_points=512, level_points=level_points_for(512), width_scale=0.25,
                                   eval_norm_stats=mode))
    net.train()
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():  # a few training-mode passes give the running statistics values of their own
        for _ in range(3):
            net(torch.randn(2, 512, 3, generator=g) * 5, torch.randn(2, 512, 3, generator=g) * 5)
    return net.eval()


def test_input_statistics_equal_training_mode_norm_and_leave_the_buffers_alone():
    torch.set_num_threads(1)
    net = _net("input")
    buffers = {k: v.clone() for k, v in net.state_dict().items()}
    g = torch.Generator().manual_seed(2)
    pc1 = torch.randn(1, 512, 3, generator=g) * 4 + torch.tensor([0.0, 0.0, 12.0])
    pc2 = pc1 + torch.tensor([0.1, 0.0, -0.9])
    with torch.no_grad():
        out = net(pc1, pc2).flows[0]
        net.set_eval_norm_stats("running")
        running = net(pc1, pc2).flows[0]
        reference = _net("running")
        for m in reference.modules():  # batch statistics, momentum 0: running statistics stay as they were
            if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
                m.train()
                m.momentum = 0.0
        ref = reference(pc1, pc2).flows[0]
    assert torch.allclose(out, ref, atol=1e-5)
    assert not torch.allclose(out, running, atol=1e-3)
    assert all(torch.equal(buffers[k], v) for k, v in net.state_dict().items())


def test_unknown_mode_is_refused():
    with pytest.raises(ConfigError, match="eval_norm_stats"):
        HALFlowConfig(eval_norm_stats="batch")


def test_layer_norm_sees_one_cloud_at_a_time_in_training_and_at_inference():
    """With norm "layer" a scene's flow depends on nothing but the scene: the same with another scene in the
    batch, in training mode and in eval mode (batch norm differs in all three)."""
    torch.set_num_threads(1)
    g = torch.Generator().manual_seed(3)
    pc1 = torch.randn(2, 512, 3, generator=g) * 4 + torch.tensor([0.0, 0.0, 12.0])
    pc2 = pc1 + torch.tensor([0.1, 0.0, -0.9])
    cfg = dict(n_points=512, level_points=level_points_for(512), width_scale=0.25)
    for norm, same in (("layer", True), ("batch", False)):
        torch.manual_seed(0)
        net = HALFlowNet(HALFlowConfig(**cfg, norm=norm))
        with torch.no_grad():
            batched = net.train()(pc1, pc2).flows[0][:1]
            alone = net(pc1[:1], pc2[:1]).flows[0]
            evaluated = net.eval()(pc1[:1], pc2[:1]).flows[0]
        assert torch.allclose(batched, alone, atol=1e-5) == same
        assert torch.allclose(alone, evaluated, atol=1e-5) == same
    layer = HALFlowNet(HALFlowConfig(**cfg, norm="layer"))
    assert not any(isinstance(m, torch.nn.modules.batchnorm._BatchNorm) for m in layer.modules())
    assert any(isinstance(m, torch.nn.LayerNorm) for m in layer.modules())


def test_unknown_norm_and_input_statistics_without_batch_norm_are_refused():
    with pytest.raises(ConfigError, match="norm must be one of"):
        HALFlowConfig(norm="group")
    with pytest.raises(ConfigError, match="needs norm 'batch'"):
        HALFlowConfig(norm="layer", eval_norm_stats="input")
    net = HALFlowNet(HALFlowConfig(n_points=512, level_points=level_points_for(512), width_scale=0.25, norm="layer"))
    with pytest.raises(ConfigError, match="needs norm 'batch'"):  # switched at test time, as learning_curve does
        net.set_eval_norm_stats("input")
