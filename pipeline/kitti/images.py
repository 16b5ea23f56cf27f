"""8-bit camera images (KITTI ``image_0..3`` PNGs): read as RGB, write from RGB."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

from pipeline.kitti._png import decode, encode
from pipeline.kitti._text import PathLike

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def read_image(path: PathLike) -> np.ndarray:
    """(H, W, 3) uint8 RGB; a grayscale file is replicated to 3 channels, alpha dropped, 16-bit scaled to 8."""
    bgr = decode(path, cv2.IMREAD_COLOR)
    return np.ascontiguousarray(bgr[..., ::-1])


def write_image(path: PathLike, rgb: np.ndarray) -> None:
    """Write (H, W, 3) uint8 RGB, or (H, W) uint8 gray, in the format of the suffix (PNG is lossless)."""
    img = np.asarray(rgb)
    if img.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 3:
        img = np.ascontiguousarray(img[..., ::-1])
    elif img.ndim != 2:
        raise ValueError(f"image must be (H, W, 3) RGB or (H, W) gray, got shape {img.shape}")
    encode(path, img)


def image_size(path: PathLike) -> tuple[int, int]:
    """(height, width) in pixels; PNGs answer from their header without decoding."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(24)
    except OSError:
        head = b""
    if head[:8] == _PNG_SIGNATURE and head[12:16] == b"IHDR":
        width, height = struct.unpack(">II", head[16:24])
        return int(height), int(width)
    img = decode(p, cv2.IMREAD_UNCHANGED)
    return int(img.shape[0]), int(img.shape[1])


__all__ = ["image_size", "read_image", "write_image"]
