"""A rigid scene-flow test split built from one real KITTI LiDAR scan, not from the synthetic generator.

The learned flow is trained on the synthetic world; its own test splits come from the same generator, so
they cannot show whether the net has learned that world's geometry rather than scene flow. This tool
writes a FlowNet3D ``kitti_rm_ground`` split (``*.npz``: pos1, pos2, gt; LiDAR axes, see
``evaluation/readers/flownet3d.py``) from a real Velodyne scan and its calibration: the scan is moved into
the rectified camera-0 frame (x right, y down, z forward, metres) with ``R0_rect · Tr_velo_to_cam``, the
ground (camera y ≥ ``ground_y``, the road ~1.65 m below the camera) and points beyond ``max_depth`` are
dropped as FlowNet3D's split does, and each pair then

* splits the points at random into two disjoint halves: frame t keeps one, frame t+1 the other, so no
  point of frame t has an exact copy in frame t+1 (as with two real scans);
* moves the camera by one frame-to-frame motion of the KITTI odometry ground truth (``poses``: pose files
  ``NN.txt``, cam0 camera-to-world 3×4 rows), drawn at random over all their frames, so the motions follow
  KITTI's 10 Hz distribution (over sequences 00–10: |yaw| median 0.15°, 95th percentile 2.6°; translation
  median 0.94 m); without ``poses``, forward by ``forward_m`` (uniform) along an arc that turns it by
  ``yaw_deg`` (uniform ±, median 1.5°: a stress test of turns) and pitches it by ``pitch_deg`` (±);
* expresses frame t+1's half in the moved camera's frame; the true flow of frame t's points is the
  camera's motion alone (the paper's eq. 11, ``sf = (R p + t) − p``), every point static.

Two halves of one scan keep that scan's sampling pattern: frame t+1's rings stay where the scanner was at
frame t, whereas a real second scan's rings, and its density fall-off, move with the sensor. ``rescan``
removes that difference: each frame is the whole scan re-sampled by a virtual ring scanner at that frame's
own sensor position (:func:`ring_scan`: the nearest point per elevation × azimuth cell, moved onto the
cell's centre ray at its range), so both frames have a sensor-fixed pattern, as two consecutive LiDAR
scans have, and the ground and depth cuts are made in each frame's own camera.

So it checks the camera-motion part of the flow (most of KITTI's points) on real street geometry: the
range distribution, density fall-off and surfaces of a Velodyne HDL-64 scan. It has no movers; their error
is measured on the synthetic splits only. Used in docs/learned-flow.md (seventeenth round)::

    python -m benchmarks.real_rigid --scan ../shared/data/kitti_object_000008/000008.bin \\
        --calib ../shared/data/kitti_object_000008/calib_000008.txt \\
        --poses ../shared/data/kitti_odometry_gt_poses --pairs 24 --out w/real_kitti
    monoflow-evaluate run --split w/real_kitti --checkpoint runs/curve/step_000500.pt --protocol fps \\
        --baselines icp-p2p,nsfp --out eval_real_kitti
"""

from __future__ import annotations

import argparse
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.axes import FORMAT_AXES
from core.errors import InputError
from core.geometry import euler_to_matrix, se3_inverse, static_flow, transform_points


@dataclass
class RealRigidConfig:
    """Options of the real-scan rigid split.

    Attributes:
        scan: a KITTI Velodyne ``.bin`` (x forward, y left, z up; float32 x, y, z, reflectance).
        calib: its calibration, object-benchmark format (P0..P3, R0_rect, Tr_velo_to_cam).
        out: the split folder to write (one ``NNNNNN.npz`` per pair); written whole or not at all.
        poses: KITTI odometry pose files (a ``NN.txt`` or a folder of them): the camera motions are drawn
            from their consecutive frames; empty: the uniform ranges below.
        pairs: number of pairs, each with its own camera motion and split of the points.
        seed: seed of the motions and the splits.
        forward_m: the camera's forward motion between the two frames, metres (uniform in the range).
        yaw_deg: largest turn of the camera about its y axis, degrees (uniform in ±).
        pitch_deg: largest pitch of the camera about its x axis, degrees (uniform in ±).
        ground_y: points with camera y at or below this height are ground and dropped, metres (y down).
        max_depth: points with camera z at or beyond this are dropped, metres (FlowNet3D keeps z < 35).
        rescan: each frame re-sampled from the whole scan by a virtual ring scanner at its own sensor
            position (sensor-fixed rings and density, as in two real scans) instead of two halves of it.
        ring_deg: elevation spacing of the virtual scanner's rings, degrees (HDL-64E: about 0.4).
        azimuth_deg: azimuth step of the virtual scanner, degrees.
    """

    scan: str = ""
    calib: str = ""
    out: str = ""
    poses: str = ""
    pairs: int = 24
    seed: int = 0
    forward_m: tuple[float, float] = (0.5, 1.5)
    yaw_deg: float = 3.0
    pitch_deg: float = 0.5
    ground_y: float = 1.4
    max_depth: float = 35.0
    rescan: bool = False
    ring_deg: float = 0.4
    azimuth_deg: float = 0.2


def scan_points(scan: str | Path, calib: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The whole scan (N, 3) and the scanner's centre (3,) in the rectified camera-0 frame, float64 metres."""
    from pipeline.kitti.calib import read_object_calib
    from pipeline.kitti.velodyne import read_velodyne_bin

    velo = read_velodyne_bin(scan)[:, :3].astype(np.float64)
    T = read_object_calib(calib).velo_to_cam_rect()
    return transform_points(T, velo), T[:3, 3].astype(np.float64)


def split_keep(points: np.ndarray, ground_y: float, max_depth: float) -> np.ndarray:
    """FlowNet3D's cuts in one frame's camera: in front of it, above the ground, nearer than ``max_depth``."""
    from pipeline.filters import far_keep, ground_keep

    return (points[:, 2] > 0.0) & far_keep(points, max_depth) & ground_keep(points, ground_y)


def ring_scan(points: np.ndarray, sensor: np.ndarray, ring_deg: float, azimuth_deg: float) -> np.ndarray:
    """What a spinning scanner at ``sensor`` (3,) would return from the surfaces that ``points`` (N, 3)
    sample, camera axes (x right, y down, z forward), metres: every point's direction from the sensor falls in
    a cell of ``ring_deg`` elevation (atan2(−y, √(x² + z²))) by ``azimuth_deg`` azimuth (atan2(x, z)); per
    cell the nearest point is returned (the others are behind it), moved onto the cell's centre ray at its
    range, so the rings and the density fall-off are the sensor's own. (M, 3), M ≤ N, in cell order."""
    d = points - sensor
    rng = np.linalg.norm(d, axis=1)
    flat = np.hypot(d[:, 0], d[:, 2])
    e = np.floor(np.degrees(np.arctan2(-d[:, 1], flat)) / ring_deg).astype(np.int64)
    a = np.floor(np.degrees(np.arctan2(d[:, 0], d[:, 2])) / azimuth_deg).astype(np.int64)
    order = np.lexsort((rng, a, e))  # by cell, nearest first
    cell = np.stack([e[order], a[order]], axis=1)
    first = np.ones(len(order), bool)
    first[1:] = (cell[1:] != cell[:-1]).any(axis=1)
    pick = order[first]
    el = np.radians((e[pick] + 0.5) * ring_deg)
    az = np.radians((a[pick] + 0.5) * azimuth_deg)
    ray = np.stack([np.cos(el) * np.sin(az), -np.sin(el), np.cos(el) * np.cos(az)], axis=1)
    return sensor + rng[pick, None] * ray


def camera_motion(rng: np.random.Generator, cfg: RealRigidConfig) -> np.ndarray:
    """``T_{t→t+1}`` (4, 4): camera-t coordinates → camera-(t+1) coordinates for one random forward motion
    on an arc (the camera turns by yaw, its position moves along the chord's half angle)."""
    d = rng.uniform(*cfg.forward_m)
    yaw = np.deg2rad(rng.uniform(-cfg.yaw_deg, cfg.yaw_deg))
    pitch = np.deg2rad(rng.uniform(-cfg.pitch_deg, cfg.pitch_deg))
    pose = np.eye(4)  # camera t+1 in camera t's frame
    pose[:3, :3] = euler_to_matrix(np.array([pitch, yaw, 0.0]))
    pose[:3, 3] = d * np.array([np.sin(yaw / 2), 0.0, np.cos(yaw / 2)])
    return se3_inverse(pose)


def kitti_motions(poses: str | Path) -> np.ndarray:
    """Every frame-to-frame ``T_{t→t+1}`` (M, 4, 4) of the KITTI pose files at ``poses`` (a file, or a
    folder's ``NN.txt``), cam0 frame, metres: ``inv(Pose_{t+1}) · Pose_t``."""
    from core.geometry import relative_pose
    from pipeline.kitti.poses import read_poses

    root = Path(poses)
    files = [root] if root.is_file() else sorted(f for f in root.glob("*.txt") if f.stem.isdigit())
    if not files:
        raise InputError(root, "no KITTI pose files (NN.txt)")
    rel = [relative_pose(p[:-1], p[1:]) for p in (read_poses(f) for f in files) if len(p) > 1]
    if not rel:
        raise InputError(root, "the pose files hold fewer than two frames each")
    return np.concatenate(rel)


def build_split(cfg: RealRigidConfig) -> int:
    """Write ``cfg.pairs`` pairs to ``cfg.out`` (a fresh folder, renamed into place when complete);
    returns the number of frame-t points per pair."""
    from pipeline.synth.writer import frame_name, save_npz

    whole, sensor = scan_points(cfg.scan, cfg.calib)
    points = whole[split_keep(whole, cfg.ground_y, cfg.max_depth)]
    if len(points) < 64:
        raise InputError(Path(cfg.scan), f"only {len(points)} non-ground points within {cfg.max_depth} m")
    out = Path(cfg.out)
    if out.exists():
        raise InputError(out, "exists; choose a new folder (the split is written whole or not at all)")
    part = out.with_name(out.name + ".partial")
    shutil.rmtree(part, ignore_errors=True)
    rng = np.random.default_rng(cfg.seed)
    axes = FORMAT_AXES["flownet3d"]
    half = len(points) // 2
    if cfg.rescan:  # frame t is scanned from the same sensor position for every pair: once
        first = ring_scan(whole, sensor, cfg.ring_deg, cfg.azimuth_deg)
        first = first[split_keep(first, cfg.ground_y, cfg.max_depth)]
        half = len(first)
    motions = kitti_motions(cfg.poses) if cfg.poses else None
    for k in range(cfg.pairs):
        T = camera_motion(rng, cfg) if motions is None else motions[rng.integers(len(motions))]
        order = rng.permutation(len(points))  # drawn either way: with rescan, the same motions as without
        if cfg.rescan:  # frame t+1 scanned from its own sensor position, cut in its own camera
            second = ring_scan(transform_points(T, whole), sensor, cfg.ring_deg, cfg.azimuth_deg)
            second = second[split_keep(second, cfg.ground_y, cfg.max_depth)]
        else:
            first, second = points[order[:half]], transform_points(T, points[order[half:]])
        save_npz(part / f"{frame_name(k)}.npz",
                 pos1=axes.from_camera(first).astype(np.float32),
                 pos2=axes.from_camera(second).astype(np.float32),
                 gt=axes.from_camera(static_flow(first, T)).astype(np.float32),
                 moving=np.zeros(len(first), dtype=bool))
    part.rename(out)
    return half


def _main(argv: list[str] | None) -> int:
    from core.options import add_dataclass_args, build_config

    p = argparse.ArgumentParser(prog="real_rigid", description=__doc__.split("\n\n")[0])
    add_dataclass_args(p, RealRigidConfig)
    cfg = build_config(RealRigidConfig, p.parse_args(argv), base=RealRigidConfig())
    for name in ("scan", "calib", "out"):
        if not getattr(cfg, name):
            p.error(f"--{name} is required")
    n = build_split(cfg)
    print(f"real_rigid: {cfg.pairs} pairs of {n} points each in {cfg.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; a bad scan, calibration or an existing ``--out`` is one ``error:`` line, exit code 2."""
    from core.errors import run_cli

    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
