"""Fast Point Feature Histograms (Rusu, Blodow & Beetz, ICRA 2009), 33 bins, vectorised.

For a pair of oriented points the *source* is the one whose normal makes the smaller angle with the
line joining them (on a tie, the one that makes ``φ ≥ 0``); with ``u`` its normal, ``d`` the unit vector to the other point (normal ``n_t``),
``v = u × d / ‖u × d‖`` and ``w = u × v``, the pair features are

* ``θ = atan2(w · n_t, u · n_t)`` ∈ [−π, π],
* ``α = v · n_t`` ∈ [−1, 1],
* ``φ = u · d`` ∈ [−1, 1],

each binned into 11 equal bins. SPFH(p) is the histogram over p's neighbours, each of the three
11-bin blocks scaled to sum to 100. FPFH(p) = SPFH(p) + Σ_k w_k SPFH(p_k) over the neighbours
p_k within the feature radius, ``w_k = 1 / ‖p_k − p‖``, each block of the weighted sum rescaled to 100
(so a point's own histogram and its neighbours' weigh alike, as in Open3D).

Neighbourhoods are "hybrid": the ``max_nn`` nearest within ``radius`` (Open3D's ``KDTreeSearchParamHybrid``,
whose tutorial uses a normal radius of 2 and a feature radius of 5 voxel sizes with 30 / 100 neighbours).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from evaluation.baselines.base import as_cloud
from evaluation.baselines.normals import estimate_normals, hybrid_neighbours

N_BINS = 11
FEATURE_DIM = 3 * N_BINS


@dataclass
class FPFHConfig:
    """FPFH settings (distances in metres).

    Attributes:
        normal_radius: radius of the normal-estimation neighbourhood; None = ``normal_scale`` × spacing.
        normal_max_nn: at most this many neighbours per normal.
        feature_radius: radius of the feature neighbourhood; None = ``feature_scale`` × spacing.
        feature_max_nn: at most this many neighbours per feature.
        normal_scale, feature_scale: multiples of the cloud's point spacing (the median distance to
            the 4th nearest neighbour, ≈ one voxel of a voxel-downsampled cloud) used when a radius
            is None.
    """

    normal_radius: float | None = None
    normal_max_nn: int = 30
    feature_radius: float | None = None
    feature_max_nn: int = 100
    normal_scale: float = 2.0
    feature_scale: float = 5.0


def point_spacing(points: np.ndarray, tree: cKDTree | None = None) -> float:
    """Median distance to the 4th nearest neighbour (metres), a robust point spacing."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 5:
        return 1.0
    tree = cKDTree(pts) if tree is None else tree
    dist, _ = tree.query(pts, k=5)
    return float(np.median(dist[:, 4]))


def resolve_radii(config: FPFHConfig, spacing: float) -> tuple[float, float]:
    """(normal_radius, feature_radius) in metres, filling the automatic ones from ``spacing``."""
    rn = config.normal_radius if config.normal_radius is not None else config.normal_scale * spacing
    rf = config.feature_radius if config.feature_radius is not None else config.feature_scale * spacing
    return float(rn), float(rf)


def pair_features(
    p_s: np.ndarray, n_s: np.ndarray, p_t: np.ndarray, n_t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θ, α, φ) of point pairs (arrays of shape (P, 3)); coincident points give zeros."""
    d = p_t - p_s
    dist = np.linalg.norm(d, axis=1)
    ok = dist > 0
    d = d / np.where(ok, dist, 1.0)[:, None]
    a_s = np.abs(np.einsum("pi,pi->p", n_s, d))
    a_t = np.abs(np.einsum("pi,pi->p", n_t, d))
    # the point whose normal is better aligned with the line becomes the source; on a tie (equal
    # normals) the orientation with u · d ≥ 0 is taken, so the choice does not hinge on round-off
    tie = np.abs(a_t - a_s) <= 1e-9
    swap = np.where(tie, np.einsum("pi,pi->p", n_s, d) < 0, a_t > a_s)
    u = np.where(swap[:, None], n_t, n_s)
    other = np.where(swap[:, None], n_s, n_t)
    d = np.where(swap[:, None], -d, d)
    phi = np.einsum("pi,pi->p", u, d)
    v = np.cross(u, d)
    vnorm = np.linalg.norm(v, axis=1)
    ok &= vnorm > 1e-12
    v = v / np.where(vnorm > 1e-12, vnorm, 1.0)[:, None]
    w = np.cross(u, v)
    alpha = np.einsum("pi,pi->p", v, other)
    theta = np.arctan2(np.einsum("pi,pi->p", w, other), np.einsum("pi,pi->p", u, other))
    return np.where(ok, theta, 0.0), np.where(ok, alpha, 0.0), np.where(ok, phi, 0.0)


def _bin(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    idx = np.floor((values - lo) / (hi - lo) * N_BINS).astype(np.int64)
    return np.clip(idx, 0, N_BINS - 1)


def _normalise_blocks(hist: np.ndarray) -> np.ndarray:
    blocks = hist.reshape(len(hist), 3, N_BINS)
    sums = blocks.sum(2, keepdims=True)
    blocks = np.where(sums > 0, blocks * (100.0 / np.where(sums > 0, sums, 1.0)), 0.0)
    return blocks.reshape(len(hist), FEATURE_DIM)


def compute_fpfh(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    config: FPFHConfig | None = None,
    spacing: float | None = None,
) -> np.ndarray:
    """FPFH descriptors (N, 33) float64 of ``points`` (N, 3, metres).

    Args:
        points: the cloud.
        normals: optional (N, 3) unit normals; estimated (oriented towards the origin) when None.
        config: radii and neighbour caps.
        spacing: point spacing used by automatic radii (computed from ``points`` when None); pass the
            same value for two clouds whose features will be matched.
    """
    cfg = config or FPFHConfig()
    pts = as_cloud("points", points)
    n = len(pts)
    if n == 0:
        return np.zeros((0, FEATURE_DIM))
    tree = cKDTree(pts)
    if spacing is None:
        spacing = point_spacing(pts, tree)
    r_normal, r_feature = resolve_radii(cfg, spacing)
    if normals is None:
        normals = estimate_normals(pts, cfg.normal_max_nn, r_normal, tree=tree)
    normals = np.asarray(normals, dtype=np.float64)

    dist, idx, valid = hybrid_neighbours(tree, pts, cfg.feature_max_nn + 1, r_feature)
    valid &= idx != np.arange(n)[:, None]  # drop the point itself
    rows, cols = np.nonzero(valid)
    nbr = idx[rows, cols]
    d_pair = dist[rows, cols]

    theta, alpha, phi = pair_features(pts[rows], normals[rows], pts[nbr], normals[nbr])
    bins = np.stack([_bin(theta, -np.pi, np.pi), N_BINS + _bin(alpha, -1.0, 1.0), 2 * N_BINS + _bin(phi, -1.0, 1.0)], 1)
    flat = (rows[:, None] * FEATURE_DIM + bins).ravel()
    spfh = np.bincount(flat, minlength=n * FEATURE_DIM).astype(np.float64).reshape(n, FEATURE_DIM)
    spfh = _normalise_blocks(spfh)

    weights = np.where(d_pair > 0, 1.0 / np.maximum(d_pair, 1e-12), 0.0)
    wmat = sparse.csr_matrix((weights, (rows, nbr)), shape=(n, n))
    neighbour_term = _normalise_blocks(np.asarray(wmat @ spfh))
    return spfh + neighbour_term
