"""Rigid polish: another method's ego-motion and movers' motions sharpened by robust ICP (label-free).

The net's flow gets the camera's motion roughly right but not precisely: on the synthetic worlds' LiDAR
splits the rigid motion fitted to it is typically 0.3–0.7° and 0.1–0.4 m off, which at
15–30 m range is most of the net's static error (docs/learned-flow.md, fourth round). Registration
does the opposite: robust ICP from the identity lands in a wrong basin on fast-driving scenes (1.1 m
static error on the demo's split), but started inside the right basin it is precise. This wrapper,
usable around any method, combines the two:

1. runs the method and fits one rigid motion ``T₀ = (R, t)`` to its flow robustly
   (:func:`evaluation.view_prune.rigid_fit`, IRLS with Cauchy weights);
2. keeps the frame-1 points whose flow agrees with ``T₀`` (residual below
   ``max(static_scale_min, mad_factor · 1.4826 · median residual)``): the method's own guess of what is
   static;
3. registers them onto pc2 by point-to-plane ICP with Cauchy weights, started at ``T₀``
   (:func:`evaluation.baselines.icp.icp`, ``kernel="cauchy"``, ``max_distance`` as the pair limit);
4. a frame-1 point takes the rigid flow ``T p − p`` when both say it moves with the camera: the method
   (it was kept in step 2) and the geometry (its polished target ``T p`` lands on pc2: the nearest pc2
   point is closer than ``max(static_scale_min, mad_factor · 1.4826 · median distance)``). The others —
   movers, points without a counterpart — keep the method's own flow for now. The geometry alone would not
   do: a car that drives less than its own length still lands on its own new surface;
5. (``objects``) the remaining points are split into Euclidean clusters (points closer than
   ``cluster_radius`` are linked); each cluster of at least ``cluster_min_points`` is registered by robust
   point-to-point ICP onto the pc2 points that the polished static scene does not explain, started at the
   ego-motion plus the cluster's median disagreement with it in the method's flow (so the start is the
   method's own guess of the object's motion). A cluster takes its rigid flow when more than
   ``cluster_min_fitness`` of its points then land within ``static_scale_min`` of those pc2 points; else
   it keeps the method's flow. Cars, cyclists and pedestrians move rigidly from one frame to the next.

No learning and no gradient steps: a bounded number of closed-form (Gauss–Newton / Kabsch) steps, with
no labels, pose or calibration. Without a good start it is no better than ICP: started from zero flow
(the identity) it lands in the same wrong basin as plain ICP on fast-driving scenes
(docs/learned-flow.md, fifth round) — the method supplies the basin, registration the precision.
Clouds: camera frames of frames 1 and 2 (x right, y down, z forward), metres. The row it adds is named
``"<method> + rigid polish"``; the method's own row is unchanged. A refinement stacked after it holds the
registered ego-motion (:meth:`evaluation.optimise.RefineConfig.after_registration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.clusters import radius_components
from evaluation.baselines.base import apply_transform
from evaluation.baselines.icp import ICPConfig, icp
from evaluation.view_prune import rigid_fit
from evaluation.wrapping import MethodWrapper


@dataclass
class RigidPolishConfig:
    """iterations: ICP iterations at most (point-to-plane, Cauchy-weighted).
    max_distance: metres; ICP pairs farther apart are ignored.
    kernel_scale_min: metres; the smallest Cauchy scale of the ICP residuals.
    static_scale_min: metres; the smallest residual scale that separates the points that move with the
        camera from those that do not, both for the method's flow (step 2) and for the polished targets
        against pc2 (step 4).
    mad_factor: the scale used is max(static_scale_min, mad_factor × 1.4826 × the cloud's median residual).
    min_points: fewer points agreeing with the method's rigid motion than this: the method's flow is
        returned unchanged.
    sigma, fit_iterations: the Cauchy scale (metres) and rounds of the rigid fit to the method's flow
        (:func:`evaluation.view_prune.rigid_fit`).
    objects: also polish each cluster of the points left out of the ego-motion (step 5 of the module
        docstring); false = the ego-motion only.
    cluster_radius: metres; points of one cluster are linked by hops shorter than this.
    cluster_min_points: smaller clusters keep the method's flow.
    cluster_iterations: ICP iterations at most per cluster (point-to-point, Cauchy-weighted).
    cluster_min_fitness: share of a cluster's points that must land on unexplained pc2 points for the
        cluster to take its rigid flow."""

    iterations: int = 20
    max_distance: float = 1.0
    kernel_scale_min: float = 0.05
    static_scale_min: float = 0.3
    mad_factor: float = 3.0
    min_points: int = 32
    sigma: float = 0.25
    fit_iterations: int = 4
    objects: bool = True
    cluster_radius: float = 0.8
    cluster_min_points: int = 8
    cluster_iterations: int = 15
    cluster_min_fitness: float = 0.5

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.fit_iterations < 1 or self.cluster_iterations < 1 or self.min_points < 6:
            raise ValueError("iterations, fit_iterations and cluster_iterations must be >= 1, min_points >= 6")
        if not (self.cluster_radius > 0 and self.cluster_min_points >= 3 and 0 <= self.cluster_min_fitness < 1):
            raise ValueError("need cluster_radius > 0, cluster_min_points >= 3 and 0 <= cluster_min_fitness < 1")
        if not (self.max_distance > 0 and self.kernel_scale_min > 0 and self.static_scale_min > 0
                and self.sigma > 0 and self.mad_factor >= 0):
            raise ValueError("max_distance, kernel_scale_min, static_scale_min and sigma must be > 0, "
                             "mad_factor >= 0")


def _agreeing(residual: np.ndarray, cfg: RigidPolishConfig) -> np.ndarray:
    """(N,) bool: residuals (metres) below ``max(static_scale_min, mad_factor · 1.4826 · median)``."""
    limit = max(cfg.static_scale_min, cfg.mad_factor * 1.4826 * float(np.median(residual)))
    return residual < limit


def polish_rigid(pc1: np.ndarray, pc2: np.ndarray, flow: np.ndarray,
               cfg: RigidPolishConfig | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(flow_out (N, 3) float32, T (4, 4), static (N,) bool)``: ``flow`` (N, 3) at ``pc1`` (N, 3) with its
    ego-motion (and, with ``objects``, its movers' motions) polished against ``pc2`` (M, 3) (module
    docstring); ``T`` maps camera 1 to camera 2 and ``static`` marks the points that took its rigid flow.
    Metres."""
    cfg = cfg or RigidPolishConfig()
    p1, p2 = np.asarray(pc1, np.float64), np.asarray(pc2, np.float64)
    f = np.asarray(flow, np.float64)
    R, t = rigid_fit(p1, f, cfg.sigma, cfg.fit_iterations, cfg.mad_factor)
    init = np.eye(4)
    init[:3, :3], init[:3, 3] = R, t
    agree = _agreeing(np.linalg.norm(p1 + f - apply_transform(init, p1), axis=1), cfg)
    if agree.sum() < cfg.min_points or len(p2) < 6:
        return f.astype(np.float32), init, np.zeros(len(p1), bool)
    icp_cfg = ICPConfig(method="point_to_plane", max_correspondence_distance=cfg.max_distance,
                        max_iterations=cfg.iterations, kernel="cauchy", kernel_scale_min=cfg.kernel_scale_min)
    T = icp(p1[agree], p2, icp_cfg, init=init).transform
    target = apply_transform(T, p1)
    dist, _ = cKDTree(p2).query(target)
    static = agree & _agreeing(dist, cfg)
    out = f.copy()
    out[static] = (target - p1)[static]
    if cfg.objects:
        _polish_clusters(p1, p2, out, T, static, cfg)
    return out.astype(np.float32), T, static


def _polish_clusters(p1: np.ndarray, p2: np.ndarray, flow: np.ndarray, T: np.ndarray, static: np.ndarray,
                     cfg: RigidPolishConfig) -> None:
    """Step 5 of the module docstring, in place on ``flow`` (N, 3): each cluster of the non-static points
    registered onto the pc2 points that the static scene moved by ``T`` does not explain."""
    rest = np.flatnonzero(~static)
    if len(rest) < cfg.cluster_min_points or not static.any():
        return
    gap, _ = cKDTree(apply_transform(T, p1[static])).query(p2)
    free = p2[gap > cfg.static_scale_min]  # pc2 points the static scene does not explain
    if len(free) < cfg.cluster_min_points:
        return
    label = radius_components(p1[rest], cfg.cluster_radius)
    free_tree = cKDTree(free)
    icp_cfg = ICPConfig(method="point_to_point", max_correspondence_distance=cfg.max_distance,
                        max_iterations=cfg.cluster_iterations, kernel="cauchy",
                        kernel_scale_min=cfg.kernel_scale_min)
    for c in np.unique(label):
        rows = rest[label == c]
        if len(rows) < cfg.cluster_min_points:
            continue
        pts = p1[rows]
        start = T.copy()  # the ego-motion plus the cluster's median disagreement with it in the method's flow
        start[:3, 3] += np.median(pts + flow[rows] - apply_transform(T, pts), axis=0)
        moved = apply_transform(icp(pts, free, icp_cfg, init=start).transform, pts)
        dist, _ = free_tree.query(moved)
        if (dist < cfg.static_scale_min).mean() > cfg.cluster_min_fitness:
            flow[rows] = moved - pts


class RigidPolished(MethodWrapper):
    """``inner`` (any flow method) with its ego-motion and movers polished by robust ICP (:func:`polish_rigid`)."""

    suffix = "rigid polish"
    config_type = RigidPolishConfig
    registered_ego = True  # a refinement after it holds this ego-motion (RefineConfig.after_registration)

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        flow = self.inner(pc1, pc2, color1, color2)
        return polish_rigid(pc1, pc2, flow, self.config)[0]


def rigid_polished(method, config: RigidPolishConfig | None = None) -> RigidPolished:
    """``method`` with its ego-motion and movers polished, named ``"<method name> + rigid polish"`` (its own row)."""
    return RigidPolished(method, config)
