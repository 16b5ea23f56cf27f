"""Single-linkage clustering of a point cloud by a link radius (numpy/scipy; points in metres, any frame)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def radius_components(points: np.ndarray, link_m: float) -> np.ndarray:
    """A component label (N,) for each of ``points`` (N, 3): two points share a label when a chain of points,
    each closer than ``link_m`` metres to the next, joins them. Labels run 0 … count − 1."""
    n = len(points)
    pairs = cKDTree(points).query_pairs(link_m, output_type="ndarray")
    links = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(links, directed=False)[1]
