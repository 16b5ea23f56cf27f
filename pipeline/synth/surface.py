"""What a ray hit: map-frame point, unit normal and albedo of the surface (see :mod:`textures`).

Face codes: boxes 0..5 (−x, +x, −y, +y, −z, +z of the local box), 6 cylinder side, 7 sphere,
8 ground plane, 9 slab top, 10 slab side at l0, 11 slab side at l1.
"""

from __future__ import annotations

import numpy as np

from pipeline.synth import textures as tex
from pipeline.synth.raycast import Hits
from pipeline.synth.road import Road
from pipeline.synth.world import Part, WorldObject


def _face(part: Part, P: np.ndarray, road: Road) -> np.ndarray:
    """Face code of local hit points P (n, 3) on ``part``: the surface they lie (nearest) on."""
    g = part.geom
    if part.kind == "box":
        lo, hi = np.asarray(g["lo"], float), np.asarray(g["hi"], float)
        d = np.stack([np.abs(P[:, 0] - lo[0]), np.abs(P[:, 0] - hi[0]), np.abs(P[:, 1] - lo[1]),
                      np.abs(P[:, 1] - hi[1]), np.abs(P[:, 2] - lo[2]), np.abs(P[:, 2] - hi[2])], -1)
        return np.argmin(d, axis=1).astype(np.int8)
    if part.kind == "slab":
        _, l = road.to_road(P[:, 0], P[:, 2])
        d = np.stack([np.abs(P[:, 1] + g["h"]), np.abs(l - g["l0"]), np.abs(l - g["l1"])], -1)
        return (9 + np.argmin(d, axis=1)).astype(np.int8)
    code = {"cylinder": 6, "sphere": 7, "ground": 8}[part.kind]
    return np.full(len(P), code, dtype=np.int8)


def _local_normal(part: Part, P: np.ndarray, face: np.ndarray) -> np.ndarray:
    n = np.zeros_like(P)
    if part.kind == "box":
        axis = face // 2
        n[np.arange(len(P)), axis] = np.where(face % 2 == 0, -1.0, 1.0)
    elif part.kind == "cylinder":
        g = part.geom
        n[:, 0], n[:, 2] = (P[:, 0] - g["cx"]) / g["r"], (P[:, 2] - g["cz"]) / g["r"]
    elif part.kind == "sphere":
        n = (P - np.asarray(part.geom["c"])) / part.geom["r"]
    else:
        n[:, 1] = -1.0
    return n


def _albedo(part: Part, P: np.ndarray, face: np.ndarray, road: Road, fp: np.ndarray) -> np.ndarray:
    m, mp = part.material, part.mparams
    if m == "ground":
        s, l = road.to_road(P[:, 0], P[:, 2])
        return tex.ground(s, l, mp["seed"], fp)
    if m == "pavement":
        s, l = road.to_road(P[:, 0], P[:, 2])
        out = np.empty((len(P), 3))
        top = face == 9
        out[top] = tex.pavement_top(s[top], l[top], mp["seed"], fp[top])
        out[~top] = tex.kerb_face(s[~top], P[~top, 1], mp["seed"] + 1, fp[~top])
        return out
    if m == "facade":
        return tex.facade(P, face, np.asarray(part.geom["lo"], float), mp, fp)
    if m in ("car_body", "car_cabin"):
        fn = tex.car_body if m == "car_body" else tex.car_cabin
        return fn(P, face, np.asarray(part.geom["lo"], float), np.asarray(part.geom["hi"], float), mp, fp)
    if m == "pole":
        return tex.pole(P, mp, fp)
    if m == "bark":
        return tex.bark(P, mp, fp)
    if m == "foliage":
        return tex.foliage(P - np.asarray(part.geom["c"]), mp, fp)
    raise ValueError(f"unknown material {m!r}")


def surface(objects: list[WorldObject], k: int, origin: np.ndarray, dirs: np.ndarray, hits: Hits,
            road: Road, albedo: bool = True, ray_angle: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Map points (N, 3), map unit normals (N, 3) and albedo (N, 3) (or None) of hit rays.

    ``ray_angle`` (radians) is the angular spacing of the rays (a pixel's, a LiDAR step's): with the
    range and the incidence it gives each sample's footprint on the surface, which prefilters textures.
    Rows of rays that hit nothing are NaN (points, normals) and 0 (albedo).
    """
    n = len(dirs)
    X = np.full((n, 3), np.nan)
    N = np.full((n, 3), np.nan)
    A = np.zeros((n, 3)) if albedo else None
    hit = np.flatnonzero(hits.obj >= 0)
    X[hit] = origin + hits.t[hit, None] * dirs[hit]
    key = hits.obj[hit].astype(np.int64) * 64 + hits.part[hit]
    order = np.argsort(key, kind="stable")
    keys, starts = np.unique(key[order], return_index=True)
    bounds = list(starts) + [len(order)]
    for j, kk in enumerate(keys):
        rows = hit[order[bounds[j]:bounds[j + 1]]]
        o = objects[int(kk) // 64]
        part = o.parts[int(kk) % 64]
        M = o.pose(k)
        R = M[:3, :3]
        P = (X[rows] - M[:3, 3]) @ R
        f = _face(part, P, road)
        nl = _local_normal(part, P, f)
        if part.kind == "slab":
            side = np.isin(f, (10, 11))
            if side.any():
                s, _ = road.to_road(P[side, 0], P[side, 2])
                rx, rz = road.right(s)
                sign = np.where(f[side] == 11, 1.0, -1.0)
                nl[side] = np.stack([sign * rx, np.zeros_like(rx), sign * rz], -1)
        N[rows] = nl @ R.T
        if albedo:
            d = dirs[rows]
            dn = np.linalg.norm(d, axis=1)
            cos = np.abs(np.einsum("ij,ij->i", N[rows], d)) / dn
            fp = hits.t[rows] * dn * ray_angle / np.sqrt(np.maximum(cos, 0.05))
            A[rows] = _albedo(part, P, f, road, fp)
    return X, N, A
