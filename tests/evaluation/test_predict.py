"""monoflow-predict: on the real seq-06 frames (dataset poses, random depth net, camera-height scale) it writes the
HDF5 file, PLY files and pictures; on the synthetic world its flow equals what monoflow-evaluate scores for the same
net on the same points; interrupted runs resume; bad input is one line."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from evaluation.predict.cli import main as predict_main
from evaluation.predict.config import PredictConfig
from evaluation.predict.inputs import parse_intrinsics
from evaluation.predict.run import run_predict
from pipeline.kitti.poses import read_poses
from pipeline.scale import ScaleConfig
from testkit.flow_checkpoint import tiny_flow_checkpoint

GRAY = "kitti_odometry_06_gray"


@pytest.fixture(scope="module")
def flow_ckpt(tmp_path_factory) -> Path:
    return tiny_flow_checkpoint(tmp_path_factory.mktemp("flow") / "tiny.pt", seed=3)


def gray_sequence(shared_data: Path, tmp_path: Path, n: int) -> Path:
    """root/sequences/06/{image_0 (the first n real grey frames), calib.txt}; root/poses/06.txt = the full
    1,101-line official file (predict's default pose count check is lenient)."""
    seq = tmp_path / "kitti" / "sequences" / "06"
    (seq / "image_0").mkdir(parents=True)
    for i in range(n):
        (seq / "image_0" / f"{i:06d}.png").symlink_to(shared_data / GRAY / "image_l" / f"{i:06d}.png")
    (seq / "calib.txt").symlink_to(shared_data / GRAY / "calib.txt")
    (tmp_path / "kitti" / "poses").mkdir()
    shutil.copy(shared_data / "kitti_odometry_06_color" / "videos_kitti06" / "06.txt", tmp_path / "kitti/poses/06.txt")
    return seq


@pytest.mark.slow
def test_predict_real_seq06_dataset_poses_camera_height(shared_data, tmp_path, flow_ckpt):
    pytest.importorskip("matplotlib")
    seq = gray_sequence(shared_data, tmp_path, 5)
    out = tmp_path / "pred"
    rc = predict_main(["--input", str(seq), "--camera", "image_0", "--depth", "net", "--random_init", "true",
                       "--pose", "gt", "--scale.mode", "camera-height", "--size", "256x96", "--block_size", "2",
                       "--checkpoint", str(flow_ckpt), "--out", str(out), "--pictures", "true", "--ply", "true",
                       "--progress", "false", "--flow_batch", "3", "--keep_parts", "true"])
    assert rc == 0
    h5 = out / "06.h5"
    poses = read_poses(shared_data / GRAY / "poses.txt")
    with h5py.File(h5, "r") as f:
        assert f.attrs["units"] == "metres" and f.attrs["format"] == "monoflow-predict"
        assert f.attrs["moving_threshold_m"] == pytest.approx(0.3)
        assert f["frames"][...].tolist() == [[0, 1], [1, 2], [2, 3], [3, 4]]
        K = f["intrinsics"][...]
        assert K[0, 0] == pytest.approx(707.0912 * 256 / 1226, rel=1e-6)
        assert tuple(f.attrs["image_size_hw"]) == (96, 256)
        assert f["scale"].shape == (4,) and np.all(f["scale"][...] > 0)
        for k, (t, t1) in enumerate([(0, 1), (1, 2), (2, 3), (3, 4)]):
            g = f["pairs"][f"06_{t:06d}_{t1:06d}"]
            pc1, flow, static, dyn = (g[x][...] for x in ("pc1", "flow", "static_flow", "dynamic_flow"))
            n1, n2 = len(pc1), len(g["pc2"])
            assert n1 > 500 and n2 > 500
            assert flow.shape == static.shape == dyn.shape == (n1, 3) and g["rgb1"].shape == (n1, 3)
            assert g["uv1"].shape == (n1, 2) and g["moving"].shape == (n1,) and g["pc2"].shape == (n2, 3)
            assert g["pc1"].attrs["units"].startswith("metres") and g["flow"].attrs["units"].startswith("metres")
            # the pose is the dataset's (metric, not rescaled) and the static flow is exactly what it implies
            T_expected = np.linalg.inv(poses[t1]) @ poses[t]
            T = f["poses"][k]
            assert np.allclose(T, T_expected, atol=1e-9) and np.allclose(g.attrs["T"], T)
            implied = pc1.astype(np.float64) @ T[:3, :3].T + T[:3, 3] - pc1
            assert np.allclose(static, implied, atol=1e-5)
            assert 0.5 < np.linalg.norm(T[:3, 3]) < 1.5  # seq 06 drives ≈ 1 m per frame
            assert np.allclose(dyn, flow - static, atol=1e-6)
            assert np.array_equal(g["moving"][...], np.linalg.norm(dyn, axis=1) > 0.3)
            assert np.all(np.isfinite(flow))
            # the filters ran in metres: nothing below the ground cut or beyond the far cut
            assert pc1[:, 1].max() < 1.15 and pc1[:, 2].max() < 35.0
    pictures = sorted((out / "06-pictures").glob("*.png"))
    plys = sorted((out / "06-ply").glob("*.ply"))
    assert len(pictures) == 4 and len(plys) == 4
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 20_000 for p in pictures)
    head = plys[0].read_bytes()[:400].decode("ascii", "replace")
    assert "element vertex" in head and "property float fz" in head

    # a finished run is not overwritten silently; --overwrite true redoes it
    assert predict_main(["--input", str(seq), "--camera", "image_0", "--checkpoint", str(flow_ckpt),
                         "--out", str(out), "--random_init", "true", "--progress", "false"]) == 2


@pytest.mark.parametrize("polish", [False, True])
def test_predict_matches_evaluate_on_synthetic_world(synth_root, tmp_path, flow_ckpt, polish):
    """predict's flow for each pair = monoflow-evaluate's saved prediction (protocol full) for the same net on
    the same points (the pair's clouds written as a FlowNet3D split); with ``rigid_polish``, the same as the
    '+ rigid polish' row."""
    from evaluation.cli import main as evaluate_main
    from evaluation.predictions import read_predictions
    from core.axes import FORMAT_AXES

    camera_to_flownet3d = FORMAT_AXES["flownet3d"].from_camera

    out = tmp_path / "pred"
    cfg = PredictConfig(input=str(synth_root / "sequences" / "00"), depth="gt", pose="gt",
                        scale=ScaleConfig(mode="none"), size="native", max_frames=4, block_size=2,
                        checkpoint=str(flow_ckpt), out=str(out), flow_batch=2, progress=False, sample_seed=5,
                        rigid_polish=polish)
    summary = run_predict(cfg)
    assert summary.pairs == 3 and summary.h5_path.is_file() and not summary.warnings
    split = tmp_path / "split"
    split.mkdir()
    flows = {}
    with h5py.File(summary.h5_path, "r") as f:
        for name in f["pairs"]:
            g = f["pairs"][name]
            flows[name] = g["flow"][...]
            assert "gt_flow" in g  # the synthetic world's ground truth comes along
            np.savez(split / f"{name}.npz", pos1=camera_to_flownet3d(g["pc1"][...]),
                     pos2=camera_to_flownet3d(g["pc2"][...]), gt=np.zeros_like(g["pc1"][...]),
                     color1=g["rgb1"][...].astype(np.float32) / 255, color2=g["rgb2"][...].astype(np.float32) / 255)
    ev = tmp_path / "eval"
    assert evaluate_main(["run", "--split", str(split), "--checkpoint", str(flow_ckpt), "--baselines", "",
                          "--protocol", "full", "--seeds", "5", "--save-predictions", "--out", str(ev),
                          "--no-progress", *(["--rigid-polish"] if polish else [])]) == 0
    files = sorted(ev.glob("predictions-*.h5"), key=lambda f: len(f.name))
    assert len(files) == (2 if polish else 1)
    preds = read_predictions(files[-1])  # the polished row's name is the longer one
    if polish:  # the polish changed something, so matching its row is not matching the net's
        plain = {p.name: p.pred_flow for p in read_predictions(files[0])}
        assert any(not np.allclose(p.pred_flow, plain[p.name], atol=1e-4) for p in preds)
    assert sorted(p.name for p in preds) == sorted(flows)
    for p in preds:
        assert p.pred_flow.shape == flows[p.name].shape
        assert np.allclose(p.pred_flow, flows[p.name], atol=1e-5), p.name
        assert np.abs(flows[p.name]).max() > 1e-3  # a real prediction, not zeros


def test_predict_resumes_from_finished_pairs(synth_root, tmp_path, flow_ckpt, monkeypatch):
    from evaluation.predict import run as run_mod

    base = dict(input=str(synth_root / "sequences" / "00"), depth="gt", pose="gt", scale=ScaleConfig(mode="none"),
                size="native", max_frames=5, block_size=2, checkpoint=str(flow_ckpt), progress=False)
    first = run_predict(PredictConfig(**base, out=str(tmp_path / "a")))
    calls = []
    real = run_mod.FlowPredictor.__call__

    def interrupted(self, pairs):
        calls.append(len(pairs))
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(self, pairs)

    monkeypatch.setattr(run_mod.FlowPredictor, "__call__", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_predict(PredictConfig(**base, out=str(tmp_path / "b")))
    assert not (tmp_path / "b" / "00.h5").exists()
    done = sorted((tmp_path / "b" / "00.parts").glob("*.npz"))
    assert len(done) == 2  # the first block's pairs
    monkeypatch.setattr(run_mod.FlowPredictor, "__call__", real)
    second = run_predict(PredictConfig(**base, out=str(tmp_path / "b")))
    assert second.pairs_done_before == 2 and second.pairs == first.pairs == 4
    with h5py.File(first.h5_path) as a, h5py.File(second.h5_path) as b:
        for name in a["pairs"]:
            assert np.array_equal(a["pairs"][name]["flow"][...], b["pairs"][name]["flow"][...])


@pytest.mark.slow
def test_image_folder_and_video_inputs(synth_root, tmp_path, flow_ckpt):
    """A plain folder of images and a video (OpenCV) run with given intrinsics (random depth net, fixed scale)."""
    import cv2

    images = sorted((synth_root / "sequences" / "00" / "image_2").glob("*.png"))[:3]
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, p in enumerate(images):
        shutil.copy(p, folder / f"shot_{k:03d}.png")
    common = ["--checkpoint", str(flow_ckpt), "--depth", "net", "--pose", "net", "--random_init", "true",
              "--scale.mode", "fixed", "--scale.factor", "50", "--size", "192x64", "--progress", "false",
              "--intrinsics", "100,100,104,32"]
    assert predict_main(["--input", str(folder), "--out", str(tmp_path / "o1"), *common]) == 0
    with h5py.File(tmp_path / "o1" / "frames.h5") as f:
        assert f["frames"].shape == (2, 2) and f.attrs["input_kind"] == "images"
        assert np.allclose(f["intrinsics"][...][0], [100 * 192 / 208, 0, 104 * 192 / 208])
    video = tmp_path / "clip.avi"
    first = cv2.imread(str(images[0]))
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (first.shape[1], first.shape[0]))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG videos")
    for p in images:
        writer.write(cv2.imread(str(p)))
    writer.release()
    assert predict_main(["--input", str(video), "--out", str(tmp_path / "o2"), *common]) == 0
    with h5py.File(tmp_path / "o2" / "clip.h5") as f:
        assert f["frames"].shape == (2, 2) and f.attrs["input_kind"] == "video"


def test_bad_inputs_are_one_line(tmp_path, flow_ckpt, capsys):
    assert predict_main(["--input", str(tmp_path / "nope"), "--checkpoint", str(flow_ckpt)]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    folder = tmp_path / "imgs"
    folder.mkdir()
    (folder / "a.png").write_bytes(b"x")
    (folder / "b.png").write_bytes(b"x")
    assert predict_main(["--input", str(folder), "--checkpoint", str(flow_ckpt)]) == 2  # no intrinsics
    assert "intrinsics" in capsys.readouterr().err
    bad_ck = tmp_path / "bad.pt"
    bad_ck.write_bytes(b"not a checkpoint")
    assert predict_main(["--input", str(folder), "--checkpoint", str(bad_ck), "--intrinsics", "1,1,1,1"]) == 2
    assert "bad.pt" in capsys.readouterr().err


def test_parse_intrinsics(tmp_path, shared_data):
    K = parse_intrinsics("721.5,721.5,609.6,172.9")
    assert K[0, 0] == 721.5 and K[1, 2] == 172.9 and K[2, 2] == 1
    K2 = parse_intrinsics(str(shared_data / "kitti_object_000008" / "calib_000008.txt"))
    assert K2[0, 0] == pytest.approx(721.5377) and K2[0, 2] == pytest.approx(609.5593)
    f = tmp_path / "k.txt"
    f.write_text("700 0 600\n0 700 180\n0 0 1\n")
    assert parse_intrinsics(str(f))[1, 2] == 180
