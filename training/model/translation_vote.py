"""The camera's translation between two clouds by voting over all point-pair offsets (no learning).

Most points of a driving scene are static, so frame 2's cloud is frame 1's moved by one rigid motion
``p ↦ R p + t``; over one frame (0.1 s) the rotation is a few degrees at most and the translation is
what dominates the static flow. For a pure translation, every static frame-1 point ``p_i`` has a
frame-2 point near ``p_i + t``, so among all offsets ``d_ij = q_j − p_i`` (metres, one common camera
frame: x right, y down, z forward) the offsets near ``t`` are much denser than anywhere else. Their
density is the kernel correlation of the two clouds as a function of the shift (Tsin & Kanade's
kernel-correlation registration), computed here for all shifts at once:

1. vote: a histogram of the offsets inside the search cube ``|d|_∞ ≤ max_translation_m`` with cells of
   ``cell_m``, smoothed by a 3×3×3 binomial kernel; its fullest cell is the global mode (no initial
   guess, unlike ICP);
2. refine: mean shift of that mode over the offsets with Gaussian kernels of shrinking widths
   ``bandwidths_m``, ``t ← Σ_ij w_ij d_ij / Σ_ij w_ij``, ``w_ij = exp(−‖d_ij − t‖² / 2h²)``.

Movers vote for their own offsets and lose to the static majority; a rotation spreads the static
votes (by the rotation angle times the distance), which the wide first bandwidth absorbs. The result
has no gradient: it serves :class:`~training.model.halflownet.HALFlowNet` (``model.translation_vote``)
as a pre-alignment whose response to a change of speed is one by construction, and the ``tvote``
baseline of :mod:`evaluation.methods` as a rigid-translation registration.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class VoteConfig:
    """The translation vote's search, in metres.

    max_translation_m: half the side of the search cube around zero offset (twice KITTI's largest
        motion per frame at 10 Hz, about 2.5 m, would be 5; 3 covers 100 km/h).
    cell_m: the histogram's cell size.
    bandwidths_m: mean-shift kernel widths, widest first, two rounds each.
    """

    max_translation_m: float = 3.0
    cell_m: float = 0.25
    bandwidths_m: tuple[float, ...] = (0.5, 0.25, 0.1)

    def __post_init__(self) -> None:
        if not (self.max_translation_m > 0 and self.cell_m > 0 and self.bandwidths_m
                and all(h > 0 for h in self.bandwidths_m)):
            raise ValueError(f"need a positive max_translation_m, cell_m and bandwidths_m, got {self}")


def _binomial_blur(grid: Tensor) -> Tensor:
    """(B, X, Y, Z) counts smoothed by the separable [1, 2, 1] / 4 kernel along every axis."""
    k = torch.tensor([0.25, 0.5, 0.25], dtype=grid.dtype, device=grid.device)
    kernel = (k[:, None, None] * k[None, :, None] * k[None, None, :])[None, None]
    return torch.nn.functional.conv3d(grid[:, None], kernel, padding=1)[:, 0]


@torch.no_grad()
def vote_translation(xyz1: Tensor, xyz2: Tensor, config: VoteConfig | None = None) -> Tensor:
    """The dominant translation (B, 3) in metres that moves frame-1 points ``xyz1`` (B, M, 3) onto
    frame-2 points ``xyz2`` (B, N, 3); zero for a cloud with no offset inside the search cube."""
    cfg = config or VoteConfig()
    x1, x2 = xyz1.detach().float(), xyz2.detach().float()
    B = x1.shape[0]
    d = (x2[:, None, :, :] - x1[:, :, None, :]).reshape(B, -1, 3)  # (B, M·N, 3) offsets q_j − p_i
    R, c = cfg.max_translation_m, cfg.cell_m
    n = int(round(2 * R / c))
    cell = torch.floor((d + R) / c).long()
    inside = ((cell >= 0) & (cell < n)).all(dim=-1)
    flat = (cell[..., 0] * n + cell[..., 1]) * n + cell[..., 2]
    flat = torch.where(inside, flat, torch.zeros_like(flat))
    counts = torch.zeros(B, n * n * n, dtype=x1.dtype, device=x1.device)
    counts.scatter_add_(1, flat, inside.to(x1.dtype))
    best = _binomial_blur(counts.reshape(B, n, n, n)).reshape(B, -1).argmax(dim=1)
    ix, iy, iz = best // (n * n), (best // n) % n, best % n
    t = (torch.stack([ix, iy, iz], dim=-1).to(x1.dtype) + 0.5) * c - R
    t = torch.where(inside.any(dim=1, keepdim=True), t, torch.zeros_like(t))
    for h in cfg.bandwidths_m:
        for _ in range(2):
            w = torch.exp(-((d - t[:, None]) ** 2).sum(-1) / (2 * h * h)) * inside
            t = torch.where(w.sum(1, keepdim=True) > 0,
                            (w[..., None] * d).sum(1) / w.sum(1, keepdim=True).clamp_min(1e-30), t)
    return t.to(xyz1.dtype)
