"""PointNet++ set abstraction (set conv) with kNN grouping — HALFlowNet's encoder layer.

For every sampled centre p (chosen by the caller), gather its k nearest points p_j of the denser level,
embed ``[p_j − p, f_j]`` with a shared MLP and pool over the k neighbours: ``"max"`` (PointNet++,
HALFlowNet's choice) or ``"attentive"`` (softmax-weighted sum with per-channel weights from a linear
score layer). Offsets p_j − p in the frame of the points (metres).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import torch
from torch import Tensor, nn

from core.errors import InputError
from training.choices import NormKind
from training.knn import KnnBackend, knn
from training.model.layers import SharedMLP
from training.pointops import group

Pooling = Literal["max", "attentive"]


def pool_neighbours(x: Tensor, pooling: str, score: nn.Module | None) -> Tensor:
    """(B, M, k, C) -> (B, M, C) by max or by a softmax over k of ``score(x)``."""
    if pooling == "max":
        return x.max(dim=2).values
    weights = torch.softmax(score(x), dim=2)
    return (weights * x).sum(dim=2)


class SetConv(nn.Module):
    """Set abstraction: features at sampled centres from their k nearest neighbours."""

    def __init__(
        self,
        in_channels: int,
        widths: Sequence[int],
        k: int,
        pooling: Pooling = "max",
        norm: NormKind = "batch",
        knn_backend: KnnBackend = "auto",
    ) -> None:
        super().__init__()
        if pooling not in ("max", "attentive"):
            raise InputError("SetConv", f"pooling must be 'max' or 'attentive', got {pooling!r}")
        self.k = k
        self.pooling = pooling
        self.knn_backend = knn_backend
        self.mlp = SharedMLP(in_channels + 3, widths, norm)
        self.out_channels = self.mlp.out_channels
        self.score = nn.Linear(self.out_channels, self.out_channels) if pooling == "attentive" else None

    def forward(self, xyz: Tensor, feat: Tensor, centres: Tensor) -> Tensor:
        """Args: ``xyz`` (B, N, 3) and ``feat`` (B, N, C) of the denser level; ``centres`` (B, M, 3).
        Returns (B, M, out_channels). k is clamped to N."""
        idx = knn(centres, xyz, min(self.k, xyz.shape[1]), self.knn_backend)[1]
        offsets = group(xyz, idx) - centres.unsqueeze(2)
        x = self.mlp(torch.cat([offsets, group(feat, idx)], dim=-1))
        return pool_neighbours(x, self.pooling, self.score)
