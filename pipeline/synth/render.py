"""Render one camera frame: colour image, depth, per-pixel object index and map-frame surface points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.synth import textures as tex
from pipeline.synth.raycast import CameraRays, Hits, cast
from pipeline.synth.surface import surface
from pipeline.synth.world import World


@dataclass
class CameraFrame:
    """A rendered frame (H, W): ``image`` uint8 RGB, ``depth`` z in metres (0 = sky), ``obj`` object
    index (−1 = sky), ``points_cam`` camera-frame points (NaN = sky), ``points_map`` map-frame points."""

    image: np.ndarray
    depth: np.ndarray
    obj: np.ndarray
    points_cam: np.ndarray
    points_map: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.obj >= 0


def _colour(world: World, k: int, rays: CameraRays, hits: Hits, ray_angle: float) -> np.ndarray:
    _, N, A = surface(world.objects, k, rays.origin, rays.dirs, hits, world.road, ray_angle=ray_angle)
    rgb = np.zeros((len(rays), 3))
    h = hits.valid
    rgb[h] = tex.shade(A[h], N[h])
    rgb[~h] = tex.sky(rays.dirs[~h])
    return rgb


def render_camera(world: World, k: int, K: np.ndarray, cam_to_map: np.ndarray, width: int, height: int,
                  max_depth: float, supersample: int = 1) -> CameraFrame:
    """Ray-cast frame k from a camera with intrinsics K and pose ``cam_to_map`` (4×4).

    Depth, object ids and points are those of each pixel centre's ray; with ``supersample`` = s > 1 the
    colour is the mean of s×s rays spread evenly over the pixel. Textures are prefiltered to the
    pixel's footprint (see :mod:`textures`).
    """
    rays = CameraRays(K, cam_to_map, grid=(np.arange(width, dtype=float), np.arange(height, dtype=float)))
    hits = cast(world.objects, k, rays, world.road, max_depth)
    pixel_angle = 1.0 / float(np.sqrt(K[0, 0] * K[1, 1]))
    X, N, A = surface(world.objects, k, rays.origin, rays.dirs, hits, world.road, albedo=supersample == 1,
                      ray_angle=pixel_angle)
    if supersample == 1:
        rgb = np.zeros((len(rays), 3))
        h = hits.valid
        rgb[h] = tex.shade(A[h], N[h])
        rgb[~h] = tex.sky(rays.dirs[~h])
    else:
        s = supersample
        off = (np.arange(s) + 0.5) / s - 0.5
        u_axis = (np.arange(width)[:, None] + off[None, :]).ravel()
        v_axis = (np.arange(height)[:, None] + off[None, :]).ravel()
        sub = CameraRays(K, cam_to_map, grid=(u_axis, v_axis))
        sub_rgb = _colour(world, k, sub, cast(world.objects, k, sub, world.road, max_depth), pixel_angle / s)
        rgb = sub_rgb.reshape(height, s, width, s, 3).mean(axis=(1, 3)).reshape(-1, 3)
    image = np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8).reshape(height, width, 3)
    valid = hits.valid
    depth = np.where(valid, hits.t, 0.0).reshape(height, width)
    pc = rays.dirs_cam * np.where(valid, hits.t, np.nan)[:, None]
    return CameraFrame(image=image, depth=depth, obj=hits.obj.reshape(height, width),
                       points_cam=pc.reshape(height, width, 3), points_map=X.reshape(height, width, 3))
