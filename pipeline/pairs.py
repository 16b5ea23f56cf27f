"""One frame pair (t, t+1) of stage one: back-project, filter, record (docs/design.md §3.5–3.7).

Every pixel with valid depth is back-projected with :func:`pipeline.cache.points.points_from_depth` —
the very call the cache reader makes — so the filters judge exactly the points the cache will hand
out. The filters run in :data:`pipeline.filters.FILTER_NAMES` order; the count of points left after
each one is recorded in the pair's stats (``pc1_<name>`` for frame t, ``pc2_<name>`` for frame t+1,
``valid`` = pixels with depth; ``pc1_gt`` = frame-t points left that have ground truth, when the source
has it). Static flow is not stored: the reader derives it from the kept points and ``T``
(:func:`core.geometry.static_flow`).

Depth maps handed in must already be scaled and on the cache's grid
(:func:`pipeline.cache.points.canonical_depth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.cache.points import points_from_depth
from pipeline.cache.records import PairRecord
from pipeline.filters import FilterConfig, far_keep, ground_keep, lidar_keep, occlusion_keep
from core.geometry import se3_inverse
from pipeline.sources import GroundTruthFlow


def valid_pixels(depth: np.ndarray) -> np.ndarray:
    """(N,) int32 flat indices ``v * W + u`` of pixels with valid depth (> 0, finite), ascending."""
    flat = depth.reshape(-1)
    return np.flatnonzero(np.isfinite(flat) & (flat > 0)).astype(np.int32)


@dataclass
class FramePoints:
    """A frame's points after the filters that depend on that frame alone (ground, far, LiDAR range).

    idx (N,) int32 ascending flat pixel indices; points (N, 3) float32 camera frame, metres
    (:func:`points_from_depth`); counts: {"valid": n, "<filter>": n after it, …}. Computed once per
    frame and shared by the two pairs holding it; only the occlusion check depends on the partner.
    """

    idx: np.ndarray
    points: np.ndarray
    counts: dict[str, int]


def frame_points(
    depth: np.ndarray, K: np.ndarray, filters: FilterConfig, T_velo_to_cam: np.ndarray | None = None
) -> FramePoints:
    """Valid pixels of ``depth`` (H, W, metres) back-projected with K, then the frame-only filters in order."""
    idx = valid_pixels(depth)
    counts = {"valid": int(idx.size)}
    pts = points_from_depth(depth, idx, K)
    for name in filters.enabled():
        if name == "ground":
            keep = ground_keep(pts, filters.ground_max_y)
        elif name == "far":
            keep = far_keep(pts, filters.far_max_z)
        elif name == "lidar":
            keep = lidar_keep(pts, T_velo_to_cam, filters.lidar_min_elevation_deg,
                              filters.lidar_max_elevation_deg, filters.lidar_max_range)
        else:
            continue  # occlusion: per pair, see filter_frame
        idx, pts = idx[keep], pts[keep]
        counts[name] = int(idx.size)
    return FramePoints(idx, pts, counts)


def filter_frame(
    depth: np.ndarray,
    K: np.ndarray,
    filters: FilterConfig,
    depth_other: np.ndarray,
    T_to_other: np.ndarray,
    T_velo_to_cam: np.ndarray | None = None,
    points: FramePoints | None = None,
) -> tuple[np.ndarray, dict[str, int]]:
    """Kept pixels of one frame of a pair and the point count after each stage.

    depth (H, W) metres; K (3, 3); ``depth_other`` / ``T_to_other``: the other frame's depth map and the
    transform into its camera (for the occlusion check); ``points``: this frame's :func:`frame_points`
    when already computed. Returns (idx (N,) int32 ascending, {"valid": n, "<filter>": n after it, …}).
    """
    fp = points if points is not None else frame_points(depth, K, filters, T_velo_to_cam)
    counts = dict(fp.counts)
    if not filters.occlusion:
        return fp.idx, counts
    keep = occlusion_keep(fp.points, T_to_other, depth_other, K, filters.occlusion_threshold)
    idx = fp.idx[keep]
    counts["occlusion"] = int(idx.size)
    return idx, counts


def build_pair(
    frame_t: int,
    frame_t1: int,
    depth_t: np.ndarray,
    depth_t1: np.ndarray,
    T: np.ndarray,
    K: np.ndarray,
    filters: FilterConfig,
    *,
    scale: float = 1.0,
    T_velo_to_cam: np.ndarray | None = None,
    gt: GroundTruthFlow | None = None,
    points_t: FramePoints | None = None,
    points_t1: FramePoints | None = None,
) -> PairRecord:
    """The :class:`PairRecord` of frames (t, t+1).

    depth_t, depth_t1 (H, W) float32 metric depth (scaled, canonical); T (4, 4) ``T_{t→t+1}`` metric;
    K (3, 3) at the working size; frame t+1 is checked for occlusion backwards with ``inv(T)``.
    ``gt``: ground truth of frame t at the working size; the kept points' flow and moving flags are
    attached, and kept frame-t points on pixels without ground truth (sky in the ground truth, seen as
    a surface by another depth source) are dropped — their count after that is ``pc1_gt``.
    ``points_t`` / ``points_t1``: the frames' :func:`frame_points`, when the caller shares them between pairs.
    """
    T = np.asarray(T, dtype=np.float64)
    idx1, c1 = filter_frame(depth_t, K, filters, depth_t1, T, T_velo_to_cam, points_t)
    idx2, c2 = filter_frame(depth_t1, K, filters, depth_t, se3_inverse(T), T_velo_to_cam, points_t1)
    gt_flow = moving = None
    if gt is not None:
        has_gt = gt.valid.reshape(-1)[idx1] & np.isfinite(gt.flow.reshape(-1, 3)[idx1]).all(axis=1)
        idx1 = idx1[has_gt]
        c1["gt"] = int(idx1.size)
        gt_flow = gt.flow.reshape(-1, 3)[idx1].astype(np.float32)
        moving = gt.moving.reshape(-1)[idx1].astype(bool)
    stats = {f"pc1_{k}": v for k, v in c1.items()} | {f"pc2_{k}": v for k, v in c2.items()}
    return PairRecord(frame_t=int(frame_t), frame_t1=int(frame_t1), idx1=idx1, idx2=idx2, T=T,
                      scale=float(scale), stats=stats, gt_flow=gt_flow, moving=moving)


__all__ = ["FramePoints", "build_pair", "filter_frame", "frame_points", "valid_pixels"]
