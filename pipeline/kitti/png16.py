"""KITTI 16-bit PNG maps: depth, disparity and optical flow (the devkit's conventions).

* depth / disparity: uint16 single channel, value / 256 (metres, resp. pixels); 0 = invalid.
* flow: uint16 three channels; on disk R = u, G = v (each ``(value − 2^15) / 64`` pixels), B = valid
  (1 / 0). OpenCV orders channels BGR, so in its array B = valid, G = v, R = u.

Read with OpenCV ``IMREAD_UNCHANGED``: PIL truncates 16-bit PNGs to 8 bits.
"""

from __future__ import annotations

import cv2
import numpy as np

from core.errors import InputError
from pipeline.kitti._png import decode, encode
from pipeline.kitti._text import PathLike

SCALE_MAP = 256.0  # depth (m) and disparity (px) are stored as value * 256
SCALE_FLOW = 64.0  # flow (px) is stored as value * 64 + 2^15
OFFSET_FLOW = 2.0**15
MAX_MAP = 65535 / SCALE_MAP  # 255.996…: the largest storable depth / disparity
MAX_FLOW = (65535 - OFFSET_FLOW) / SCALE_FLOW  # 511.98…: the largest storable |u|, |v|


def _read_uint16(path: PathLike, channels: int, what: str) -> np.ndarray:
    img = decode(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint16:
        raise InputError(path, f"expected a 16-bit PNG ({what}), got {img.dtype} ({8 * img.itemsize}-bit)")
    got = 1 if img.ndim == 2 else img.shape[2]
    if got != channels:
        raise InputError(path, f"expected {channels} channel(s) ({what}), got {got}")
    return img


def _read_map(path: PathLike, what: str) -> np.ndarray:
    return (_read_uint16(path, 1, what).astype(np.float32) / np.float32(SCALE_MAP)).astype(np.float32)


def _write_map(path: PathLike, values: np.ndarray) -> None:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2:
        raise ValueError(f"map must be (H, W), got shape {v.shape}")
    ok = np.isfinite(v) & (v > 0) & (v <= MAX_MAP)
    out = np.zeros(v.shape, dtype=np.uint16)
    out[ok] = np.clip(np.round(v[ok] * SCALE_MAP), 1, 65535).astype(np.uint16)
    encode(path, out)


def read_depth_png(path: PathLike) -> np.ndarray:
    """(H, W) float32 depth in metres (z along the optical axis); 0 = invalid."""
    return _read_map(path, "depth = uint16 / 256")


def write_depth_png(path: PathLike, depth: np.ndarray) -> None:
    """Write (H, W) depth in metres as uint16 · 256, rounded; ≤ 0, > 255.99 m or non-finite → 0 (invalid)."""
    _write_map(path, depth)


def read_disparity_png(path: PathLike) -> np.ndarray:
    """(H, W) float32 disparity in pixels (at the PNG's resolution); 0 = invalid."""
    return _read_map(path, "disparity = uint16 / 256")


def write_disparity_png(path: PathLike, disparity: np.ndarray) -> None:
    """Write (H, W) disparity in pixels as uint16 · 256; ≤ 0, > 255.99 px or non-finite → 0 (invalid)."""
    _write_map(path, disparity)


def disparity_to_depth(disp: np.ndarray, focal_px: float, baseline_m: float) -> np.ndarray:
    """Depth (metres) = focal · baseline / disparity where disparity > 0, else 0; float32, same shape."""
    d = np.asarray(disp, dtype=np.float64)
    out = np.zeros(d.shape, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0)
    out[ok] = focal_px * baseline_m / d[ok]
    return out.astype(np.float32)


def read_flow_png(path: PathLike) -> tuple[np.ndarray, np.ndarray]:
    """(flow (H, W, 2) float32 pixels (u right, v down), valid (H, W) bool); flow is 0 where invalid."""
    img = _read_uint16(path, 3, "KITTI flow: R=u, G=v, B=valid")
    valid = img[..., 0] > 0
    flow = (img[..., [2, 1]].astype(np.float32) - np.float32(OFFSET_FLOW)) / np.float32(SCALE_FLOW)
    flow[~valid] = 0.0
    return flow.astype(np.float32), valid


def write_flow_png(path: PathLike, flow: np.ndarray, valid: np.ndarray | None = None) -> None:
    """Write (H, W, 2) flow in pixels as a KITTI flow PNG.

    ``valid`` (H, W) bool defaults to all True. Pixels with non-finite flow or |u|, |v| > 511.98 px (not
    storable) are written invalid; invalid pixels store zero flow (2^15) with B = 0, as KITTI's GT does.
    """
    f = np.asarray(flow, dtype=np.float64)
    if f.ndim != 3 or f.shape[2] != 2:
        raise ValueError(f"flow must be (H, W, 2), got shape {f.shape}")
    ok = np.ones(f.shape[:2], dtype=bool) if valid is None else np.asarray(valid, dtype=bool).copy()
    if ok.shape != f.shape[:2]:
        raise ValueError(f"valid must be {f.shape[:2]}, got shape {ok.shape}")
    ok &= np.all(np.isfinite(f), axis=2) & np.all(np.abs(f) <= MAX_FLOW, axis=2)
    out = np.full(f.shape[:2] + (3,), OFFSET_FLOW, dtype=np.float64)
    out[ok, 2] = f[ok, 0] * SCALE_FLOW + OFFSET_FLOW
    out[ok, 1] = f[ok, 1] * SCALE_FLOW + OFFSET_FLOW
    out[..., 0] = ok
    encode(path, np.clip(np.round(out), 0, 65535).astype(np.uint16))


__all__ = [
    "disparity_to_depth",
    "read_depth_png",
    "read_disparity_png",
    "read_flow_png",
    "write_depth_png",
    "write_disparity_png",
    "write_flow_png",
]
