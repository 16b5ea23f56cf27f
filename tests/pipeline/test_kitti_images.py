"""8-bit image reader/writer: RGB order, gray replication, round trips, header size, bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from core.errors import InputError
from pipeline.kitti.images import image_size, read_image, write_image


def test_colour_frame_is_rgb(shared_data: Path):
    f = shared_data / "kitti_odometry_06_color/test_data/kitti06-12-color.png"
    rgb = read_image(f)
    assert rgb.shape == (370, 1226, 3) and rgb.dtype == np.uint8
    np.testing.assert_array_equal(rgb, cv2.imread(str(f), cv2.IMREAD_COLOR)[..., ::-1])
    # daylight sky over the road: the top rows are bluer than they are red
    top = rgb[:40].reshape(-1, 3).astype(np.float64).mean(axis=0)
    assert top[2] > top[0]


def test_gray_frame_is_replicated(shared_data: Path):
    f = shared_data / "kitti_odometry_06_gray/image_l/000000.png"
    rgb = read_image(f)
    gray = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
    assert gray.ndim == 2 and rgb.shape == (370, 1226, 3)
    for c in range(3):
        np.testing.assert_array_equal(rgb[..., c], gray)
    assert image_size(f) == (370, 1226)


def test_write_image_stores_rgb_as_png_bgr_and_round_trips(tmp_path: Path):
    img = np.zeros((4, 6, 3), dtype=np.uint8)
    img[0, 0] = [255, 0, 0]  # red
    img[1:, 2:] = np.arange(3 * 4 * 3, dtype=np.uint8).reshape(3, 4, 3)
    f = tmp_path / "image_2" / "000000.png"
    write_image(f, img)
    np.testing.assert_array_equal(cv2.imread(str(f), cv2.IMREAD_UNCHANGED)[0, 0], [0, 0, 255])  # on disk: BGR
    np.testing.assert_array_equal(read_image(f), img)
    gray = np.arange(24, dtype=np.uint8).reshape(4, 6)
    write_image(tmp_path / "g.png", gray)
    np.testing.assert_array_equal(read_image(tmp_path / "g.png"), np.repeat(gray[..., None], 3, axis=2))
    assert image_size(f) == (4, 6)
    write_image(tmp_path / "j.jpg", img)
    assert image_size(tmp_path / "j.jpg") == (4, 6)  # not a PNG: decoded
    with pytest.raises(ValueError):
        write_image(tmp_path / "x.png", img.astype(np.float32))


def test_unreadable_images_are_input_errors(tmp_path: Path):
    bad = tmp_path / "000000.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(InputError) as e:
        read_image(bad)
    assert str(bad) in str(e.value) and "cannot decode" in str(e.value)
    with pytest.raises(InputError, match="file not found"):
        read_image(tmp_path / "missing.png")
    with pytest.raises(InputError):
        image_size(tmp_path / "missing.png")
