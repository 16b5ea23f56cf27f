"""Procedural materials: albedo (RGB in [0, 1]) as a pure function of a surface's LOCAL coordinates.

Each function takes coordinates in metres on the surface (or, for round things, in the object's local
3-D frame) plus the part's parameters, so a surface point has the same colour in every frame. ``fp``
(metres) is the footprint of the sample on the surface: noise octaves finer than it fade to their mean
(a prefiltered texture, :func:`pipeline.synth.noise.fbm2`), which keeps distant detail from aliasing. Detail
comes from multi-octave value noise (:mod:`pipeline.synth.noise`) and patterns (lane markings, paving
slabs, windows, wheels).

Box face codes (local axes as a camera's: x right, y down, z forward): 0 −x, 1 +x, 2 −y (top),
3 +y (bottom), 4 −z (back), 5 +z (front).
"""

from __future__ import annotations

import numpy as np

from pipeline.synth.noise import fbm2, fbm3, hash_unit, noise2
from pipeline.synth.road import LANE_WIDTH, PARKING_EDGE, ROAD_HALF_WIDTH

SUN_DIRECTION = np.array([0.35, -0.85, 0.40]) / np.linalg.norm([0.35, -0.85, 0.40])  # towards the sun, map
AMBIENT, DIFFUSE = 0.5, 0.55


def shade(albedo: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Lambertian shading under the fixed sun (map-frame unit normals (n, 3)) → RGB, unclipped."""
    lam = np.clip(normal @ SUN_DIRECTION, 0.0, None)
    return albedo * (AMBIENT + DIFFUSE * lam)[:, None]


def _rgb(g: np.ndarray, tint) -> np.ndarray:
    return g[:, None] * np.asarray(tint, dtype=np.float64)[None, :]


def _mix(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    return a + (b - a) * w[:, None]


# --------------------------------------------------------------------------- ground level


def ground(s: np.ndarray, l: np.ndarray, seed: int, fp: np.ndarray) -> np.ndarray:
    """Road surface at road coordinates (s, l): asphalt, lane markings, parking strip; soil beyond.

    The asphalt carries visible metre-scale mottling (wear, repairs, stains), as real roads do: at the small
    working sizes of self-supervised depth training a near-uniform road gives the photometric loss no
    signal, and the depth net then learns an infinitely far road (measured: median-scaled AbsRel 0.55 →
    2.4 in 100 steps with the former ±0.08 grain, 0.55 → 0.3 with this texture).
    """
    a = np.abs(l)
    g = 0.24 + 0.40 * (fbm2(s, l, seed, 0.5, 6, gain=0.6, fp=fp) - 0.5)
    g *= 0.6 + 0.8 * noise2(s * 0.4, l * 0.4, seed + 1)  # patches of 1–3 m (repairs, wear, stains)
    out = _rgb(g, (0.97, 0.98, 1.04))
    parking = (a >= PARKING_EDGE) & (a < ROAD_HALF_WIDTH)
    out[parking] *= np.array([1.12, 1.08, 1.02])
    paint = (
        (np.abs(a - 0.12) < 0.06)
        | ((np.abs(a - LANE_WIDTH) < 0.07) & (np.mod(s, 6.0) < 3.0))
        | (np.abs(a - PARKING_EDGE) < 0.08)
        | (parking & (np.mod(s, 6.0) < 0.12))
    )
    if paint.any():
        wear = 0.75 + 0.2 * fbm2(s[paint] * 3.0, l[paint] * 3.0, seed + 2, 1.0, 3, fp=fp[paint] * 3.0)
        out[paint] = _rgb(wear, (0.92, 0.92, 0.88))
    soil = a >= ROAD_HALF_WIDTH
    if soil.any():
        w = fbm2(s[soil], l[soil], seed + 3, 0.3, 6, fp=fp[soil])
        out[soil] = _mix(np.array([[0.20, 0.30, 0.12]]), np.array([[0.36, 0.30, 0.20]]), np.clip(2 * w - 0.5, 0, 1))
        out[soil] *= (0.8 + 0.4 * fbm2(s[soil], l[soil], seed + 4, 4.0, 3, fp=fp[soil]))[:, None]
    return out


def pavement_top(s: np.ndarray, l: np.ndarray, seed: int, fp: np.ndarray) -> np.ndarray:
    """Paving slabs of 0.6 m with dark joints, per-slab tint and fine grain."""
    size = 0.6
    cs, cl = np.floor(s / size), np.floor(l / size)
    fs, fl = s / size - cs, l / size - cl
    tint = 0.50 + 0.16 * (hash_unit(seed, cs.astype(np.int64), cl.astype(np.int64)) - 0.5)
    g = tint * (0.85 + 0.3 * fbm2(s, l, seed + 1, 2.0, 4, fp=fp))
    joint = (fs < 0.05) | (fs > 0.95) | (fl < 0.05) | (fl > 0.95)
    g[joint] *= 0.55
    return _rgb(g, (1.0, 0.97, 0.93))


def kerb_face(s: np.ndarray, y: np.ndarray, seed: int, fp: np.ndarray) -> np.ndarray:
    """Concrete kerb stones (1 m long) seen from the side."""
    g = 0.62 + 0.2 * (fbm2(s, y, seed, 2.0, 4, fp=fp) - 0.5)
    g[np.mod(s, 1.0) < 0.03] *= 0.6
    return _rgb(g, (1.0, 1.0, 0.98))


# --------------------------------------------------------------------------- buildings


def facade(P: np.ndarray, face: np.ndarray, lo: np.ndarray, p: dict, fp: np.ndarray) -> np.ndarray:
    """Building box: walls with floors, windows (frames, glass), a door; a dark roof on top.

    ``P`` local points (n, 3) of a box spanning ``lo``..hi; height above ground is −y.
    """
    seed = p["seed"]
    b = -P[:, 1]
    a = np.where(face <= 1, P[:, 2] - lo[2], P[:, 0] - lo[0]) + 17.0 * face  # along the face
    wall = np.asarray(p["wall"], dtype=np.float64)
    g = 0.8 + 0.35 * (fbm2(a, b, seed, 0.7, 6, gain=0.55, fp=fp) - 0.5)
    out = g[:, None] * wall[None, :]
    fh, spacing, ww, wh = p["floor_h"], p["win_spacing"], p["win_w"], p["win_h"]
    floor = np.floor(b / fh)
    fb = b - floor * fh
    out[fb < 0.18] *= 0.8  # cornice band at each floor
    col = np.floor(a / spacing)
    fa = a - col * spacing - 0.5 * (spacing - ww)
    sill = np.where(floor == 0, 0.5, 0.9)
    top = np.where(floor == 0, np.minimum(fh - 0.4, 2.6), 0.9 + wh)
    win = (fa >= 0) & (fa <= ww) & (fb >= sill) & (fb <= top) & (face != 2) & (face != 3)
    if win.any():
        fa_w, fb_w = fa[win], fb[win]
        frame = (fa_w < 0.08) | (fa_w > ww - 0.08) | (fb_w - sill[win] < 0.08) | (top[win] - fb_w < 0.08)
        lit = hash_unit(seed + 5, col[win].astype(np.int64), floor[win].astype(np.int64))
        glass = 0.10 + 0.22 * lit + 0.12 * fbm2(a[win] * 0.5, b[win] * 2.0, seed + 6, 1.0, 3, fp=fp[win] * 2.0)
        gw = _rgb(glass, (0.75, 0.85, 1.0))
        gw[frame] = np.asarray(p["frame"])[None, :] * (0.9 + 0.2 * fbm2(a[win][frame], b[win][frame], seed, 9.0, 1, fp=fp[win][frame]))[:, None]
        out[win] = gw
    door = (face == p["door_face"]) & (np.abs(a - p["door_a"]) < 0.6) & (b < 2.2)
    if door.any():
        panel = 0.8 + 0.2 * (np.mod((a[door] - p["door_a"]) * 5.0, 1.0) < 0.8)
        out[door] = _rgb(panel * (0.8 + 0.4 * fbm2(a[door], b[door], seed + 7, 4.0, 3, fp=fp[door])), (0.36, 0.23, 0.13))
    roof = face == 2
    if roof.any():
        out[roof] = _rgb(0.22 + 0.12 * fbm2(P[roof, 0], P[roof, 2], seed + 8, 1.0, 5, fp=fp[roof]), (1.0, 0.95, 0.92))
    return out


# --------------------------------------------------------------------------- cars


def car_body(P: np.ndarray, face: np.ndarray, lo: np.ndarray, hi: np.ndarray, p: dict, fp: np.ndarray) -> np.ndarray:
    """Car body box (local z = forward): paint, bumpers, wheels on the sides, lights front and back."""
    seed = p["seed"]
    paint = np.asarray(p["paint"], dtype=np.float64)
    b = -P[:, 1]  # height above ground
    g = 0.9 + 0.2 * fbm2(P[:, 0] + P[:, 2], b + 3.0 * face, seed, 2.0, 4, fp=fp)
    out = g[:, None] * paint[None, :]
    out[(b < 0.3) & (face != 2)] = 0.14
    side = face <= 1
    if side.any():
        hz = 0.5 * (hi[2] - lo[2])
        zc = 0.5 * (hi[2] + lo[2])
        dz = np.minimum(np.abs(P[side, 2] - zc - (hz - 0.75)), np.abs(P[side, 2] - zc + (hz - 0.75)))
        r = np.hypot(dz, b[side] - 0.33)
        o = out[side]
        o[r < 0.33] = 0.05 + 0.04 * fbm2(P[side, 2][r < 0.33], b[side][r < 0.33], seed, 20.0, 1, fp=fp[side][r < 0.33])[:, None]
        o[r < 0.17] = 0.55
        out[side] = o
    ends = (face == 4) | (face == 5)
    if ends.any():
        hw = 0.5 * (hi[0] - lo[0])
        x = P[ends, 0] - 0.5 * (hi[0] + lo[0])
        lamp = (np.abs(x) > hw - 0.35) & (b[ends] > 0.55) & (b[ends] < 0.75)
        plate = (np.abs(x) < 0.26) & (b[ends] > 0.3) & (b[ends] < 0.42)
        o = out[ends]
        front = face[ends] == 5
        o[lamp & front] = (0.92, 0.92, 0.82)
        o[lamp & ~front] = (0.75, 0.08, 0.06)
        o[plate] = (0.9, 0.9, 0.88)
        out[ends] = o
    return out


def car_cabin(P: np.ndarray, face: np.ndarray, lo: np.ndarray, hi: np.ndarray, p: dict, fp: np.ndarray) -> np.ndarray:
    """Cabin box: windows (dark glass with reflections) between pillars, painted roof."""
    seed = p["seed"]
    paint = np.asarray(p["paint"], dtype=np.float64)
    g = 0.9 + 0.2 * fbm2(P[:, 0] + P[:, 2], P[:, 1] + 3.0 * face, seed + 1, 2.0, 4, fp=fp)
    out = g[:, None] * paint[None, :]
    along = np.where(face <= 1, P[:, 2] - lo[2], P[:, 0] - lo[0])
    length = np.where(face <= 1, hi[2] - lo[2], hi[0] - lo[0])
    h = P[:, 1] - lo[1]  # from the roof down
    glass = (face != 2) & (face != 3) & (along > 0.12) & (along < length - 0.12) & (h > 0.08) & (h < (hi[1] - lo[1]) - 0.06)
    if face.size and glass.any():
        pillar = (face[glass] <= 1) & (np.abs(along[glass] - 0.5 * length[glass]) < 0.06)
        refl = 0.08 + 0.18 * fbm2(along[glass] * 0.8, h[glass] * 3.0 + face[glass], seed + 2, 1.0, 3, fp=fp[glass] * 3.0)
        gl = _rgb(refl, (0.8, 0.9, 1.0))
        gl[pillar] = out[glass][pillar]
        out[glass] = gl
    return out


# --------------------------------------------------------------------------- street furniture, trees


def pole(P: np.ndarray, p: dict, fp: np.ndarray) -> np.ndarray:
    ang = np.arctan2(P[:, 2], P[:, 0]) * p["radius"]
    g = 0.5 + 0.25 * (fbm2(ang, P[:, 1], p["seed"], 3.0, 4, fp=fp) - 0.5)
    g[np.mod(-P[:, 1], 1.0) < 0.05] *= 0.6
    return _rgb(g, (0.95, 0.97, 1.0))


def bark(P: np.ndarray, p: dict, fp: np.ndarray) -> np.ndarray:
    ang = np.arctan2(P[:, 2], P[:, 0]) * p["radius"]
    g = 0.55 + 0.9 * (fbm2(ang * 6.0, P[:, 1] * 0.8, p["seed"], 1.5, 4, fp=fp * 6.0) - 0.5)
    return _rgb(np.clip(g, 0.1, 1.2), (0.34, 0.25, 0.16))


def foliage(P: np.ndarray, p: dict, fp: np.ndarray) -> np.ndarray:
    w = fbm3(P[:, 0], P[:, 1], P[:, 2], p["seed"], 1.2, 4, gain=0.6, fp=fp)
    out = _mix(np.array([[0.10, 0.22, 0.07]]), np.array([[0.36, 0.50, 0.17]]), np.clip(1.8 * w - 0.4, 0, 1))
    return out * (0.8 + 0.4 * fbm2(P[:, 0] + 0.5 * P[:, 2], P[:, 1], p["seed"] + 1, 6.0, 1, fp=fp))[:, None]


def sky(D: np.ndarray) -> np.ndarray:
    """Sky colour for map-frame ray directions (n, 3): blue gradient with soft clouds."""
    Dn = D / np.linalg.norm(D, axis=1, keepdims=True)
    up = np.clip(-Dn[:, 1], -0.2, 1.0)
    base = _mix(np.array([[0.78, 0.84, 0.90]]), np.array([[0.35, 0.55, 0.85]]), np.clip(up * 2.5, 0, 1))
    k = 1.0 / np.maximum(up + 0.08, 0.05)
    c = fbm2(Dn[:, 0] * k, Dn[:, 2] * k, 99, 0.8, 4)
    return _mix(base, np.full_like(base, 0.95), np.clip(2.5 * (c - 0.55), 0, 0.8))
