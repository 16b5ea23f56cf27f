"""The per-level loss inputs of the two passes: each level's own pc2 points (the paper) or the finest level's
(``LossWeights.pc2_target="finest"``)."""

from __future__ import annotations

import pytest
import torch

from core.errors import ConfigError
from training.config import LossWeights
from training.data import FlowBatch
from training.model.contract import FlowOutput
from training.two_pass import level_inputs


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


def test_pc2_target_is_checked():
    with pytest.raises(ConfigError, match="pc2_target"):
        LossWeights(pc2_target="dense")
