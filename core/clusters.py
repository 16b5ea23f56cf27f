"""Single-linkage clustering of a point cloud by a link radius, and the object-sized clusters among its components
(numpy/scipy; points in metres, any frame)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

OBJECT_LINK_M = 0.8  # points closer than this belong to one cluster (single linkage)
OBJECT_MIN_POINTS = 8  # a cluster with fewer points is noise, not an object
OBJECT_MAX_EXTENT_M = 6.0  # a cluster longer than this along any axis is a wall or a row of things, not an object
OBJECT_MAX_SHARE = 0.1  # nor one that holds more than this share of the cloud


def radius_components(points: np.ndarray, link_m: float) -> np.ndarray:
    """A component label (N,) for each of ``points`` (N, 3): two points share a label when a chain of points,
    each closer than ``link_m`` metres to the next, joins them. Labels run 0 … count − 1."""
    n = len(points)
    pairs = cKDTree(points).query_pairs(link_m, output_type="ndarray")
    links = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(links, directed=False)[1]


def object_clusters(points: np.ndarray, link_m: float = OBJECT_LINK_M, min_points: int = OBJECT_MIN_POINTS,
                    max_extent_m: float = OBJECT_MAX_EXTENT_M, max_share: float = OBJECT_MAX_SHARE) -> list[np.ndarray]:
    """Object-sized clusters of ``points`` (N, 3), metres: the indices of each single-linkage component (points
    chained by gaps shorter than ``link_m``) with at least ``min_points`` points, at most ``max_share`` of the
    cloud and an axis-aligned extent of at most ``max_extent_m`` on every axis. Label-free: stage one has
    removed the ground, so what stands on it falls apart into things (cars, poles, trunks) and long
    structures (walls, fences), which the extent leaves out."""
    n = len(points)
    if n < min_points:
        return []
    label = radius_components(points, link_m)
    out = []
    for k in range(label.max() + 1):
        idx = np.flatnonzero(label == k)
        if not min_points <= len(idx) <= max_share * n:
            continue
        if (np.ptp(points[idx], axis=0) <= max_extent_m).all():
            out.append(idx)
    return out
