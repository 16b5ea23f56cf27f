"""Two-pass inference that sets aside the frame-t points leaving the sensor's view (label-free).

A LiDAR test cloud keeps every return of frame t, including the points that leave the camera's field of
view or the 35 m range by frame t+1 (8–17 % of the points on the synthetic worlds' LiDAR splits) and so
have no counterpart in pc2. Stage one's default occlusion filter drops such points from the training
clouds, and a net that never met them drags its flow, and its rigid ego-motion, towards wrong matches for
them; a net trained on clouds that keep them (the demo's cache, ``--filters.occlusion false``) still has
no correct match to learn for them (docs/learned-flow.md, third round). This wrapper, usable around any
method:

1. runs the method on the whole clouds and fits one rigid motion (R, t) to its flow (IRLS with Cauchy
   weights, :func:`evaluation.rigid_fit.rigid_fit`);
2. marks the frame-t points whose rigid target ``R p + t`` falls outside pc2's own extent — its azimuth
   sector (the circle less its widest azimuth gap) narrowed by ``margin_deg`` on each side, its elevation
   range and its farthest depth (its farthest horizontal range for a surround sweep), all read from pc2
   itself, so no label, pose or calibration is used (:class:`core.view.ViewExtent`);
3. runs the method again on the remaining points (topped up by repeats to the input size) and pc2; the
   marked points take the rigid flow.

Clouds: camera frames of frames 1 and 2 (x right, y down, z forward), metres. The row it adds is named
``"<method> + view pruning"``; the method's own row is unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.view import VIEW_MARGIN_DEG, ViewExtent
from evaluation.answers import ask
from evaluation.rigid_fit import rigid_fit
from evaluation.wrapping import MethodWrapper

__all__ = ["ViewPruneConfig", "ViewPruned", "inside_extent", "view_pruned"]


@dataclass
class ViewPruneConfig:
    """margin_deg: the azimuth band (degrees) at each side of pc2's extent that counts as outside.
    min_share: below this share of points in view the first pass's flow is returned unchanged.
    sigma, iterations, mad_factor: the rigid fit's Cauchy scale (metres), rounds and robust-scale factor
    (:func:`training.model.ego_motion.rigid_plus_residual`, the ego head's defaults)."""

    margin_deg: float = VIEW_MARGIN_DEG
    min_share: float = 0.25
    sigma: float = 0.25
    iterations: int = 4
    mad_factor: float = 3.0


def inside_extent(points: np.ndarray, pc2: np.ndarray, margin_deg: float) -> np.ndarray:
    """(N,) bool: ``points`` (camera-2 frame) within pc2's azimuth sector (less ``margin_deg`` each side),
    its elevation range and its reach (:class:`ViewExtent`: its farthest depth for a sector ahead of the camera,
    its farthest horizontal range for a surround sweep)."""
    return ViewExtent.of(pc2, margin_deg).contains(points)


class ViewPruned(MethodWrapper):
    """``inner`` (any flow method) run twice, the second time without the points leaving pc2's view."""

    suffix = "view pruning"
    config_type = ViewPruneConfig

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        cfg = self.config
        first = np.asarray(ask(self.inner, pc1, pc2, color1, color2), np.float32)  # the inner row's own answer
        R, t = rigid_fit(pc1, first, cfg.sigma, cfg.iterations, cfg.mad_factor)
        target = np.asarray(pc1, np.float64) @ R.T + t
        keep = np.flatnonzero(inside_extent(target, np.asarray(pc2, np.float64), cfg.margin_deg))
        if len(keep) == len(pc1) or len(keep) < max(64, cfg.min_share * len(pc1)):
            return first
        rng = np.random.default_rng(0)
        rows = np.concatenate([keep, rng.choice(keep, len(pc1) - len(keep))])  # the input size, as trained
        c1 = None if color1 is None else color1[rows]
        second = np.asarray(self.inner(pc1[rows], pc2, c1, color2), np.float32)
        out = (target - pc1).astype(np.float32)
        out[keep] = second[: len(keep)]
        return out


def view_pruned(method, config: ViewPruneConfig | None = None) -> ViewPruned:
    """``method`` with two-pass view pruning, named ``"<method name> + view pruning"`` (its own row)."""
    return ViewPruned(method, config)
