"""Chamfer loss (paper §III-D, eq. 13)."""

from __future__ import annotations

import math

from torch import Tensor

from training.knn import KnnBackend, knn
from training.losses._common import check_points
from training.pointops import group


def nearest_sq_dist(query: Tensor, ref: Tensor, backend: KnnBackend = "auto") -> Tensor:
    """Squared distance (B, M) from every ``query`` point (B, M, 3) to its nearest ``ref`` point (B, N, 3).

    The neighbour is found without gradient (:func:`training.knn.knn`); the distance is recomputed from
    the gathered coordinates, so it is differentiable in both clouds (no square root: finite gradient
    even for coinciding points).
    """
    _, idx = knn(query, ref, 1, backend)
    return ((group(ref, idx)[:, :, 0] - query) ** 2).sum(-1)


def chamfer(p_warped: Tensor, pc2: Tensor, backend: KnnBackend = "auto", mask1: Tensor | None = None,
            mask2: Tensor | None = None, truncate: float = math.inf) -> Tensor:
    """``L_Cha = mean_{p̄ ∈ P̄} min_{q ∈ PC2} ‖p̄ − q‖² + mean_{q ∈ PC2} min_{p̄ ∈ P̄} ‖p̄ − q‖²`` (eq. 13).

    ``p_warped`` (B, N, 3) = pc1 + f_o and ``pc2`` (B, M, 3), both camera-2 frame, metres; result in m².
    Each direction is averaged over its own points (the paper writes sums), then over the batch.
    ``mask1`` (B, N) / ``mask2`` (B, M), bool: only these points enter their direction's mean (every point
    stays a candidate neighbour); ``loss.view_mask`` passes the points that have a counterpart in view.
    ``truncate`` τ (metres; ``inf`` = the paper): a nearest-neighbour distance above τ counts as τ, with no
    gradient (NSFP's truncation, Li et al. 2021): a point with no counterpart in the other cloud (out of
    view, occluded, beyond the other frame's range) adds a constant instead of pulling the flow.
    """
    check_points("chamfer", "p_warped", p_warped)
    check_points("chamfer", "pc2", pc2, p_warped.shape[0])
    d12, d21 = nearest_sq_dist(p_warped, pc2, backend), nearest_sq_dist(pc2, p_warped, backend)
    if math.isfinite(truncate):
        d12, d21 = d12.clamp(max=truncate * truncate), d21.clamp(max=truncate * truncate)
    return masked_mean(d12, mask1) + masked_mean(d21, mask2)


def masked_mean(values: Tensor, mask: Tensor | None) -> Tensor:
    """Mean of ``values`` (B, N) over the ``mask`` (B, N) entries (all when None or when none is set)."""
    if mask is None:
        return values.mean()
    weight = mask.to(values.dtype)
    total = weight.sum()
    return (values * weight).sum() / total if bool(total > 0) else values.mean()
