"""Neighbourhoods and surface normals of point clouds (scipy KD-tree, vectorised numpy).

Normals are the eigenvector of the smallest eigenvalue of each point's neighbourhood covariance (PCA),
oriented towards a viewpoint (default: the camera centre, the origin of the cloud's own frame).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def hybrid_neighbours(
    tree: cKDTree, points: np.ndarray, max_nn: int, radius: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The up-to-``max_nn`` nearest neighbours of each query point within ``radius`` (Open3D's "hybrid").

    Returns:
        dist (Q, K) float64, idx (Q, K) int64 (padding entries point at index 0), valid (Q, K) bool.
        The query point itself is included when it belongs to the tree.
    """
    k = min(int(max_nn), tree.n)
    bound = np.inf if radius is None else float(radius)
    dist, idx = tree.query(points, k=k, distance_upper_bound=bound)
    if k == 1:
        dist, idx = dist[:, None], idx[:, None]
    valid = idx < tree.n
    idx = np.where(valid, idx, 0).astype(np.int64)
    dist = np.where(valid, dist, np.inf)
    return dist, idx, valid


def estimate_normals(
    points: np.ndarray,
    max_nn: int = 30,
    radius: float | None = None,
    viewpoint: np.ndarray | None = None,
    tree: cKDTree | None = None,
) -> np.ndarray:
    """Unit normals (N, 3) float64 by PCA over the ``max_nn`` nearest neighbours (within ``radius``).

    Points with fewer than 3 neighbours get the unit vector towards the viewpoint. Every normal is
    flipped to face ``viewpoint`` (default the origin).
    """
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    view = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    to_view = view - pts
    fallback = to_view / np.maximum(np.linalg.norm(to_view, axis=1, keepdims=True), 1e-12)
    if n < 3:
        return fallback
    tree = cKDTree(pts) if tree is None else tree
    _, idx, valid = hybrid_neighbours(tree, pts, max_nn, radius)
    w = valid.astype(np.float64)
    count = w.sum(1)
    nb = pts[idx]  # (N, K, 3)
    mean = (nb * w[..., None]).sum(1) / np.maximum(count, 1)[:, None]
    centred = (nb - mean[:, None, :]) * w[..., None]
    cov = np.einsum("nki,nkj->nij", centred, centred) / np.maximum(count, 1)[:, None, None]
    _, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]
    bad = count < 3
    normals[bad] = fallback[bad]
    flip = np.einsum("ni,ni->n", normals, to_view) < 0
    normals[flip] *= -1.0
    return normals
