"""Axis conventions of the scene-flow file formats, stated once, and their conversion to our camera frame.

Our camera frame (docs/design.md §2): x right, y down, z forward, metres. Every other frame a file may
store is a signed permutation of it, so each convention is one proper rotation ``A`` (det +1) with
``camera = A @ stored``:

* :data:`LIDAR` — LiDAR-like axes, x forward, y left, z up (the velodyne of KITTI and of our synthetic
  rig; FlowNet3D's ``kitti_rm_ground``; OpenSceneFlow / Argoverse-2's ego frame). Camera = ``(−y, −z, x)``,
  stored = ``(cam_z, −cam_x, −cam_y)``.
* :data:`HPLFLOWNET` — HPLFlowNet's ``KITTI_processed_occ_final``: stored = ``(−x, −y, z)`` of the camera
  (its ``pixel2xyz`` negates x and y), so stored y is up and stored z is depth; its own inverse.

:data:`FORMAT_AXES` says which convention each scene-flow format's files use; the synthetic writer
(:mod:`pipeline.synth.sceneflow_export`) and the evaluation readers (:mod:`evaluation.readers`) both take
it from here. A rotation applies unchanged to points and to flow vectors, and a rigid transform ``T`` in
the stored axes is ``A T Aᵀ`` in camera axes (:meth:`Axes.pose_to_camera`).

Conversions permute and negate columns (no arithmetic), so they are exact and keep the input's float dtype.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class Axes:
    """One axis convention: ``camera = matrix @ stored`` for a signed-permutation rotation ``matrix``.

    Attributes:
        name: short name (``"lidar"``, ``"hplflownet"``).
        matrix: (3, 3) rotation, stored axes → camera axes (read-only).
        description: the stored axes in words.
    """

    name: str
    matrix: np.ndarray
    description: str
    _perm: tuple[int, ...] = field(init=False, repr=False)
    _sign: tuple[float, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        m = np.array(self.matrix, dtype=np.float64)
        if m.shape != (3, 3) or not np.allclose(np.abs(m).sum(axis=1), 1) or round(np.linalg.det(m)) != 1:
            raise ValueError(f"axes {self.name!r}: matrix must be a signed permutation with det +1, got {m.tolist()}")
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)
        perm = tuple(int(np.argmax(np.abs(row))) for row in m)
        object.__setattr__(self, "_perm", perm)
        object.__setattr__(self, "_sign", tuple(float(m[i, j]) for i, j in enumerate(perm)))

    @staticmethod
    def _apply(perm: tuple[int, ...], sign: tuple[float, ...], vectors: np.ndarray) -> np.ndarray:
        v = np.asarray(vectors)
        if v.dtype.kind != "f":
            v = v.astype(np.float64)
        return np.stack([v[..., j] if s > 0 else -v[..., j] for j, s in zip(perm, sign)], axis=-1)

    def to_camera(self, vectors: np.ndarray) -> np.ndarray:
        """(..., 3) points or flow vectors in these axes → camera axes (metres unchanged)."""
        return self._apply(self._perm, self._sign, vectors)

    def from_camera(self, vectors: np.ndarray) -> np.ndarray:
        """(..., 3) points or flow vectors in camera axes → these axes (the inverse of :meth:`to_camera`)."""
        inv = np.argsort(self._perm)
        return self._apply(tuple(int(j) for j in inv), tuple(self._sign[j] for j in inv), vectors)

    def pose_to_camera(self, pose: np.ndarray) -> np.ndarray:
        """A 4×4 rigid transform expressed in these axes → the same motion in camera axes (``A T Aᵀ``)."""
        a4 = np.eye(4)
        a4[:3, :3] = self.matrix
        return a4 @ np.asarray(pose, dtype=np.float64) @ a4.T


#: x forward, y left, z up: camera = (−y, −z, x).
LIDAR = Axes("lidar", np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]),
             "x forward, y left, z up (LiDAR / ego frame)")
#: stored = (−x, −y, z) of the camera: camera = (−x_s, −y_s, z_s).
HPLFLOWNET = Axes("hplflownet", np.diag([-1.0, -1.0, 1.0]),
                  "(−x, −y, z) of the camera: x left, y up, z forward")

#: The axes each scene-flow format stores its points and flow in.
FORMAT_AXES: dict[str, Axes] = {"flownet3d": LIDAR, "hplflownet": HPLFLOWNET, "opensceneflow": LIDAR}
