"""LiDAR scene-flow splits from a street of boxes, written without the synthetic generator.

Every other synthetic split the project scores comes from :mod:`pipeline.synth` (its worlds, its LiDAR model, its
traffic), which also built the training world, so a net could do well on them by learning that generator's habits.
This tool shares none of its code: a street is a set of oriented boxes — façade segments with gaps and setbacks on
both sides, poles, trees (a trunk and a crown), parked cars along the kerbs, one to four moving cars driving with
the camera, towards it or across the street — and each frame is ray-cast from the sensor with a 64-beam pattern
(−24.9° … +2° elevation, 0.2° azimuth steps over ±``half_fov`` degrees, each beam's elevation jittered per
scan), range below ``max_range``. The ground is not cast (the clouds are ground-removed, as the community's KITTI
splits are). The camera drives 0–1.6 m per frame and turns by a few degrees; the boxes' own motions are drawn per
scene. The truth is exact: a frame-1 hit moves with the box it hit.

Two layouts, both FlowNet3D's ``.npz`` (``pos1``, ``pos2``, ``gt``, ``moving``; LiDAR-like axes, x forward,
y left, z up, metres — the reader turns them into camera axes):

* ``rescan``: frame 2 is the scan from the moved sensor of the moved boxes, as a LiDAR sees the next sweep;
* ``pairs``: frame 2 is frame 1's own points moved by the truth, rows shuffled, as FlowNet3D's ``kitti_rm_ground``
  stores KITTI's correspondences.

Both clouds get ``noise_m`` of Gaussian range-like noise (after the truth is taken, so the truth is exact for the
noiseless surface point). ::

    python -m benchmarks.box_world --out w/boxes --seed 0
    monoflow-evaluate run --split w/boxes --checkpoint … --baselines icp-p2p,fgr,nsfp --rigid_polish --refine

Camera motion and box motions are drawn with ``numpy.random.default_rng([seed, scene])``
(docs/learned-flow.md, forty-sixth round).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import ConfigError, InputError, run_cli

LAYOUTS = ("rescan", "pairs")
SENSOR_HEIGHT_M = 1.73  # above the (uncast) ground plane z = −SENSOR_HEIGHT_M


@dataclass
class BoxWorldConfig:
    """Options of the box-world split.

    Attributes:
        out: the split folder to create (must not exist; written whole or not at all).
        seed: the draws of every scene (streets, motions, beam jitter, noise).
        scenes: scenes to write.
        layout: ``rescan`` (frame 2 scanned again from the moved sensor) or ``pairs`` (frame 2 = frame 1's points
            moved, rows shuffled).
        half_fov: half the horizontal field of view, degrees (the camera's, about KITTI's).
        max_range: points farther than this from the sensor are not kept, metres.
        noise_m: standard deviation of the Gaussian noise on each point, metres.
    """

    out: str = ""
    seed: int = 0
    scenes: int = 20
    layout: str = "rescan"
    half_fov: float = 45.0
    max_range: float = 35.0
    noise_m: float = 0.01


@dataclass
class Box:
    """An oriented box standing on the ground: ``centre`` (3,) metres, ``half`` (3,) half-extents, ``yaw`` radians
    about z; ``motion`` ``(R (3, 3), t (3,))`` maps its frame-1 points to frame 2 (world = the frame-1 sensor's
    axes), ``None`` for a static box."""

    centre: np.ndarray
    half: np.ndarray
    yaw: float
    motion: tuple[np.ndarray, np.ndarray] | None = None

    def moved(self) -> Box:
        """The box where it stands in frame 2."""
        if self.motion is None:
            return self
        rot, t = self.motion
        turn = float(np.arctan2(rot[1, 0], rot[0, 0]))
        return Box(rot @ self.centre + t, self.half, self.yaw + turn, None)


def rot_z(angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` radians about z (up)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def street(rng: np.random.Generator) -> tuple[list[Box], np.ndarray, np.ndarray]:
    """One street's boxes and the camera's motion ``(R, t)``: the frame-2 sensor's pose in frame 1's axes."""
    ground = -SENSOR_HEIGHT_M
    width = rng.uniform(5.0, 9.0)
    boxes: list[Box] = []
    for side in (-1.0, 1.0):  # façade segments with gaps and setbacks
        x = -10.0
        while x < 60.0:
            length = rng.uniform(6.0, 20.0)
            setback = rng.uniform(0.0, 4.0) if rng.random() < 0.5 else 0.0
            if rng.random() < 0.85:
                boxes.append(Box(np.array([x + length / 2, side * (width + setback + 0.5), ground + 4.0]),
                                 np.array([length / 2, 0.5, 4.0]), 0.0))
            x += length + rng.uniform(0.0, 3.0)
    for _ in range(rng.integers(4, 12)):  # poles and trees by the kerb
        x, y = rng.uniform(3.0, 40.0), rng.choice([-1.0, 1.0]) * (width - rng.uniform(0.5, 1.5))
        if rng.random() < 0.5:
            boxes.append(Box(np.array([x, y, ground + 2.5]), np.array([0.1, 0.1, 2.5]), 0.0))
        else:
            boxes.append(Box(np.array([x, y, ground + 1.5]), np.array([0.2, 0.2, 1.5]), 0.0))
            boxes.append(Box(np.array([x, y, ground + 4.0]), np.array([1.2, 1.2, 1.0]), rng.uniform(0.0, 1.0)))
    for _ in range(rng.integers(2, 8)):  # parked cars
        x, y = rng.uniform(4.0, 40.0), rng.choice([-1.0, 1.0]) * (width - 1.3)
        boxes.append(Box(np.array([x, y, ground + 0.75]), np.array([2.1, 0.9, 0.75]), rng.normal(0.0, 0.05)))
    for _ in range(rng.integers(1, 5)):  # moving cars
        kind = rng.choice(["with", "oncoming", "crossing"], p=[0.4, 0.4, 0.2])
        x = rng.uniform(6.0, 32.0)
        if kind == "crossing":
            y = rng.uniform(-width + 2, width - 2)
            heading, speed = np.pi / 2 + rng.normal(0, 0.1), rng.uniform(0.3, 1.2)
            speed *= rng.choice([-1.0, 1.0])
        else:
            y = rng.uniform(1.0, 2.5) * (1.0 if kind == "oncoming" else -1.0)
            heading, speed = rng.normal(0.0, 0.05), rng.uniform(0.5, 1.8) * (-1.0 if kind == "oncoming" else 1.0)
        centre = np.array([x, y, ground + 0.8])
        turn = rot_z(rng.normal(0.0, 0.02))  # about the car's own centre, then along its heading
        shift = rot_z(heading) @ np.array([speed, 0.0, 0.0])
        boxes.append(Box(centre, np.array([2.2, 0.95, 0.8]), heading, (turn, centre + shift - turn @ centre)))
    cam_rot = rot_z(np.deg2rad(rng.normal(0.0, 1.5)))
    cam_t = np.array([rng.uniform(0.0, 1.6), rng.normal(0.0, 0.05), rng.normal(0.0, 0.01)])
    return boxes, cam_rot, cam_t


def beams(rng: np.random.Generator, half_fov: float) -> np.ndarray:
    """Unit ray directions (R, 3) of one scan in the sensor's axes: 64 beams (elevations jittered by 0.05°)
    × azimuths every 0.2° over ±``half_fov`` degrees."""
    elevation = np.deg2rad(np.linspace(-24.9, 2.0, 64) + rng.normal(0.0, 0.05, 64))
    azimuth = np.deg2rad(np.arange(-half_fov, half_fov, 0.2))
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)


def cast(origin: np.ndarray, directions: np.ndarray, boxes: list[Box]) -> tuple[np.ndarray, np.ndarray]:
    """The nearest hit of each ray from ``origin`` (3,) along ``directions`` (R, 3) on ``boxes`` (slab test in
    each box's own axes): hit points (R, 3) metres (NaN where none) and the index of the box hit (−1: none)."""
    best = np.full(len(directions), np.inf)
    which = np.full(len(directions), -1)
    for b, box in enumerate(boxes):
        to_box = rot_z(box.yaw).T
        o, d = to_box @ (origin - box.centre), directions @ to_box.T
        with np.errstate(divide="ignore", invalid="ignore"):
            near, far = (-box.half - o) / d, (box.half - o) / d
        enter = np.nanmax(np.minimum(near, far), axis=1)
        leave = np.nanmin(np.maximum(near, far), axis=1)
        nearer = (leave >= enter) & (enter > 0.1) & (enter < best)
        best[nearer], which[nearer] = enter[nearer], b
    hits = np.full(directions.shape, np.nan)
    seen = which >= 0
    hits[seen] = origin + directions[seen] * best[seen, None]
    return hits, which


def scan_pair(rng: np.random.Generator, cfg: BoxWorldConfig) -> dict[str, np.ndarray]:
    """One scene: ``pos1`` (N, 3), ``pos2`` (M, 3), ``gt`` (N, 3), ``moving`` (N,), LiDAR-like axes, metres."""
    boxes, cam_rot, cam_t = street(rng)
    hits, which = cast(np.zeros(3), beams(rng, cfg.half_fov), boxes)
    keep = (which >= 0) & (np.linalg.norm(hits, axis=1) < cfg.max_range)
    p1, which = hits[keep], which[keep]
    world2 = p1.copy()  # each frame-1 hit where its box takes it (frame-1 axes)
    for b in np.unique(which):
        if boxes[b].motion is not None:
            rot, t = boxes[b].motion
            world2[which == b] = p1[which == b] @ rot.T + t
    gt = (world2 - cam_t) @ cam_rot - p1  # into the frame-2 sensor's axes: R_camᵀ (X − t_cam)
    moving = np.array([boxes[b].motion is not None for b in which], bool)
    noisy1 = p1 + rng.normal(0.0, cfg.noise_m, p1.shape)
    if cfg.layout == "pairs":
        pos2 = (noisy1 + gt)[rng.permutation(len(p1))]
    else:
        hits2, which2 = cast(cam_t, beams(rng, cfg.half_fov) @ cam_rot.T, [b.moved() for b in boxes])
        seen = which2 >= 0
        p2 = (hits2[seen] - cam_t) @ cam_rot
        p2 = p2[np.linalg.norm(p2, axis=1) < cfg.max_range]
        pos2 = p2 + rng.normal(0.0, cfg.noise_m, p2.shape)
    return {"pos1": noisy1.astype(np.float32), "pos2": pos2.astype(np.float32), "gt": gt.astype(np.float32),
            "moving": moving}


def build_split(cfg: BoxWorldConfig) -> tuple[int, int, float]:
    """Write the split to ``cfg.out`` (a ``.partial`` folder renamed into place when complete); returns (scenes,
    frame-1 points per scene on average, the fraction of them moving)."""
    if cfg.scenes < 1:
        raise ConfigError(f"scenes must be ≥ 1, got {cfg.scenes}")
    if cfg.layout not in LAYOUTS:
        raise ConfigError(f"layout must be one of {LAYOUTS}, got {cfg.layout!r}")
    if not 0.0 < cfg.half_fov <= 90.0 or cfg.max_range <= 0.0 or cfg.noise_m < 0.0:
        raise ConfigError("need 0 < half_fov ≤ 90, max_range > 0 and noise_m ≥ 0, got "
                         f"{cfg.half_fov}, {cfg.max_range}, {cfg.noise_m}")
    out = Path(cfg.out)
    if out.exists():
        raise InputError(out, "exists; choose a new folder (the split is written whole or not at all)")
    part = out.with_name(out.name + ".partial")
    shutil.rmtree(part, ignore_errors=True)
    part.mkdir(parents=True)
    points, moved = 0, 0
    for k in range(cfg.scenes):
        scene = scan_pair(np.random.default_rng([cfg.seed, k]), cfg)
        points, moved = points + len(scene["pos1"]), moved + int(scene["moving"].sum())
        np.savez(part / f"{k:06d}.npz", **scene)
    part.rename(out)
    return cfg.scenes, points // cfg.scenes, moved / max(points, 1)


def _main(argv: list[str] | None) -> int:
    from core.options import parse_config

    cfg = parse_config(BoxWorldConfig, argv, "box_world", __doc__.split("\n\n")[0], required=("out",))
    n, points, moving = build_split(cfg)
    print(f"box_world: {n} scenes ({cfg.layout}) of about {points} frame-1 points each in {cfg.out}; "
          f"{moving:.1%} moving")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; an existing ``--out`` is one ``error:`` line."""
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
