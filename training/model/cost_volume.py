"""HALFlowNet's double attentive cost volume (flow embedding) between frame 1 and frame 2.

1. Point-to-patch: each (possibly warped) frame-1 point p finds its ``k_pc2`` nearest frame-2 points q.
   Each pair is described by the geometry ``g(p, q) = [p, q, q − p, ‖q − p‖]`` (10 numbers) and both
   features; an MLP turns that into a matching cost; a second MLP, fed the cost and an embedding of
   g, gives per-channel attention logits; a softmax over the ``k_pc2`` pairs weights the costs into
   one point cost per p.
2. Patch-to-patch: each p gathers the point costs of its ``k_pc1`` nearest frame-1 neighbours
   (itself included); attention logits from ``[embed(g(p, p_j)), f1(p), cost_j]`` weight them into
   the final cost of p.

Positions in metres, in whatever common frame the caller uses (HALFlowNet: both clouds centred on
frame 1's mean).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from core.errors import InputError
from training.choices import NormKind
from training.knn import KnnBackend, knn
from training.model.layers import SharedMLP
from training.pointops import group


def pair_geometry(centres: Tensor, neighbours: Tensor) -> Tensor:
    """``[p, q, q − p, ‖q − p‖]`` for centres (B, M, 3) and their neighbours (B, M, k, 3) -> (B, M, k, 10)."""
    p = centres.unsqueeze(2).expand_as(neighbours)
    diff = neighbours - p
    dist = (diff * diff).sum(-1, keepdim=True).add(1e-12).sqrt()
    return torch.cat([p, neighbours, diff, dist], dim=-1)


class AttentiveCostVolume(nn.Module):
    """Double attentive cost volume; output (B, M, out_channels) per frame-1 point."""

    def __init__(
        self,
        in_channels: int,
        cost_widths: Sequence[int],
        attention_widths: Sequence[int],
        k_pc2: int,
        k_pc1: int,
        norm: NormKind = "batch",
        knn_backend: KnnBackend = "auto",
    ) -> None:
        """Args:
            in_channels: feature channels of both frames.
            cost_widths: MLP on ``[g, f1, f2]`` per pair (HALFlowNet's ``mlp1``); its last width is the
                cost width.
            attention_widths: the attention-logit MLPs (``mlp2``); the last width must equal the cost width
                (per-channel attention). The last layer is linear (logits).
        """
        super().__init__()
        c = cost_widths[-1]
        if attention_widths[-1] != c:
            raise InputError("AttentiveCostVolume", f"last attention width {attention_widths[-1]} != cost width {c}")
        self.k_pc2, self.k_pc1 = k_pc2, k_pc1
        self.knn_backend = knn_backend
        self.pair_cost = SharedMLP(10 + 2 * in_channels, cost_widths, norm)
        self.pair_geometry = SharedMLP(10, [c], norm)
        self.pair_attention = SharedMLP(2 * c, attention_widths, norm, last_linear=True)
        self.patch_geometry = SharedMLP(10, [c], norm)
        self.patch_attention = SharedMLP(2 * c + in_channels, attention_widths, norm, last_linear=True)
        self.out_channels = c

    def forward(self, xyz1: Tensor, feat1: Tensor, xyz2: Tensor, feat2: Tensor) -> Tensor:
        """Args: frame-1 points (B, M, 3) (warped by the current flow estimate) with features (B, M, C);
        frame-2 points (B, N, 3) with features (B, N, C). Returns (B, M, out_channels)."""
        # Point-to-patch: frame-1 point against its k_pc2 nearest frame-2 points.
        idx2 = knn(xyz1, xyz2, min(self.k_pc2, xyz2.shape[1]), self.knn_backend)[1]
        g = pair_geometry(xyz1, group(xyz2, idx2))
        f1 = feat1.unsqueeze(2).expand(-1, -1, idx2.shape[2], -1)
        cost = self.pair_cost(torch.cat([g, f1, group(feat2, idx2)], dim=-1))
        logits = self.pair_attention(torch.cat([self.pair_geometry(g), cost], dim=-1))
        point_cost = (torch.softmax(logits, dim=2) * cost).sum(2)  # (B, M, c)

        # Patch-to-patch: aggregate the point costs of the k_pc1 nearest frame-1 neighbours.
        idx1 = knn(xyz1, xyz1, min(self.k_pc1, xyz1.shape[1]), self.knn_backend)[1]
        g = pair_geometry(xyz1, group(xyz1, idx1))
        costs = group(point_cost, idx1)
        f1 = feat1.unsqueeze(2).expand(-1, -1, idx1.shape[2], -1)
        logits = self.patch_attention(torch.cat([self.patch_geometry(g), f1, costs], dim=-1))
        return (torch.softmax(logits, dim=2) * costs).sum(2)
