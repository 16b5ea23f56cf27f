"""Shared OpenCV decode/encode with InputError on failure (byte buffers, so any path name works)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from core.errors import InputError
from pipeline.kitti._text import PathLike


def decode(path: PathLike, flags: int) -> np.ndarray:
    """Decode the image file at ``path`` with ``cv2.imdecode(…, flags)``; failure → InputError."""
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "file not found" if not p.exists() else "not a file")
    try:
        buf = np.fromfile(p, dtype=np.uint8)
    except OSError as exc:
        raise InputError(p, f"cannot read ({exc})") from None
    if buf.size == 0:
        raise InputError(p, "empty file")
    try:
        img = cv2.imdecode(buf, flags)
    except cv2.error:
        img = None
    if img is None:
        raise InputError(p, "cannot decode image (corrupt or not an image file)")
    return img


def encode(path: PathLike, img: np.ndarray) -> None:
    """Encode ``img`` (OpenCV channel order) in the format of ``path``'s suffix and write it."""
    p = Path(path)
    try:
        ok, buf = cv2.imencode(p.suffix or ".png", img)
    except cv2.error:
        ok = False
    if not ok:
        raise ValueError(f"OpenCV cannot encode an image of shape {img.shape} dtype {img.dtype} as {p.suffix!r}")
    p.parent.mkdir(parents=True, exist_ok=True)
    buf.tofile(p)
