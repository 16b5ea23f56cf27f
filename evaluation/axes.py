"""Axis conventions of the public scene-flow test sets, and their conversion to our camera frame.

Our camera frame (docs/design.md §2): x right, y down, z forward, metres.

* LiDAR-like axes (FlowNet3D ``kitti_rm_ground``; OpenSceneFlow / Argoverse-2 ego frame): x forward,
  y left, z up. Camera = ``(−y, −z, x)``: ``cam_x = −y``, ``cam_y = −z``, ``cam_z = x``.
* HPLFlowNet ``KITTI_processed_occ_final``: stored = ``(−x, −y, z)`` of the camera (its ``pixel2xyz``
  negates x and y), so camera = ``(−x_s, −y_s, z_s)``; stored y is up, stored z is depth.

Both conversions are proper rotations (det +1), so they apply unchanged to points and to flow vectors,
and a rigid transform ``T`` in the source axes becomes ``A T Aᵀ`` in camera axes.
"""

from __future__ import annotations

import numpy as np

#: camera = LIDAR_TO_CAMERA @ lidar
LIDAR_TO_CAMERA = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
#: camera = HPL_TO_CAMERA @ hpl_stored
HPL_TO_CAMERA = np.diag([-1.0, -1.0, 1.0])


def rotate_vectors(rot: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``rot @ v`` for each row ``v`` of (N, 3) ``vectors``; keeps the input's float dtype."""
    vectors = np.asarray(vectors)
    out = vectors @ rot.T.astype(vectors.dtype if vectors.dtype.kind == "f" else np.float64)
    return np.ascontiguousarray(out)


def lidar_to_camera(vectors: np.ndarray) -> np.ndarray:
    """(N, 3) points or flow vectors in LiDAR-like axes (x fwd, y left, z up) → camera axes."""
    return rotate_vectors(LIDAR_TO_CAMERA, vectors)


def hpl_to_camera(vectors: np.ndarray) -> np.ndarray:
    """(N, 3) points or flow vectors in HPLFlowNet's stored axes (−x, −y, z of the camera) → camera axes."""
    return rotate_vectors(HPL_TO_CAMERA, vectors)


def conjugate_pose(axes: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """A 4×4 rigid transform expressed in source axes → the same motion in target axes (``A T Aᵀ``)."""
    a4 = np.eye(4)
    a4[:3, :3] = axes
    return a4 @ np.asarray(pose, dtype=np.float64) @ a4.T
