"""Stage one's sources: frames at the working size, depth (net / gt / LiDAR / disparity), poses, ground truth."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from core.errors import ConfigError, InputError
from pipeline.sources import (
    DatasetPose,
    DisparityDepth,
    GroundTruthDepth,
    LidarDepth,
    NetDepth,
    NetSpec,
    build_runner,
    make_depth_source,
    nearest_resample,
    pad_to_multiple,
    project_lidar,
    read_frames,
    read_gt_flow,
    velo_to_cam,
    working_K,
)

SYNTH = dict(seed=0, width=208, height=64, n_sequences=1, frames=9, test_frames=0)
R_VELO = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@pytest.fixture(scope="session")
def synth_root(tmp_path_factory):
    from pipeline.synth import SynthConfig, generate

    root = tmp_path_factory.getbasetemp() / "synth_w208_h64_s0_f9"
    generate(SynthConfig(**SYNTH), root)
    return root


@pytest.fixture()
def seq(synth_root):
    from pipeline.kitti.odometry import OdometrySequence

    return OdometrySequence(synth_root, "00")


# --------------------------------------------------------------------------- pure helpers


def test_nearest_resample_takes_the_native_pixel_under_the_scaled_K():
    native = np.arange(4 * 6).reshape(4, 6)
    # Working (u, v) ↔ native (u / sx, v / sy) with sx = sy = 0.5: rows 0, 2; columns 0, 2, 4.
    assert nearest_resample(native, (2, 3)).tolist() == [[0, 2, 4], [12, 14, 16]]
    assert nearest_resample(native, (4, 6)) is native
    flow = np.stack([native] * 3, -1)
    assert nearest_resample(flow, (2, 3))[..., 1].tolist() == [[0, 2, 4], [12, 14, 16]]


def test_pad_to_multiple_replicates_edges():
    img = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(1, 2, 3, 3)
    out = pad_to_multiple(img, 4)
    assert out.shape == (1, 4, 4, 3)
    assert (out[0, 3, 3] == img[0, 1, 2]).all() and (out[0, 0, 3] == img[0, 0, 2]).all()
    assert pad_to_multiple(np.zeros((1, 370, 1226, 3), np.uint8)).shape == (1, 384, 1248, 3)


def test_project_lidar_z_buffers_the_nearest_return():
    K = np.array([[10.0, 0, 4.0], [0, 10.0, 3.0], [0, 0, 1]])
    scan = np.array(
        [
            [10.0, 0.0, 0.0, 0.5],  # straight ahead → pixel (4, 3), z 10
            [5.0, 0.0, 0.0, 0.5],  # same ray, nearer → wins
            [10.0, -1.0, 1.0, 0.5],  # right and up: cam (1, -1, 10) → pixel (5, 2)
            [-10.0, 0.0, 0.0, 0.5],  # behind
            [10.0, 20.0, 0.0, 0.5],  # far left, outside
        ],
        dtype=np.float32,
    )
    d = project_lidar(scan, R_VELO, K, (6, 8))
    assert d[3, 4] == 5.0 and d[2, 5] == 10.0
    assert np.count_nonzero(d) == 2


def test_build_runner_needs_a_checkpoint_or_random_init():
    assert build_runner(NetSpec()) is None
    with pytest.raises(ConfigError, match="depth_checkpoint"):
        build_runner(NetSpec(need_depth=True))
    with pytest.raises(ConfigError):
        make_depth_source("stereo")


# --------------------------------------------------------------------------- on the synthetic world


def test_frames_and_K_at_a_working_size(seq):
    imgs = read_frames(seq, [0, 1], (32, 104))
    assert imgs.shape == (2, 32, 104, 3) and imgs.dtype == np.uint8
    K = working_K(seq, (32, 104))
    assert np.allclose(K[0], seq.K[0] * 0.5) and np.allclose(K[1], seq.K[1] * 0.5) and K[2, 2] == 1
    full = seq.read_image(0).astype(np.float64)
    assert abs(imgs[0].mean() - full.mean()) < 2.0  # area resize keeps the brightness


def test_ground_truth_depth_native_and_resized(seq):
    from pipeline.kitti.png16 import read_depth_png

    H, W = seq.image_shape
    native = read_depth_png(seq.seq_dir / "depth_2" / "000002.png")
    d = GroundTruthDepth().depths(seq, [2], np.zeros((1, H, W, 3), np.uint8), seq.K)
    assert np.array_equal(d[0], native)
    half = GroundTruthDepth().depths(seq, [2], np.zeros((1, H // 2, W // 2, 3), np.uint8), seq.K)
    assert np.array_equal(half[0], native[::2, ::2])


def test_lidar_depth_agrees_with_ground_truth_depth(seq):
    H, W = seq.image_shape
    lidar = LidarDepth().depths(seq, [0], np.zeros((1, H, W, 3), np.uint8), seq.K)[0]
    gt = GroundTruthDepth().depths(seq, [0], np.zeros((1, H, W, 3), np.uint8), seq.K)[0]
    both = (lidar > 0) & (gt > 0)
    assert both.sum() > 500
    rel = np.abs(lidar[both] - gt[both]) / gt[both]
    assert np.median(rel) < 0.02  # same surfaces (rounding to the pixel centre moves a return a little)


def test_dataset_pose_is_the_relative_pose(seq):
    T = DatasetPose().poses(seq, [(0, 1), (3, 4)], None, None)
    assert T.shape == (2, 4, 4)
    assert np.allclose(T[1], seq.relative_pose(3, 4))
    assert T[0][2, 3] < -0.5  # driving forward: the scene comes towards the camera


def test_gt_flow_reading_and_bad_files(seq, tmp_path):
    H, W = seq.image_shape
    gt = read_gt_flow(seq, 0, (H, W))
    assert gt.flow.shape == (H, W, 3) and gt.valid.any() and gt.moving.dtype == bool
    from pipeline.kitti.odometry import OdometrySequence

    root = tmp_path / "w"
    shutil.copytree(seq.root, root)
    broken = OdometrySequence(root, "00")
    (root / "sequences" / "00" / "flow3d_2" / "000001.npz").unlink()
    with pytest.raises(InputError, match="000001.npz"):
        read_gt_flow(broken, 1, (H, W))
    np.savez(root / "sequences" / "00" / "flow3d_2" / "000002.npz", flow=np.zeros((3, 3, 3)),
             moving=np.zeros((3, 3), bool), valid=np.zeros((3, 3), bool), visible_next=np.zeros((3, 3), bool))
    with pytest.raises(InputError, match="shape"):
        read_gt_flow(broken, 2, (H, W))


def test_velo_to_cam_needs_tr(seq, tmp_path):
    assert np.allclose(velo_to_cam(seq), seq.T_velo_to_cam)
    from pipeline.kitti.calib import write_odometry_calib
    from pipeline.kitti.odometry import OdometrySequence

    root = tmp_path / "w"
    shutil.copytree(seq.root, root)
    write_odometry_calib(root / "sequences" / "00" / "calib.txt", seq.calib.P)  # no Tr
    with pytest.raises(InputError, match="calib.txt"):
        velo_to_cam(OdometrySequence(root, "00"))


def test_net_depth_pads_runs_once_per_frame_and_crops(seq):
    runner = build_runner(NetSpec(need_depth=True, random_init=True, device="cpu", batch_size=2))
    imgs = read_frames(seq, [0, 1, 2], (40, 100))  # sides not multiples of 32
    d = NetDepth(runner).depths(seq, [0, 1, 2], imgs, working_K(seq, (40, 100)))
    assert d.shape == (3, 40, 100) and d.dtype == np.float32
    assert runner.depth_images == 3 and runner.depth_forwards == 2
    assert (d >= 1 / 10.01 - 1e-4).all() and (d <= 100.0 + 1e-3).all()  # 1 / (10 σ + 0.01)
    again = build_runner(NetSpec(need_depth=True, random_init=True, device="cpu", batch_size=2))
    assert np.array_equal(NetDepth(again).depths(seq, [0, 1, 2], imgs, None), d)  # seeded: reproducible


# --------------------------------------------------------------------------- real KITTI: external disparity


def test_disparity_depth_on_kitti_2015_scene_139(shared_data, tmp_path):
    """Published Self-Mono-SF disparities of scene 139 → depth = fx · 0.54 / d with P_rect_02's fx."""
    from pipeline.kitti.calib import read_raw_cam_to_cam, write_odometry_calib
    from pipeline.kitti.odometry import OdometrySequence
    from pipeline.kitti.png16 import read_disparity_png

    sf = shared_data / "kitti_sceneflow2015_000139"
    raw = read_raw_cam_to_cam(shared_data / "kitti_raw_calib_2011_09_26/2011_09_26_calib/2011_09_26/calib_cam_to_cam.txt")
    seq_dir = tmp_path / "kitti" / "sequences" / "00"
    (seq_dir / "image_2").mkdir(parents=True)
    shutil.copy(sf / "kitti_img/image_2/000139_10.png", seq_dir / "image_2/000000.png")
    write_odometry_calib(seq_dir / "calib.txt", {"P0": raw.P_rect["00"], "P2": raw.P_rect["02"]})
    disp_dir = tmp_path / "disp" / "00"
    disp_dir.mkdir(parents=True)
    shutil.copy(sf / "results/disp_0/000139_10.png", disp_dir / "000000.png")
    seq = OdometrySequence(tmp_path / "kitti", "00")
    assert seq.K[0, 0] == pytest.approx(721.5377)

    src = DisparityDepth(str(tmp_path / "disp" / "{seq}"), baseline=0.54)
    H, W = seq.image_shape
    d = src.depths(seq, [0], np.zeros((1, H, W, 3), np.uint8), seq.K)[0]
    disp = read_disparity_png(disp_dir / "000000.png")
    assert disp[200, 600] == pytest.approx(13.26953125)
    assert d[200, 600] == pytest.approx(721.5377 * 0.54 / 13.26953125, rel=1e-6)  # ≈ 29.4 m
    assert np.all((d > 0) == (disp > 0))
    # At the default working size the map is resampled (nearest) and stays metric.
    small = src.depths(seq, [0], np.zeros((1, 256, 832, 3), np.uint8), None)[0]
    assert small.shape == (256, 832) and small[0, 0] == d[0, 0]
    # Explicit focal length; a missing file is named.
    assert DisparityDepth(str(disp_dir), focal=700.0).depths(seq, [0], np.zeros((1, H, W, 3), np.uint8), None)[0][
        200, 600] == pytest.approx(700.0 * 0.54 / 13.26953125, rel=1e-6)
    with pytest.raises(InputError, match="000000.png"):
        DisparityDepth(str(tmp_path / "nowhere")).depths(seq, [0], np.zeros((1, H, W, 3), np.uint8), None)
