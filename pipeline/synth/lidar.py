"""An HDL-64E-like spinning LiDAR: 64 beams evenly spread over elevations +2.0° … −24.8°, a
configurable azimuth step, returns up to ``lidar_range`` metres, reflectance from the surface albedo.

Sensor (velodyne) frame: x forward, y left, z up, metres. The scan is instantaneous (no motion
distortion) and noise-free, so every point lies exactly on a rendered surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.synth.config import SynthConfig
from pipeline.synth.raycast import LidarRays, cast
from pipeline.synth.surface import surface
from pipeline.synth.world import World


@dataclass
class LidarScan:
    """Returns of one scan: ``points`` (N, 4) float32 (x, y, z velodyne frame, reflectance in [0, 1]),
    ``points_map`` (N, 3) float64 map-frame hit points, ``obj`` (N,) object index of each return."""

    points: np.ndarray
    points_map: np.ndarray
    obj: np.ndarray


def beam_elevations(cfg: SynthConfig) -> np.ndarray:
    """Beam elevations in radians, descending (beam 0 is the top one)."""
    return np.radians(np.linspace(cfg.lidar_elev_max_deg, cfg.lidar_elev_min_deg, cfg.lidar_beams))


def azimuths(step_deg: float) -> np.ndarray:
    """Azimuths in radians, ascending in [−π, π), counter-clockwise from the x (forward) axis."""
    n = int(round(360.0 / step_deg))
    return -np.pi + 2.0 * np.pi * np.arange(n) / n


def scan(world: World, k: int, velo_to_map: np.ndarray, cfg: SynthConfig, step_deg: float | None = None) -> LidarScan:
    """Ray-cast the scan of frame k from a sensor with pose ``velo_to_map`` (4×4); azimuth step
    ``step_deg`` (default ``cfg.lidar_azimuth_step_deg``)."""
    step_deg = cfg.lidar_azimuth_step_deg if step_deg is None else step_deg
    rays = LidarRays(beam_elevations(cfg), azimuths(step_deg), velo_to_map)
    hits = cast(world.objects, k, rays, world.road, cfg.lidar_range)
    keep = np.flatnonzero(hits.valid)
    X, _, A = surface(world.objects, k, rays.origin, rays.dirs, hits, world.road,
                      ray_angle=np.radians(step_deg))
    refl = 0.05 + 0.9 * np.clip(A[keep] @ np.array([0.299, 0.587, 0.114]), 0.0, 1.0)
    xyz = rays.dirs_sensor[keep] * hits.t[keep, None]
    pts = np.concatenate([xyz, refl[:, None]], axis=1).astype(np.float32)
    return LidarScan(points=pts, points_map=X[keep], obj=hits.obj[keep])
