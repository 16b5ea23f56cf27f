"""A KITTI-odometry-layout sequence folder (real KITTI or the synthetic generator's output).

Layout::

    root/sequences/NN/image_0 … image_3/XXXXXX.png   (any subset of the cameras)
    root/sequences/NN/calib.txt                        P0..P3 (as present), Tr (optional)
    root/sequences/NN/times.txt                        optional, one line per frame
    root/sequences/NN/velodyne/XXXXXX.bin              optional
    root/poses/NN.txt                                  optional (KITTI's test sequences 11–21 have none)

**Frame ids index the poses and times files**: the frame id is the number in the image's file name,
and line i (0-based) of ``poses/NN.txt`` / ``times.txt`` belongs to frame id i. A folder may hold a
subset of a sequence's frames (e.g. only 000012–000014.png): it then still needs the sequence's full
poses file, and frame 12 takes line 12.

Pose count check: when the frame ids are exactly 0..N−1 (a complete sequence, the ordinary case) the
poses file must have exactly N lines; otherwise (a subset) it must have a line for every frame id.
``strict_pose_count=False`` applies only the second rule (e.g. frames 0..50 beside the full 06.txt).

**Indices**: ``image_path(i)``, ``read_image(i)``, ``relative_pose(i, j)``, ``velodyne_path(i)`` … take
*positions* ``i`` in ``0 .. len(seq) − 1``; the frame id of position i is ``frames[i]``.

Frames: ``poses_cam0`` are camera-to-world of cam0 (KITTI's convention, world = cam0 at frame 0);
``poses`` are camera-to-world of the chosen camera; ``relative_pose(i, j)`` = ``T_{i→j}`` maps points
of the chosen camera at position i to the same camera at position j (docs/design.md §2).
"""

from __future__ import annotations

import re
from functools import cached_property
from pathlib import Path

import numpy as np

from core.errors import ConfigError, InputError
from core.geometry import camera_offset_from_projection, relative_pose, se3_inverse
from pipeline.kitti._text import PathLike
from pipeline.kitti.calib import OdometryCalib, read_odometry_calib
from pipeline.kitti.images import image_size, read_image
from pipeline.kitti.poses import read_poses, read_times
from pipeline.kitti.velodyne import read_velodyne_bin

CAMERAS = ("image_0", "image_1", "image_2", "image_3")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
_FRAME_RE = re.compile(r"^(\d+)$")


def camera_p_key(camera: str) -> str:
    """'image_k' → 'Pk' (the calib.txt projection of that camera)."""
    if camera not in CAMERAS:
        raise ConfigError(f"unknown camera {camera!r}: expected one of {', '.join(CAMERAS)}")
    return "P" + camera[-1]


def _sequences_dir(root: PathLike) -> Path:
    d = Path(root) / "sequences"
    if not d.is_dir():
        raise InputError(d, "folder not found (expected the KITTI odometry layout root/sequences/NN/)")
    return d


def find_sequences(root: PathLike) -> list[str]:
    """Sequence ids (folder names under root/sequences holding a calib.txt), sorted."""
    return sorted(p.name for p in _sequences_dir(root).iterdir() if p.is_dir() and (p / "calib.txt").is_file())


def _list_frames(folder: Path) -> tuple[list[int], dict[int, Path]]:
    paths: dict[int, Path] = {}
    for p in folder.iterdir():
        m = _FRAME_RE.match(p.stem)
        if not m or p.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        fid = int(m.group(1))
        if fid in paths:
            raise InputError(folder, f"two images for frame {fid}: {paths[fid].name} and {p.name}")
        paths[fid] = p
    if not paths:
        raise InputError(folder, "no images named like 000000.png")
    frames = sorted(paths)
    return frames, paths


class OdometrySequence:
    """One sequence of a KITTI-odometry-layout folder, seen through one camera (default the colour image_2).

    Validated at construction: the sequence and camera folders exist and hold images, calib.txt has the
    camera's projection, the poses file (if any) matches the frames (see the module docstring), and
    times.txt (if any) has a line for every frame id.
    """

    def __init__(
        self, root: PathLike, sequence: str | int, camera: str = "image_2", *, strict_pose_count: bool = True
    ) -> None:
        self.root = Path(root)
        self.sequence = f"{sequence:02d}" if isinstance(sequence, int) else str(sequence)
        self.camera = camera
        self.p_key = camera_p_key(camera)
        self.seq_dir = _sequences_dir(self.root) / self.sequence
        if not self.seq_dir.is_dir():
            raise InputError(self.seq_dir, "sequence folder not found")
        self.image_dir = self.seq_dir / camera
        if not self.image_dir.is_dir():
            raise InputError(self.image_dir, f"camera folder not found (sequence {self.sequence})")
        self.frames, self._paths = _list_frames(self.image_dir)

        self.calib_path = self.seq_dir / "calib.txt"
        self.calib: OdometryCalib = read_odometry_calib(self.calib_path)
        if self.p_key not in self.calib.P:
            raise InputError(self.calib_path, f"missing key {self.p_key!r} (needed for {camera})")
        K = self.calib.P[self.p_key][:, :3]
        if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0 and abs(np.linalg.det(K)) > 0):
            raise InputError(self.calib_path, f"{self.p_key}: not a camera projection (its left 3x3 needs positive "
                                              f"focal lengths and must be invertible), got {K.ravel().tolist()}")

        self.poses_path = self.root / "poses" / f"{self.sequence}.txt"
        self._poses_all = read_poses(self.poses_path) if self.poses_path.is_file() else None
        if self._poses_all is not None:
            self._check_count(self.poses_path, "poses", len(self._poses_all), strict_pose_count)

        self.times_path = self.seq_dir / "times.txt"
        self._times_all = read_times(self.times_path) if self.times_path.is_file() else None
        if self._times_all is not None:
            self._check_count(self.times_path, "timestamps", len(self._times_all), strict=False)

    def _check_count(self, path: Path, what: str, count: int, strict: bool) -> None:
        n, last = len(self.frames), self.frames[-1]
        complete = self.frames[0] == 0 and last == n - 1
        span = f"frames {self.frames[0]}..{last}" if complete else f"frame ids {self.frames[0]}..{last}"
        if strict and complete and count != n:
            raise InputError(path, f"{count} {what} but {n} images in {self.image_dir} ({span}): counts differ "
                             "(--strict_pose_count false accepts a longer file, one line per frame id)")
        if count <= last:
            raise InputError(
                path, f"{count} {what} but {n} images in {self.image_dir} ({span}): no line for frame id {last}"
            )

    # ------------------------------------------------------------------ frames and images

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"OdometrySequence({str(self.root)!r}, {self.sequence!r}, {self.camera!r}, {len(self)} frames)"

    def _check_index(self, i: int) -> int:
        if not 0 <= i < len(self.frames):
            raise IndexError(f"position {i} out of range for {len(self.frames)} frames")
        return self.frames[i]

    def index_of(self, frame_id: int) -> int:
        """Position of frame id ``frame_id``; KeyError if the folder has no such frame."""
        if frame_id not in self._paths:
            raise KeyError(f"frame id {frame_id} not in {self.image_dir}")
        return self.frames.index(frame_id)

    def image_path(self, i: int) -> Path:
        """Path of the image at position i."""
        return self._paths[self._check_index(i)]

    def read_image(self, i: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB image at position i (a gray camera's image replicated to 3 channels)."""
        return read_image(self.image_path(i))

    @cached_property
    def image_size(self) -> tuple[int, int]:
        """(height, width) in pixels, from the first image (KITTI images of a sequence share a size).

        Same order as :func:`pipeline.kitti.images.image_size` and numpy's ``shape``.
        """
        return image_size(self.image_path(0))

    @property
    def image_shape(self) -> tuple[int, int]:
        """Alias of :attr:`image_size`: (height, width)."""
        return self.image_size

    @property
    def height(self) -> int:
        return self.image_shape[0]

    @property
    def width(self) -> int:
        return self.image_shape[1]

    # ------------------------------------------------------------------ calibration

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection of the chosen camera: rectified cam0 coordinates → its pixels."""
        return self.calib.P[self.p_key].copy()

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsics of the chosen camera (left 3×3 of P), pixels."""
        return self.P[:, :3].copy()

    @property
    def T_cam0_to_cam(self) -> np.ndarray:
        """(4, 4) cam0 → chosen camera (a translation; ≈ (+0.06, 0, 0) m for image_2)."""
        return camera_offset_from_projection(self.P)

    @property
    def Tr(self) -> np.ndarray | None:
        """(4, 4) velodyne → cam0 from calib.txt, or None when it has no Tr line."""
        return self.calib.Tr

    @property
    def T_velo_to_cam(self) -> np.ndarray | None:
        """(4, 4) velodyne → chosen camera: ``T_cam0_to_cam · Tr``; None without Tr."""
        return None if self.Tr is None else self.T_cam0_to_cam @ self.Tr

    # ------------------------------------------------------------------ poses and times

    @property
    def has_poses(self) -> bool:
        return self._poses_all is not None

    @property
    def poses_cam0(self) -> np.ndarray | None:
        """(N, 4, 4) camera-to-world of cam0 for the folder's frames (row k ↔ position k), or None."""
        return None if self._poses_all is None else self._poses_all[self.frames]

    @property
    def poses(self) -> np.ndarray | None:
        """(N, 4, 4) camera-to-world of the chosen camera: ``Pose_cam0 · inv(T_cam0_to_cam)``, or None."""
        p = self.poses_cam0
        return None if p is None else p @ se3_inverse(self.T_cam0_to_cam)

    def relative_pose(self, i: int, j: int) -> np.ndarray:
        """(4, 4) ``T_{i→j} = inv(Pose_j) · Pose_i`` of the chosen camera, positions i, j."""
        if self._poses_all is None:
            raise InputError(self.poses_path, "poses file not found: this sequence has no poses")
        fi, fj = self._check_index(i), self._check_index(j)
        off_inv = se3_inverse(self.T_cam0_to_cam)
        return relative_pose(self._poses_all[fi] @ off_inv, self._poses_all[fj] @ off_inv)

    @property
    def times(self) -> np.ndarray | None:
        """(N,) timestamps in seconds of the folder's frames, or None without times.txt."""
        return None if self._times_all is None else self._times_all[self.frames]

    # ------------------------------------------------------------------ velodyne

    @property
    def velodyne_dir(self) -> Path:
        return self.seq_dir / "velodyne"

    def velodyne_path(self, i: int) -> Path:
        """Path of the scan of position i (``velodyne/<image stem>.bin``; may not exist)."""
        return self.velodyne_dir / (self.image_path(i).stem + ".bin")

    def has_velodyne(self, i: int) -> bool:
        return self.velodyne_path(i).is_file()

    def read_velodyne(self, i: int) -> np.ndarray:
        """(M, 4) float32 scan (velodyne frame: x forward, y left, z up, metres; reflectance)."""
        return read_velodyne_bin(self.velodyne_path(i))


__all__ = ["CAMERAS", "OdometrySequence", "camera_p_key", "find_sequences"]
