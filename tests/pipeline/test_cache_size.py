"""Bytes per pair on disk at the default working size 832×256 (target ≤ 1 MB, docs/design.md §3)."""

from __future__ import annotations

import os

import pytest

from pipeline.cache import CacheWriter
from pipeline.cache.layout import block_dir
from testkit.demo_scene import street_block

TARGET = 1_000_000  # bytes
PAIRS = 8


def _bytes_per_pair(root, block) -> float:
    w = CacheWriter(root, {"size": [832, 256]}, {})
    assert w.write_block(block)
    d = block_dir(root, block.sequence, block.block_index)
    total = sum(os.path.getsize(os.path.join(p, f)) for p, _, fs in os.walk(d) for f in fs)
    return total / len(block.pairs)


def test_synthetic_street_with_ground_truth(tmp_path):
    block = street_block("00", 0, PAIRS, 256, 832)
    n = sum(p.idx1.size + p.idx2.size for p in block.pairs) / PAIRS
    per_pair = _bytes_per_pair(tmp_path, block)
    print(f"\nsynthetic street 832x256, {PAIRS} pairs/block, {n:.0f} kept points/pair, with GT flow: "
          f"{per_pair / 1e3:.0f} kB/pair")
    assert n > 100_000  # the measurement is of a realistically full pair
    assert per_pair <= TARGET


def test_real_kitti_frames_and_predicted_depth(tmp_path, shared_data):
    from testkit.kitti_sample import kitti_block

    folder = shared_data / "kitti_sceneflow2015_000139"
    if not folder.is_dir():
        pytest.skip(f"{folder} absent")
    block = kitti_block(folder, PAIRS)
    per_pair = _bytes_per_pair(tmp_path, block)
    print(f"\nreal KITTI 2015 frames + Self-Mono-SF depth at 832x256, {PAIRS} pairs/block: {per_pair / 1e3:.0f} kB/pair")
    assert per_pair <= TARGET
