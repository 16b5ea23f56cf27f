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
                    max_extent_m: float = OBJECT_MAX_EXTENT_M, max_share: float = OBJECT_MAX_SHARE,
                    whole: np.ndarray | None = None, whole_max_extent_m: float | None = None,
                    min_link_m: float | None = None) -> list[np.ndarray]:
    """Object-sized clusters of ``points`` (N, 3), metres: the indices of each single-linkage component (points
    chained by gaps shorter than ``link_m``) with at least ``min_points`` points, at most ``max_share`` of the
    cloud and an axis-aligned extent of at most ``max_extent_m`` on every axis. Label-free: stage one has
    removed the ground, so what stands on it falls apart into things (cars, poles, trunks) and long
    structures (walls, fences), which the extent leaves out.

    A component's extent tells a thing from a wall only where both its ends are seen. ``whole`` (N,) bool marks
    the points away from the edges of the view (:func:`view_interior`); a component of such points alone is
    whole in view, and with ``whole_max_extent_m`` it may be that long (a van, a lorry, a tram: up to 12 m),
    whereas a wall runs out of the view and its visible length is the view's, not its own. ``min_link_m`` <
    ``link_m``: a component that is no object is split again at half the link radius, and so on while the
    radius stays at least ``min_link_m``; of the parts, those whole in view and no longer than
    ``whole_max_extent_m`` (``max_extent_m`` without it) are objects. In a dense cloud (stereo or image-grid
    points) a car touches the car behind it or the kerb beside it at gaps below ``link_m``. Without ``whole``
    and ``min_link_m`` the result is the first paragraph's."""
    n = len(points)
    if n < min_points:
        return []
    floor = link_m if min_link_m is None else min_link_m
    longest = max_extent_m if whole_max_extent_m is None else max(max_extent_m, whole_max_extent_m)
    out: list[np.ndarray] = []

    def visit(idx: np.ndarray, link: float, top: bool) -> None:
        label = radius_components(points[idx], link)
        for k in range(label.max() + 1):
            sub = idx[label == k]
            if len(sub) < min_points:
                continue
            extent = float(np.ptp(points[sub], axis=0).max())
            in_view = whole is not None and bool(whole[sub].all())
            limit = longest if in_view else (max_extent_m if top else -1.0)
            if extent <= limit:
                if len(sub) <= max_share * n:
                    out.append(sub)
            elif link / 2 >= floor and whole is not None and whole[sub].any():
                visit(sub, link / 2, False)

    visit(np.arange(n), link_m, True)
    return out


def view_interior(points: np.ndarray, margin_m: float) -> np.ndarray:
    """(N,) bool: the ``points`` (N, 3; camera frame: x right, y down, z forward, metres) lying at least
    ``margin_m`` inside the view that the cloud itself shows — nearer than its farthest depth and than its
    farthest horizontal range by the margin (a camera-frustum split is cut in depth, a surround LiDAR sweep in
    range), and inside its azimuth range (the horizontal angle, read from the cloud's own extremes) by the angle
    the margin subtends at the point's horizontal range. A cluster that reaches the edge may continue beyond it."""
    p = np.asarray(points, dtype=np.float64)
    if not len(p):
        return np.zeros(0, dtype=bool)
    az = np.arctan2(p[:, 0], p[:, 2])
    rng = np.hypot(p[:, 0], p[:, 2])
    pad = np.arctan2(margin_m, np.maximum(rng, 1e-6))
    return ((p[:, 2] <= p[:, 2].max() - margin_m) & (rng <= rng.max() - margin_m)
            & (az - pad >= az.min()) & (az + pad <= az.max()))
