"""benchmarks/real_stereo.py: a stereo-KITTI-style split with movers from the real KITTI 2015 scene 000139 (Self-Mono-SF's
predicted disparities and flow), read back by the evaluation's HPLFlowNet reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchmarks.real_stereo import RealStereoConfig, build_split, dominant_motion, main
from evaluation.readers import load_split
from _point_pairs import assert_flownet3d_holds_the_same_pairs

SCENE = "kitti_sceneflow2015_000139"
CALIB = "kitti_raw_calib_2011_09_26/2011_09_26_calib/2011_09_26/calib_cam_to_cam.txt"


def _cfg(shared_data: Path, out: Path, **kw) -> RealStereoConfig:
    return RealStereoConfig(scene=str(shared_data / SCENE), calib=str(shared_data / CALIB), out=str(out), **kw)


def test_scenes_are_disjoint_pixels_of_one_street_with_its_movers(shared_data: Path, tmp_path: Path):
    cfg = _cfg(shared_data, tmp_path / "split", pairs=3)
    per_scene, moving_share = build_split(cfg)
    names = sorted(p.name for p in (tmp_path / "split").iterdir() if p.is_dir())
    assert names == ["000000", "000001", "000002"]
    assert (tmp_path / "split" / "mapping.txt").read_text().count("\n") == 3  # every line non-empty: all kept
    split = load_split(str(tmp_path / "split"), "auto")  # the reader's ground and 35 m cuts
    pc1 = [split[i].pc1 for i in range(3)]
    assert all(abs(len(p) - per_scene) <= 0.02 * per_scene for p in pc1)
    assert len(np.unique(np.concatenate(pc1), axis=0)) == sum(len(p) for p in pc1)  # no pixel twice
    s = split[0]
    assert s.pc1[:, 2].max() < 35 and s.pc1[:, 1].max() < 1.4 + 0.5  # the reader cut the ground (both clouds)
    # the street: the camera drives forward (static points come closer by most of a metre per frame) ...
    static = ~s.moving
    assert -1.2 < np.median(s.flow[static, 2]) < -0.4
    # ... and the flow of the points labelled static is close to one rigid motion, the movers' is not
    T = dominant_motion(s.pc1[static], (s.pc1 + s.flow)[static])
    resid = np.linalg.norm(s.pc1 @ T[:3, :3].T + T[:3, 3] - (s.pc1 + s.flow), axis=1)
    assert np.median(resid[static]) < 0.15 and resid[~s.moving].max() <= cfg.moving_m + 0.05
    assert resid[s.moving].min() > 0.25 and 0.1 < moving_share < 0.5  # the oncoming van, the cars ahead


def test_an_existing_folder_or_a_missing_png_is_one_line(shared_data: Path, tmp_path: Path, capsys):
    (tmp_path / "taken").mkdir()
    assert main(["--scene", str(shared_data / SCENE), "--calib", str(shared_data / CALIB),
                 "--out", str(tmp_path / "taken")]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["--scene", str(tmp_path), "--calib", str(shared_data / CALIB), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "disp_0" in err[0] and not (tmp_path / "x").exists()


def test_the_rigid_background_gives_the_static_points_one_rigid_motion_and_keeps_the_movers(shared_data: Path,
                                                                                          tmp_path: Path):
    """``--rigid_background``: the points labelled static take the dominant rigid motion as their truth (as
    KITTI's ground truth gives the background the camera's motion); the movers and frame 1 are unchanged."""
    build_split(_cfg(shared_data, tmp_path / "est", pairs=2))
    build_split(_cfg(shared_data, tmp_path / "rigid", pairs=2, rigid_background=True))
    est, rigid = load_split(str(tmp_path / "est"), "auto")[0], load_split(str(tmp_path / "rigid"), "auto")[0]
    static = ~rigid.moving
    T = dominant_motion(rigid.pc1[static], (rigid.pc1 + rigid.flow)[static])
    resid = np.linalg.norm(rigid.pc1 @ T[:3, :3].T + T[:3, 3] - (rigid.pc1 + rigid.flow), axis=1)
    assert resid[static].max() < 1e-3  # one rigid motion, to float32 rounding
    keyed = {tuple(p): f for p, f in zip(est.pc1[est.moving], est.flow[est.moving])}
    kept = [np.array_equal(keyed[tuple(p)], f) for p, f in zip(rigid.pc1[rigid.moving], rigid.flow[rigid.moving])
            if tuple(p) in keyed]
    assert len(kept) > 0.9 * rigid.moving.sum() and all(kept)  # (the reader's cut reads pc2: a few differ)
    # and the estimate's own static flow is not one rigid motion (what the switch removes)
    T0 = dominant_motion(est.pc1[~est.moving], (est.pc1 + est.flow)[~est.moving])
    resid0 = np.linalg.norm(est.pc1 @ T0[:3, :3].T + T0[:3, 3] - (est.pc1 + est.flow), axis=1)
    assert np.median(resid0[~est.moving]) > 0.02


@pytest.mark.parametrize("rigid_background", [False, True])
def test_the_flownet3d_layout_holds_the_same_pairs_as_frame_one_s_points_moved(shared_data: Path, tmp_path: Path,
                                                                              rigid_background: bool):
    """``--layout flownet3d`` writes what the ``hplflownet`` reader keeps of each scene, as FlowNet3D's
    ``kitti_rm_ground`` was written from KITTI's correspondences: pos2 is pos1 + gt in rows of its own order, so
    ``--pairing auto`` reads the split as built from correspondences. With a rigid background too: the cut is
    made on the frame-2 points written, as the reader makes it."""
    from evaluation.pairing import choose_pairing

    build_split(_cfg(shared_data, tmp_path / "hpl", pairs=2, rigid_background=rigid_background))
    build_split(_cfg(shared_data, tmp_path / "fn3d", pairs=2, layout="flownet3d", rigid_background=rigid_background))
    assert sorted(p.name for p in (tmp_path / "fn3d").iterdir()) == ["000000.npz", "000001.npz"]
    hpl, fn3d = load_split(str(tmp_path / "hpl"), "auto"), load_split(str(tmp_path / "fn3d"), "auto")
    assert_flownet3d_holds_the_same_pairs(hpl, fn3d)
    assert choose_pairing(fn3d, "flownet3d", by_format=False).pairing == "points"
