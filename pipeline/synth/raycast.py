"""Vectorised CPU ray casting against the world's primitives, with per-object culling.

A ray set shares one origin (a camera centre or the LiDAR centre, map frame) and has one direction per
ray. Camera rays use directions ``R · K⁻¹ [u, v, 1]`` so the ray parameter t *is* the camera depth z;
LiDAR rays are unit vectors so t is the range. Each object is tested only against the rays that can
see its bounding box (a pixel rectangle for cameras, a beam × azimuth window for the LiDAR) and have
not already hit something nearer than the box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.synth.road import Road
from pipeline.synth.world import Part, WorldObject

EPS = 1e-6
_NONE = np.zeros(0, dtype=np.int64)


def _span(axis: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Indices of the sorted (ascending) ``axis`` values within [lo, hi]."""
    a, b = np.searchsorted(axis, lo, "left"), np.searchsorted(axis, hi, "right")
    return np.arange(a, b)


class CameraRays:
    """Pinhole rays through pixel positions (u, v) of a camera with intrinsics K and pose cam→map.

    ``grid`` = (u_axis (W',), v_axis (H',)) for a full raster (rays in row-major order), else the rays
    are arbitrary positions ``uv`` (N, 2).
    """

    def __init__(self, K: np.ndarray, cam_to_map: np.ndarray, uv: np.ndarray | None = None,
                 grid: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.K, self.M = K, cam_to_map
        self.grid = grid
        if grid is not None:
            vv, uu = np.meshgrid(grid[1], grid[0], indexing="ij")
            uv = np.stack([uu.ravel(), vv.ravel()], -1)
        self.uv = np.asarray(uv, dtype=np.float64)
        y = (self.uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (self.uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        d_cam = np.stack([x, y, np.ones_like(x)])  # (3, N); z component 1: t = depth
        self.dirs_cam = d_cam.T
        self.origin = cam_to_map[:3, 3].copy()
        self.dirs_T = np.ascontiguousarray(cam_to_map[:3, :3] @ d_cam)  # (3, N) map frame
        self.dirs = self.dirs_T.T

    def __len__(self) -> int:
        return len(self.uv)

    def candidates(self, corners: np.ndarray) -> tuple[np.ndarray | None, float]:
        """Rays that may hit the box with map corners (8, 3) — indices, None meaning all — and a lower
        bound on their t (depth) there."""
        pc = (corners - self.origin) @ self.M[:3, :3]
        z = pc[:, 2]
        if np.all(z <= 1e-3):
            return _NONE, 0.0
        if np.any(z <= 1e-3):
            return None, 0.0
        K = self.K
        u = K[0, 0] * pc[:, 0] / z + K[0, 1] * pc[:, 1] / z + K[0, 2]
        v = K[1, 1] * pc[:, 1] / z + K[1, 2]
        u0, u1, v0, v1 = u.min() - 1.0, u.max() + 1.0, v.min() - 1.0, v.max() + 1.0
        if self.grid is not None:
            cols, rows = _span(self.grid[0], u0, u1), _span(self.grid[1], v0, v1)
            if len(cols) == 0 or len(rows) == 0:
                return _NONE, 0.0
            return (rows[:, None] * len(self.grid[0]) + cols[None, :]).ravel(), float(z.min())
        if not hasattr(self, "_by_v"):
            self._by_v = np.argsort(self.uv[:, 1], kind="stable")
            self._v_sorted = self.uv[self._by_v, 1]
        a, b = np.searchsorted(self._v_sorted, v0, "left"), np.searchsorted(self._v_sorted, v1, "right")
        sub = self._by_v[a:b]
        u = self.uv[sub, 0]
        return sub[(u >= u0) & (u <= u1)], float(z.min())


class LidarRays:
    """A spinning LiDAR's rays: beams (elevations, radians, descending) × azimuths (radians, ascending,
    from the sensor's x axis towards y). Sensor frame: x forward, y left, z up; ``sensor_to_map`` pose."""

    def __init__(self, elevations: np.ndarray, azimuths: np.ndarray, sensor_to_map: np.ndarray) -> None:
        self.elev, self.azim, self.M = elevations, azimuths, sensor_to_map
        e, a = np.meshgrid(elevations, azimuths, indexing="ij")
        self.dirs_sensor = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
        self.origin = sensor_to_map[:3, 3].copy()
        self.dirs_T = np.ascontiguousarray(sensor_to_map[:3, :3] @ self.dirs_sensor.T)  # (3, N) map frame
        self.dirs = self.dirs_T.T
        self._elev_asc = elevations[::-1]

    def __len__(self) -> int:
        return len(self.dirs)

    def candidates(self, corners: np.ndarray) -> tuple[np.ndarray | None, float]:
        """Rays (indices into the beam-major grid) that may hit the box with map corners (8, 3), and a
        lower bound on their t (range) there."""
        p = (corners - self.origin) @ self.M[:3, :3]
        c = p[:, :2].mean(0)
        rad = np.max(np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]))
        dc = float(np.hypot(c[0], c[1]))
        A, B = len(self.azim), len(self.elev)
        if dc <= rad + 1e-6:
            cols = np.arange(A)
            dmin = 0.0
        else:
            azc = np.arctan2(c[1], c[0])
            d = np.angle(np.exp(1j * (np.arctan2(p[:, 1], p[:, 0]) - azc)))
            rel = np.angle(np.exp(1j * (self.azim - azc)))
            cols = np.flatnonzero((rel >= d.min() - 1e-3) & (rel <= d.max() + 1e-3))
            dmin = dc - rad
        dmax = dc + rad
        zmax, zmin = p[:, 2].max(), p[:, 2].min()
        el_hi = np.arctan2(zmax, dmin if zmax > 0 else dmax) + 1e-3
        el_lo = np.arctan2(zmin, dmin if zmin < 0 else dmax) - 1e-3
        asc = _span(self._elev_asc, el_lo, el_hi)
        rows = (B - 1 - asc)[::-1]
        if len(cols) == 0 or len(rows) == 0:
            return _NONE, 0.0
        centre = p.mean(0)
        lower = max(0.0, float(np.linalg.norm(centre)) - float(np.max(np.linalg.norm(p - centre, axis=1))))
        return (rows[:, None] * A + cols[None, :]).ravel(), lower


# --------------------------------------------------------------------------- primitives


def hit_box(O: np.ndarray, D: np.ndarray, lo, hi) -> np.ndarray:
    """Slab test: entry t of rays O (3,) + t D (D: (3, n), component-major) into the box lo..hi
    (inf = miss)."""
    tnear = tfar = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for a in range(3):
            inv = 1.0 / D[a]
            t1 = (lo[a] - O[a]) * inv
            t2 = (hi[a] - O[a]) * inv
            lo_t, hi_t = np.minimum(t1, t2), np.maximum(t1, t2)
            tnear = lo_t if tnear is None else np.maximum(tnear, lo_t)
            tfar = hi_t if tfar is None else np.minimum(tfar, hi_t)
    return np.where((tnear <= tfar) & (tnear > EPS), tnear, np.inf)


def hit_cylinder(O, D, cx, cz, r, y0, y1) -> np.ndarray:
    """Outside of a vertical cylinder's side (axis ∥ y, y0 ≤ y ≤ y1): entry t or inf. D (3, n)."""
    ox, oz = O[0] - cx, O[2] - cz
    a = D[0] * D[0] + D[2] * D[2]
    b = 2.0 * (ox * D[0] + oz * D[2])
    c = ox * ox + oz * oz - r * r
    disc = b * b - 4.0 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-b - np.sqrt(disc)) / (2.0 * a)
    y = O[1] + t * D[1]
    ok = (disc >= 0) & (a > 1e-12) & (t > EPS) & (y >= y0) & (y <= y1)
    return np.where(ok, t, np.inf)


def hit_sphere(O, D, c, r) -> np.ndarray:
    """Outside of a sphere: entry t or inf. D (3, n)."""
    oc = O - np.asarray(c)
    a = D[0] * D[0] + D[1] * D[1] + D[2] * D[2]
    b = 2.0 * (oc[0] * D[0] + oc[1] * D[1] + oc[2] * D[2])
    cc = oc @ oc - r * r
    disc = b * b - 4.0 * a * cc
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2.0 * a)
    return np.where((disc >= 0) & (t > EPS), t, np.inf)


def _in_road(road: Road, X: np.ndarray, Z: np.ndarray):
    s, l = road.to_road(X, Z)
    return (s >= road.s_min) & (s <= road.s_max) & (np.abs(l) <= road.ground_half_width), s, l


def hit_ground(O, D, road: Road) -> np.ndarray:
    """The road plane y = 0 within the ground's extent. D (3, n)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -O[1] / D[1]
    ok = (D[1] > 0) & (t > EPS)
    t = np.where(ok, t, np.inf)
    fin = np.flatnonzero(ok)
    inside, _, _ = _in_road(road, O[0] + t[fin] * D[0, fin], O[2] + t[fin] * D[2, fin])
    t[fin[~inside]] = np.inf
    return t


def hit_slab(O, D, road: Road, l0: float, l1: float, h: float) -> np.ndarray:
    """Road-aligned raised strip: top (y = −h, l0 ≤ l ≤ l1) and its two vertical sides. D (3, n)."""
    best = np.full(D.shape[1], np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-h - O[1]) / D[1]
    cand = np.flatnonzero((D[1] > 0) & (t > EPS))
    if len(cand):
        ok, _, l = _in_road(road, O[0] + t[cand] * D[0, cand], O[2] + t[cand] * D[2, cand])
        ok &= (l >= l0) & (l <= l1)
        best[cand[ok]] = t[cand[ok]]
    for lat in (l0, l1):
        for tc in road.lateral_hits(O, D, lat):
            y = O[1] + tc * D[1]
            cand = np.flatnonzero((tc > EPS) & (y >= -h) & (y <= 0.0) & (tc < best))
            if len(cand):
                ok, _, _ = _in_road(road, O[0] + tc[cand] * D[0, cand], O[2] + tc[cand] * D[2, cand])
                best[cand[ok]] = tc[cand[ok]]
    return best


def hit_part(part: Part, O: np.ndarray, D: np.ndarray, road: Road) -> np.ndarray:
    """Entry t (inf = miss) of rays O (3,) + t D (D: (3, n)) with a part (in the part's object frame)."""
    g, k = part.geom, part.kind
    if k == "box":
        return hit_box(O, D, g["lo"], g["hi"])
    if k == "cylinder":
        return hit_cylinder(O, D, g["cx"], g["cz"], g["r"], g["y0"], g["y1"])
    if k == "sphere":
        return hit_sphere(O, D, g["c"], g["r"])
    if k == "ground":
        return hit_ground(O, D, road)
    if k == "slab":
        return hit_slab(O, D, road, g["l0"], g["l1"], g["h"])
    raise ValueError(f"unknown part kind {k!r}")


# --------------------------------------------------------------------------- scene


@dataclass
class Hits:
    """Nearest hit per ray: t (inf = none), object index (−1 = none), part index within the object."""

    t: np.ndarray
    obj: np.ndarray
    part: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.obj >= 0


def cast(objects: list[WorldObject], k: int, rays, road: Road, t_max: float) -> Hits:
    """Nearest surface along every ray of ``rays`` in the world at frame k, up to ``t_max``.

    Unbounded objects (ground, pavements) go first, then the others nearest first; an object is tested
    only on rays that can see its bounding box and have found nothing nearer than the box yet.
    """
    n = len(rays)
    t_best = np.full(n, float(t_max))
    obj = np.full(n, -1, dtype=np.int32)
    part = np.full(n, -1, dtype=np.int16)
    everything = np.arange(n)
    work = []
    for oi, o in enumerate(objects):
        corners = o.corners(k)
        if corners is None:
            work.append((-1.0, oi, None))
            continue
        idx, lower = rays.candidates(corners)
        if idx is None or len(idx):
            work.append((lower, oi, idx))
    work.sort(key=lambda w: (w[0], w[1]))
    for lower, oi, idx in work:
        idx = everything if idx is None else idx
        if lower > 0:
            idx = idx[t_best[idx] > lower]
        if len(idx) == 0:
            continue
        o = objects[oi]
        M = o.pose(k)
        R, T = M[:3, :3], M[:3, 3]
        O_l = R.T @ (rays.origin - T)
        D_l = R.T @ rays.dirs_T[:, idx]
        for pi, p in enumerate(o.parts):
            t = hit_part(p, O_l, D_l, road)
            better = np.flatnonzero(t < t_best[idx])
            if len(better) == 0:
                continue
            sel = idx[better]
            t_best[sel] = t[better]
            obj[sel] = oi
            part[sel] = pi
    t_best[obj < 0] = np.inf
    return Hits(t_best, obj, part)
