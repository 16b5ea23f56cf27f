"""Generating one sequence's files, frame by frame (each frame independent of the others).

Per frame k of image_2: ``image_2/k.png``, ``depth_2/k.png`` (KITTI 16-bit depth, 0 = sky),
``velodyne/k.bin`` and, for k < last, ``flow3d_2/k.npz`` (flow, moving, valid, visible_next).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.geometry import in_image, project, se3_inverse
from pipeline.kitti import write_depth_png, write_image, write_odometry_calib, write_poses, write_times, write_velodyne_bin
from pipeline.synth import lidar
from pipeline.synth.config import SynthConfig
from pipeline.synth.groundtruth import moving_mask, scene_flow, visible_in_next
from pipeline.synth.render import render_camera
from pipeline.synth.rig import Rig
from pipeline.synth.sceneflow_export import ScanGT, object_classes
from pipeline.synth.world import GROUND_CATEGORIES, World
from pipeline.synth.writer import frame_name, save_npz


@dataclass
class SequenceJob:
    """Everything a worker needs to write frames of one sequence."""

    name: str
    world: World
    rig: Rig
    cfg: SynthConfig
    seq_dir: Path
    want_scan_gt: bool

    def cam2_pose(self, k: int) -> np.ndarray:
        """image_2 camera → map at frame k: ``Pose_cam0 · inv(T_cam0_to_cam2)``."""
        return self.world.cam0_poses[k] @ se3_inverse(self.rig.T_cam0_to_cam2)

    def velo_pose(self, k: int) -> np.ndarray:
        """velodyne → map at frame k: ``Pose_cam0 · Tr``."""
        return self.world.cam0_poses[k] @ self.rig.T_velo_to_cam0


@dataclass
class FrameResult:
    k: int
    scan_points: int
    scan_gt: ScanGT | None


def write_sequence_files(job: SequenceJob, root: Path) -> None:
    """calib.txt, times.txt and poses/NN.txt (cam0 camera-to-world, frame 0 = identity)."""
    w = job.world
    write_odometry_calib(job.seq_dir / "calib.txt", job.rig.P, job.rig.T_velo_to_cam0)
    write_times(job.seq_dir / "times.txt", np.arange(w.n_frames) / w.fps)
    poses = se3_inverse(w.cam0_poses[0]) @ w.cam0_poses
    poses[0] = np.eye(4)  # exactly, not up to rounding
    write_poses(root / "poses" / f"{job.name}.txt", poses)


def generate_frame(job: SequenceJob, k: int) -> FrameResult:
    cfg, w, K = job.cfg, job.world, job.rig.K
    W, H = cfg.width, cfg.height
    name = frame_name(k)
    last = k + 1 >= w.n_frames
    M2 = job.cam2_pose(k)
    M2n = None if last else job.cam2_pose(k + 1)
    cam = render_camera(w, k, K, M2, W, H, cfg.camera_range, cfg.supersample)
    write_image(job.seq_dir / "image_2" / f"{name}.png", cam.image)
    write_depth_png(job.seq_dir / "depth_2" / f"{name}.png", cam.depth)
    if not last:
        valid = cam.valid.ravel()
        idx = np.flatnonzero(valid)
        obj = cam.obj.ravel()[idx]
        flow = np.zeros((H * W, 3))
        vis = np.zeros(H * W, dtype=bool)
        f, p1 = scene_flow(w, k, cam.points_map.reshape(-1, 3)[idx], obj, cam.points_cam.reshape(-1, 3)[idx], M2n)
        flow[idx] = f
        vis[idx] = visible_in_next(w, k + 1, p1, K, M2n, W, H, cfg.camera_range)
        save_npz(
            job.seq_dir / "flow3d_2" / f"{name}.npz",
            flow=flow.reshape(H, W, 3).astype(np.float32),
            moving=moving_mask(w, cam.obj.ravel()).reshape(H, W),
            valid=valid.reshape(H, W),
            visible_next=vis.reshape(H, W),
        )
    if not job.want_scan_gt and cfg.lidar_scans != "all":  # a training sequence without scans (lidar_scans)
        return FrameResult(k=k, scan_points=0, scan_gt=None)
    step = cfg.test_lidar_azimuth_step_deg if job.want_scan_gt else cfg.lidar_azimuth_step_deg
    sc = lidar.scan(w, k, job.velo_pose(k), cfg, step)
    write_velodyne_bin(job.seq_dir / "velodyne" / f"{name}.bin", sc.points)
    gt = None
    if job.want_scan_gt:
        Minv = se3_inverse(M2)
        p = sc.points_map @ Minv[:3, :3].T + Minv[:3, 3]
        uv, z = project(p, K)
        fov = np.flatnonzero(in_image(uv, H, W) & (z > 1e-3))
        ground_ids = np.array([o.category in GROUND_CATEGORIES for o in w.objects])
        flow = None if last else scene_flow(w, k, sc.points_map[fov], sc.obj[fov], p[fov], M2n)[0]
        obj = sc.obj[fov]
        gt = ScanGT(points=p[fov], flow=flow, moving=moving_mask(w, obj), ground=ground_ids[obj],
                    classes=object_classes([o.category for o in w.objects], obj), instance=obj.astype(np.int32))
    return FrameResult(k=k, scan_points=len(sc.points), scan_gt=gt)
