"""Laplacian regularisation loss (paper §III-E, eqs. 14–16)."""

from __future__ import annotations

import torch
from torch import Tensor

from training.knn import KnnBackend, knn
from training.losses._common import check_points
from training.pointops import group, knn_interpolate, surface_normals


def neighbours(points: Tensor, k: int, backend: KnnBackend = "auto") -> Tensor:
    """Indices (B, n, k') of the k' = min(k, n − 1) nearest *other* points of every point of ``points`` (B, n, 3).

    The point itself is left out even when another point coincides with it (then the duplicate is a
    neighbour at distance 0). No gradient. With n = 1 the result has k' = 0 columns.
    """
    B, n, _ = points.shape
    kk = min(k, n - 1)
    if kk <= 0:
        return torch.zeros(B, n, 0, dtype=torch.int64, device=points.device)
    _, idx = knn(points, points, kk + 1, backend)  # (B, n, kk+1), ascending
    own = torch.arange(n, device=idx.device).view(1, n, 1)
    is_self = idx == own
    # Drop the column holding the point itself; where it was not found (ties among duplicates), the last.
    drop = torch.where(is_self.any(-1), is_self.to(torch.int64).argmax(-1), torch.full_like(idx[..., 0], kk))
    keep = torch.ones_like(idx, dtype=torch.bool).scatter_(-1, drop.unsqueeze(-1), False)
    return idx[keep].view(B, n, kk)


def laplacian_coordinates(points: Tensor, idx: Tensor) -> Tensor:
    """``γ(p_i) = (1/|N(p_i)|) Σ_{j ∈ N(p_i)} (p_j − p_i)`` (eq. 14): (B, n, 3) metres.

    ``idx`` (B, n, k) holds the neighbourhoods N(p_i) as indices into ``points`` (B, n, 3); they may have
    been computed on another cloud with the same point order (the warped cloud uses pc1's). With k = 0
    the Laplacian is zero. Differentiable in ``points``.
    """
    if idx.shape[-1] == 0:
        return torch.zeros_like(points)
    return (group(points, idx) - points.unsqueeze(2)).mean(dim=2)


def laplacian(
    p_warped: Tensor,
    pc1: Tensor,
    pc2: Tensor,
    k: int = 10,
    k_interp: int = 5,
    backend: KnnBackend = "auto",
    plane: float = 0.0,
    normals2: Tensor | None = None,
    neighbours1: Tensor | None = None,
    plane_weight: Tensor | None = None,
) -> Tensor:
    """``L_LR = mean_{p̄ ∈ P̄} ‖γ(p̄) − γ̄(p̄)‖²`` (eq. 16), m².

    * ``γ(p̄)`` (eq. 14): Laplacian of the warped cloud ``p_warped`` = pc1 + f_o (B, n, 3), with the k
      nearest neighbours of each point taken **in pc1** (B, n, 3) — the warp must not change which points
      are neighbours, only where they are;
    * ``γ̄(p̄)`` (eq. 15): pc2's own Laplacian (k nearest pc2 neighbours, pc2 (B, m, 3)), interpolated at
      the warped point from its ``k_interp`` nearest pc2 points with inverse-distance weights
      ``w_j = 1 / ‖p̄ − q_j‖`` (:func:`training.pointops.knn_interpolate`).

    Neighbourhoods exclude the point itself (k = 10 other points; the released/PointPWC code takes 10
    including the point and divides by 9, i.e. 9 others). The squared norm is averaged over the warped
    points and the batch (the paper writes Σ). Gradient flows through the warped points, both in γ and
    in the interpolation weights; neighbour indices carry none.

    ``plane`` λ in [0, 1] (0 = the paper): the squared difference ``‖r‖²`` becomes ``(1 − λ) ‖r‖² +
    λ (r · n)²``, ``n`` the surface normal at the warped point's nearest pc2 point
    (:func:`training.pointops.surface_normals`). On a surface the Laplacian of a sample lies mostly along
    the surface and depends on where the samples happen to fall, so two samples of the same surface differ
    there even at the true flow; its normal component is the surface's curvature, which they share.
    ``normals2`` (B, m, 3): pc2's normals when the caller already has them (computed here otherwise);
    ``neighbours1`` (B, n, k'): :func:`neighbours` of ``pc1`` with this ``k``, likewise. ``plane_weight``
    (B, n) in [0, 1], no gradient: each warped point counts with ``λ w_i`` instead of λ
    (``loss.plane_where_held``).
    """
    check_points("laplacian", "p_warped", p_warped)
    B, n, _ = p_warped.shape
    check_points("laplacian", "pc1", pc1, B, n)
    check_points("laplacian", "pc2", pc2, B)
    gamma_warped = laplacian_coordinates(p_warped, neighbours(pc1, k, backend) if neighbours1 is None else neighbours1)
    gamma_pc2 = laplacian_coordinates(pc2, neighbours(pc2, k, backend))
    gamma_interp = knn_interpolate(p_warped, pc2, gamma_pc2, k=k_interp, backend=backend)
    diff = gamma_warped - gamma_interp
    full = (diff ** 2).sum(-1)
    if plane <= 0:
        return full.mean()
    _, near = knn(p_warped, pc2, 1, backend)
    normals = surface_normals(pc2, backend=backend) if normals2 is None else normals2
    normal = group(normals, near)[:, :, 0]
    lam = plane if plane_weight is None else plane * plane_weight
    return ((1 - lam) * full + lam * (diff * normal).sum(-1) ** 2).mean()
