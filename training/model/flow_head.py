"""Flow prediction: the refinement MLP of a warping level and the linear flow heads.

A flow head is one linear layer (a 1×1 conv) with no norm and no activation, so the flow can take any
sign and size; flow in metres, in the frame of the input points (camera frame of frame 1).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from training.choices import NormKind
from training.model.layers import SharedMLP


class FlowHead(nn.Module):
    """Linear map (B, M, C) -> (B, M, 3) flow; ``zero_init``: weights and bias start at zero, so the head's
    first output is no flow (``HALFlowConfig.zero_flow_heads``)."""

    def __init__(self, in_channels: int, zero_init: bool = False) -> None:
        super().__init__()
        self.linear = nn.Linear(in_channels, 3)
        if zero_init:
            nn.init.zeros_(self.linear.weight)
            nn.init.zeros_(self.linear.bias)

    def forward(self, x: Tensor) -> Tensor:
        return self.linear(x)


class FlowRefiner(nn.Module):
    """Refinement features of one level from ``[coarse flow, frame-1 features, cost volume, upsampled
    features]`` (B, M, 3 + C1 + Cc + Cu) through a shared MLP; a :class:`FlowHead` on top gives the
    flow correction."""

    def __init__(
        self, feat_channels: int, cost_channels: int, up_channels: int, widths: Sequence[int], norm: NormKind = "batch"
    ) -> None:
        super().__init__()
        self.mlp = SharedMLP(3 + feat_channels + cost_channels + up_channels, widths, norm)
        self.out_channels = self.mlp.out_channels

    def forward(self, coarse_flow: Tensor, feat: Tensor, cost: Tensor, upsampled: Tensor) -> Tensor:
        return self.mlp(torch.cat([coarse_flow, feat, cost, upsampled], dim=-1))
