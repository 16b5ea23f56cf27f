"""Stage one on real KITTI samples (../shared/data): odometry 06 colour frames 12–14 with the depth net and the
dataset's poses at the native size, and KITTI-2015 scene 139 with published monocular disparities."""

from __future__ import annotations

import shutil

import numpy as np

from pipeline.preprocess import PreprocessConfig, run_preprocess
from pipeline.scale import ScaleConfig


def odometry_06_tree(shared_data, tmp_path):
    """A KITTI odometry tree holding frames 12–14 of sequence 06 (image_2), the transcribed calib (P0..P3,
    no Tr) and the official poses file."""
    src = shared_data / "kitti_odometry_06_color"
    seq = tmp_path / "kitti" / "sequences" / "06"
    (seq / "image_2").mkdir(parents=True)
    for f in (12, 13, 14):
        shutil.copy(src / f"test_data/kitti06-{f}-color.png", seq / f"image_2/{f:06d}.png")
    shutil.copy(src / "calib_odometry_seq04-12_TRANSCRIBED.txt", seq / "calib.txt")
    (tmp_path / "kitti" / "poses").mkdir()
    shutil.copy(src / "videos_kitti06/06.txt", tmp_path / "kitti" / "poses" / "06.txt")
    return tmp_path / "kitti"


def test_odometry_06_net_depth_dataset_poses_native_size(shared_data, tmp_path):
    from pipeline.cache import CacheReader
    from pipeline.kitti.images import read_image
    from pipeline.kitti.odometry import OdometrySequence

    root = odometry_06_tree(shared_data, tmp_path)
    results = []
    # Random weights give a near-constant depth of ≈ 0.19 (1 / (10 σ + 0.01) with σ ≈ 0.5); a fixed factor of
    # 50 puts that "wall" ≈ 10 m away, so the metric dataset poses keep it in view.
    cfg = PreprocessConfig(root=str(root), depth="net", pose="gt", random_init=True, size="native", device="cpu",
                           batch_size=3, scale=ScaleConfig(mode="fixed", factor=50.0), out=str(tmp_path / "cache"),
                           progress=False)
    summary = run_preprocess(cfg, on_block=results.append)
    assert summary.pairs == 2 and summary.manifest_written
    assert summary.depth_net_images == 3 and summary.pose_net_pairs == 0  # frame 13 serves both pairs
    assert [r.depth_images for r in results] == [3]

    seq = OdometrySequence(root, "06")
    assert seq.T_velo_to_cam is None  # the LiDAR-range filter used KITTI's default mount
    reader = CacheReader(summary.cache_root)
    assert reader.image_size == (370, 1226)
    for i, (t, t1) in enumerate([(12, 13), (13, 14)]):
        s = reader[i]
        assert (s.frame_t, s.frame_t1) == (t, t1)
        assert np.allclose(s.K, seq.K, atol=1e-4)  # native size: K is P2's
        assert np.allclose(s.T, seq.relative_pose(t - 12, t1 - 12), atol=1e-6) and s.scale == 50.0
        assert 0.5 < -s.T[2, 3] < 2.0  # seq 06 drives forward ≈ 1 m per frame
        assert len(s.pc1) > 1000 and len(s.pc2) > 1000
        image = read_image(root / f"sequences/06/image_2/{t:06d}.png")
        u, v = s.uv1[:, 0].astype(int), s.uv1[:, 1].astype(int)
        assert np.array_equal(s.rgb1, image[v, u])  # colours are the RGB pixels under the points
        assert s.pc1[:, 1].max() < 1.15 and s.pc1[:, 2].max() < 35.0


def test_kitti_2015_scene_139_external_disparity(shared_data, tmp_path):
    """Depth from Self-Mono-SF's published disparities (fx of P_rect_02, baseline 0.54 m); pose from the net.

    Only frame 10 has its own disparity map; frame 11 uses ``disp_1`` (the disparity at t+1 of frame 10's
    pixels, KITTI's d2) as a stand-in depth map — good enough to run the stage, not a true frame-11 map.
    """
    from pipeline.cache import CacheReader
    from pipeline.cache.points import canonical_depth
    from pipeline.kitti.png16 import read_disparity_png
    from testkit.kitti_sample import scene139_odometry_tree

    seq = scene139_odometry_tree(shared_data, tmp_path / "kitti2015") / "sequences" / "139"

    cfg = PreprocessConfig(root=str(tmp_path / "kitti2015"), depth="disparity", disparity_baseline=0.54,
                           pose="net", random_init=True, size="native", device="cpu",
                           out=str(tmp_path / "cache"), progress=False)
    summary = run_preprocess(cfg)
    assert summary.pairs == 1 and summary.pose_net_pairs == 1 and summary.depth_net_images == 0
    s = CacheReader(summary.cache_root)[0]
    disp = read_disparity_png(seq / "disp_2/000001.png")
    expected = canonical_depth(np.where(disp > 0, 721.5377 * 0.54 / np.maximum(disp, 1e-6), 0).astype(np.float32))
    assert np.allclose(s.depth2, expected, atol=1e-6)
    # Metric points: the filters keep a street scene's nearby structure.
    assert len(s.pc1) > 5000
    assert 3.0 < np.median(s.pc1[:, 2]) < 35.0
    assert s.pc1[:, 1].max() < 1.15
    st = s.stats
    assert st["pc1_valid"] == 375 * 1242 and st["pc1_ground"] < st["pc1_valid"]
