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
  camera's motion alone (the paper's eq. 11, ``sf = (R p + t) − p``), every point static;
* with ``movers``, first moves that many of the scan's object-sized clusters (cars, a cyclist, a post:
  :func:`core.clusters.object_clusters`, at least ``mover_min_points`` points) by a motion of their own — along
  the cluster's longer horizontal axis, either way, with a small turn about its centre — so frame t+1 sees
  them where they went; their true flow is that motion and then the camera's, and they are marked ``moving``
  (and ``instance``: which mover, −1 for the static points, as the synthetic splits write it).

The movers are real scanned shapes, but their motion is drawn here, not observed: what a split with them
checks is how the flow follows a real car's points (its shape, its sampling, its occlusion of what is behind
it) when that car moves, independently of the synthetic generator's boxes and meshes.

Two halves of one scan keep that scan's sampling pattern: frame t+1's rings stay where the scanner was at
frame t, whereas a real second scan's rings, and its density fall-off, move with the sensor. ``rescan``
removes that difference: each frame is the whole scan re-sampled by a virtual ring scanner at that frame's
own sensor position (:func:`ring_scan`: the nearest point per elevation × azimuth cell, moved onto the
cell's centre ray at its range), so both frames have a sensor-fixed pattern, as two consecutive LiDAR
scans have, and the ground and depth cuts are made in each frame's own camera.

So it checks the camera-motion part of the flow (most of KITTI's points) on real street geometry: the
range distribution, density fall-off and surfaces of a Velodyne HDL-64 scan; with ``movers``, also the
movers' part on real shapes. Used in docs/learned-flow.md (seventeenth round)::

    python -m benchmarks.real_rigid --scan ../shared/data/kitti_object_000008/000008.bin \\
        --calib ../shared/data/kitti_object_000008/calib_000008.txt \\
        --poses ../shared/data/kitti_odometry_gt_poses --pairs 24 --out w/real_kitti
    monoflow-evaluate run --split w/real_kitti --checkpoint runs/curve/step_000500.pt --protocol fps \\
        --baselines icp-p2p,nsfp --out eval_real_kitti
"""

from __future__ import annotations

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
        movers: object-sized clusters moved per pair by their own motion (drawn anew for each pair among the
            scan's clusters of at least ``mover_min_points`` points; fewer when it has fewer); 0 = a static scene.
        mover_min_points: smallest cluster (scan points within the cuts) that may be moved.
        mover_m: how far a mover goes between the two frames along its longer horizontal axis, metres (uniform
            in the range; 0.3–1.5 m is 3–15 m/s at KITTI's 10 Hz), the direction either way at random.
        mover_yaw_deg: largest turn of a mover about the vertical through its centre, degrees (uniform in ±).
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
    movers: int = 0
    mover_min_points: int = 30
    mover_m: tuple[float, float] = (0.3, 1.5)
    mover_yaw_deg: float = 2.0


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
    return ring_pick(points, sensor, ring_deg, azimuth_deg)[1]


def ring_pick(points: np.ndarray, sensor: np.ndarray, ring_deg: float,
              azimuth_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ring_scan` with its sources: the index (M,) into ``points`` of the point each returned one was
    taken from, and the returned points (M, 3)."""
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
    return pick, sensor + rng[pick, None] * ray


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


def object_motion(rng: np.random.Generator, points: np.ndarray, cfg: RealRigidConfig) -> np.ndarray:
    """``M`` (4, 4) in camera-t coordinates: one mover's own motion between the two frames, for the cluster
    ``points`` (K, 3), metres: a turn by up to ``mover_yaw_deg`` about the camera's y axis through the cluster's
    centre, then ``mover_m`` metres along the cluster's longer horizontal (x–z) axis, either way."""
    centre = points.mean(axis=0)
    xz = points[:, [0, 2]] - centre[[0, 2]]
    axis = np.linalg.eigh(xz.T @ xz)[1][:, -1]  # the longer horizontal axis (a car's length)
    heading = np.array([axis[0], 0.0, axis[1]]) * rng.choice((-1.0, 1.0))
    yaw = np.deg2rad(rng.uniform(-cfg.mover_yaw_deg, cfg.mover_yaw_deg))
    R = euler_to_matrix(np.array([0.0, yaw, 0.0]))
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = centre - R @ centre + rng.uniform(*cfg.mover_m) * heading
    return M


def mover_clusters(whole: np.ndarray, kept: np.ndarray, min_points: int) -> list[np.ndarray]:
    """The clusters that may be moved: the object-sized clusters (:func:`core.clusters.object_clusters`) of
    ``whole[kept]`` (``kept``: indices into ``whole``) with at least ``min_points`` points, each as indices into
    ``whole``."""
    from core.clusters import object_clusters

    return [kept[o] for o in object_clusters(whole[kept]) if len(o) >= min_points]


def moved_scene(rng: np.random.Generator, whole: np.ndarray, clusters: list[np.ndarray],
                cfg: RealRigidConfig) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """One pair's movers: ``cfg.movers`` of ``clusters`` (fewer when there are fewer) drawn with ``rng``, each
    moved by its own :func:`object_motion`. Returns the scan at frame t+1 in camera-t coordinates (N, 3), which
    mover each scan point belongs to (N,; −1: static) and the movers' motions ``M`` (4, 4) in that order."""
    label = np.full(len(whole), -1, dtype=np.int64)
    moved = whole.copy()
    motions: list[np.ndarray] = []
    if cfg.movers <= 0:
        return moved, label, motions
    for k, c in enumerate(rng.choice(len(clusters), size=min(cfg.movers, len(clusters)), replace=False)):
        M = object_motion(rng, whole[clusters[c]], cfg)
        moved[clusters[c]] = transform_points(M, whole[clusters[c]])
        label[clusters[c]] = k
        motions.append(M)
    return moved, label, motions


def true_flow(points: np.ndarray, label: np.ndarray, T: np.ndarray, motions: list[np.ndarray]) -> np.ndarray:
    """The true flow (N, 3) of frame-t points ``points`` (N, 3), camera-t frame, metres: ``T p − p`` for the static
    ones (label −1; eq. 11), ``T M_k p − p`` for those of mover ``k``."""
    flow = static_flow(points, T)
    for k, M in enumerate(motions):
        on = label == k
        flow[on] = static_flow(points[on], T @ M)
    return flow


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
    kept = np.flatnonzero(split_keep(whole, cfg.ground_y, cfg.max_depth))  # the scan's points within the cuts
    points = whole[kept]
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
    clusters = mover_clusters(whole, kept, cfg.mover_min_points) if cfg.movers > 0 else []
    if cfg.movers > 0 and not clusters:
        raise InputError(Path(cfg.scan), f"no object-sized cluster of {cfg.mover_min_points} or more points to move")
    if cfg.rescan:  # frame t is scanned from the same sensor position for every pair: once
        source, first = ring_pick(whole, sensor, cfg.ring_deg, cfg.azimuth_deg)
        cut = split_keep(first, cfg.ground_y, cfg.max_depth)
        source, first = source[cut], first[cut]
        half = len(first)
    motions = kitti_motions(cfg.poses) if cfg.poses else None
    for k in range(cfg.pairs):
        T = camera_motion(rng, cfg) if motions is None else motions[rng.integers(len(motions))]
        order = rng.permutation(len(points))  # drawn either way: with rescan, the same motions as without
        later, label, own = moved_scene(rng, whole, clusters, cfg)  # draws nothing without movers
        if cfg.rescan:  # frame t+1 scanned from its own sensor position, cut in its own camera
            second = ring_scan(transform_points(T, later), sensor, cfg.ring_deg, cfg.azimuth_deg)
            second = second[split_keep(second, cfg.ground_y, cfg.max_depth)]
        else:
            source, first = kept[order[:half]], points[order[:half]]
            second = transform_points(T, later[kept[order[half:]]])
        # with movers, which one each point lies on (instance, −1: static), as the synthetic splits write it
        labels = {"instance": label[source].astype(np.int32)} if cfg.movers > 0 else {}
        save_npz(part / f"{frame_name(k)}.npz",
                 pos1=axes.from_camera(first).astype(np.float32),
                 pos2=axes.from_camera(second).astype(np.float32),
                 gt=axes.from_camera(true_flow(first, label[source], T, own)).astype(np.float32),
                 moving=label[source] >= 0, **labels)
    part.rename(out)
    return half


def _main(argv: list[str] | None) -> int:
    from core.options import parse_config

    cfg = parse_config(RealRigidConfig, argv, "real_rigid", __doc__.split("\n\n")[0],
                       required=("scan", "calib", "out"))
    n = build_split(cfg)
    print(f"real_rigid: {cfg.pairs} pairs of {n} points each in {cfg.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; a bad scan, calibration or an existing ``--out`` is one ``error:`` line, exit code 2."""
    from core.errors import run_cli

    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
