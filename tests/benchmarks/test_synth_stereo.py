"""benchmarks/synth_stereo.py: stereoKITTI-style image-grid point-pair splits from a synthetic world's per-pixel
depth and true flow, read back by the evaluation's readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.real_stereo import dominant_motion
from benchmarks.synth_stereo import SynthStereoConfig, build_split, main, pixel_pairs
from core.geometry import project
from evaluation.pairing import choose_pairing
from evaluation.readers import load_split
from pipeline.kitti.odometry import OdometrySequence
from _point_pairs import assert_flownet3d_holds_the_same_pairs


def test_pixels_become_pairs_whose_static_flow_is_the_camera_s_rigid_motion(synth_root: Path, tmp_path: Path):
    seq = OdometrySequence(synth_root, "00")
    pairs, moving = pixel_pairs(seq, 0)
    # every pair is a pixel of frame t: its point projects back onto that pixel
    uv, _ = project(pairs.pc1.astype(np.float64), seq.K.astype(np.float64))
    np.testing.assert_allclose(uv, pairs.pixels, atol=1e-3)
    assert len(pairs.pc1) > 0.5 * seq.image_shape[0] * seq.image_shape[1]  # most pixels see something
    n, kept, share = build_split(SynthStereoConfig(world=str(synth_root), pairs=3, out=str(tmp_path / "split")))
    assert n == 3 and kept > 1000 and 0 < share < 0.5
    split = load_split(str(tmp_path / "split"), "auto")
    assert len(split) == 3 and split.fmt == "hplflownet"
    assert (tmp_path / "split" / "mapping.txt").read_text().count("\n") == 3
    s = split[1]
    static = ~s.moving
    T = dominant_motion(s.pc1[static], (s.pc1 + s.flow)[static])
    resid = np.linalg.norm(s.pc1 @ T[:3, :3].T + T[:3, 3] - (s.pc1 + s.flow), axis=1)
    assert resid[static].max() < 1e-3  # the background moves exactly with the camera (float32 rounding)
    assert s.moving.any() and np.median(resid[s.moving]) > 0.1  # the movers do not
    assert s.pc1[:, 2].max() < 35  # the reader's range cut
    assert not (tmp_path / "split.partial").exists()


def test_the_flownet3d_layout_holds_the_reader_s_pairs_in_rows_of_their_own(synth_root: Path, tmp_path: Path):
    build_split(SynthStereoConfig(world=str(synth_root), pairs=2, out=str(tmp_path / "hpl")))
    build_split(SynthStereoConfig(world=str(synth_root), pairs=2, layout="flownet3d", out=str(tmp_path / "fn3d")))
    hpl, fn3d = load_split(str(tmp_path / "hpl"), "auto"), load_split(str(tmp_path / "fn3d"), "auto")
    assert_flownet3d_holds_the_same_pairs(hpl, fn3d)
    assert choose_pairing(fn3d, "flownet3d", by_format=False).pairing == "points"


def test_an_existing_folder_or_a_missing_depth_map_is_one_line(synth_root: Path, tmp_path: Path, capsys):
    (tmp_path / "taken").mkdir()
    assert main(["--world", str(synth_root), "--out", str(tmp_path / "taken")]) == 2
    assert "exists" in capsys.readouterr().err
    broken = tmp_path / "world"
    (broken / "sequences" / "00").mkdir(parents=True)
    for item in (synth_root / "sequences" / "00").iterdir():
        if item.name != "depth_2":
            (broken / "sequences" / "00" / item.name).symlink_to(item)
    (broken / "sequences" / "00" / "depth_2").mkdir()
    assert main(["--world", str(broken), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "depth_2" in err[0] and not (tmp_path / "x").exists()
