"""KITTI calibration files: odometry ``calib.txt``, object-benchmark ``calib/XXXXXX.txt``, raw ``calib_*.txt``.

Frames: ``P_k`` (3×4) projects *rectified cam0* coordinates to pixels of camera k (image_k), so
``P_k = K_k [I | t_k]`` with ``t_k`` the offset of camera k from cam0 (metres). ``Tr`` maps velodyne
coordinates (x forward, y left, z up, metres) to (rectified, for odometry) cam0 coordinates
(x right, y down, z forward).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import InputError
from core.geometry import to_homogeneous_3x4
from pipeline.kitti._text import (
    PathLike,
    format_row,
    get_matrix,
    parse_floats,
    read_key_values,
    read_text,
    split_key,
    write_text,
)

P_KEYS = ("P0", "P1", "P2", "P3")


# --------------------------------------------------------------------------- odometry


@dataclass
class OdometryCalib:
    """Contents of a KITTI odometry ``calib.txt``.

    ``P``: {'P0'..'P3' as present: (3, 4) float64}, rectified cam0 → pixels of image_k.
    ``Tr``: (4, 4) float64 velodyne → rectified cam0, or None when the file has no ``Tr`` line.
    """

    P: dict[str, np.ndarray]
    Tr: np.ndarray | None = None
    path: Path | None = None


def read_odometry_calib(path: PathLike) -> OdometryCalib:
    """Read an odometry ``calib.txt``.

    Accepts ``P0: …`` / ``Tr: …`` lines (12 numbers each, row-major 3×4) and key-less lines of 12
    numbers, which are P0, P1, … in the order they appear (the 2-line form some copies use);
    '#' comment lines and blank lines are skipped, other keys are ignored. At least one P is needed.
    """
    P: dict[str, np.ndarray] = {}
    Tr: np.ndarray | None = None
    n_keyless = 0
    for lineno, raw in enumerate(read_text(path).splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, tokens = split_key(line)
        if key is None:
            key = f"P{n_keyless}"
            n_keyless += 1
            if key not in P_KEYS:
                raise InputError(path, f"line {lineno}: more than {len(P_KEYS)} key-less projection lines")
        if key not in P_KEYS and key != "Tr":
            continue
        if key in P or (key == "Tr" and Tr is not None):
            raise InputError(path, f"line {lineno}: key {key!r} appears twice")
        if len(tokens) != 12:
            raise InputError(path, f"line {lineno}: key {key!r}: expected 12 numbers, got {len(tokens)}")
        M = parse_floats(path, tokens, f"line {lineno}: key {key!r}").reshape(3, 4)
        if key == "Tr":
            Tr = to_homogeneous_3x4(M)
        else:
            P[key] = M
    if not P:
        raise InputError(path, "missing key 'P0' (no projection matrix P0..P3 found)")
    return OdometryCalib(P=dict(sorted(P.items())), Tr=Tr, path=Path(path))


def write_odometry_calib(path: PathLike, P: dict[str, np.ndarray], Tr: np.ndarray | None = None) -> None:
    """Write an odometry ``calib.txt`` in KITTI's text format.

    One line per key, ``"P0: v1 … v12"`` with every value as ``%.12e``, P keys in order, then
    ``Tr`` (3×4 or 4×4, written as its top 3×4) when given.
    """
    lines = []
    for key in sorted(P):
        if key not in P_KEYS:
            raise ValueError(f"projection key must be one of {P_KEYS}, got {key!r}")
        M = np.asarray(P[key], dtype=np.float64)
        if M.shape != (3, 4):
            raise ValueError(f"{key} must be 3x4, got shape {M.shape}")
        lines.append(f"{key}: {format_row(M)}")
    if Tr is not None:
        T = np.asarray(Tr, dtype=np.float64)
        if T.shape not in ((3, 4), (4, 4)):
            raise ValueError(f"Tr must be 3x4 or 4x4, got shape {T.shape}")
        lines.append(f"Tr: {format_row(T[:3])}")
    write_text(path, "\n".join(lines) + "\n")


# --------------------------------------------------------------------------- object benchmark

_OBJECT_ALIASES = {"R_rect": "R0_rect", "Tr_velo_cam": "Tr_velo_to_cam", "Tr_imu_velo": "Tr_imu_to_velo"}


@dataclass
class ObjectCalib:
    """KITTI object-benchmark calibration (also the tracking benchmark's, whose key names differ).

    ``P``: {'P0'..'P3': (3, 4)} rectified cam0 → pixels; ``R0_rect`` (3, 3): unrectified cam0 →
    rectified cam0; ``Tr_velo_to_cam`` (3, 4): velodyne → unrectified cam0; ``Tr_imu_to_velo``
    (3, 4) or None.
    """

    P: dict[str, np.ndarray]
    R0_rect: np.ndarray
    Tr_velo_to_cam: np.ndarray
    Tr_imu_to_velo: np.ndarray | None = None
    path: Path | None = None

    def velo_to_cam_rect(self) -> np.ndarray:
        """4×4 velodyne → rectified cam0: ``R0_rect · Tr_velo_to_cam`` (both padded to 4×4)."""
        R0 = np.eye(4)
        R0[:3, :3] = self.R0_rect
        return R0 @ to_homogeneous_3x4(self.Tr_velo_to_cam)

    def velo_to_image(self, camera: int = 2) -> np.ndarray:
        """3×4 velodyne → homogeneous pixels of image_k: ``P_k · R0_rect · Tr_velo_to_cam``."""
        return self.P[f"P{camera}"] @ self.velo_to_cam_rect()


def read_object_calib(path: PathLike) -> ObjectCalib:
    """Read an object-benchmark calib (keys P0..P3, R0_rect, Tr_velo_to_cam, optional Tr_imu_to_velo).

    Tracking-benchmark names (R_rect, Tr_velo_cam, Tr_imu_velo, no colon) are accepted too.
    """
    table = {_OBJECT_ALIASES.get(k, k): v for k, v in read_key_values(path).items()}
    P = {k: get_matrix(path, table, k, (3, 4)) for k in P_KEYS}
    R0 = get_matrix(path, table, "R0_rect", (3, 3))
    Tr = get_matrix(path, table, "Tr_velo_to_cam", (3, 4))
    imu = get_matrix(path, table, "Tr_imu_to_velo", (3, 4)) if "Tr_imu_to_velo" in table else None
    return ObjectCalib(P=P, R0_rect=R0, Tr_velo_to_cam=Tr, Tr_imu_to_velo=imu, path=Path(path))


# --------------------------------------------------------------------------- raw recordings

_RAW_FIELDS: dict[str, tuple[int, ...]] = {
    "S": (2,),
    "K": (3, 3),
    "D": (5,),
    "R": (3, 3),
    "T": (3,),
    "S_rect": (2,),
    "R_rect": (3, 3),
    "P_rect": (3, 4),
}


@dataclass
class RawCamToCam:
    """KITTI raw ``calib_cam_to_cam.txt``; every dict is keyed by camera id '00'..'03'.

    ``S``/``S_rect``: (2,) image size (width, height) in pixels before / after rectification;
    ``K`` (3, 3), ``D`` (5,): unrectified intrinsics and distortion; ``R`` (3, 3), ``T`` (3,) metres:
    cam00 → camera xx (unrectified); ``R_rect`` (3, 3): unrectified → rectified camera xx;
    ``P_rect`` (3, 4): rectified cam00 → pixels of rectified camera xx.
    """

    S: dict[str, np.ndarray]
    K: dict[str, np.ndarray]
    D: dict[str, np.ndarray]
    R: dict[str, np.ndarray]
    T: dict[str, np.ndarray]
    S_rect: dict[str, np.ndarray]
    R_rect: dict[str, np.ndarray]
    P_rect: dict[str, np.ndarray]
    calib_time: str | None = None
    corner_dist: float | None = None
    path: Path | None = None

    @property
    def cameras(self) -> list[str]:
        """Camera ids present, e.g. ['00', '01', '02', '03']."""
        return sorted(self.P_rect)

    def velo_to_cam_rect(self, T_velo_to_cam: np.ndarray) -> np.ndarray:
        """4×4 velodyne → rectified cam00: ``R_rect_00 · T_velo_to_cam`` (from :func:`read_raw_velo_to_cam`)."""
        R0 = np.eye(4)
        R0[:3, :3] = self.R_rect["00"]
        return R0 @ np.asarray(T_velo_to_cam, dtype=np.float64)


def read_raw_cam_to_cam(path: PathLike) -> RawCamToCam:
    """Read a raw ``calib_cam_to_cam.txt``: per camera S, K, D, R, T, S_rect, R_rect, P_rect (all required)."""
    table = read_key_values(path)
    cams = sorted(m.group(1) for k in table if (m := re.fullmatch(r"P_rect_(\d\d)", k)))
    if not cams:
        raise InputError(path, "missing key 'P_rect_00' (no camera found)")
    if "00" not in cams:
        raise InputError(path, "missing key 'P_rect_00' (the reference camera)")
    fields: dict[str, dict[str, np.ndarray]] = {name: {} for name in _RAW_FIELDS}
    for cam in cams:
        for name, shape in _RAW_FIELDS.items():
            fields[name][cam] = get_matrix(path, table, f"{name}_{cam}", shape)
    corner = None
    if "corner_dist" in table:
        corner = float(get_matrix(path, table, "corner_dist", (1,))[0])
    time = " ".join(table["calib_time"]) if "calib_time" in table else None
    return RawCamToCam(**fields, calib_time=time, corner_dist=corner, path=Path(path))


def read_raw_rigid(path: PathLike) -> np.ndarray:
    """4×4 float64 ``[R | T]`` from a raw rigid calibration (``R:`` 9 numbers, ``T:`` 3 numbers, metres)."""
    table = read_key_values(path)
    M = np.eye(4)
    M[:3, :3] = get_matrix(path, table, "R", (3, 3))
    M[:3, 3] = get_matrix(path, table, "T", (3,))
    return M


def read_raw_velo_to_cam(path: PathLike) -> np.ndarray:
    """4×4 velodyne → unrectified cam00 from a raw ``calib_velo_to_cam.txt``."""
    return read_raw_rigid(path)


def read_raw_imu_to_velo(path: PathLike) -> np.ndarray:
    """4×4 IMU/GPS → velodyne from a raw ``calib_imu_to_velo.txt``."""
    return read_raw_rigid(path)


__all__ = [
    "ObjectCalib",
    "OdometryCalib",
    "RawCamToCam",
    "read_object_calib",
    "read_odometry_calib",
    "read_raw_cam_to_cam",
    "read_raw_imu_to_velo",
    "read_raw_rigid",
    "read_raw_velo_to_cam",
    "write_odometry_calib",
]
