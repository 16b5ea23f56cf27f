"""Where stage one's frames, depth maps, poses and ground truth come from (docs/design.md §3.1–3.3).

Depth sources (each returns metric-or-net-scale depth at the working size, (N, H, W) float32, 0 = invalid):

* ``net``: the depth net (DispResNet), batched; frames are edge-padded to multiples of 32 and cropped back.
* ``gt``: the dataset's own depth maps, ``sequences/NN/depth_2/<frame>.png`` (KITTI 16-bit depth PNGs;
  the synthetic generator writes them).
* ``lidar``: the frame's Velodyne scan projected into the image (z-buffered, sparse), needs ``Tr``.
* ``disparity``: external disparity PNGs (KITTI 16-bit), ``depth = focal · baseline / disparity``.

Pose sources (``T_{t→t+1}``, (N, 4, 4)): ``net`` (PoseResNet) or ``gt`` (the dataset's poses file).

Working size: images are resized to (W, H) and K is scaled with :func:`core.geometry.scale_intrinsics`.
File-based maps at the native size are resampled by nearest neighbour at native pixel
``(u / sx, v / sy)`` — the pixel that the scaled K puts under working pixel (u, v) — so depth values are
never blended across object edges.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from core.errors import ConfigError, InputError
from core.geometry import project, scale_intrinsics

if TYPE_CHECKING:  # the KITTI readers import OpenCV: loaded when a source first reads a file
    from pipeline.kitti.odometry import OdometrySequence

DEPTH_SOURCES = ("net", "gt", "lidar", "disparity")
POSE_SOURCES = ("net", "gt")
GT_DEPTH_DIR = "depth_2"
GT_FLOW_DIR = "flow3d_2"
NET_MULTIPLE = 32  # the depth net's input sides must be multiples of this


# --------------------------------------------------------------------------- working size and frames


def working_size(native_hw: tuple[int, int], size: tuple[int, int] | None) -> tuple[int, int]:
    """(H, W) at which stage one works: ``size`` given as (W, H), or the native (H, W) when None."""
    if size is None:
        return int(native_hw[0]), int(native_hw[1])
    W, H = int(size[0]), int(size[1])
    if W < 1 or H < 1:
        raise ConfigError(f"working size must be positive, got {W}x{H}")
    return H, W


def working_K(seq: OdometrySequence, hw: tuple[int, int]) -> np.ndarray:
    """(3, 3) float64 intrinsics of ``seq``'s camera at working size hw = (H, W)."""
    H0, W0 = seq.image_shape
    return scale_intrinsics(seq.K.astype(np.float64), hw[1] / W0, hw[0] / H0)


def resize_image(rgb: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """(H0, W0, 3) uint8 → (H, W, 3) uint8 (area averaging when shrinking, bilinear when enlarging)."""
    import cv2

    H, W = hw
    if rgb.shape[:2] == (H, W):
        return np.ascontiguousarray(rgb)
    shrink = H * W < rgb.shape[0] * rgb.shape[1]
    return cv2.resize(rgb, (W, H), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def nearest_resample(values: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """Resample a native-size map (H0, W0, …) to (H, W, …): working pixel (u, v) takes native (u/sx, v/sy) rounded."""
    H, W = hw
    H0, W0 = values.shape[:2]
    if (H0, W0) == (H, W):
        return values
    rows = np.clip(np.rint(np.arange(H) * (H0 / H)), 0, H0 - 1).astype(np.int64)
    cols = np.clip(np.rint(np.arange(W) * (W0 / W)), 0, W0 - 1).astype(np.int64)
    return values[rows][:, cols]


def read_frames(seq: OdometrySequence, positions: list[int], hw: tuple[int, int]) -> np.ndarray:
    """(N, H, W, 3) uint8 RGB frames at the working size; a frame of another size than the first → InputError."""
    out = np.empty((len(positions), hw[0], hw[1], 3), dtype=np.uint8)
    for k, i in enumerate(positions):
        rgb = seq.read_image(i)
        if rgb.shape[:2] != seq.image_shape:
            raise InputError(seq.image_path(i), f"size {rgb.shape[1]}x{rgb.shape[0]} differs from the sequence's "
                             f"{seq.image_shape[1]}x{seq.image_shape[0]}")
        out[k] = resize_image(rgb, hw)
    return out


# --------------------------------------------------------------------------- depth sources


class DepthSource(Protocol):
    """Depth of frames at the working size: (N, H, W) float32, metres or the net's scale, 0 = invalid."""

    name: str

    def depths(self, seq: OdometrySequence, positions: list[int], images: np.ndarray, K: np.ndarray) -> np.ndarray:
        ...


def pad_to_multiple(images: np.ndarray, multiple: int = NET_MULTIPLE) -> np.ndarray:
    """Edge-pad (N, H, W, 3) at the bottom and right so H and W are multiples of ``multiple``."""
    H, W = images.shape[1:3]
    ph, pw = (-H) % multiple, (-W) % multiple
    if not (ph or pw):
        return images
    return np.pad(images, ((0, 0), (0, ph), (0, pw), (0, 0)), mode="edge")


class NetDepth:
    """Depth net source: ``runner.depth`` on edge-padded frames, cropped back to (H, W)."""

    name = "net"

    def __init__(self, runner: Any) -> None:
        self.runner = runner

    def depths(self, seq: OdometrySequence, positions: list[int], images: np.ndarray, K: np.ndarray) -> np.ndarray:
        H, W = images.shape[1:3]
        out = self.runner.depth(pad_to_multiple(images))
        return np.ascontiguousarray(out[:, :H, :W], dtype=np.float32)


def _frame_file(seq: OdometrySequence, i: int, folder: Path) -> Path:
    return folder / (seq.image_path(i).stem + ".png")


def _checked_map(path: Path, values: np.ndarray, seq: OdometrySequence) -> np.ndarray:
    if values.shape != seq.image_shape:
        raise InputError(path, f"size {values.shape[1]}x{values.shape[0]} differs from the images' "
                         f"{seq.image_shape[1]}x{seq.image_shape[0]}")
    return values


class GroundTruthDepth:
    """The dataset's own depth maps: ``sequences/NN/depth_2/<frame>.png`` (metres, KITTI depth PNG)."""

    name = "gt"

    def __init__(self, folder: str = GT_DEPTH_DIR) -> None:
        self.folder = folder

    def depths(self, seq: OdometrySequence, positions: list[int], images: np.ndarray, K: np.ndarray) -> np.ndarray:
        from pipeline.kitti.png16 import read_depth_png

        hw = images.shape[1:3]
        out = np.empty((len(positions),) + tuple(hw), dtype=np.float32)
        for k, i in enumerate(positions):
            path = _frame_file(seq, i, seq.seq_dir / self.folder)
            out[k] = nearest_resample(_checked_map(path, read_depth_png(path), seq), hw)
        return out


def project_lidar(scan: np.ndarray, T_velo_to_cam: np.ndarray, K: np.ndarray, hw: tuple[int, int],
                  min_depth: float = 0.1) -> np.ndarray:
    """Sparse depth (H, W) float32 of a Velodyne scan (M, ≥3; x forward, y left, z up) seen by camera K.

    Points are moved into the camera frame, those with z > min_depth projected and rounded to the nearest
    pixel; where several land on one pixel the nearest wins. 0 = no return.
    """
    from pipeline.filters import transform_columns

    H, W = hw
    x, y, z = transform_columns(T_velo_to_cam, scan[:, :3])
    front = z > min_depth
    uv, z = project(np.stack([x[front], y[front], z[front]], axis=-1), np.asarray(K, dtype=np.float64))
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u, v, z = u[ok], v[ok], z[ok]
    order = np.argsort(-z, kind="stable")  # far first, so the nearest return is written last
    depth = np.zeros(H * W, dtype=np.float32)
    depth[(v * W + u)[order]] = z[order]
    return depth.reshape(H, W)


def velo_to_cam(seq: OdometrySequence) -> np.ndarray:
    """(4, 4) velodyne → ``seq``'s camera; InputError naming calib.txt when it has no ``Tr``."""
    T = seq.T_velo_to_cam
    if T is None:
        raise InputError(seq.calib_path, "no 'Tr' line: cannot project Velodyne scans into the camera")
    return T


class LidarDepth:
    """Projected LiDAR depth (sparse, metric) from ``sequences/NN/velodyne/<frame>.bin`` and calib ``Tr``."""

    name = "lidar"

    def depths(self, seq: OdometrySequence, positions: list[int], images: np.ndarray, K: np.ndarray) -> np.ndarray:
        hw = images.shape[1:3]
        T = velo_to_cam(seq)
        return np.stack([project_lidar(seq.read_velodyne(i), T, K, hw) for i in positions]).astype(np.float32)


class DisparityDepth:
    """External disparity PNGs: ``folder/<frame>.png`` (KITTI 16-bit, pixels at the images' native size).

    ``folder`` may contain ``{seq}``, replaced by the sequence id; default ``sequences/NN/disp_2``.
    ``depth = focal · baseline / disparity`` with ``focal`` in native pixels (default: the camera's fx)
    and ``baseline`` in metres (KITTI: 0.54).
    """

    name = "disparity"

    def __init__(self, folder: str | None = None, focal: float | None = None, baseline: float = 0.54) -> None:
        if baseline <= 0:
            raise ConfigError(f"disparity baseline must be positive metres, got {baseline}")
        if focal is not None and focal <= 0:
            raise ConfigError(f"disparity focal length must be positive pixels, got {focal}")
        self.folder = folder
        self.focal = focal
        self.baseline = baseline

    def directory(self, seq: OdometrySequence) -> Path:
        if not self.folder:
            return seq.seq_dir / "disp_2"
        return Path(self.folder.replace("{seq}", seq.sequence))

    def depths(self, seq: OdometrySequence, positions: list[int], images: np.ndarray, K: np.ndarray) -> np.ndarray:
        from pipeline.kitti.png16 import disparity_to_depth, read_disparity_png

        hw = images.shape[1:3]
        focal = float(seq.K[0, 0]) if self.focal is None else float(self.focal)
        folder = self.directory(seq)
        out = np.empty((len(positions),) + tuple(hw), dtype=np.float32)
        for k, i in enumerate(positions):
            path = _frame_file(seq, i, folder)
            disp = _checked_map(path, read_disparity_png(path), seq)
            out[k] = nearest_resample(disparity_to_depth(disp, focal, self.baseline), hw)
        return out


# --------------------------------------------------------------------------- pose sources


class PoseSource(Protocol):
    """``T_{t→t+1}`` (N, 4, 4) float64 for the pairs (positions[k], positions[k] + 1)."""

    name: str

    def poses(self, seq: OdometrySequence, pairs: list[tuple[int, int]], images_t: np.ndarray,
              images_t1: np.ndarray) -> np.ndarray:
        ...


class NetPose:
    """Pose net source: ``runner.pose(img_t, img_t1)`` (translation in the depth net's scale)."""

    name = "net"

    def __init__(self, runner: Any) -> None:
        self.runner = runner

    def poses(self, seq: OdometrySequence, pairs: list[tuple[int, int]], images_t: np.ndarray,
              images_t1: np.ndarray) -> np.ndarray:
        return np.asarray(self.runner.pose(images_t, images_t1), dtype=np.float64)


class DatasetPose:
    """The dataset's poses file: ``T_{t→t+1} = inv(Pose_{t+1}) · Pose_t`` of the chosen camera (metric)."""

    name = "gt"

    def poses(self, seq: OdometrySequence, pairs: list[tuple[int, int]], images_t: np.ndarray,
              images_t1: np.ndarray) -> np.ndarray:
        return np.stack([seq.relative_pose(i, j) for i, j in pairs]).astype(np.float64)


# --------------------------------------------------------------------------- ground truth of the synthetic world


@dataclass
class GroundTruthFlow:
    """Per-pixel ground truth of frame t at the working size (synthetic world, ``flow3d_2/<frame>.npz``).

    flow (H, W, 3) float32: point at t+1 in camera-(t+1) coordinates minus point at t in camera-t
    coordinates (metres); moving (H, W) bool; valid (H, W) bool; visible_next (H, W) bool.
    """

    flow: np.ndarray
    moving: np.ndarray
    valid: np.ndarray
    visible_next: np.ndarray


def gt_flow_path(seq: OdometrySequence, i: int) -> Path:
    return seq.seq_dir / GT_FLOW_DIR / (seq.image_path(i).stem + ".npz")


def has_gt_flow(seq: OdometrySequence) -> bool:
    """True when the sequence has a ground-truth scene-flow folder."""
    return (seq.seq_dir / GT_FLOW_DIR).is_dir()


def read_gt_flow(seq: OdometrySequence, i: int, hw: tuple[int, int], visible_next: bool = True) -> GroundTruthFlow:
    """Ground truth of the pair starting at position i, resampled (nearest) to hw = (H, W).

    ``visible_next=False`` skips decoding that mask (stage one does not use it); it is then all False.
    """
    path = gt_flow_path(seq, i)
    if not path.is_file():
        raise InputError(path, "file not found (ground-truth scene flow)")
    keys = ("flow", "moving", "valid", "visible_next") if visible_next else ("flow", "moving", "valid")
    try:
        with np.load(path) as npz:
            arrays = {k: np.asarray(npz[k]) for k in keys}
    except KeyError as exc:
        raise InputError(path, f"missing array {exc.args[0]!r}") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # a truncated file is a BadZipFile
        raise InputError(path, f"not a readable .npz ({type(exc).__name__}: {exc})") from None
    H0, W0 = seq.image_shape
    if arrays["flow"].shape != (H0, W0, 3):
        raise InputError(path, f"flow has shape {arrays['flow'].shape}, expected {(H0, W0, 3)}")
    for key in keys[1:]:
        if arrays[key].shape != (H0, W0):
            raise InputError(path, f"{key} has shape {arrays[key].shape}, expected {(H0, W0)}")
    r = {k: nearest_resample(v, hw) for k, v in arrays.items()}
    vis = r["visible_next"].astype(bool) if visible_next else np.zeros(r["valid"].shape, dtype=bool)
    return GroundTruthFlow(flow=r["flow"].astype(np.float32), moving=r["moving"].astype(bool),
                           valid=r["valid"].astype(bool), visible_next=vis)


# --------------------------------------------------------------------------- nets


@dataclass
class NetSpec:
    """What a worker needs to build the nets itself (picklable): checkpoints or a seeded random init."""

    depth_checkpoint: str | None = None
    pose_checkpoint: str | None = None
    need_depth: bool = False
    need_pose: bool = False
    random_init: bool = False
    seed: int = 0
    resnet_layers: int = 18
    device: str = "auto"
    amp: bool = False
    batch_size: int = 8


def build_runner(spec: NetSpec):
    """A :class:`pipeline.nets.DepthPoseRunner` with the nets ``spec`` asks for, or None if it asks for none.

    A missing checkpoint is a :class:`ConfigError` unless ``random_init`` (seeded, for tests and benchmarks).
    """
    if not (spec.need_depth or spec.need_pose):
        return None
    wanted = (("depth", spec.need_depth, spec.depth_checkpoint), ("pose", spec.need_pose, spec.pose_checkpoint))
    for kind, need, ckpt in wanted:
        if need and not ckpt and not spec.random_init:
            raise ConfigError(f"{kind} source 'net' needs --{kind}_checkpoint (or --random_init true for tests)")
    import torch

    from pipeline.nets import DepthPoseRunner, DispResNet, PoseResNet, load_depth_net, load_pose_net

    def make(kind: str, ckpt: str | None, cls, loader, offset: int):
        if ckpt:
            return loader(ckpt, resnet_layers=None)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(spec.seed + offset)
            return cls(spec.resnet_layers)

    depth_net = make("depth", spec.depth_checkpoint, DispResNet, load_depth_net, 0) if spec.need_depth else None
    pose_net = make("pose", spec.pose_checkpoint, PoseResNet, load_pose_net, 1) if spec.need_pose else None
    return DepthPoseRunner(depth_net, pose_net, device=spec.device, amp=spec.amp, batch_size=spec.batch_size)


def make_depth_source(name: str, runner: Any = None, *, disparity_dir: str | None = None,
                      disparity_focal: float | None = None, disparity_baseline: float = 0.54) -> DepthSource:
    """The depth source called ``name`` (one of :data:`DEPTH_SOURCES`)."""
    if name == "net":
        if runner is None or runner.depth_net is None:
            raise ConfigError("depth source 'net' needs a depth net")
        return NetDepth(runner)
    if name == "gt":
        return GroundTruthDepth()
    if name == "lidar":
        return LidarDepth()
    if name == "disparity":
        return DisparityDepth(disparity_dir, disparity_focal, disparity_baseline)
    raise ConfigError(f"depth source must be one of {', '.join(DEPTH_SOURCES)}, got {name!r}")


def make_pose_source(name: str, runner: Any = None) -> PoseSource:
    """The pose source called ``name`` (one of :data:`POSE_SOURCES`)."""
    if name == "net":
        if runner is None or runner.pose_net is None:
            raise ConfigError("pose source 'net' needs a pose net")
        return NetPose(runner)
    if name == "gt":
        return DatasetPose()
    raise ConfigError(f"pose source must be one of {', '.join(POSE_SOURCES)}, got {name!r}")


__all__ = [
    "DEPTH_SOURCES",
    "DatasetPose",
    "DepthSource",
    "DisparityDepth",
    "GroundTruthDepth",
    "GroundTruthFlow",
    "LidarDepth",
    "NetDepth",
    "NetPose",
    "NetSpec",
    "POSE_SOURCES",
    "PoseSource",
    "build_runner",
    "has_gt_flow",
    "make_depth_source",
    "make_pose_source",
    "nearest_resample",
    "pad_to_multiple",
    "project_lidar",
    "read_frames",
    "read_gt_flow",
    "resize_image",
    "velo_to_cam",
    "working_K",
    "working_size",
]
