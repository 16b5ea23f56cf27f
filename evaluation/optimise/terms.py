"""Label-free loss terms of the per-scene optimisation, built on the training losses
(:mod:`training.losses.chamfer`, :mod:`training.losses.laplacian`) rather than re-implemented.

Points are (B, N, 3) tensors in metres; ``pc1 + flow`` lies in camera-2 coordinates.
"""

from __future__ import annotations

import math

from torch import Tensor

from training.losses.chamfer import chamfer
from training.losses.laplacian import laplacian


def truncated_chamfer(p_warped: Tensor, pc2: Tensor, truncate: float = math.inf, plane: float = 0.0,
                      normals2: Tensor | None = None) -> Tensor:
    """``mean_p min(min_q ‖p − q‖², τ²) + mean_q min(min_p ‖p − q‖², τ²)``, m² (τ = ``truncate``, metres):
    :func:`training.losses.chamfer.chamfer` with its truncation. ``τ = inf`` is the paper's eq. 13; a
    finite τ is NSFP's: a point farther than τ from the other cloud adds a constant and no gradient, so
    unmatched points (occlusion, field of view) stop dragging the flow. ``plane`` λ in [0, 1]: each pair
    counts ``(1 − λ)`` of its squared distance and λ of its square along the frame-2 point's surface normal
    (``normals2`` (B, M, 3) when given, else estimated), as the training loss's ``loss.chamfer_plane``."""
    return chamfer(p_warped, pc2, truncate=truncate, plane=plane, normals2=normals2)


def laplacian_term(p_warped: Tensor, pc1: Tensor, pc2: Tensor, k: int = 10) -> Tensor:
    """The paper's Laplacian regularisation (eq. 16), :func:`training.losses.laplacian.laplacian`, m²."""
    return laplacian(p_warped, pc1, pc2, k=k)


def geman_mcclure(residual: Tensor, scale: float) -> Tensor:
    """``mean ρ(‖r‖)`` with ``ρ(r) = r² / (r² + s²)`` ∈ [0, 1) for residuals (B, N, 3) in metres, s = ``scale``."""
    r2 = (residual ** 2).sum(-1)
    return (r2 / (r2 + scale * scale)).mean()


def cycle_term(forward: Tensor, backward: Tensor) -> Tensor:
    """``mean ‖f + g‖²`` (m²): the backward flow ``g`` at the warped points should undo the forward flow ``f``."""
    return ((forward + backward) ** 2).sum(-1).mean()


__all__ = ["truncated_chamfer", "laplacian_term", "geman_mcclure", "cycle_term"]
