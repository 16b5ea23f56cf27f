"""KITTI Velodyne scans: ``.bin`` files of little-endian float32 (x, y, z, reflectance) records.

Coordinates are the velodyne frame: x forward, y left, z up, metres; reflectance in [0, 1].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.errors import InputError
from pipeline.kitti._text import PathLike

RECORD_BYTES = 16  # 4 × float32


def read_velodyne_bin(path: PathLike) -> np.ndarray:
    """(N, 4) float32 points (x, y, z, reflectance); a size that is not a multiple of 16 bytes → InputError."""
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "file not found" if not p.exists() else "not a file")
    size = p.stat().st_size
    if size % RECORD_BYTES:
        raise InputError(
            p, f"size {size} bytes is not a multiple of {RECORD_BYTES} (x, y, z, reflectance float32): truncated?"
        )
    try:
        data = np.fromfile(p, dtype="<f4")
    except OSError as exc:
        raise InputError(p, f"cannot read ({exc})") from None
    return data.reshape(-1, 4).astype(np.float32, copy=False)


def write_velodyne_bin(path: PathLike, points: np.ndarray) -> None:
    """Write (N, 4) points (x, y, z, reflectance), or (N, 3) with reflectance 0, as KITTI ``.bin``."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] not in (3, 4):
        raise ValueError(f"points must be (N, 3) or (N, 4), got shape {pts.shape}")
    if pts.shape[1] == 3:
        pts = np.concatenate([pts, np.zeros((len(pts), 1), dtype=pts.dtype)], axis=1)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    np.ascontiguousarray(pts, dtype="<f4").tofile(p)


__all__ = ["read_velodyne_bin", "write_velodyne_bin"]
