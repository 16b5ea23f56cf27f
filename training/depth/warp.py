"""Inverse warping of a reference view into the target view (SC-SfMLearner's ``inverse_warp2``).

Every target pixel (u, v) with depth D_t is back-projected, ``P_t = D_t · K⁻¹ [u, v, 1]ᵀ`` (target camera,
metres up to the nets' scale), moved into the reference camera, ``P_r = R P_t + t`` with ``T = T_{t→r}``
(the pose net's ``pose_net(tgt, ref)``), and projected, ``(u', v') = π(K P_r)``. The reference image and
the reference depth map are sampled bilinearly at (u', v'); ``computed_depth`` is P_r's z.

Pixel convention (docs/design.md §2): pixel centres at integer (u, v), so u ∈ [0, W−1] maps to grid_sample's
[−1, 1] with ``align_corners=True``. (The released code normalises by W−1 but samples with
``align_corners=False``, a half-pixel shift; we keep geometry and sampling consistent.)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch.nn.functional as F
from torch import Tensor

from core.geometry import backproject, project, transform_points

MIN_DEPTH = 1e-3
"""z below this (behind or at the reference camera) is invalid; computed depths are clamped to it."""
GRID_TOLERANCE = 1e-4
"""Rounding slack of the in-image test (grid units): a border pixel mapped onto itself stays valid."""


@dataclass
class Warped:
    """The reference view seen from the target camera; all (B, ·, H, W) at the target's size.

    image: the reference image sampled at (u', v'); valid: 1 where (u', v') lies inside the reference
    image and in front of its camera, else 0 (float); projected_depth: the reference depth map sampled at
    (u', v'); computed_depth: z of the target points in the reference camera (clamped ≥ MIN_DEPTH).
    """

    image: Tensor
    valid: Tensor
    projected_depth: Tensor
    computed_depth: Tensor


def pixel_to_grid(uv: Tensor, height: int, width: int) -> Tensor:
    """Pixel coordinates (…, 2) → grid_sample coordinates in [−1, 1] (``align_corners=True``)."""
    scale = uv.new_tensor([2.0 / max(width - 1, 1), 2.0 / max(height - 1, 1)])
    return uv * scale - 1.0


def inverse_warp(ref_img: Tensor, tgt_depth: Tensor, ref_depth: Tensor, T_tgt_to_ref: Tensor, K: Tensor,
                 padding_mode: str = "zeros") -> Warped:
    """Warp ``ref_img`` (B, C, H, W) and ``ref_depth`` (B, 1, H, W) into the target view.

    ``tgt_depth`` (B, 1, H, W) is the target's depth, ``T_tgt_to_ref`` (B, 4, 4) maps target-camera points
    to reference-camera points, ``K`` (B, 3, 3) are the (shared) intrinsics in pixels.
    """
    B, _, H, W = ref_img.shape
    points = backproject(tgt_depth[:, 0], K).reshape(B, H * W, 3)
    moved = transform_points(T_tgt_to_ref, points)
    uv, z = project(moved, K, eps=MIN_DEPTH)
    grid = pixel_to_grid(uv, H, W).reshape(B, H, W, 2)
    image = F.grid_sample(ref_img, grid, mode="bilinear", padding_mode=padding_mode, align_corners=True)
    projected = F.grid_sample(ref_depth, grid, mode="bilinear", padding_mode=padding_mode, align_corners=True)
    inside = (grid.abs().amax(dim=-1) <= 1.0 + GRID_TOLERANCE) & (z.reshape(B, H, W) > MIN_DEPTH)
    computed = z.clamp(min=MIN_DEPTH).reshape(B, 1, H, W)
    return Warped(image=image, valid=inside[:, None].to(ref_img.dtype), projected_depth=projected,
                  computed_depth=computed)
