"""pipeline.cache.points: the depth grid and the one way clouds are built from depth + kept pixels."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.cache.points import (
    DEPTH_MAX_METRES,
    canonical_depth,
    colours_at,
    dequantize_depth,
    flat_index,
    pixel_uv,
    points_from_depth,
    quantize_depth,
)
from core.geometry import static_flow

REPO = Path(__file__).resolve().parents[2]


def test_importing_the_package_does_not_import_zarr():
    code = "import sys, pipeline.cache; assert 'zarr' not in sys.modules and 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], cwd=REPO, check=True, timeout=60)


def test_quantize_known_codes_and_saturation():
    d = np.array([0.0, 1.0, 2.3, 1 / 1024, 300.0, np.inf], np.float32)
    codes = quantize_depth(d)
    assert codes.dtype == np.uint16
    # 2.3 m * 256 = 588.8 -> 589; 1/1024 m rounds to 0 (invalid); beyond 255.996 m saturates
    assert codes.tolist() == [0, 256, 589, 0, 65535, 65535]
    assert dequantize_depth(codes).tolist() == [0.0, 1.0, 589 / 256, 0.0, DEPTH_MAX_METRES, DEPTH_MAX_METRES]


def test_quantize_rejects_nan_and_negative():
    with pytest.raises(ValueError, match="NaN"):
        quantize_depth(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="negative"):
        quantize_depth(np.array([1.0, -0.5]))


def test_canonical_depth_is_idempotent_and_within_half_a_step():
    rng = np.random.default_rng(0)
    d = rng.uniform(0.5, 80.0, (7, 9)).astype(np.float32)
    c = canonical_depth(d)
    assert c.dtype == np.float32
    assert np.array_equal(canonical_depth(c), c)
    assert np.abs(c - d).max() <= 1 / 512 + 1e-6


def test_points_from_depth_hand_computed():
    K = np.array([[100.0, 0.0, 1.0], [0.0, 50.0, 0.5], [0.0, 0.0, 1.0]])
    depth = np.zeros((2, 4), np.float32)
    depth[1, 3] = 2.0  # pixel (u=3, v=1)
    depth[0, 0] = 4.0  # pixel (u=0, v=0)
    idx = flat_index(np.array([0, 3]), np.array([0, 1]), 4)
    assert idx.tolist() == [0, 7]
    pts = points_from_depth(depth, idx, K)
    assert pts.dtype == np.float32
    # x = (u - cx) / fx * z, y = (v - cy) / fy * z
    np.testing.assert_allclose(pts, [[(0 - 1) / 100 * 4, (0 - 0.5) / 50 * 4, 4.0], [0.04, 0.02, 2.0]], rtol=1e-6)
    assert pixel_uv(idx, 4).tolist() == [[0.0, 0.0], [3.0, 1.0]]


def test_points_from_raw_and_canonical_depth_are_bitwise_equal():
    rng = np.random.default_rng(1)
    depth = rng.uniform(1.0, 60.0, (6, 10)).astype(np.float32)
    K = np.array([[7.1, 0.0, 4.9], [0.0, 7.3, 2.6], [0.0, 0.0, 1.0]])
    idx = np.array([0, 5, 17, 59], np.int32)
    a = points_from_depth(depth, idx, K)
    b = points_from_depth(canonical_depth(depth), idx, K)
    assert np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_colours_and_static_flow():
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    assert colours_at(rgb, np.array([4])).tolist() == [[12, 13, 14]]  # pixel (u=1, v=1)
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.0, -1.0]
    p = np.array([[1.0, 2.0, 3.0]], np.float32)
    sf = static_flow(p, T, as_float32=True)
    assert sf.dtype == np.float32
    assert sf.tolist() == [[0.5, 0.0, -1.0]]
    assert np.array_equal(sf, static_flow(p.astype(np.float64), T).astype(np.float32))
