"""The sensor rig: intrinsics, KITTI-like projection matrices P0..P3 and the velodyne mount.

Frames: cam0 is the rectified reference camera (x right, y down, z forward). The colour camera image_2
sits 0.06 m to the *left* of cam0 — KITTI's ``P2 = K [I | (+0.06, 0, 0)]``, so a cam0 point X is
``X + (0.06, 0, 0)`` in camera 2. The velodyne (x forward, y left, z up) is mounted 0.08 m above and
0.27 m behind cam0 (≈ 1.73 m above the road), as on KITTI's car.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.axes import LIDAR
from pipeline.synth.config import KITTI_CX, KITTI_CY, KITTI_FX, KITTI_FY, KITTI_SIZE, SynthConfig

#: x offsets t_i (metres) in ``P_i = K [I | (t_i, 0, 0)]`` for cameras 0..3 (KITTI-like baselines).
CAMERA_X_OFFSETS = (0.0, -0.537, 0.06, -0.473)
#: velodyne origin in cam0 coordinates (metres): 0.08 m above, 0.27 m behind.
VELO_IN_CAM0 = (0.0, -0.08, -0.27)
#: rotation velodyne axes (x fwd, y left, z up) → camera axes (x right, y down, z fwd).
R_VELO_TO_CAM = LIDAR.matrix


@dataclass(frozen=True)
class Rig:
    """Intrinsics K (3×3) of every camera, P0..P3 (3×4) and the 4×4 extrinsics used by the renderer."""

    K: np.ndarray
    P: dict[str, np.ndarray]
    T_velo_to_cam0: np.ndarray
    T_cam0_to_cam2: np.ndarray

    @property
    def T_velo_to_cam2(self) -> np.ndarray:
        return self.T_cam0_to_cam2 @ self.T_velo_to_cam0


def intrinsics(config: SynthConfig) -> np.ndarray:
    """K of the rendered images: KITTI's (1226×370) scaled to the image size, focal × focal_scale."""
    sx = config.width / KITTI_SIZE[0]
    sy = config.height / KITTI_SIZE[1]
    return np.array(
        [
            [KITTI_FX * sx * config.focal_scale, 0.0, KITTI_CX * sx],
            [0.0, KITTI_FY * sy * config.focal_scale, KITTI_CY * sy],
            [0.0, 0.0, 1.0],
        ]
    )


def make_rig(config: SynthConfig) -> Rig:
    K = intrinsics(config)
    P = {}
    for i, tx in enumerate(CAMERA_X_OFFSETS):
        P[f"P{i}"] = K @ np.hstack([np.eye(3), np.array([[tx], [0.0], [0.0]])])
    Tr = np.eye(4)
    Tr[:3, :3] = R_VELO_TO_CAM
    Tr[:3, 3] = VELO_IN_CAM0
    T02 = np.eye(4)
    T02[0, 3] = CAMERA_X_OFFSETS[2]
    return Rig(K=K, P=P, T_velo_to_cam0=Tr, T_cam0_to_cam2=T02)
