"""The building block of every HALFlowNet module: a shared MLP applied to the last (channel) axis.

Channels-last tensors (..., C) of any rank — per point (B, M, C) or per neighbour (B, M, k, C) — go
through ``Linear → norm → ReLU`` layers. The norm (:data:`training.choices.NORMS`) is HALFlowNet's batch norm, which
normalises over every leading position (the statistics a 1×1 convolution with ``BatchNorm2d`` would use;
running statistics at inference), or a per-position layer norm over the channels, which depends on
nothing but the position's own features (the same in training and at inference, on any cloud), or none.
``last_linear=True`` leaves the last layer without norm and activation (for attention logits and flow
heads).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from training.choices import NORMS, NormKind


def scaled(width: int, scale: float) -> int:
    """A layer width multiplied by the config's ``width_scale`` (at least 1)."""
    return max(1, int(round(width * scale)))


class SharedMLP(nn.Module):
    """Pointwise MLP over the last axis: ``in_channels → widths[0] → … → widths[-1]``."""

    def __init__(
        self, in_channels: int, widths: Sequence[int], norm: NormKind = "batch", last_linear: bool = False
    ) -> None:
        super().__init__()
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
        self.in_channels = in_channels
        self.out_channels = widths[-1] if widths else in_channels
        self.linears = nn.ModuleList()
        self.norms = nn.ModuleList()
        self.activate: list[bool] = []
        # eval mode only: normalise with the statistics of the input itself instead of the running ones
        # (set by HALFlowNet from HALFlowConfig.eval_norm_stats; see there)
        self.input_stats = False
        c = in_channels
        for i, w in enumerate(widths):
            plain = last_linear and i == len(widths) - 1
            normed = norm != "none" and not plain
            self.linears.append(nn.Linear(c, w, bias=not normed))
            if not normed:
                self.norms.append(nn.Identity())
            else:
                self.norms.append(nn.BatchNorm1d(w) if norm == "batch" else nn.LayerNorm(w))
            self.activate.append(not plain)
            c = w

    def forward(self, x: Tensor) -> Tensor:
        """(..., in_channels) -> (..., out_channels)."""
        for linear, norm, act in zip(self.linears, self.norms, self.activate):
            x = linear(x)
            if isinstance(norm, nn.LayerNorm):
                x = norm(x)
            elif not isinstance(norm, nn.Identity):  # batch norm (or its SyncBatchNorm conversion)
                shape = x.shape
                flat = x.reshape(-1, shape[-1])
                if self.input_stats and not self.training:
                    flat = F.batch_norm(flat, None, None, norm.weight, norm.bias, True, 0.0, norm.eps)
                else:
                    flat = norm(flat)
                x = flat.view(shape)
            if act:
                x = torch.relu(x)
        return x
