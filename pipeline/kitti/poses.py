"""KITTI odometry ``poses/XX.txt`` and ``times.txt``.

A poses file holds one camera-to-world pose per line (3×4 row-major, 12 numbers; for KITTI odometry the
camera is cam0 and the world is cam0 at frame 0); line i (0-based) is frame i. ``times.txt`` holds one
timestamp per line, seconds since the first frame.
"""

from __future__ import annotations

import numpy as np

from core.errors import InputError
from core.geometry import to_homogeneous_3x4
from pipeline.kitti._text import PathLike, format_row, parse_floats, read_text, write_text

ORTHONORMAL_TOL = 1e-3  # KITTI writes 7 significant digits; a rotation off by more than this is not one


def read_poses(path: PathLike) -> np.ndarray:
    """(N, 4, 4) float64 camera-to-world poses; blank lines are skipped.

    A line without exactly 12 numbers, a non-number, a rotation block that is not orthonormal or an
    empty file raises InputError naming the file and the 1-based line.
    """
    rows = []
    for lineno, raw in enumerate(read_text(path).splitlines(), start=1):
        tokens = raw.split()
        if not tokens:
            continue
        if len(tokens) != 12:
            raise InputError(path, f"line {lineno}: expected 12 numbers (a 3x4 pose), got {len(tokens)}")
        M = parse_floats(path, tokens, f"line {lineno}").reshape(3, 4)
        R = M[:, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=ORTHONORMAL_TOL):
            raise InputError(path, f"line {lineno}: the 3x3 rotation block is not orthonormal")
        rows.append(M)
    if not rows:
        raise InputError(path, "contains no poses")
    return to_homogeneous_3x4(np.stack(rows))


def write_poses(path: PathLike, poses: np.ndarray) -> None:
    """Write (N, 4, 4) or (N, 3, 4) poses as KITTI lines: the top 3×4, row-major, 12 × ``%.12e``."""
    P = np.asarray(poses, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] not in ((4, 4), (3, 4)):
        raise ValueError(f"poses must be (N, 4, 4) or (N, 3, 4), got shape {P.shape}")
    write_text(path, "".join(format_row(M[:3]) + "\n" for M in P))


def read_times(path: PathLike) -> np.ndarray:
    """(N,) float64 timestamps in seconds, one per line; blank lines skipped."""
    values = []
    for lineno, raw in enumerate(read_text(path).splitlines(), start=1):
        tokens = raw.split()
        if not tokens:
            continue
        if len(tokens) != 1:
            raise InputError(path, f"line {lineno}: expected 1 number (a timestamp), got {len(tokens)}")
        values.append(parse_floats(path, tokens, f"line {lineno}")[0])
    if not values:
        raise InputError(path, "contains no timestamps")
    return np.asarray(values, dtype=np.float64)


def write_times(path: PathLike, times: np.ndarray, fmt: str = "%.6e") -> None:
    """Write (N,) timestamps (seconds), one per line, as KITTI does (``%.6e``, e.g. ``1.044989e-01``)."""
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1:
        raise ValueError(f"times must be 1-D, got shape {t.shape}")
    write_text(path, "".join(fmt % v + "\n" for v in t))


__all__ = ["read_poses", "read_times", "write_poses", "write_times"]
