"""training.model: the HALFlowNet-style scene-flow net at a tiny size (and one forward at the paper's)."""

from __future__ import annotations

import pytest
import torch

from core.errors import ConfigError, InputError
from training.model import FlowOutput, HALFlowConfig, HALFlowNet, Sampling, count_parameters
from training.pointops import gather_points

@pytest.fixture(autouse=True)
def one_thread():
    """Tiny tensors: intra-op threads only add overhead here (and thrash on a shared 2-core box)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


SMALL = dict(n_points=512, level_points=(128, 64, 32, 16, 8), width_scale=0.25)


def scene(n: int = 512, batch: int = 2, seed: int = 0):
    """A toy pair in camera coordinates (metres): pc2 = pc1 moved by a per-point flow, reshuffled."""
    g = torch.Generator().manual_seed(seed)
    pc1 = torch.rand(batch, n, 3, generator=g) * torch.tensor([20.0, 2.0, 30.0]) + torch.tensor([-10.0, -1.0, 3.0])
    flow = torch.tensor([0.1, 0.0, -0.8]) + 0.2 * torch.tanh(pc1[..., :1] / 5).expand(-1, -1, 3)
    perm = torch.randperm(n, generator=g)
    pc2 = (pc1 + flow)[:, perm]
    rgb1 = torch.rand(batch, n, 3, generator=g)
    return pc1, pc2, rgb1, rgb1[:, perm], flow


@pytest.mark.parametrize("sampling", ["fps", "random"])
def test_shapes_and_indices(sampling):
    torch.manual_seed(0)
    cfg = HALFlowConfig(**SMALL, sampling=sampling)
    net = HALFlowNet(cfg)
    pc1, pc2, f1, f2, _ = scene()
    out = net(pc1, pc2, f1, f2)
    assert isinstance(out, FlowOutput)
    sizes = cfg.level_points[:4]
    assert [tuple(f.shape) for f in out.flows] == [(2, n, 3) for n in sizes]
    assert [tuple(i.shape) for i in out.indices] == [(2, n) for n in sizes]
    for lvl in range(4):
        assert out.indices[lvl].dtype == torch.int64
        assert torch.equal(out.points[lvl], gather_points(pc1, out.indices[lvl]))
        assert torch.equal(out.points2[lvl], gather_points(pc2, out.indices2[lvl]))
        assert torch.isfinite(out.flows[lvl]).all()
        for row in out.indices[lvl].tolist():
            assert len(set(row)) == len(row) and 0 <= min(row) and max(row) < 512
        if lvl:  # levels nest: every coarse point is one of the finer level's points
            for b in range(2):
                assert set(out.indices[lvl][b].tolist()) <= set(out.indices[lvl - 1][b].tolist())
    if sampling == "random":  # first-N: level l is the first n_l input points
        assert all(torch.equal(i, torch.arange(n).expand(2, n)) for i, n in zip(out.indices, sizes))
    else:
        assert torch.all(out.indices[0][:, 0] == 0)
        assert not torch.equal(out.indices[0], torch.arange(128).expand(2, 128))


@pytest.mark.parametrize("extra", [{}, {"l0_cost_volume": True}, {"l0_cost_volume": True, "ego_head": True}])
def test_gradients_reach_every_parameter(extra):
    torch.manual_seed(1)
    net = HALFlowNet(HALFlowConfig(**SMALL, **extra))
    pc1, pc2, f1, f2, _ = scene(seed=1)
    out = net(pc1, pc2, f1, f2)
    sum(f.square().mean() for f in out.flows).backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not torch.any(p.grad != 0)]
    assert not missing, f"no gradient reaches {missing}"
    assert all(torch.isfinite(p.grad).all() for p in net.parameters())


def test_l0_cost_volume_is_a_residual_on_the_papers_l0_flow():
    """With the L0 refinement's head zeroed the finest flow is exactly the paper's L0 flow (same weights
    elsewhere): the switch adds a residual stage and changes nothing above it."""
    torch.manual_seed(2)
    paper = HALFlowNet(HALFlowConfig(**SMALL)).eval()
    extended = HALFlowNet(HALFlowConfig(**SMALL, l0_cost_volume=True)).eval()
    missing, unexpected = extended.load_state_dict(paper.state_dict(), strict=False)
    assert not unexpected and missing and all(k.split(".")[0] in ("cost0", "refine0", "head0_refine") for k in missing)
    torch.nn.init.zeros_(extended.head0_refine.linear.weight)
    torch.nn.init.zeros_(extended.head0_refine.linear.bias)
    pc1, pc2, f1, f2, _ = scene(seed=2)
    with torch.no_grad():
        a, b = paper(pc1, pc2, f1, f2), extended(pc1, pc2, f1, f2)
    assert all(torch.equal(x, y) for x, y in zip(a.flows, b.flows))


def test_overfits_one_pair_with_supervision():
    """A few Adam steps on one pair with an L2 loss on the flow at every level reduce the loss."""
    torch.manual_seed(2)
    net = HALFlowNet(HALFlowConfig(**SMALL))
    pc1, pc2, f1, f2, flow = scene(batch=1, seed=2)
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)

    def loss_fn() -> torch.Tensor:
        out = net(pc1, pc2, f1, f2)
        return sum((f - gather_points(flow, i)).square().sum(-1).mean() for f, i in zip(out.flows, out.indices))

    losses = []
    for _ in range(40):
        opt.zero_grad()
        loss = loss_fn()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.2 * losses[0], losses
    # ... and beyond the mean flow: the best constant prediction would leave the flow's spread.
    with torch.no_grad():
        idx = net(pc1, pc2, f1, f2).indices
    gt = [gather_points(flow, i) for i in idx]
    spread = sum((g - g.mean(1, keepdim=True)).square().sum(-1).mean() for g in gt)
    assert losses[-1] < 0.5 * spread.item(), (losses[-1], spread.item())


def test_eval_is_deterministic_and_options_run():
    torch.manual_seed(3)
    pc1, pc2, f1, f2, _ = scene(seed=3)
    net = HALFlowNet(HALFlowConfig(**SMALL)).eval()
    with torch.no_grad():
        a, b = net(pc1, pc2, f1, f2), net(pc1, pc2, f1, f2)
    assert all(torch.equal(x, y) for x, y in zip(a.flows, b.flows))
    # Other options: no features, attentive pooling, no batch norm, the torch kNN backend, N1 != N2.
    cfg = HALFlowConfig(**SMALL, feature_dim=0, set_conv_pooling="attentive", norm="none", knn_backend="torch")
    out = HALFlowNet(cfg)(pc1, pc2[:, :400])
    assert [tuple(f.shape) for f in out.flows] == [(2, n, 3) for n in cfg.level_points[:4]]
    assert all(i.max() < 400 for i in out.indices2)


def test_backends_give_the_same_net_output():
    torch.manual_seed(4)
    pc1, pc2, f1, f2, _ = scene(seed=4)
    net = HALFlowNet(HALFlowConfig(**SMALL, knn_backend="kdtree")).eval()
    with torch.no_grad():
        a = net(pc1, pc2, f1, f2)
        net_t = HALFlowNet(HALFlowConfig(**SMALL, knn_backend="torch")).eval()
        net_t.load_state_dict(net.state_dict())
        b = net_t(pc1, pc2, f1, f2)
    for x, y in zip(a.flows, b.flows):
        torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-5)


def test_paper_size_forward_on_cpu():
    torch.manual_seed(5)
    net = HALFlowNet().eval()
    assert 4_000_000 < count_parameters(net) < 6_000_000
    pc1, pc2, f1, f2, _ = scene(n=8192, batch=1, seed=5)
    with torch.no_grad():
        out = net(pc1, pc2, f1, f2)
    assert [tuple(f.shape) for f in out.flows] == [(1, 2048, 3), (1, 1024, 3), (1, 256, 3), (1, 64, 3)]
    assert torch.equal(out.points[0], gather_points(pc1, out.indices[0]))


def test_bad_input_and_config():
    net = HALFlowNet(HALFlowConfig(**SMALL))
    pc1, pc2, f1, f2, _ = scene()
    with pytest.raises(InputError, match=r"pc1 must be a \(B, N, 3\)"):
        net(pc1[..., :2], pc2, f1, f2)
    with pytest.raises(InputError, match="fewer than level_points"):
        net(pc1[:, :100], pc2, f1[:, :100], f2)
    with pytest.raises(InputError, match="feat2 must have shape"):
        net(pc1, pc2, f1, f2[..., :2])
    with pytest.raises(InputError, match="differ in batch size"):
        net(pc1, pc2[:1], f1, f2[:1])
    with pytest.raises(ConfigError, match="strictly decreasing"):
        HALFlowConfig(level_points=(2048, 1024, 256, 300, 16))
    with pytest.raises(ConfigError, match="need 5 entries"):
        HALFlowConfig(level_points=(2048, 1024, 256, 64))
    with pytest.raises(ConfigError, match="sampling"):
        HALFlowConfig(sampling="poisson")


def test_sampling_can_be_reused_by_a_second_pass():
    """The dynamic pass net(pc1 + sf_s, pc2) must predict at the same points as net(pc1, pc2)."""
    torch.manual_seed(6)
    net = HALFlowNet(HALFlowConfig(**SMALL)).eval()
    pc1, pc2, f1, f2, _ = scene(seed=6)
    angle = torch.tensor(0.05)
    rot = torch.tensor([[torch.cos(angle), 0, torch.sin(angle)], [0, 1, 0], [-torch.sin(angle), 0, torch.cos(angle)]])
    moved = pc1 @ rot.T + torch.tensor([0.2, 0.0, 1.0])  # pc1 + static flow of a rigid motion
    with torch.no_grad():
        first = net(pc1, pc2, f1, f2)
        second = net(moved, pc2, f1, f2, sampling=first.sampling)
        again = net(pc1, pc2, f1, f2, sampling=first.sampling)
    assert len(first.sampling.pc1) == 5 and len(first.sampling.pc2) == 4
    for a, b in zip(first.indices + first.indices2, second.indices + second.indices2):
        assert torch.equal(a, b)
    torch.testing.assert_close(second.points[0], gather_points(moved, first.indices[0]))
    assert all(torch.equal(a, b) for a, b in zip(first.flows, again.flows))  # its own sampling: same result
    bad = first.sampling
    with pytest.raises(InputError, match="sampling.pc1 needs 5 levels"):
        net(pc1, pc2, f1, f2, sampling=Sampling(pc1=bad.pc1[:4], pc2=bad.pc2))
    with pytest.raises(InputError, match=r"sampling.pc2\[0\] must index"):
        net(pc1, pc2, f1, f2, sampling=Sampling(pc1=bad.pc1, pc2=[bad.pc2[0] + 1000, *bad.pc2[1:]]))


@pytest.mark.parametrize("norm", ["layer", "batch"])
def test_a_second_pass_on_the_same_frame_2_reuses_its_encoding(norm, monkeypatch):
    """The trainer's dynamic pass net(pc1 + sf_s, pc2, sampling=…) takes the first pass's frame-2 encoder levels
    (shifted to its own centre) instead of encoding pc2 again: the same flows and the same gradients as
    encoding it anew, to float rounding, with frame 2 encoded once; never under batch norm (batch statistics)."""
    from training.model.halflownet import HALFlowSampling

    torch.manual_seed(7)
    net = HALFlowNet(HALFlowConfig(**SMALL, norm=norm, ego_head=True)).train()
    pc1, pc2, _, _, flow = scene(seed=7)
    static = flow + torch.tensor([0.3, 0.0, 0.5])
    encoded = []
    real = net._encode
    monkeypatch.setattr(net, "_encode", lambda xyz, *a: encoded.append(xyz.shape[0]) or real(xyz, *a))

    def run(reuse: bool):
        net.zero_grad()
        first = net(pc1, pc2)
        given = first.sampling if reuse else Sampling(pc1=first.sampling.pc1, pc2=first.sampling.pc2)
        second = net(pc1 + static, pc2, sampling=given)
        loss = sum((f ** 2).mean() for f in first.flows + second.flows)
        loss.backward()
        return second.flows, {k: p.grad.clone() for k, p in net.named_parameters() if p.grad is not None}

    assert isinstance(net(pc1, pc2).sampling, HALFlowSampling)
    encoded.clear()
    anew, grads_anew = run(False)
    assert encoded == [4, 4]  # both passes encode pc1 and pc2 stacked (B = 2)
    encoded.clear()
    reused, grads_reused = run(True)
    assert encoded == ([4, 2] if norm == "layer" else [4, 4])  # frame 2 taken from the first pass
    for a, b in zip(anew, reused):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
    assert grads_anew.keys() == grads_reused.keys()
    for k in grads_anew:
        torch.testing.assert_close(grads_anew[k], grads_reused[k], rtol=1e-3, atol=1e-5, msg=k)
    # another pc2 tensor (equal values) is not taken for the same frame: encoded anew
    encoded.clear()
    net(pc1 + static, pc2.clone(), sampling=net(pc1, pc2).sampling)
    assert encoded == [4, 4]
