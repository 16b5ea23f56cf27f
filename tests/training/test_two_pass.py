"""The per-level loss inputs of the two passes: each level's own pc2 points (the paper), the finest level's
(``LossWeights.pc2_target="finest"``) or an independent draw (``"independent"``)."""

from __future__ import annotations

import pytest
import torch

from core.errors import ConfigError
from training.config import LossWeights
from training.data import FlowBatch
from training.model.contract import FlowOutput
from training.two_pass import level_inputs
from _trainer_fixtures import tiny_cache  # noqa: F401


def _batch_and_outputs(B: int = 2, N: int = 64) -> tuple[FlowBatch, FlowOutput, FlowOutput]:
    g = torch.Generator().manual_seed(0)
    pc1, pc2 = torch.randn(B, N, 3, generator=g), torch.randn(B, N, 3, generator=g)
    batch = FlowBatch(pc1=pc1, pc2=pc2, feat1=torch.zeros(B, N, 3), feat2=torch.zeros(B, N, 3),
                      static_flow=torch.randn(B, N, 3, generator=g), K=torch.eye(3).expand(B, 3, 3).clone(),
                      depth2=torch.ones(B, 8, 8), index=torch.arange(B))
    sizes = (32, 16, 8, 4)
    idx1 = [torch.stack([torch.randperm(N, generator=g)[:n] for _ in range(B)]) for n in sizes]
    idx2 = [torch.stack([torch.randperm(N, generator=g)[:n] for _ in range(B)]) for n in sizes]
    flows = [torch.randn(B, n, 3, generator=g) for n in sizes]
    out = FlowOutput(flows=flows, indices=idx1, points=[torch.gather(pc1, 1, i[..., None].expand(-1, -1, 3)) for i in idx1],
                     indices2=idx2)
    return batch, out, out


def test_pc2_target_level_and_finest():
    batch, out_o, out_d = _batch_and_outputs()
    paper = level_inputs(batch, out_o, out_d)
    finest = level_inputs(batch, out_o, out_d, "finest")
    for l, (a, b) in enumerate(zip(paper, finest)):
        want = torch.gather(batch.pc2, 1, out_o.indices2[l][..., None].expand(-1, -1, 3))
        assert torch.equal(a.pc2, want)  # the paper: the level's own pc2 sample
        assert torch.equal(b.pc2, paper[0].pc2)  # every level against the finest level's pc2 points
        assert torch.equal(a.pc1, b.pc1) and torch.equal(a.flow_o, b.flow_o)  # frame t untouched
    assert paper[3].pc2.shape[1] == 4 and finest[3].pc2.shape[1] == 32


def test_pc2_target_independent_uses_the_second_draw_at_every_level_size():
    batch, out_o, out_d = _batch_and_outputs()
    with pytest.raises(ValueError, match="pc2_target"):
        level_inputs(batch, out_o, out_d, "independent")  # the batch has no second draw
    g = torch.Generator().manual_seed(1)
    target = torch.randn(2, 64, 3, generator=g) + 100.0  # far from pc2: any point of it can only come from here
    batch.pc2_target = target
    levels = level_inputs(batch, out_o, out_d, "independent")
    paper = level_inputs(batch, out_o, out_d)
    for l, (a, b) in enumerate(zip(levels, paper)):
        assert a.pc2.shape == b.pc2.shape  # the level's size
        assert (a.pc2 > 50).all()  # taken from the second draw
        if l:  # each level is a subset of the one before (nested, as the net samples)
            prev = levels[l - 1].pc2
            assert all((a.pc2[k][:, None] == prev[k][None]).all(-1).any(-1).all() for k in range(2))
        assert torch.equal(a.pc1, b.pc1) and torch.equal(a.flow_o, b.flow_o)


def test_independent_draw_avoids_the_input_points(tiny_cache):  # noqa: F811
    """The second draw of frame t+1 shares no point with the net's pc2 while the cloud has enough points;
    off, nothing is drawn (the same sample as before)."""
    import numpy as np

    from pipeline.cache import CacheReader
    from training.data import PairDataset

    r = CacheReader(tiny_cache)
    n_cloud = len(r[3].pc2)
    n = n_cloud // 3
    plain = PairDataset(r, [3], n, seed=0)[0]
    drawn = PairDataset(r, [3], n, seed=0, target_draw=True)[0]
    assert all(np.array_equal(plain[k], drawn[k]) for k in plain) and "pc2_target" not in plain
    shared = (drawn["pc2_target"][:, None] == drawn["pc2"][None]).all(-1).any(-1)
    assert drawn["pc2_target"].shape == drawn["pc2"].shape and not shared.any()
    on_cloud = (drawn["pc2_target"][:, None] == r[3].pc2[None]).all(-1).any(-1)
    assert on_cloud.all()  # every target point is a frame-(t+1) point


def test_pc2_target_is_checked():
    with pytest.raises(ConfigError, match="pc2_target"):
        LossWeights(pc2_target="dense")


def test_view_mask_leaves_points_without_counterpart_out_of_the_chamfer_means():
    """A frame-t point whose target left the view pulls the plain Chamfer term; masked, the term is the
    one of the points that have counterparts, and every point is still a candidate neighbour."""
    from training.losses.chamfer import chamfer

    pc2 = torch.tensor([[[0.0, 0.0, 5.0], [1.0, 0.0, 5.0]]])
    warped = torch.tensor([[[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [9.0, 0.0, 5.0]]])  # the last one has left the view
    plain = chamfer(warped, pc2, "torch")
    masked = chamfer(warped, pc2, "torch", torch.tensor([[True, True, False]]), torch.tensor([[True, True]]))
    assert float(plain) == pytest.approx(64.0 / 3)  # (0 + 0 + 8²) / 3, the other direction 0
    assert float(masked) == pytest.approx(0.0)
    assert float(chamfer(warped, pc2, "torch", torch.zeros(1, 3, dtype=torch.bool))) == pytest.approx(64.0 / 3)


def test_in_view_and_the_batch_masks(tiny_cache):  # noqa: F811
    """``in_view``: in front, nearer than the far limit, inside the image; the dataset's view1 is in_view of
    each point's camera-motion target, and level_inputs hands the masks to every level."""
    import numpy as np

    from pipeline.cache import CacheReader
    from training.data import PairDataset, collate, in_view

    K = np.array([[100.0, 0, 50], [0, 100.0, 20], [0, 0, 1]])
    pts = np.array([[0, 0, 10.0], [0, 0, -1.0], [0, 0, 40.0], [6.0, 0, 10.0], [0, 2.0, 10.0]])
    assert in_view(pts, K, (41, 101)).tolist() == [True, False, False, False, True]
    r = CacheReader(tiny_cache)
    d = PairDataset(r, [3], 128, seed=0, view_masks=True)[0]
    s = r[3]
    assert np.array_equal(d["view1"], in_view(d["pc1"] + d["static_flow"], s.K, s.depth2.shape))
    assert d["view1"].dtype == bool and d["view2"].shape == (128,)
    batch = collate([d, PairDataset(r, [5], 128, seed=0, view_masks=True)[0]])
    _, out_o, out_d = _batch_and_outputs(B=2, N=128)
    levels = level_inputs(batch, out_o, out_d, view_mask=True)
    for l, lv in enumerate(levels):
        assert torch.equal(lv.view1, torch.gather(batch.view1, 1, out_o.indices[l]))
        assert torch.equal(lv.view2, torch.gather(batch.view2, 1, out_o.indices2[l]))
    with pytest.raises(ValueError, match="view_mask"):
        level_inputs(_batch_and_outputs(B=2, N=128)[0], out_o, out_d, view_mask=True)


def test_view_masks_use_the_far_limit_the_cache_was_built_with(tiny_cache):  # noqa: F811
    import math

    import numpy as np

    from pipeline.cache import CacheReader
    from pipeline.filters import FAR_LIMIT_M
    from training.data import PairDataset, cache_far_limit, in_view

    r = CacheReader(tiny_cache)  # the manifest is edited in memory only, as stage one would have written it
    assert cache_far_limit(object()) == FAR_LIMIT_M  # no stage-one filters recorded: stage one's default
    r.manifest.setdefault("config", {})["filters"] = {"far": True, "far_max_z": 30.0}
    assert cache_far_limit(r) == 30.0
    r.manifest["config"]["filters"]["far"] = False
    assert cache_far_limit(r) == math.inf
    r.manifest["config"]["filters"].update(far=True, far_max_z=4.0)  # nearer than part of the scene
    d = PairDataset(r, [3], 128, seed=0, view_masks=True)[0]
    s = r[3]
    target = d["pc1"] + d["static_flow"]
    assert np.array_equal(d["view1"], in_view(target, s.K, s.depth2.shape, 4.0))
    assert not d["view1"][target[:, 2] > 4.0].any() and (target[:, 2] > 4.0).any()
