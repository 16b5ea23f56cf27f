"""Snippets, splits and augmentation of the depth trainer on a hand-built KITTI-layout folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import ConfigError, InputError
from core.geometry import project
from pipeline.kitti.calib import write_odometry_calib
from pipeline.kitti.images import write_image
from pipeline.kitti.odometry import OdometrySequence
from pipeline.kitti.poses import write_poses
from training.depth.config import DepthDataConfig
from training.depth.data import (
    SnippetDataset,
    check_size,
    collate,
    hflip,
    open_sequences,
    resolve_splits,
    scale_crop,
    snippet_centres,
)

H0, W0 = 64, 96
K0 = np.array([[50.0, 0.0, 47.5], [0.0, 50.0, 31.5], [0.0, 0.0, 1.0]])


def _sequence(root: Path, name: str, frame_ids: list[int], rng: np.random.Generator) -> None:
    seq = root / "sequences" / name
    (seq / "image_2").mkdir(parents=True)
    for f in frame_ids:
        write_image(seq / "image_2" / f"{f:06d}.png", rng.integers(0, 256, size=(H0, W0, 3), dtype=np.uint8))
    P = np.hstack([K0, np.zeros((3, 1))])
    write_odometry_calib(seq / "calib.txt", {"P0": P, "P2": P})
    (root / "poses").mkdir(exist_ok=True)
    write_poses(root / "poses" / f"{name}.txt", np.repeat(np.eye(4)[None], max(frame_ids) + 1, axis=0))


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("kitti")
    rng = np.random.default_rng(0)
    _sequence(root, "00", [0, 1, 2, 3, 5, 6, 7], rng)  # frame 4 missing
    _sequence(root, "01", [0, 1, 2, 3, 4], rng)
    return root


def test_snippets_never_cross_a_gap_in_frame_ids(tree: Path):
    seq = OdometrySequence(tree, "00")
    assert snippet_centres(seq, 1) == [1, 2, 5]  # ids 1, 2, 6
    assert snippet_centres(seq, 2) == [3, 4]  # ids 3 (1, 5) and 5 (3, 7)
    with pytest.raises(ConfigError):
        snippet_centres(seq, 0)


def test_splits(tree: Path):
    assert resolve_splits(DepthDataConfig(root=str(tree), val_sequences=("last",))) == (["00"], ["01"])
    assert resolve_splits(DepthDataConfig(root=str(tree))) == (["00", "01"], [])
    with pytest.raises(InputError, match="sequences/07"):
        resolve_splits(DepthDataConfig(root=str(tree), sequences=("07",)))
    with pytest.raises(ConfigError, match="no training sequence"):
        resolve_splits(DepthDataConfig(root=str(tree), val_sequences=("00", "01")))


def test_working_size_must_suit_the_net():
    assert check_size(128, 64) == (64, 128)
    for w, h in ((100, 64), (128, 32), (64, 48)):
        with pytest.raises(ConfigError, match="multiples of 32"):
            check_size(w, h)


def _blob(K: np.ndarray, point: np.ndarray, h: int, w: int) -> np.ndarray:
    u, v = project(point[None], K)[0][0]
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    g = np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2 * 2.0**2))
    return np.repeat((255 * g).astype(np.uint8)[None, ..., None], 3, axis=-1)  # (1, h, w, 3)


def _centroid(img: np.ndarray) -> np.ndarray:
    g = img[..., 0].astype(np.float64)
    g = np.where(g > 40, g, 0)
    vv, uu = np.mgrid[: g.shape[0], : g.shape[1]]
    return np.array([(uu * g).sum() / g.sum(), (vv * g).sum() / g.sum()])


def test_flip_and_scale_crop_keep_k_consistent_with_the_pixels():
    point = np.array([-1.0, 0.4, 6.0])  # left of and below the optical axis, 6 m ahead
    frames = _blob(K0, point, H0, W0)
    flipped, Kf = hflip(frames, K0)
    uv_f = project(point[None] * [-1, 1, 1], Kf)[0][0]  # the mirrored world seen with the flipped K
    np.testing.assert_allclose(_centroid(flipped[0]), uv_f, atol=0.05)
    np.testing.assert_allclose(hflip(flipped, Kf)[1], K0)
    zoomed, Kz = scale_crop(frames, K0, 1.15, 1.1, np.random.default_rng(3))
    assert zoomed.shape == frames.shape
    np.testing.assert_allclose(_centroid(zoomed[0]), project(point[None], Kz)[0][0], atol=0.2)


def test_dataset_items_are_deterministic_per_epoch_and_collate(tree: Path):
    cfg = DepthDataConfig(root=str(tree), width=64, height=64, max_scale=1.15)
    ds = SnippetDataset(open_sequences(str(tree), ["00", "01"], "image_2"), cfg, seed=5)
    assert len(ds) == 3 + 3
    a, b = ds[4], ds[4]
    np.testing.assert_array_equal(a["images"], b["images"])
    assert a["images"].shape == (3, 64, 64, 3) and a["images"].dtype == np.uint8 and a["K"].dtype == np.float32
    changed = False
    for epoch in range(1, 6):
        ds.set_epoch(epoch)
        changed |= not np.array_equal(ds[4]["K"], a["K"])
    assert changed
    plain = SnippetDataset(open_sequences(str(tree), ["01"], "image_2"), cfg, seed=5, augment=False)
    item = plain[0]  # centre position 1: frames 0, 1, 2 resized 96×64 → 64×64, K scaled by (2/3, 1)
    np.testing.assert_allclose(item["K"], [[50 * 2 / 3, 0, 47.5 * 2 / 3], [0, 50, 31.5], [0, 0, 1]], rtol=1e-6)
    batch = collate([plain[0], plain[1]])
    assert tuple(batch.images.shape) == (2, 3, 3, 64, 64) and batch.index.tolist() == [0, 1]
    np.testing.assert_array_equal(batch.images[1, 2].permute(1, 2, 0).numpy(), plain[1]["images"][2])
