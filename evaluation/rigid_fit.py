"""One rigid motion fitted robustly to a flow field, for numpy callers (the view pruning, the rigid polish).

A thin front for :func:`training.model.ego_motion.rigid_plus_residual` — the net's own ego head fit (IRLS
with Cauchy weights and a robust scale from the residuals' median), run in float64 on the CPU — so that the
wrappers in ``evaluation/`` and the net measure a flow's camera motion the same way.
"""

from __future__ import annotations

import numpy as np

__all__ = ["rigid_fit"]


def rigid_fit(pc1: np.ndarray, flow: np.ndarray, sigma: float = 0.25, iterations: int = 4,
              mad_factor: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """``(R (3, 3), t (3,))`` such that ``R p + t`` follows ``flow`` (N, 3) at ``pc1`` (N, 3) for most points:
    the camera-1 → camera-2 motion of the points that move with the camera, movers down-weighted. ``sigma``
    (metres, the Cauchy scale's floor), ``iterations`` (IRLS rounds) and ``mad_factor`` (the robust scale is
    ``max(sigma, mad_factor · 1.4826 · median residual)``) as :func:`training.model.ego_motion.rigid_plus_residual`.
    Camera frames (x right, y down, z forward), metres."""
    import torch

    from training.model.ego_motion import rigid_plus_residual

    def t(x: np.ndarray) -> torch.Tensor:
        return torch.tensor(np.asarray(x, np.float64))[None]

    split = rigid_plus_residual(t(pc1), t(flow), sigma, iterations, mad_factor)
    return split.R[0].numpy(), split.t[0].numpy()
