"""Iterative Closest Point, point-to-point and point-to-plane, on a scipy KD-tree.

Each iteration pairs every transformed pc1 point with its nearest pc2 point, keeps pairs closer than
``max_correspondence_distance`` and solves for the increment:

* point-to-point: the closed-form least-squares rigid transform (Kabsch / SVD);
* point-to-plane: minimise ``Σ ((R p + t − q) · n_q)²`` with the target normals ``n_q`` (PCA over pc2's
  k nearest neighbours), linearised for a small rotation ``R ≈ I + [ω]×`` and solved as a 6×6 system.

With ``kernel="cauchy"`` every pair is weighted by ``w = 1 / (1 + (r / s)²)`` of its residual ``r``
(point-to-point distance, or point-to-plane distance), with the scale ``s = max(kernel_scale_min,
1.4826 · median |r|)`` re-estimated at every iteration (iteratively re-weighted least squares; the
median absolute residual times 1.4826 estimates a Gaussian's σ robustly). Without it (``"none"``, the
default and Open3D's behaviour) every pair within the distance limit counts fully, so a few wrong pairs,
a moving car or points that have left the view, can pull the fit away.

With ``two_way`` (point-to-point only) the pairs also run the other way: every pc2 point within the distance
limit of the moved pc1 is paired with its nearest moved pc1 point (the reverse half of a Chamfer distance).
One-way pairs hold a surface that slides along itself where it is — a car that drove less than its own
length still lands on its own new surface — while the reverse pairs of the pc2 points beyond its new front
end pull it forward; under the Cauchy kernel those few pairs weigh little, so the pull is weak.

With ``hold_vertical`` (point-to-plane only) the increments may move the points in the ground plane alone: a
turn about the camera's vertical axis (y) through the paired pc1 points' weighted centroid and a translation along x
and z, so the start's height, pitch and roll stay. They do when the start's pairs hold the motion weakly in some
direction: the smallest eigenvalue of their normal equations per pair (the twist taken about their centroid, its
rotation scaled by their spread, so that 1 means every normal lies along that direction and 0 none) below
``hold_vertical``. Once the ground is removed few surfaces face up or down; the motion along y is then set by the
small vertical parts of wall normals, which PCA over a LiDAR's rings gets wrong by more than they are, and a
six-degree registration started at the true motion slid up to 0.17 m vertically (a shift with a pitch) on ray-cast
streets of boxes, and up to 0.6 m on the synthetic LiDAR worlds from a method's motion; holding the height alone
let the pitch slide instead. The smallest eigenvalue was 0–0.027 per scene on those worlds and 0.065–0.096 on
the real KITTI scans (docs/learned-flow.md, forty-seventh round).

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
    within_box,
)
from evaluation.baselines.normals import estimate_normals

METHODS = ("point_to_point", "point_to_plane")
KERNELS = ("none", "cauchy")


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
        kernel: ``"none"`` (every pair within the limit counts fully) or ``"cauchy"`` (robust weights,
            module docstring).
        kernel_scale_min: metres; the smallest Cauchy scale (a residual of this size halves a pair's weight).
        two_way: point-to-point only: also pair every pc2 point within ``max_correspondence_distance`` of the
            moved pc1 with its nearest moved pc1 point (module docstring).
        hold_vertical: point-to-plane only: when the start's pairs' information along their least held direction
            (per pair, module docstring) is below this, fit the motion in the ground plane alone (the turn about
            camera y and the translation along x and z), keeping the start's height, pitch and roll. 0 = never
            (all six degrees of freedom, the default), above 1 = always.
    """

    method: str = "point_to_point"
    max_correspondence_distance: float = 1.0
    max_iterations: int = 50
    tolerance: float = 1e-6
    normal_max_nn: int = 20
    normal_radius: float | None = None
    kernel: str = "none"
    kernel_scale_min: float = 0.05
    two_way: bool = False
    hold_vertical: float = 0.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {KERNELS}, got {self.kernel!r}")
        if not self.kernel_scale_min > 0:
            raise ValueError(f"kernel_scale_min must be > 0, got {self.kernel_scale_min}")
        if self.two_way and self.method != "point_to_point":
            raise ValueError("two_way pairs need method='point_to_point'")
        if self.hold_vertical and self.method != "point_to_plane":
            raise ValueError("hold_vertical needs method='point_to_plane'")
        if self.hold_vertical < 0:
            raise ValueError(f"hold_vertical must be >= 0, got {self.hold_vertical}")
        if self.max_correspondence_distance <= 0 or self.max_iterations < 1:
            raise ValueError("max_correspondence_distance must be > 0 and max_iterations >= 1")


def _cauchy_weights(r: np.ndarray, scale_min: float) -> np.ndarray:
    """``1 / (1 + (r / s)²)`` with ``s = max(scale_min, 1.4826 · median |r|)`` (module docstring)."""
    s = max(scale_min, 1.4826 * float(np.median(np.abs(r))))
    return 1.0 / (1.0 + (r / s) ** 2)


def _plane_jacobian(src: np.ndarray, normals: np.ndarray, centre: np.ndarray, spread: float = 1.0) -> np.ndarray:
    """(N, 6) derivative of the point-to-plane residuals ``(p − q) · n`` of the pairs ``src`` with the target
    ``normals`` by the twist ``(ω, t')`` about ``centre`` (``x → R (x − c) + c + t'``); the rotation's columns
    divided by ``spread`` (metres) so that both halves are in metres."""
    return np.hstack([np.cross(src - centre, normals) / spread, normals])


def _point_to_plane_step(src: np.ndarray, dst: np.ndarray, normals: np.ndarray,
                         scale_min: float | None = None, ground_plane: bool = False) -> np.ndarray | None:
    """Increment (4×4) minimising the linearised point-to-plane error (Cauchy-weighted when ``scale_min``
    is given), None if degenerate. With ``ground_plane`` the twist is taken about the weighted centroid ``c``
    of ``src`` and only ``ω_y``, ``t'_x`` and ``t'_z`` are fitted (``hold_vertical`` in the module docstring)."""
    r = np.einsum("ni,ni->n", src - dst, normals)
    w = np.ones_like(r) if scale_min is None else _cauchy_weights(r, scale_min)
    c = (w[:, None] * src).sum(0) / w.sum() if ground_plane else np.zeros(3)
    cols = [1, 3, 5] if ground_plane else [0, 1, 2, 3, 4, 5]  # (ω_y, t'_x, t'_z): the ground plane's motion
    jac = _plane_jacobian(src, normals, c)[:, cols]
    jtj = (jac * w[:, None]).T @ jac
    jtr = (jac * w[:, None]).T @ r
    if np.linalg.matrix_rank(jtj) < len(cols):
        return None
    xi = np.zeros(6)
    xi[cols] = np.linalg.solve(jtj, -jtr)
    step = twist_to_transform(np.r_[xi[:3], np.zeros(3)])
    step[:3, 3] = c + xi[3:] - step[:3, :3] @ c  # the centroid moves by t' exactly
    return step


def weakest_hold(src: np.ndarray, normals: np.ndarray) -> float:
    """The smallest eigenvalue of the point-to-plane normal equations per pair (``JᵀJ / N``) of the pairs' source
    points ``src`` (N, 3) with their targets' ``normals`` (N, 3) (the targets themselves do not enter): the twist
    taken about the pairs' centroid, its rotation scaled by their RMS distance from it, so that a unit motion along
    an eigenvector moves the points by about a metre. 1 when every normal lies along the least held direction, 0 when
    none has a part along it."""
    centre = src.mean(0)
    spread = max(float(np.sqrt(((src - centre) ** 2).sum(1).mean())), 1e-9)
    jac = _plane_jacobian(src, normals, centre, spread)
    return float(np.linalg.eigvalsh(jac.T @ jac / len(jac))[0])


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
    scale_min = cfg.kernel_scale_min if cfg.kernel == "cauchy" else None

    def correspond(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        src = apply_transform(t, src0)
        dist, idx = tree.query(src, distance_upper_bound=cfg.max_correspondence_distance)
        inl = np.isfinite(dist)
        fitness = float(inl.mean())
        rmse = float(np.sqrt(np.mean(dist[inl] ** 2))) if inl.any() else float("nan")
        return src, idx, inl, fitness, rmse

    src, idx, inl, fitness, rmse = correspond(transform)
    hold = bool(cfg.hold_vertical and inl.sum() >= 6
                and weakest_hold(src[inl], normals[idx[inl]]) < cfg.hold_vertical)
    converged = False
    iterations = 0
    n_used = int(inl.sum())
    for iterations in range(1, cfg.max_iterations + 1):
        n_used = int(inl.sum())
        if n_used < min_pairs:
            break
        if cfg.method == "point_to_point":
            a, b = src[inl], dst[idx[inl]]
            if cfg.two_way:
                reach = dst[within_box(dst, src, cfg.max_correspondence_distance)]  # the others pair with none
                back_dist, back = cKDTree(src).query(reach, distance_upper_bound=cfg.max_correspondence_distance)
                near = np.isfinite(back_dist)
                a, b = np.concatenate([a, src[back[near]]]), np.concatenate([b, reach[near]])
            w = None if scale_min is None else _cauchy_weights(np.linalg.norm(a - b, axis=1), scale_min)
            step: np.ndarray | None = kabsch(a, b, w)
        else:
            assert normals is not None
            step = _point_to_plane_step(src[inl], dst[idx[inl]], normals[idx[inl]], scale_min, hold)
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
