"""KITTI Scene Flow 2015 → point pairs (pipeline/kitti/stereo_flow.py): geometry, the written layout, the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import InputError
from evaluation.readers import HPLFlowNetOptions, load_split
from pipeline.cli import main as preprocess_main
from pipeline.kitti.png16 import write_disparity_png, write_flow_png
from pipeline.kitti.stereo_flow import (BASELINE_M, back_project, build_split, stereo_pairs, temporary_folder,
                                         write_hpl_scene)

H, W = 60, 90
F, CX, CY = 80.0, 44.5, 29.5


def _projection(p03: float = 0.0, p13: float = 0.0, p23: float = 0.0) -> np.ndarray:
    return np.array([[F, 0, CX, p03], [0, F, CY, p13], [0, 0, 1, p23]], dtype=np.float64)


def _yaw(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _rendered(R: np.ndarray, t: np.ndarray, P: np.ndarray):
    """KITTI-style maps of a slanted wall seen at every pixel, which moves by (R, t) (camera axes, metres):
    frame t's disparity, frame t+1's disparity at frame t's pixels, the optical flow. Returns the maps and the
    true (H·W, 3) points at t and t+1, in the frame ``back_project`` uses."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    depth = 8.0 + 0.05 * u + 0.02 * v  # a slanted wall, 8–13 m away
    pts = back_project(u.ravel(), v.ravel(), depth.ravel(), P)
    moved = pts @ R.T + t
    z2 = moved[:, 2]
    u2 = (F * moved[:, 0] + CX * z2 + P[0, 3]) / (z2 + P[2, 3])
    v2 = (F * moved[:, 1] + CY * z2 + P[1, 3]) / (z2 + P[2, 3])
    d0 = (F * BASELINE_M / depth).astype(np.float32)
    d1 = (F * BASELINE_M / z2).reshape(H, W).astype(np.float32)
    flow = np.stack([u2 - u.ravel(), v2 - v.ravel()], axis=1).reshape(H, W, 2).astype(np.float32)
    return d0, d1, flow, pts, moved


@pytest.mark.parametrize("offsets", [(0.0, 0.0, 0.0), (44.86, 0.216, 0.0027)])  # none / KITTI's P_rect_02
def test_pairs_are_the_surface_points_at_both_times(offsets):
    P = _projection(*offsets)
    R, t = _yaw(2.0), np.array([0.3, -0.05, -1.1])
    d0, d1, flow, pts, moved = _rendered(R, t, P)
    pairs = stereo_pairs(d0, d1, flow, np.ones((H, W), bool), P)
    assert len(pairs.pc1) == H * W
    order = pairs.pixels[:, 1] * W + pairs.pixels[:, 0]
    # the depth's 1e-5 px disparity offset (HPLFlowNet's) and float32 maps leave well under a millimetre here
    np.testing.assert_allclose(pairs.pc1, pts[order], atol=1e-3)
    np.testing.assert_allclose(pairs.pc2, moved[order], atol=1e-3)
    np.testing.assert_allclose(pairs.flow, (moved - pts)[order], atol=2e-3)


def test_invalid_pixels_are_left_out():
    P = _projection()
    d0, d1, flow, _, _ = _rendered(np.eye(3), np.zeros(3), P)
    valid = np.ones((H, W), bool)
    valid[:10] = False  # no flow there
    d0[20, :] = 0  # no disparity at t
    d1[30, 5] = 0  # no disparity at t+1
    pairs = stereo_pairs(d0, d1, flow, valid, P)
    assert len(pairs.pc1) == H * W - 10 * W - W - 1
    assert pairs.pixels[:, 1].min() == 10 and not (pairs.pixels[:, 1] == 20).any()


def test_mismatched_maps_and_bad_projection_are_one_line_errors():
    P = _projection()
    d0, d1, flow, _, _ = _rendered(np.eye(3), np.zeros(3), P)
    with pytest.raises(InputError, match="share one"):
        stereo_pairs(d0, d1[:-1], flow, np.ones((H, W), bool), P, where="x.png")
    skew = P.copy()
    skew[0, 1] = 0.5
    with pytest.raises(InputError, match="rectified projection"):
        stereo_pairs(d0, d1, flow, np.ones((H, W), bool), skew, where="calib.txt")


def _kitti_folder(root: Path, scenes: int) -> list[np.ndarray]:
    """A KITTI Scene Flow 2015 training folder with ``scenes`` rendered scenes; their true flows."""
    P = _projection(44.86, 0.216, 0.0027)
    train = root / "training"
    truths = []
    for i in range(scenes):
        d0, d1, flow, pts, moved = _rendered(_yaw(1.0 * i), np.array([0.0, 0.0, -0.5 - 0.2 * i]), P)
        write_disparity_png(train / "disp_occ_0" / f"{i:06d}_10.png", d0)
        write_disparity_png(train / "disp_occ_1" / f"{i:06d}_10.png", d1)
        write_flow_png(train / "flow_occ" / f"{i:06d}_10.png", flow)
        lines = [f"calib_time: 09-Jan-2012 13:57:47"]
        for cam in ("00", "01", "02", "03"):
            lines += [f"S_{cam}: {W} {H}", f"K_{cam}: " + " ".join(map(str, P[:, :3].ravel())),
                      f"D_{cam}: 0 0 0 0 0", f"R_{cam}: 1 0 0 0 1 0 0 0 1", f"T_{cam}: 0 0 0",
                      f"S_rect_{cam}: {W} {H}", f"R_rect_{cam}: 1 0 0 0 1 0 0 0 1",
                      f"P_rect_{cam}: " + " ".join(map(str, P.ravel()))]
        (train / "calib_cam_to_cam").mkdir(parents=True, exist_ok=True)
        (train / "calib_cam_to_cam" / f"{i:06d}.txt").write_text("\n".join(lines) + "\n")
        truths.append(moved - pts)
    return truths


def test_cli_writes_a_split_the_hplflownet_reader_reads(tmp_path, capsys):
    truths = _kitti_folder(tmp_path / "data_scene_flow", 2)
    out = tmp_path / "KITTI_processed_occ_final"
    assert preprocess_main(["kitti-sceneflow", str(tmp_path / "data_scene_flow"), str(out), "--scenes", "2"]) == 0
    assert "2 scenes" in capsys.readouterr().out
    split = load_split(out, hplflownet=HPLFlowNetOptions(remove_ground=False, max_depth=None))
    assert split.fmt == "hplflownet" and len(split) == 2
    for k in range(2):
        sample = split[k]  # read back in camera axes
        assert len(sample.pc1) == H * W
        # PNG storage rounds disparity to 1/256 px (≤ 0.6 mm per px of a 3.3 px disparity: ≤ 1 cm of depth at
        # 13 m, per frame) and flow to 1/64 px (≤ 1 cm sideways at 13 m, f = 80 px): the stored precision
        err = np.linalg.norm(sample.flow - truths[k], axis=1)
        assert np.median(err) < 0.01 and err.max() < 0.05
        assert np.abs(sample.flow[:, 2].mean() - truths[k][:, 2].mean()) < 0.02


def test_finished_scenes_are_kept_and_a_half_written_one_is_redone(tmp_path):
    _kitti_folder(tmp_path / "sf", 2)
    out = tmp_path / "split"
    build_split(tmp_path / "sf", out, range(1), log=lambda *_: None)
    first = (out / "000000" / "pc1.npy").stat().st_mtime_ns
    tmp = temporary_folder(out / "000001")  # an interrupted write of scene 1: outside the split
    assert tmp.parent == out.parent
    tmp.mkdir()
    (tmp / "pc1.npy").write_bytes(b"partial")
    assert len(load_split(out)) == 1  # the reader sees the finished scene only
    written = build_split(tmp_path / "sf", out, range(2), log=lambda *_: None)
    assert [p.name for p in written] == ["000000", "000001"]
    assert (out / "000000" / "pc1.npy").stat().st_mtime_ns == first
    assert not tmp.exists()
    assert np.load(out / "000001" / "pc1.npy").shape == (H * W, 3)


def test_a_missing_map_is_one_line_naming_it(tmp_path, capsys):
    _kitti_folder(tmp_path / "sf", 1)
    (tmp_path / "sf" / "training" / "flow_occ" / "000000_10.png").unlink()
    assert preprocess_main(["kitti-sceneflow", str(tmp_path / "sf"), str(tmp_path / "out"), "--scenes", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "flow_occ" in err[0] and "000000_10.png" in err[0]
    assert not (tmp_path / "out" / "000000").exists()


def test_moving_labels_are_written_beside_the_points(tmp_path):
    P = _projection()
    d0, d1, flow, _, _ = _rendered(np.eye(3), np.array([0.0, 0.0, -1.0]), P)
    pairs = stereo_pairs(d0, d1, flow, np.ones((H, W), bool), P)
    moving = np.arange(len(pairs.pc1)) % 3 == 0
    write_hpl_scene(tmp_path / "s" / "000000", pairs, moving)
    sample = load_split(tmp_path / "s", hplflownet=HPLFlowNetOptions(remove_ground=False, max_depth=None))[0]
    np.testing.assert_array_equal(sample.moving, moving)
    with pytest.raises(ValueError, match="moving must be"):
        write_hpl_scene(tmp_path / "s" / "000001", pairs, moving[:-1])
