"""Ground-truth 3D flow t → t+1 of surface points, and their visibility in frame t+1.

Flow convention: the position at t+1 of the surface point, in camera-(t+1) coordinates, minus its
position in camera-t coordinates (metres). For static surfaces this is ``static_flow(p, T_{t→t+1})``.
"""

from __future__ import annotations

import numpy as np

from core.geometry import in_image, project, se3_inverse
from pipeline.synth.raycast import CameraRays, cast
from pipeline.synth.world import World

VISIBILITY_TOLERANCE = 0.01  # metres


def move_points(world: World, X: np.ndarray, obj: np.ndarray, k: int) -> np.ndarray:
    """Map-frame points X (N, 3) on objects ``obj`` (N,) at frame k → their map positions at k+1."""
    out = X.copy()
    for oi in np.unique(obj):
        o = world.objects[int(oi)]
        if not o.moving:
            continue
        A = o.pose(k + 1) @ se3_inverse(o.pose(k))
        sel = obj == oi
        out[sel] = X[sel] @ A[:3, :3].T + A[:3, 3]
    return out


def moving_mask(world: World, obj: np.ndarray) -> np.ndarray:
    """True where the object index belongs to a moving object (−1, i.e. sky, is False)."""
    flags = np.array([o.moving for o in world.objects] + [False])
    return flags[obj]


def scene_flow(world: World, k: int, X: np.ndarray, obj: np.ndarray, p_t: np.ndarray,
               cam_next_to_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flow (N, 3) of points seen at frame k (map X, camera-t coordinates p_t) and p_{t+1} (N, 3)."""
    X1 = move_points(world, X, obj, k)
    M = se3_inverse(cam_next_to_map)
    p1 = X1 @ M[:3, :3].T + M[:3, 3]
    return p1 - p_t, p1


def visible_in_next(world: World, k_next: int, p1: np.ndarray, K: np.ndarray, cam_next_to_map: np.ndarray,
                    width: int, height: int, max_depth: float) -> np.ndarray:
    """Whether camera-(t+1) points p1 (N, 3) project into the image, lie in front of the camera and are
    the first surface along their ray there (ray-cast depth at the projected sub-pixel position agrees
    with their z within :data:`VISIBILITY_TOLERANCE`)."""
    uv, z = project(p1, K)
    ok = in_image(uv, height, width) & (z > 1e-3) & np.all(np.isfinite(p1), axis=1)
    out = np.zeros(len(p1), dtype=bool)
    idx = np.flatnonzero(ok)
    if len(idx):
        rays = CameraRays(K, cam_next_to_map, uv=uv[idx])
        hits = cast(world.objects, k_next, rays, world.road, max_depth)
        out[idx] = np.abs(hits.t - z[idx]) < VISIBILITY_TOLERANCE
    return out
