"""Upsampling layers: set-upconv (learned, FlowNet3D / HALFlowNet) and feature propagation (3-NN
inverse-distance interpolation + MLP, PointNet++).

Both lift features from a sparse level (S points) to a dense one (M points); positions in metres.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from training.choices import NormKind
from training.knn import KnnBackend, knn
from training.model.layers import SharedMLP
from training.pointops import group, three_nn_interpolate


class SetUpConv(nn.Module):
    """Each dense point gathers its k nearest sparse points, embeds ``[f_sparse_j, p_j − p]`` (``widths``),
    max-pools over k, concatenates its own skip feature and applies ``post_widths``."""

    def __init__(
        self,
        dense_channels: int,
        sparse_channels: int,
        k: int,
        widths: Sequence[int],
        post_widths: Sequence[int],
        norm: NormKind = "batch",
        knn_backend: KnnBackend = "auto",
    ) -> None:
        super().__init__()
        self.k = k
        self.knn_backend = knn_backend
        self.mlp = SharedMLP(sparse_channels + 3, widths, norm)
        self.post = SharedMLP(self.mlp.out_channels + dense_channels, post_widths, norm)
        self.out_channels = self.post.out_channels

    def forward(self, dense_xyz: Tensor, sparse_xyz: Tensor, dense_feat: Tensor, sparse_feat: Tensor) -> Tensor:
        """(B, M, 3), (B, S, 3), (B, M, Cd), (B, S, Cs) -> (B, M, out_channels). k is clamped to S."""
        idx = knn(dense_xyz, sparse_xyz, min(self.k, sparse_xyz.shape[1]), self.knn_backend)[1]
        offsets = group(sparse_xyz, idx) - dense_xyz.unsqueeze(2)
        x = self.mlp(torch.cat([group(sparse_feat, idx), offsets], dim=-1)).max(dim=2).values
        return self.post(torch.cat([x, dense_feat], dim=-1))


class FeaturePropagation(nn.Module):
    """3-NN inverse-distance interpolation of sparse features, concatenated with the dense skip
    features, then a shared MLP (no MLP when ``widths`` is empty: plain interpolation)."""

    def __init__(
        self,
        dense_channels: int,
        sparse_channels: int,
        widths: Sequence[int],
        norm: NormKind = "batch",
        knn_backend: KnnBackend = "auto",
    ) -> None:
        super().__init__()
        self.knn_backend = knn_backend
        self.mlp = SharedMLP(sparse_channels + dense_channels, widths, norm)
        self.out_channels = self.mlp.out_channels

    def forward(
        self, dense_xyz: Tensor, sparse_xyz: Tensor, dense_feat: Tensor | None, sparse_feat: Tensor
    ) -> Tensor:
        """(B, M, 3), (B, S, 3), (B, M, Cd) or None, (B, S, Cs) -> (B, M, out_channels)."""
        x = three_nn_interpolate(dense_xyz, sparse_xyz, sparse_feat, backend=self.knn_backend)
        if dense_feat is not None:
            x = torch.cat([x, dense_feat], dim=-1)
        return self.mlp(x)
