"""Chamfer loss (paper §III-D, eq. 13)."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from training.knn import KnnBackend, knn
from training.losses._common import check_points
from training.pointops import group, surface_normals


def nearest_sq_dist(query: Tensor, ref: Tensor, backend: KnnBackend = "auto") -> Tensor:
    """Squared distance (B, M) from every ``query`` point (B, M, 3) to its nearest ``ref`` point (B, N, 3).

    The neighbour is found without gradient (:func:`training.knn.knn`); the distance is recomputed from
    the gathered coordinates, so it is differentiable in both clouds (no square root: finite gradient
    even for coinciding points).
    """
    return (nearest_offset(query, ref, backend)[0] ** 2).sum(-1)


def nearest_offset(query: Tensor, ref: Tensor, backend: KnnBackend = "auto") -> tuple[Tensor, Tensor]:
    """Offset (B, M, 3) from every ``query`` point to its nearest ``ref`` point, and that point's index (B, M).

    The neighbour is found without gradient; the offset ``q − p`` is differentiable in both clouds.
    """
    _, idx = knn(query, ref, 1, backend)
    return group(ref, idx)[:, :, 0] - query, idx[..., 0]


def _pair_sq_dist(offset: Tensor, normal: Tensor | None, plane: float | Tensor) -> tuple[Tensor, Tensor]:
    """Blended squared distance ``(1 − λ) ‖o‖² + λ (o · n)²`` of offsets (B, M, 3) and the plain one; ``plane``
    λ is one number or one per offset (B, M)."""
    full = (offset ** 2).sum(-1)
    if normal is None or (not isinstance(plane, Tensor) and plane <= 0):
        return full, full
    along = (offset * normal).sum(-1) ** 2
    return (1 - plane) * full + plane * along, full


def chamfer(p_warped: Tensor, pc2: Tensor, backend: KnnBackend = "auto", mask1: Tensor | None = None,
            mask2: Tensor | None = None, truncate: float = math.inf, plane: float = 0.0,
            normals2: Tensor | None = None, plane_weight1: Tensor | None = None) -> Tensor:
    """``L_Cha = mean_{p̄ ∈ P̄} min_{q ∈ PC2} ‖p̄ − q‖² + mean_{q ∈ PC2} min_{p̄ ∈ P̄} ‖p̄ − q‖²`` (eq. 13).

    ``p_warped`` (B, N, 3) = pc1 + f_o and ``pc2`` (B, M, 3), both camera-2 frame, metres; result in m².
    Each direction is averaged over its own points (the paper writes sums), then over the batch.
    ``mask1`` (B, N) / ``mask2`` (B, M), bool: only these points enter their direction's mean (every point
    stays a candidate neighbour); ``loss.view_mask`` passes the points that have a counterpart in view.
    ``truncate`` τ (metres; ``inf`` = the paper): a nearest-neighbour distance above τ counts as τ, with no
    gradient (NSFP's truncation, Li et al. 2021): a point with no counterpart in the other cloud (out of
    view, occluded, beyond the other frame's range) adds a constant instead of pulling the flow.
    ``plane`` λ in [0, 1] (0 = the paper): each pair's squared distance becomes ``(1 − λ) ‖p̄ − q‖² +
    λ ((p̄ − q) · n_q)²``, ``n_q`` the surface normal at the pair's pc2 point (:func:`surface_normals`), in
    both directions. A point-to-point distance is least at the sample itself, so it pulls every point that
    lands between two samples of a surface onto one of them — a pull along the surface that the true flow
    does not have and that a net which sees pc2 can learn. The normal component keeps the pull onto the
    surface and drops the one along it. The truncation still reads the plain distance. ``normals2`` (B, M, 3):
    pc2's normals when the caller already has them (computed here otherwise). ``plane_weight1`` (B, N) in
    [0, 1], no gradient: each warped point's pair counts with ``λ w_i`` instead of λ, and each pc2 point's
    pair with the ``w`` of its nearest warped point (``loss.plane_where_held``: ``w = 1 − m``, the ego head's
    gate).
    """
    check_points("chamfer", "p_warped", p_warped)
    check_points("chamfer", "pc2", pc2, p_warped.shape[0])
    if plane < 0 or plane > 1:
        raise ValueError(f"chamfer: plane must be in [0, 1], got {plane}")
    normals = None
    if plane > 0:
        normals = surface_normals(pc2, backend=backend) if normals2 is None else normals2
    o12, i12 = nearest_offset(p_warped, pc2, backend)
    n12 = None if normals is None else group(normals, i12[..., None])[:, :, 0]
    o21, i21 = nearest_offset(pc2, p_warped, backend)
    lam12: float | Tensor = plane
    lam21: float | Tensor = plane
    if plane_weight1 is not None and plane > 0:
        lam12, lam21 = plane * plane_weight1, plane * plane_weight1.gather(1, i21)
    (d12, f12), (d21, f21) = _pair_sq_dist(o12, n12, lam12), _pair_sq_dist(o21, normals, lam21)
    if math.isfinite(truncate):
        cap = truncate * truncate
        d12, d21 = torch.where(f12 > cap, cap, d12), torch.where(f21 > cap, cap, d21)
    return masked_mean(d12, mask1) + masked_mean(d21, mask2)


def masked_mean(values: Tensor, mask: Tensor | None) -> Tensor:
    """Mean of ``values`` (B, N) over the ``mask`` (B, N) entries (all when None or when none is set)."""
    if mask is None:
        return values.mean()
    weight = mask.to(values.dtype)
    total = weight.sum()
    return (values * weight).sum() / total if bool(total > 0) else values.mean()
