"""Iterative Closest Point, point-to-point and point-to-plane, on a scipy KD-tree.

Each iteration pairs every transformed pc1 point with its nearest pc2 point, keeps pairs closer than
``max_correspondence_distance`` and solves for the increment:

* point-to-point: the closed-form least-squares rigid transform (Kabsch / SVD);
* point-to-plane: minimise ``Σ ((R p + t − q) · n_q)²`` with the target normals ``n_q`` (PCA over pc2's
  k nearest neighbours), linearised for a small rotation ``R ≈ I + [ω]×`` and solved as a 6×6 system.

It stops when the change of both fitness (inlier fraction) and inlier RMSE falls below ``tolerance``
(Open3D's ``ICPConvergenceCriteria`` rule, defaults 1e-6 / 1e-6 / 30 iterations) or after
``max_iterations``. Distances in metres; the result maps pc1 (frame 1) onto pc2 (frame 2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from evaluation.baselines.base import (
    RegistrationResult,
    apply_transform,
    as_cloud,
    kabsch,
    rigid_flow,
    twist_to_transform,
)
from evaluation.baselines.normals import estimate_normals

METHODS = ("point_to_point", "point_to_plane")


@dataclass
class ICPConfig:
    """ICP settings.

    Attributes:
        method: ``"point_to_point"`` or ``"point_to_plane"``.
        max_correspondence_distance: metres; pairs farther apart are ignored.
        max_iterations: iteration limit.
        tolerance: stop when |Δfitness| and |ΔRMSE| (metres) both fall below it.
        normal_max_nn: neighbours per target normal (point-to-plane).
        normal_radius: optional radius (metres) bounding those neighbours.
    """

    method: str = "point_to_point"
    max_correspondence_distance: float = 1.0
    max_iterations: int = 50
    tolerance: float = 1e-6
    normal_max_nn: int = 20
    normal_radius: float | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.max_correspondence_distance <= 0 or self.max_iterations < 1:
            raise ValueError("max_correspondence_distance must be > 0 and max_iterations >= 1")


def _point_to_plane_step(src: np.ndarray, dst: np.ndarray, normals: np.ndarray) -> np.ndarray | None:
    """Increment (4×4) minimising the linearised point-to-plane error, None if degenerate."""
    r = np.einsum("ni,ni->n", src - dst, normals)
    jac = np.hstack([np.cross(src, normals), normals])  # d r / d (ω, t)
    jtj = jac.T @ jac
    jtr = jac.T @ r
    if np.linalg.matrix_rank(jtj) < 6:
        return None
    xi = np.linalg.solve(jtj, -jtr)
    return twist_to_transform(xi)


def icp(
    pc1: np.ndarray,
    pc2: np.ndarray,
    config: ICPConfig | None = None,
    init: np.ndarray | None = None,
) -> RegistrationResult:
    """Register ``pc1`` (N, 3) onto ``pc2`` (M, 3), metres, starting from ``init`` (4×4, default I)."""
    cfg = config or ICPConfig()
    src0 = as_cloud("pc1", pc1)
    dst = as_cloud("pc2", pc2)
    transform = np.eye(4) if init is None else np.asarray(init, dtype=np.float64).copy()
    if len(src0) == 0 or len(dst) == 0:
        return RegistrationResult(transform, 0, False, 0.0, float("nan"), 0)
    tree = cKDTree(dst)
    normals = None
    if cfg.method == "point_to_plane":
        normals = estimate_normals(dst, cfg.normal_max_nn, cfg.normal_radius, tree=tree)
    min_pairs = 3 if cfg.method == "point_to_point" else 6

    def correspond(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        src = apply_transform(t, src0)
        dist, idx = tree.query(src, distance_upper_bound=cfg.max_correspondence_distance)
        inl = np.isfinite(dist)
        fitness = float(inl.mean())
        rmse = float(np.sqrt(np.mean(dist[inl] ** 2))) if inl.any() else float("nan")
        return src, idx, inl, fitness, rmse

    src, idx, inl, fitness, rmse = correspond(transform)
    converged = False
    iterations = 0
    n_used = int(inl.sum())
    for iterations in range(1, cfg.max_iterations + 1):
        n_used = int(inl.sum())
        if n_used < min_pairs:
            break
        if cfg.method == "point_to_point":
            step: np.ndarray | None = kabsch(src[inl], dst[idx[inl]])
        else:
            assert normals is not None
            step = _point_to_plane_step(src[inl], dst[idx[inl]], normals[idx[inl]])
            if step is None:
                break
        transform = step @ transform
        prev_fitness, prev_rmse = fitness, rmse
        src, idx, inl, fitness, rmse = correspond(transform)
        if abs(fitness - prev_fitness) < cfg.tolerance and (
            abs(rmse - prev_rmse) < cfg.tolerance or (np.isnan(rmse) and np.isnan(prev_rmse))
        ):
            converged = True
            break
    return RegistrationResult(transform, iterations, converged, fitness, rmse, n_used)


@dataclass
class ICPBaseline:
    """Scene flow of the rigid ICP fit: ``flow = T(p) − p`` for every pc1 point."""

    config: ICPConfig = field(default_factory=ICPConfig)
    name: str = ""

    def __post_init__(self) -> None:
        if not self.name:
            self.name = "icp-" + ("p2p" if self.config.method == "point_to_point" else "p2l")

    def register(self, pc1: np.ndarray, pc2: np.ndarray) -> RegistrationResult:
        """The full registration result (transform, iterations, fitness, RMSE)."""
        return icp(pc1, pc2, self.config)

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        return rigid_flow(self.register(pc1, pc2).transform, as_cloud("pc1", pc1))
