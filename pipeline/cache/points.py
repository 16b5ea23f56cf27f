"""The one way stage one and the cache reader turn a depth map and kept pixels into a point cloud.

The cache stores each frame's depth map and the kept pixels' flat indices, not xyz (docs/cache-format.md);
the reader rebuilds the clouds with these functions. A caller that builds the clouds it filters, reports or
checks with the same functions gets bitwise the same points as the reader.

Depth is stored at KITTI's precision: metres in steps of 1/256 m (uint16, so 0 … 255.996 m; 0 = invalid).
:func:`canonical_depth` rounds a metric depth map onto that grid; it is idempotent, and
:func:`points_from_depth` applies it to the depths it gathers, so points made from the caller's float32
depth and from the stored depth are identical. Call :func:`canonical_depth` right after scaling, before the
filters, so that the filters also see exactly what the cache will hold.

Conventions (docs/design.md §2): camera frame x right, y down, z forward, metres; pixel (u, v) u right, v down,
origin at the top-left pixel's centre; flat index ``v * W + u``.
"""

from __future__ import annotations

import numpy as np

from core.geometry import backproject

DEPTH_STEPS_PER_METRE = 256
"""Stored depth unit: 1/256 m (KITTI's depth-png convention)."""
DEPTH_MAX_CODE = np.iinfo(np.uint16).max
DEPTH_MAX_METRES = DEPTH_MAX_CODE / DEPTH_STEPS_PER_METRE
"""Largest storable depth, 255.996 m; farther depths saturate there (the filters drop z ≥ 35 m anyway)."""


def quantize_depth(depth: np.ndarray) -> np.ndarray:
    """Metric depth (any shape, metres, 0 = invalid) → uint16 codes in 1/256 m, rounded to nearest.

    Depths beyond :data:`DEPTH_MAX_METRES` (and +inf) saturate; negative depths and NaN raise ValueError.
    Depths below 1/512 m round to 0 (invalid).
    """
    d = np.asarray(depth)
    if np.isnan(d).any():
        raise ValueError("depth contains NaN")
    if (d < 0).any():
        raise ValueError(f"depth contains negative values (min {float(np.min(d))})")
    codes = np.rint(np.minimum(d.astype(np.float64), DEPTH_MAX_METRES) * DEPTH_STEPS_PER_METRE)
    return codes.astype(np.uint16)


def dequantize_depth(codes: np.ndarray) -> np.ndarray:
    """uint16 codes in 1/256 m → float32 metres (exact: every code is representable)."""
    return (np.asarray(codes, dtype=np.float32) / np.float32(DEPTH_STEPS_PER_METRE)).astype(np.float32)


def canonical_depth(depth: np.ndarray) -> np.ndarray:
    """Round float metric depth onto the cache's 1/256 m grid (float32, same shape); idempotent."""
    return dequantize_depth(quantize_depth(depth))


def flat_index(u: np.ndarray, v: np.ndarray, width: int) -> np.ndarray:
    """Flat pixel indices ``v * width + u`` (int32) of integer pixel coordinates."""
    return (np.asarray(v, dtype=np.int64) * width + np.asarray(u, dtype=np.int64)).astype(np.int32)


def pixel_uv(idx: np.ndarray, width: int) -> np.ndarray:
    """(N, 2) float32 pixel coordinates (u, v) of flat pixel indices ``idx`` in an image ``width`` wide."""
    idx = np.asarray(idx, dtype=np.int64)
    return np.stack([idx % width, idx // width], axis=-1).astype(np.float32)


def points_from_depth(depth: np.ndarray, idx: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) float32, metres, of the pixels ``idx`` of a (H, W) metric depth map.

    ``P = D · K⁻¹ [u, v, 1]ᵀ`` with D rounded onto the cache's grid (:func:`canonical_depth`) and the
    arithmetic in float64 (K is taken as float64), then rounded once to float32.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth.shape}")
    idx = np.asarray(idx)
    return points_at_pixels(depth.reshape(-1)[idx], pixel_uv(idx, depth.shape[1]), K)


def points_at_pixels(depth_values: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """:func:`points_from_depth` for already gathered depths (N,) and their pixel coordinates (N, 2).

    Bitwise the same as :func:`points_from_depth` when ``uv = pixel_uv(idx, W)`` and
    ``depth_values = depth.ravel()[idx]`` (the reader uses it to compute uv once).
    """
    d = canonical_depth(depth_values).astype(np.float64)
    return backproject(d, np.asarray(K, dtype=np.float64), np.asarray(uv, dtype=np.float64)).astype(np.float32)


def colours_at(rgb: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours of the pixels ``idx`` of a (H, W, 3) image."""
    rgb = np.asarray(rgb)
    return rgb.reshape(-1, rgb.shape[-1])[np.asarray(idx)].astype(np.uint8, copy=False)
