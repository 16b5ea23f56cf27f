"""Robust rigid fit to a flow field: the ego-motion part of a mostly static scene.

Given pc1 (N, 3) and a flow (N, 3) (metres, camera frames), find ``R, t`` minimising
``Σ_i ρ(‖R p_i + t − (p_i + f_i)‖)`` with the Geman–McClure ``ρ(r) = r² / (r² + s²)``, by iteratively
reweighted least squares: each step is a weighted Kabsch/Umeyama solve (SVD of the weighted
cross-covariance, determinant-corrected to a rotation) with weights ``w_i = s² / (r_i² + s²)²``
(``ρ'(r)/r`` up to a constant). The first step weights every point equally (plain least squares), so
the static majority of a driving scene sets the start and moving objects are down-weighted after.
"""

from __future__ import annotations

import torch
from torch import Tensor


def weighted_kabsch(src: Tensor, dst: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """``R`` (3, 3), ``t`` (3,) minimising ``Σ w_i ‖R src_i + t − dst_i‖²`` (src, dst (N, 3), weights (N,) ≥ 0)."""
    w = weights / weights.sum().clamp_min(1e-12)
    mu_s = (w[:, None] * src).sum(0)
    mu_d = (w[:, None] * dst).sum(0)
    cov = ((src - mu_s) * w[:, None]).T @ (dst - mu_d)  # (3, 3): Σ w s dᵀ
    u, _, vt = torch.linalg.svd(cov)
    d = torch.sign(torch.linalg.det(vt.T @ u.T))
    d = torch.where(d == 0, torch.ones_like(d), d)  # degenerate (planar/collinear) input: keep the SVD's answer
    fix = torch.diag(torch.stack([torch.ones_like(d), torch.ones_like(d), d]))
    rot = vt.T @ fix @ u.T
    return rot, mu_d - rot @ mu_s


def robust_rigid_fit(pc1: Tensor, flow: Tensor, scale: float = 0.2, steps: int = 10) -> tuple[Tensor, Tensor, Tensor]:
    """IRLS Geman–McClure rigid fit (module docstring); returns ``R`` (3, 3), ``t`` (3,) metres and the
    rigid flow ``(R p + t) − p`` (N, 3), all in pc1's dtype (computed in float64, without gradient).

    The scale of each step is ``max(scale, 1.4826 · median residual)`` (the MAD estimate of the inliers'
    spread): with an accurate flow it is ``scale`` and moving points are rejected; with a noisy flow
    (a poorly trained net) the static points' noise is not mistaken for motion and is averaged instead.
    """
    with torch.no_grad():
        src = pc1.detach().double()
        dst = src + flow.detach().double()
        w = torch.ones(len(src), dtype=torch.float64, device=src.device)
        rot, t = weighted_kabsch(src, dst, w)
        for _ in range(steps):
            r2 = ((src @ rot.T + t - dst) ** 2).sum(-1)
            s2 = max(float(scale), 1.4826 * float(r2.sqrt().median())) ** 2
            w = s2 / (r2 + s2) ** 2
            rot, t = weighted_kabsch(src, dst, w)
        rigid = src @ rot.T + t - src
    return rot.to(pc1.dtype), t.to(pc1.dtype), rigid.to(pc1.dtype)


def so3_exp(omega: Tensor) -> Tensor:
    """Rotation matrix (3, 3) of the rotation vector ``omega`` (3,) radians (Rodrigues' formula,
    ``R = I + sin θ K + (1 − cos θ) K²`` with ``K`` the skew matrix of the unit axis); differentiable,
    including at ``omega = 0`` (where the first-order form ``I + [ω]×`` is used)."""
    theta2 = (omega * omega).sum()
    zero = torch.zeros((), dtype=omega.dtype, device=omega.device)
    wx, wy, wz = omega.unbind()
    k = torch.stack([torch.stack([zero, -wz, wy]), torch.stack([wz, zero, -wx]), torch.stack([-wy, wx, zero])])
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device)
    if float(theta2.detach()) < 1e-12:
        return eye + k
    theta = theta2.sqrt()
    return eye + torch.sin(theta) / theta * k + (1 - torch.cos(theta)) / theta2 * (k @ k)


def inlier_weights(residual: Tensor, scale: float) -> Tensor:
    """Geman–McClure inlier weight ``s² / (‖r‖² + s²)`` ∈ (0, 1] of residuals (…, 3) metres (1 at r = 0)."""
    s2 = float(scale) ** 2
    return s2 / ((residual ** 2).sum(-1) + s2)
