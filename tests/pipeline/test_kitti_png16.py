"""KITTI 16-bit depth / disparity / flow PNGs: real files, hand-computed encodings, round trips, bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from core.errors import InputError
from pipeline.kitti.png16 import (
    disparity_to_depth,
    read_depth_png,
    read_disparity_png,
    read_flow_png,
    write_depth_png,
    write_disparity_png,
    write_flow_png,
)

SF = "kitti_sceneflow2015_000139"
FX_2011_09_26 = 721.5377  # P_rect_02 of the raw calibration of this date; KITTI 2015 scenes use it
BASELINE = 0.54


def test_real_disparity_gives_plausible_depth(shared_data: Path):
    d = read_disparity_png(shared_data / SF / "results/disp_0/000139_10.png")
    assert d.shape == (375, 1242) and d.dtype == np.float32
    assert np.all(d > 0)  # a network prediction: dense
    assert d.max() < 256
    raw = cv2.imread(str(shared_data / SF / "results/disp_0/000139_10.png"), cv2.IMREAD_UNCHANGED)
    assert d[200, 600] == raw[200, 600] / 256.0
    z = disparity_to_depth(d, FX_2011_09_26, BASELINE)
    assert 10 < np.median(z) < 60
    # the road just ahead: a flat ground 1.65 m below the camera is at depth fy·1.65 / (v − cy) ≈ 6 m there
    rows = np.arange(345, 375)
    expect = FX_2011_09_26 * 1.65 / (rows - 172.854)
    got = np.median(z[345:375, 560:680], axis=1)
    np.testing.assert_allclose(got, expect, rtol=0.25)


def test_disparity_to_depth_hand_values():
    d = np.array([[50.0, 0.0], [-1.0, np.nan]])
    z = disparity_to_depth(d, FX_2011_09_26, BASELINE)
    assert z.dtype == np.float32
    assert z[0, 0] == pytest.approx(721.5377 * 0.54 / 50, rel=1e-6)  # 7.7926 m
    np.testing.assert_array_equal(z.ravel()[1:], 0)


def test_real_ground_truth_flow(shared_data: Path):
    flow, valid = read_flow_png(shared_data / "kitti_flow_pair/flow_gt.png")
    assert flow.shape == (375, 1242, 2) and flow.dtype == np.float32 and valid.dtype == bool
    assert valid.mean() == pytest.approx(0.162, abs=0.001)
    assert np.linalg.norm(flow[valid], axis=1).mean() == pytest.approx(51.0, abs=0.5)
    np.testing.assert_array_equal(flow[~valid], 0)


def test_real_predicted_flow_is_dense_and_decoded_u_from_red(shared_data: Path):
    path = shared_data / SF / "results/flow/000139_10.png"
    flow, valid = read_flow_png(path)
    assert valid.all()
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # BGR: raw[..., 2] is R = u
    assert flow[100, 900, 0] == (float(raw[100, 900, 2]) - 32768) / 64
    assert flow[100, 900, 1] == (float(raw[100, 900, 1]) - 32768) / 64


def test_write_flow_hand_encoded(tmp_path: Path):
    flow = np.array([[[1.5, -2.0], [0.0, 0.0]]], dtype=np.float32)
    valid = np.array([[True, False]])
    f = tmp_path / "flow.png"
    write_flow_png(f, flow, valid)
    raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(raw[0, 0], [1, 32768 - 128, 32768 + 96])  # B=valid, G=v, R=u
    np.testing.assert_array_equal(raw[0, 1], [0, 32768, 32768])


def test_flow_round_trip_and_unstorable_values(tmp_path: Path):
    rng = np.random.default_rng(1)
    flow = (rng.integers(-20000, 20000, size=(6, 9, 2)) / 64.0).astype(np.float32)  # exact in 1/64 steps
    valid = rng.random((6, 9)) > 0.3
    flow[0, 0] = [600.0, 0.0]  # beyond ±512 px: cannot be stored
    flow[0, 1] = [np.nan, 1.0]
    valid[0, :2] = True
    f = tmp_path / "a" / "f.png"
    write_flow_png(f, flow, valid)
    back, vback = read_flow_png(f)
    expect_valid = valid.copy()
    expect_valid[0, :2] = False
    np.testing.assert_array_equal(vback, expect_valid)
    np.testing.assert_array_equal(back[expect_valid], flow[expect_valid])
    np.testing.assert_array_equal(back[~expect_valid], 0)


def test_depth_round_trip_and_invalid_values(tmp_path: Path):
    rng = np.random.default_rng(2)
    depth = (rng.integers(1, 65535, size=(7, 5)) / 256.0).astype(np.float32)
    depth[0, :5] = [0.0, -3.0, np.inf, np.nan, 256.5]
    f = tmp_path / "d.png"
    write_depth_png(f, depth)
    assert cv2.imread(str(f), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    back = read_depth_png(f)
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back[0], 0)
    np.testing.assert_array_equal(back[1:], depth[1:])
    # non-grid values round to the nearest 1/256 m
    write_depth_png(f, np.array([[10.001, 255.99]]))
    np.testing.assert_allclose(read_depth_png(f), [[2560 / 256, 65533 / 256]])
    write_disparity_png(tmp_path / "disp.png", depth[1:])
    np.testing.assert_array_equal(read_disparity_png(tmp_path / "disp.png"), depth[1:])


def test_8bit_png_given_as_depth_is_an_input_error(shared_data: Path):
    f = shared_data / "kitti_odometry_06_gray/image_l/000000.png"
    with pytest.raises(InputError) as e:
        read_depth_png(f)
    assert str(f) in str(e.value) and "16-bit" in str(e.value) and "uint8" in str(e.value)


def test_wrong_channel_count_is_an_input_error(shared_data: Path):
    flow_png = shared_data / "kitti_flow_pair/flow_gt.png"
    with pytest.raises(InputError) as e:
        read_disparity_png(flow_png)
    assert str(flow_png) in str(e.value) and "got 3" in str(e.value)
    disp_png = shared_data / SF / "results/disp_0/000139_10.png"
    with pytest.raises(InputError) as e:
        read_flow_png(disp_png)
    assert str(disp_png) in str(e.value) and "got 1" in str(e.value)


def test_corrupt_truncated_empty_missing_png(shared_data: Path, tmp_path: Path):
    good = (shared_data / "kitti_flow_pair/flow_gt.png").read_bytes()
    cases = {
        "garbage.png": b"\x89PNG\r\n\x1a\n" + b"garbage" * 10,
        "truncated.png": good[: len(good) // 2],
        "empty.png": b"",
    }
    for name, data in cases.items():
        f = tmp_path / name
        f.write_bytes(data)
        with pytest.raises(InputError) as e:
            read_flow_png(f)
        assert str(f) in str(e.value), name
    with pytest.raises(InputError, match="file not found"):
        read_depth_png(tmp_path / "none.png")
