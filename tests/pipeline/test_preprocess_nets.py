"""Stage one with the depth and pose nets (seeded random weights: no checkpoints exist here): each frame's
depth is computed once per block and reused by both pairs holding it; each pair's pose once."""

from __future__ import annotations

import numpy as np
import pytest
from test_preprocess import gt_config

from pipeline.preprocess import run_preprocess

SYNTH_FX = 707.0912 * 208 / 1226  # the synthetic world's fx (KITTI's, scaled to 208×64)


def test_net_sources_compute_each_frame_once_per_block(synth_root, tmp_path):  # noqa: F811
    from pipeline.cache import CacheReader

    results = []
    cfg = gt_config(synth_root, tmp_path, depth="net", pose="net", random_init=True, device="cpu", size="128x48")
    summary = run_preprocess(cfg, on_block=results.append)
    assert [r.frames for r in results] == [4, 4, 3]
    assert [r.depth_images for r in results] == [4, 4, 3]  # 3 pairs share 4 frames: one depth pass each
    assert [r.pose_pairs for r in results] == [3, 3, 2]
    assert summary.depth_net_images == 11 and summary.pose_net_pairs == 8
    assert "net calls: depth 11 images for 11 block frames, pose 8 for 8 pairs" in summary.text()
    reader = CacheReader(summary.cache_root)
    s = reader[0]
    assert s.depth2.shape == (48, 128) and s.K[0, 0] == pytest.approx(SYNTH_FX * 128 / 208, rel=1e-5)
    # The pose came from the (random) net, not the dataset, and the depth map is the net's 1/(10σ+0.01).
    assert not np.allclose(s.T, np.eye(4), atol=1e-9)
    d = s.depth2[s.depth2 > 0]
    assert d.min() >= 0.09 and d.max() <= 100.01
