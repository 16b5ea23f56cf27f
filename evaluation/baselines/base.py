"""The baseline interface and rigid-transform helpers shared by the registration baselines.

A 4×4 transform ``T`` maps frame-1 camera coordinates to frame-2 camera coordinates (``p2 = R p1 + t``,
docs/design.md §2); the rigid flow it implies is ``T(p) − p``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from core.geometry import rotation_angle


@runtime_checkable
class Baseline(Protocol):
    """A scene-flow method: ``flow = baseline(pc1, pc2)``, flow (N, 3) float32 metres for pc1's points."""

    name: str

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray: ...


@dataclass
class RegistrationResult:
    """Outcome of a rigid registration of pc1 onto pc2.

    Attributes:
        transform: (4, 4) float64, maps pc1 (frame 1) onto pc2 (frame 2).
        iterations: iterations run.
        converged: True when the stopping tolerance was met before the iteration limit.
        fitness: fraction of pc1 points with a correspondence within the distance threshold.
        inlier_rmse: RMS distance of those correspondences, metres.
        n_correspondences: correspondences used in the last solve (ICP) / after filtering (FGR).
    """

    transform: np.ndarray
    iterations: int
    converged: bool
    fitness: float = float("nan")
    inlier_rmse: float = float("nan")
    n_correspondences: int = 0


def as_cloud(name: str, points: np.ndarray) -> np.ndarray:
    """(N, 3) float64 copy of ``points``, raising ValueError on a wrong shape or non-finite values."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values")
    return arr


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``R p + t`` for every row of (N, 3) ``points``."""
    transform = np.asarray(transform, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]


def within_box(points: np.ndarray, around: np.ndarray, margin: float) -> np.ndarray:
    """Mask (N,) of the ``points`` (N, 3) inside the axis-aligned box of ``around`` (K, 3, K ≥ 1) grown by
    ``margin`` metres on every side: every point within ``margin`` of one of ``around`` is inside, so a
    nearest-neighbour search bounded by ``margin`` may skip the rest."""
    return ((points >= around.min(0) - margin) & (points <= around.max(0) + margin)).all(axis=1)


def rigid_flow(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Flow ``T(p) − p`` (N, 3) float32 of a rigid motion ``T`` (4×4) at ``points``."""
    pts = np.asarray(points, dtype=np.float64)
    return (apply_transform(transform, pts) - pts).astype(np.float32)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]×`` of (..., 3) vectors, shape (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def rotation_from_vector(omega: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation of angle ``‖ω‖`` (radians) about ``ω/‖ω‖``."""
    omega = np.asarray(omega, dtype=np.float64)
    theta = float(np.linalg.norm(omega))
    k = skew(omega)
    if theta < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(theta) / theta * k + (1.0 - np.cos(theta)) / theta**2 * (k @ k)


def twist_to_transform(xi: np.ndarray) -> np.ndarray:
    """4×4 transform from a 6-vector ``(ω, t)``: rotation ``exp([ω]×)`` then translation ``t``."""
    xi = np.asarray(xi, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = rotation_from_vector(xi[:3])
    out[:3, 3] = xi[3:]
    return out


def kabsch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Least-squares rigid transform (4×4) minimising ``Σ w ‖R src + t − dst‖²`` (SVD, no reflection)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    wsum = w.sum()
    mu_s = (w[:, None] * src).sum(0) / wsum
    mu_d = (w[:, None] * dst).sum(0) / wsum
    cov = ((dst - mu_d) * w[:, None]).T @ (src - mu_s)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    rot = u @ np.diag([1.0, 1.0, d]) @ vt
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = mu_d - rot @ mu_s
    return out


def transform_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres) between two 4×4 transforms.

    The rotation error is the angle of ``R_truth⁻¹ R_estimate`` (:func:`core.geometry.rotation_angle`,
    accurate to rounding at every angle).
    """
    delta = np.linalg.inv(np.asarray(truth, np.float64)) @ np.asarray(estimate, np.float64)
    rot_deg = float(np.degrees(rotation_angle(delta[:3, :3])))
    trans = float(np.linalg.norm(np.asarray(estimate)[:3, 3] - np.asarray(truth)[:3, 3]))
    return rot_deg, trans
