"""The scene of one sequence, drawn from a seed: road, pavements, buildings, trees, poles, parked and
moving cars, and the ego camera's trajectory.

With ``SynthConfig.crossing_cars`` a side street meets the road ahead of the ego car (a gap of
:data:`SIDE_STREET_WIDTH` in the buildings, parked cars, trees and poles of both sides) and that many cars drive
across the road along it, at right angles to the road, one way or the other: the traffic at an intersection,
whose motion is across the camera's view, which the cars in the lanes never show. Their randomness comes from a
stream of its own, so a world without them is the one it was before the option.

All geometry lives in the map frame (x right, y down, z forward at the road's start; the road is the
plane y = 0, see :mod:`pipeline.synth.road`). An object is a list of parts (primitives in the object's
local frame, same axis convention) and one object→map pose per frame; only moving cars' poses change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.synth.config import SynthConfig
from pipeline.synth.road import (
    KERB_HEIGHT,
    LANE_WIDTH,
    PAVEMENT_WIDTH,
    ROAD_HALF_WIDTH,
    Road,
)

GROUND_CATEGORIES = ("ground", "pavement")
SIDE_STREET_WIDTH = 10.0  # metres between the buildings either side of the side street (crossing cars)


@dataclass
class Part:
    """One primitive of an object, in the object's local frame (metres).

    kind: ``box`` (geom lo, hi: corners), ``cylinder`` (vertical: cx, cz, r, y0 < y1), ``sphere``
    (c, r), ``ground`` (the road plane y = 0, map frame) or ``slab`` (road-aligned raised strip
    l0 ≤ l ≤ l1, top at y = −h, map frame). ``material`` names a function of :mod:`textures`.
    """

    kind: str
    geom: dict
    material: str
    mparams: dict = field(default_factory=dict)

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        g = self.geom
        if self.kind == "box":
            return np.asarray(g["lo"], float), np.asarray(g["hi"], float)
        if self.kind == "cylinder":
            return (np.array([g["cx"] - g["r"], g["y0"], g["cz"] - g["r"]]),
                    np.array([g["cx"] + g["r"], g["y1"], g["cz"] + g["r"]]))
        if self.kind == "sphere":
            c = np.asarray(g["c"], float)
            return c - g["r"], c + g["r"]
        return None


@dataclass
class WorldObject:
    """A rigid object: parts in its local frame and its object→map pose at every frame (F, 4, 4)."""

    name: str
    category: str  # ground | pavement | building | parked_car | moving_car | pole | tree
    parts: list[Part]
    poses: np.ndarray
    moving: bool = False
    speed: float = 0.0  # m/s along the road (moving cars)

    def pose(self, k: int) -> np.ndarray:
        return self.poses[k] if self.poses.ndim == 3 else self.poses

    def local_bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Local axis-aligned bounding box of all parts; None when unbounded (ground, pavements)."""
        if not hasattr(self, "_bounds"):
            bs = [p.bounds() for p in self.parts]
            self._bounds = None if any(b is None for b in bs) else (
                np.min([b[0] for b in bs], axis=0), np.max([b[1] for b in bs], axis=0))
        return self._bounds

    def corners(self, k: int) -> np.ndarray | None:
        """The 8 corners (8, 3) of the bounding box in the map frame at frame k, or None."""
        if not self.moving and hasattr(self, "_corners"):
            return self._corners
        b = self.local_bounds()
        if b is None:
            return None
        lo, hi = b
        c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        M = self.pose(k)
        c = c @ M[:3, :3].T + M[:3, 3]
        if not self.moving:
            self._corners = c
        return c


@dataclass
class World:
    """One sequence's scene: the road, the objects and the ego cam0→map poses (F, 4, 4)."""

    road: Road
    objects: list[WorldObject]
    cam0_poses: np.ndarray
    fps: float

    @property
    def n_frames(self) -> int:
        return len(self.cam0_poses)

    @property
    def movers(self) -> list[WorldObject]:
        return [o for o in self.objects if o.moving]


def rot_y(yaw: float) -> np.ndarray:
    """Rotation about the (downward) y axis: forward (0,0,1) → (sin yaw, 0, cos yaw)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(pitch: float) -> np.ndarray:
    """Rotation about x; positive pitch lifts the forward axis (towards −y)."""
    c, s = math.cos(pitch), math.sin(pitch)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _pose(R: np.ndarray, t) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = t
    return M


def _road_pose(road: Road, s: float, l: float, flip: bool = False) -> np.ndarray:
    x, z = road.point(s, l)
    yaw = float(road.heading(s)) + (math.pi if flip else 0.0)
    return _pose(rot_y(yaw), (float(x), 0.0, float(z)))


def _colour(rng: np.random.Generator, palette: list[tuple[float, float, float]], jitter: float = 0.06):
    c = np.asarray(palette[rng.integers(len(palette))], dtype=float)
    return tuple(np.clip(c + rng.uniform(-jitter, jitter, 3), 0.02, 0.98).round(4).tolist())


WALLS = [(0.80, 0.72, 0.60), (0.72, 0.45, 0.35), (0.85, 0.82, 0.75), (0.60, 0.62, 0.65),
         (0.90, 0.80, 0.55), (0.55, 0.40, 0.30), (0.75, 0.78, 0.72)]
PAINTS = [(0.75, 0.75, 0.78), (0.10, 0.10, 0.12), (0.60, 0.08, 0.07), (0.12, 0.22, 0.50),
          (0.85, 0.85, 0.82), (0.35, 0.37, 0.40), (0.15, 0.35, 0.20), (0.80, 0.55, 0.10)]


# --------------------------------------------------------------------------- ego trajectory


def _ego_track(cfg: SynthConfig, rng: np.random.Generator, n: int, road_curv: float):
    """Ego arclengths s_k, lateral offsets l_k and cam0→map poses (n, 4, 4)."""
    fps = cfg.fps
    v0 = rng.uniform(cfg.ego_speed_min, cfg.ego_speed_max)
    dv = 0.08 * v0
    Tv, phv = rng.uniform(3.0, 6.0), rng.uniform(0, 2 * math.pi)
    t = np.arange(n) / fps
    v = np.clip(v0 + dv * np.sin(2 * math.pi * t / Tv + phv), cfg.ego_speed_min * 0.9, cfg.ego_speed_max * 1.1)
    if cfg.ego_stop:  # brake to ≈0.3 m/s around a random moment and pull away again (a Gaussian dip)
        t_c, width = rng.uniform(0.3, 0.7) * t[-1], rng.uniform(0.12, 0.25) * max(t[-1], 1e-6)
        dip = np.exp(-(((t - t_c) / width) ** 2))
        v = v * (1.0 - dip) + 0.3 * dip
    s = np.concatenate([[0.0], np.cumsum(v[:-1] / fps)])
    A, lam, phl = rng.uniform(0.1, 0.35), rng.uniform(40.0, 90.0), rng.uniform(0, 2 * math.pi)
    l = 0.5 * LANE_WIDTH + A * np.sin(2 * math.pi * s / lam + phl)
    dl = A * 2 * math.pi / lam * np.cos(2 * math.pi * s / lam + phl)
    Tp, php = rng.uniform(1.5, 3.0), rng.uniform(0, 2 * math.pi)
    pitch = math.radians(cfg.ego_pitch_deg) * np.sin(2 * math.pi * t / Tp + php)
    road = Road(road_curv, 0.0, 1.0)
    x, z = road.point(s, l)
    yaw = road.heading(s) + np.arctan2(dl, 1.0 - road_curv * l)
    poses = np.stack([_pose(rot_y(yaw[k]) @ rot_x(pitch[k]), (x[k], -cfg.camera_height, z[k])) for k in range(n)])
    return s, l, poses


# --------------------------------------------------------------------------- object builders


def _building(rng, road: Road, s_c: float, side: int, width: float, name: str) -> WorldObject:
    depth, height = rng.uniform(8.0, 14.0), rng.uniform(6.0, 18.0)
    setback = rng.uniform(0.4, 2.5)
    l_c = side * (ROAD_HALF_WIDTH + PAVEMENT_WIDTH + setback + depth / 2)
    lo, hi = [-depth / 2, -height, -width / 2], [depth / 2, 0.0, width / 2]
    mp = {
        "seed": int(rng.integers(1 << 30)),
        "wall": _colour(rng, WALLS),
        "frame": _colour(rng, [(0.9, 0.9, 0.88), (0.25, 0.22, 0.2), (0.5, 0.35, 0.2)], 0.03),
        "floor_h": float(rng.uniform(2.9, 3.6)),
        "win_spacing": float(rng.uniform(2.2, 3.4)),
        "win_w": float(rng.uniform(0.9, 1.5)),
        "win_h": float(rng.uniform(1.2, 1.7)),
        "door_face": 0 if side > 0 else 1,
        "door_a": float(rng.uniform(1.0, width - 1.0)),
    }
    return WorldObject(name, "building", [Part("box", {"lo": lo, "hi": hi}, "facade", mp)], _road_pose(road, s_c, l_c))


def _car_parts(rng, length: float, width: float) -> list[Part]:
    """Body box + cabin box (or a taller van body only), local z forward, wheels on y = 0."""
    paint = _colour(rng, PAINTS)
    seed = int(rng.integers(1 << 30))
    van = rng.random() < 0.2
    hb = rng.uniform(1.7, 2.0) if van else rng.uniform(0.85, 1.0)
    body = Part("box", {"lo": [-width / 2, -hb, -length / 2], "hi": [width / 2, 0.0, length / 2]}, "car_body",
                {"paint": paint, "seed": seed})
    parts = [body]
    if not van:
        hc = rng.uniform(0.5, 0.62)
        z0, z1 = -length / 2 + rng.uniform(0.7, 1.0), length / 2 - rng.uniform(1.1, 1.5)
        parts.append(Part("box", {"lo": [-width / 2 + 0.1, -hb - hc, z0], "hi": [width / 2 - 0.1, -hb, z1]},
                          "car_cabin", {"paint": paint, "seed": seed}))
    return parts


def _clear(track: np.ndarray, others: list[np.ndarray], gaps: list[float]) -> bool:
    return all(np.all(np.abs(track - o) >= g) for o, g in zip(others, gaps))


def build_world(cfg: SynthConfig, seq_index: int, n_frames: int) -> World:
    """Draw sequence ``seq_index``'s world (deterministic in (cfg.seed, seq_index, cfg))."""
    rng = np.random.default_rng([int(cfg.seed) & 0xFFFFFFFF, int(cfg.seed) >> 32, seq_index, 0x5EED])
    k_max = 1.0 / cfg.min_turn_radius
    curv = 0.0 if rng.random() < 0.2 else float(rng.choice([-1, 1]) * rng.uniform(0.25 * k_max, k_max))
    s_ego, l_ego, cam0 = _ego_track(cfg, rng, n_frames, curv)
    s_lo, s_hi = float(s_ego[0]) - 40.0, float(s_ego[-1]) + 140.0
    road = Road(curv, s_lo - 20.0, s_hi + 15.0)
    I4 = np.eye(4)
    objs: list[WorldObject] = [WorldObject("ground", "ground", [Part("ground", {}, "ground", {"seed": int(rng.integers(1 << 30))})], I4)]
    for side, name in ((1, "pavement_right"), (-1, "pavement_left")):
        l0, l1 = sorted((side * ROAD_HALF_WIDTH, side * (ROAD_HALF_WIDTH + PAVEMENT_WIDTH)))
        objs.append(WorldObject(name, "pavement", [Part("slab", {"l0": l0, "l1": l1, "h": KERB_HEIGHT}, "pavement",
                                                         {"seed": int(rng.integers(1 << 30))})], I4))
    # buildings along both sides, and a row across each end of the street
    side_street = _side_street(cfg, seq_index, s_ego)  # (s of its centre line, its rng) or None

    def in_side_street(s: float, half_length: float) -> bool:
        return side_street is not None and abs(s - side_street[0]) < SIDE_STREET_WIDTH / 2 + half_length

    for side in (1, -1):
        s = s_lo - 20.0
        while s < s_hi:
            w = rng.uniform(8.0, 20.0)
            building = _building(rng, road, s + w / 2, side, w, f"building_{'rl'[side < 0]}{len(objs)}")
            if not in_side_street(s + w / 2, w / 2):
                objs.append(building)
            s += w + (rng.uniform(6.0, 10.0) if rng.random() < 0.25 else rng.uniform(0.0, 3.0))
    for s_end, name in ((s_hi + 8.0, "building_end"), (s_lo - 28.0, "building_start")):
        lo, hi = [-60.0, -rng.uniform(12.0, 20.0), -6.0], [60.0, 0.0, 6.0]
        mp = {"seed": int(rng.integers(1 << 30)), "wall": _colour(rng, WALLS), "frame": (0.85, 0.85, 0.85),
              "floor_h": 3.2, "win_spacing": 3.0, "win_w": 1.2, "win_h": 1.5, "door_face": 4, "door_a": 60.0}
        objs.append(WorldObject(name, "building", [Part("box", {"lo": lo, "hi": hi}, "facade", mp)], _road_pose(road, s_end, 0.0)))
    # street lamps and trees on the pavements
    for side in (1, -1):
        s = s_lo + rng.uniform(0.0, 10.0)
        while s < s_hi:
            if rng.random() < 0.35:
                r, h = rng.uniform(0.08, 0.14), rng.uniform(5.0, 8.0)
                part = Part("cylinder", {"cx": 0.0, "cz": 0.0, "r": r, "y0": -h, "y1": 0.0}, "pole",
                            {"seed": int(rng.integers(1 << 30)), "radius": r})
                if not in_side_street(s, 0.5):
                    objs.append(WorldObject(f"pole{len(objs)}", "pole", [part],
                                            _road_pose(road, s, side * (ROAD_HALF_WIDTH + 0.45))))
            else:
                rt, ht, rc = rng.uniform(0.12, 0.25), rng.uniform(2.4, 3.4), rng.uniform(1.2, 2.0)
                seed = int(rng.integers(1 << 30))
                trunk = Part("cylinder", {"cx": 0.0, "cz": 0.0, "r": rt, "y0": -ht - 0.5, "y1": 0.0}, "bark",
                             {"seed": seed, "radius": rt})
                crown = Part("sphere", {"c": [0.0, -ht - 0.7 * rc, 0.0], "r": rc}, "foliage", {"seed": seed + 1})
                pose = _road_pose(road, s, side * (ROAD_HALF_WIDTH + rng.uniform(1.8, 2.2)))
                if not in_side_street(s, rc + 0.5):
                    objs.append(WorldObject(f"tree{len(objs)}", "tree", [trunk, crown], pose))
            s += rng.uniform(8.0, 18.0)
    # parked cars in the parking strips, facing the direction of travel of their side
    placed: dict[int, list[tuple[float, float]]] = {1: [], -1: []}
    tries = 0
    while sum(len(v) for v in placed.values()) < cfg.parked_cars and tries < 50 * (cfg.parked_cars + 1):
        tries += 1
        side = 1 if rng.random() < 0.5 else -1
        length, width = rng.uniform(3.9, 4.8), rng.uniform(1.7, 1.9)
        s = rng.uniform(s_ego[0] - 15.0, s_ego[-1] + 70.0)
        if any(abs(s - s2) < (length + l2) / 2 + 0.8 for s2, l2 in placed[side]) or in_side_street(s, length / 2):
            continue
        placed[side].append((s, length))
        parts = _car_parts(rng, length, width)
        lat = side * (ROAD_HALF_WIDTH - 1.1 - rng.uniform(0.0, 0.15))
        objs.append(WorldObject(f"parked{len(objs)}", "parked_car", parts, _road_pose(road, s, lat, flip=side < 0)))
    # moving cars in the lanes: same direction on the right, oncoming on the left; no collisions
    t = np.arange(n_frames) / cfg.fps
    lanes = [(0.5 * LANE_WIDTH, 1), (1.5 * LANE_WIDTH, 1), (-0.5 * LANE_WIDTH, -1), (-1.5 * LANE_WIDTH, -1)]
    tracks: dict[float, list[tuple[np.ndarray, float]]] = {lane: [] for lane, _ in lanes}
    tracks[lanes[0][0]].append((s_ego, 5.0))  # the ego car itself, ≈ 2.5 m either side of cam0
    # the crossing cars first, clear of the ego car; the cars in the lanes are then drawn clear of them
    crossing = [] if side_street is None else _crossing_cars(cfg, road, side_street, t, s_ego, l_ego, len(objs))
    n_mov, tries = 0, 0
    mid = len(t) // 2
    while n_mov < cfg.moving_cars and tries < 100 * (cfg.moving_cars + 1):
        tries += 1
        lane, direction = lanes[rng.choice(4, p=[0.2, 0.3, 0.3, 0.2])]
        v = rng.uniform(cfg.mover_speed_min, cfg.mover_speed_max)
        length, width = rng.uniform(3.9, 4.8), rng.uniform(1.7, 1.9)
        s_mid = s_ego[mid] + (rng.uniform(10.0, 35.0) if direction > 0 else rng.uniform(8.0, 50.0))
        track = s_mid + direction * v * (t - t[mid])
        if not _clear(track, [o for o, _ in tracks[lane]], [(length + lo) / 2 + 1.5 for _, lo in tracks[lane]]):
            continue
        if any(_meet(track, lane, length, c) for c, _ in crossing):
            continue
        tracks[lane].append((track, length))
        parts = _car_parts(rng, length, width)
        poses = np.stack([_road_pose(road, float(sk), lane, flip=direction < 0) for sk in track])
        objs.append(WorldObject(f"mover{len(objs)}", "moving_car", parts, poses, moving=True, speed=float(v)))
        n_mov += 1
    objs += [car for _, car in crossing]
    return World(road=road, objects=objs, cam0_poses=cam0, fps=cfg.fps)


def _side_street(cfg: SynthConfig, seq_index: int, s_ego: np.ndarray) -> tuple[float, np.random.Generator] | None:
    """Where the side street of the crossing cars meets the road (arclength of its centre line: 12–40 m ahead of
    the ego car's position halfway through the sequence) and the random stream the crossing cars are drawn from
    (its own, so that the rest of the world is drawn as without them); None without crossing cars."""
    if cfg.crossing_cars <= 0:
        return None
    rng = np.random.default_rng([int(cfg.seed) & 0xFFFFFFFF, int(cfg.seed) >> 32, seq_index, 0xC2055])
    return float(s_ego[len(s_ego) // 2] + rng.uniform(12.0, 40.0)), rng


@dataclass
class _Crossing:
    """A crossing car's path: the arclength of its side-street lane, its lateral offsets per frame and its length
    and width (metres)."""

    s_lane: float
    lat: np.ndarray
    length: float
    width: float


def _meet(track: np.ndarray, lane: float | np.ndarray, length: float, c: _Crossing, margin: float = 1.0) -> bool:
    """Whether a car in the road's lanes (arclengths ``track`` per frame, lateral offset ``lane``, per frame or one
    for all, ``length``; at most 1.9 m wide) comes within ``margin`` metres of the crossing car ``c`` at any frame."""
    return bool(np.any((np.abs(track - c.s_lane) < (length + c.width) / 2 + margin)
                       & (np.abs(c.lat - lane) < (c.length + 1.9) / 2 + margin)))


def _crossing_cars(cfg: SynthConfig, road: Road, side_street: tuple[float, np.random.Generator], t: np.ndarray,
                   s_ego: np.ndarray, l_ego: np.ndarray, first: int) -> list[tuple[_Crossing, WorldObject]]:
    """``cfg.crossing_cars`` cars driving along the side street, across the road (the module docstring): each on the
    right-hand half of the side street for its direction, at U(mover_speed_min, mover_speed_max) m/s, on the road
    halfway through the sequence; one that would come within a metre of the ego car (arclengths ``s_ego`` and
    lateral offsets ``l_ego`` per frame, 5 m long) or within 1.5 m of another crossing car in its lane is drawn
    again (at most 100 tries per car). The cars in the lanes are drawn clear of these afterwards. Returns each car's
    path and its object."""
    s_c, rng = side_street
    mid = len(t) // 2
    out: list[tuple[_Crossing, WorldObject]] = []
    tries = 0
    while len(out) < cfg.crossing_cars and tries < 100 * cfg.crossing_cars:
        tries += 1
        direction = 1 if rng.random() < 0.5 else -1  # +1: towards +l, the road's right
        v = rng.uniform(cfg.mover_speed_min, cfg.mover_speed_max)
        length, width = rng.uniform(3.9, 4.8), rng.uniform(1.7, 1.9)
        s_lane = s_c - direction * SIDE_STREET_WIDTH / 4  # keeping to the right of its direction of travel
        lat = rng.uniform(-ROAD_HALF_WIDTH + 2.0, ROAD_HALF_WIDTH - 2.0) + direction * v * (t - t[mid])
        path = _Crossing(s_lane, lat, length, width)
        if _meet(s_ego, l_ego, 5.0, path):
            continue
        if any(abs(c.s_lane - s_lane) < 0.1 and np.any(np.abs(lat - c.lat) < (length + c.length) / 2 + 1.5)
               for c, _ in out):
            continue
        parts = _car_parts(rng, length, width)
        x, z = road.point(s_lane, lat)
        yaw = float(road.heading(s_lane)) + direction * math.pi / 2
        poses = np.stack([_pose(rot_y(yaw), (float(x[k]), 0.0, float(z[k]))) for k in range(len(t))])
        car = WorldObject(f"crossing{first + len(out)}", "moving_car", parts, poses, moving=True, speed=float(v))
        out.append((path, car))
    return out
