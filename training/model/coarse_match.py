"""A coarse camera translation measured by matching, not regressed (``HALFlowConfig.coarse_match``).

HALFlowNet's coarsest flow is regressed from the first flow embedding; the ninth round of
docs/learned-flow.md measured that after the demo's 500 steps it follows a change of the camera's speed by
only 16–41 %. This module gives the coarse level a translation whose response to a shift of frame 2 is one
by construction, as long as the matching holds: every frame-1 point ``p_i`` takes a soft correspondence

    q̂_i = Σ_j softmax_j( φ(f1_i) · φ(f2_j) / √d − ‖q_j − p_i‖² / (2 σ²) ) q_j

over all frame-2 points of the level (positions in metres, one common camera frame: x right, y down,
z forward), and the translation is the mean of ``q̂_i − p_i``. ``φ`` is one learned linear map shared by
both frames; the features come from set convolutions over neighbour *offsets*, so they do not change when
a cloud is shifted. The distance prior (``sigma_m``, metres) keeps a match within a few metres of the
point: twice KITTI's largest motion per frame (about 2.5 m) by default. Rotation is left to the levels
below (a frame's turn is a few degrees at most).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn


class SoftTranslation(nn.Module):
    """The mean soft-correspondence displacement (B, 3) of frame-1 points towards frame-2 points."""

    def __init__(self, in_channels: int, width: int = 64, sigma_m: float = 5.0) -> None:
        super().__init__()
        if not sigma_m > 0:
            raise ValueError(f"sigma_m must be > 0, got {sigma_m}")
        self.embed = nn.Linear(in_channels, width)
        self.sigma_m = float(sigma_m)
        self.scale = 1.0 / math.sqrt(width)

    def forward(self, xyz1: Tensor, feat1: Tensor, xyz2: Tensor, feat2: Tensor) -> Tensor:
        """Args: frame-1 points (B, M, 3) with features (B, M, C); frame-2 points (B, N, 3) with features
        (B, N, C), metres. Returns (B, 3), metres."""
        e1, e2 = self.embed(feat1), self.embed(feat2)
        logits = torch.einsum("bmc,bnc->bmn", e1, e2) * self.scale
        logits = logits - torch.cdist(xyz1, xyz2).square() / (2.0 * self.sigma_m**2)
        target = torch.softmax(logits, dim=2) @ xyz2  # (B, M, 3)
        return (target - xyz1).mean(dim=1)
