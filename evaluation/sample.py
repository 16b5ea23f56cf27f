"""One scene-flow test sample: two point clouds, ground-truth flow, optional colours, motion mask and pose.

Frames and units (docs/design.md §2): every array is in the camera frame of its own frame (x right, y down,
z forward), in metres. ``flow[i]`` moves ``pc1[i]`` to where that surface point is at time 2, expressed in
camera-2 coordinates, so ``pc1 + flow`` lies on the surface sampled by ``pc2``. ``pose`` is
``T_{1→2}`` (4×4): ``p2 = R p1 + t``; the static (camera-only) flow is ``(R p1 + t) − p1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _as_points(name: str, value: object, dtype: type = np.float32) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be numeric, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=dtype)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values")
    return arr


@dataclass
class SceneFlowSample:
    """A scene-flow pair with ground truth.

    Attributes:
        name: scene identifier (unique within a split; splits are sorted by it).
        pc1: (N, 3) float32, frame-1 points, camera-1 frame, metres.
        pc2: (M, 3) float32, frame-2 points, camera-2 frame, metres (M may differ from N).
        flow: (N, 3) float32, ground-truth flow of pc1, metres (``pc1 + flow`` in camera-2 frame).
        color1: optional (N, 3) float32 RGB of pc1 in [0, 1].
        color2: optional (M, 3) float32 RGB of pc2 in [0, 1].
        moving: optional (N,) bool, True where the pc1 point belongs to an independently moving object.
        pose: optional (4, 4) float64 ``T_{1→2}`` (camera 1 → camera 2).
        classes: optional (N,) int32 semantic class of each pc1 point, 0 = background (anything that is
            not a foreground object class; the three-way EPE's foreground is ``classes != 0``).
        instance: optional (N,) int32 object instance of each pc1 point (the split's own ids).
    """

    name: str
    pc1: np.ndarray
    pc2: np.ndarray
    flow: np.ndarray
    color1: np.ndarray | None = None
    color2: np.ndarray | None = None
    moving: np.ndarray | None = None
    pose: np.ndarray | None = None
    classes: np.ndarray | None = None
    instance: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        self.pc1 = _as_points("pc1", self.pc1)
        self.pc2 = _as_points("pc2", self.pc2)
        self.flow = _as_points("flow", self.flow)
        n, m = len(self.pc1), len(self.pc2)
        if len(self.flow) != n:
            raise ValueError(f"flow has {len(self.flow)} rows but pc1 has {n}")
        for attr, count in (("color1", n), ("color2", m)):
            value = getattr(self, attr)
            if value is None:
                continue
            col = _as_points(attr, value)
            if len(col) != count:
                raise ValueError(f"{attr} has {len(col)} rows, expected {count}")
            if col.size and (col.min() < 0.0 or col.max() > 1.0):
                raise ValueError(f"{attr} must lie in [0, 1], got range [{col.min():g}, {col.max():g}]")
            setattr(self, attr, col)
        if self.moving is not None:
            mov = np.asarray(self.moving)
            if mov.shape != (n,):
                raise ValueError(f"moving must have shape ({n},), got {mov.shape}")
            if mov.dtype != np.bool_:
                if not np.issubdtype(mov.dtype, np.number) or not np.all(np.isin(mov, (0, 1))):
                    raise ValueError("moving must be boolean (or 0/1)")
                mov = mov.astype(bool)
            self.moving = np.ascontiguousarray(mov)
        for attr in ("classes", "instance"):
            value = getattr(self, attr)
            if value is None:
                continue
            arr = np.asarray(value)
            if arr.shape != (n,):
                raise ValueError(f"{attr} must have shape ({n},), got {arr.shape}")
            if arr.dtype.kind not in "biu":
                raise ValueError(f"{attr} must be integer, got dtype {arr.dtype}")
            setattr(self, attr, np.ascontiguousarray(arr, dtype=np.int32))
        if self.pose is not None:
            pose = np.asarray(self.pose, dtype=np.float64)
            if pose.shape != (4, 4):
                raise ValueError(f"pose must have shape (4, 4), got {pose.shape}")
            if not np.all(np.isfinite(pose)):
                raise ValueError("pose contains non-finite values")
            if not np.allclose(pose[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
                raise ValueError(f"pose's last row must be [0, 0, 0, 1], got {pose[3].tolist()}")
            rot = pose[:3, :3]
            if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-3) or np.linalg.det(rot) < 0:
                raise ValueError("pose's rotation block is not a rotation matrix")
            self.pose = pose

    @property
    def foreground(self) -> np.ndarray | None:
        """(N,) bool, True on foreground-class points (``classes != 0``), or None without classes."""
        return None if self.classes is None else self.classes != 0

    @property
    def n1(self) -> int:
        """Number of frame-1 points."""
        return len(self.pc1)

    @property
    def n2(self) -> int:
        """Number of frame-2 points."""
        return len(self.pc2)

    def subset1(self, index: np.ndarray) -> "SceneFlowSample":
        """A copy keeping only the frame-1 points selected by ``index`` (bool mask or integer indices)."""
        return SceneFlowSample(
            name=self.name,
            pc1=self.pc1[index],
            pc2=self.pc2,
            flow=self.flow[index],
            color1=None if self.color1 is None else self.color1[index],
            color2=self.color2,
            moving=None if self.moving is None else self.moving[index],
            pose=self.pose,
            classes=None if self.classes is None else self.classes[index],
            instance=None if self.instance is None else self.instance[index],
        )
