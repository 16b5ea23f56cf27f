"""benchmarks/box_world.py: ray-cast box streets written without the synthetic generator, read back by the
FlowNet3D reader, with an exact truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.box_world import Box, BoxWorldConfig, build_split, cast, main, rot_z
from benchmarks.real_stereo import dominant_motion
from evaluation.pairing import choose_pairing
from evaluation.readers import load_split
from scipy.spatial import cKDTree


def test_a_ray_stops_at_the_nearest_face_of_the_nearest_box():
    boxes = [Box(np.array([10.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0]), 0.0),
             Box(np.array([5.0, 0.0, 0.0]), np.array([0.5, 2.0, 2.0]), np.pi / 2)]  # turned: 4 m deep along x
    hits, which = cast(np.zeros(3), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.2]]), boxes)
    np.testing.assert_allclose(hits[0], [3.0, 0.0, 0.0])  # the turned box's near face: 5 − 2
    assert which.tolist() == [1, -1, 1] and np.isnan(hits[1]).all()
    np.testing.assert_allclose(rot_z(np.pi / 2) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)


def test_static_points_move_with_the_camera_and_movers_do_not(tmp_path: Path):
    for layout in ("rescan", "pairs"):
        n, points, share = build_split(BoxWorldConfig(out=str(tmp_path / layout), seed=3, scenes=2, layout=layout))
        assert n == 2 and points > 2000 and 0 < share < 1
        split = load_split(str(tmp_path / layout), "auto")
        assert len(split) == 2 and split.fmt == "flownet3d"
        for s in split:
            static, target = ~s.moving, s.pc1 + s.flow
            T = dominant_motion(s.pc1[static], target[static])
            resid = np.linalg.norm(s.pc1 @ T[:3, :3].T + T[:3, 3] - target, axis=1)
            # exact for the noiseless point; the 1 cm noise on pc1 enters only through the camera's few-degree turn
            assert resid[static].max() < 2e-3
            if s.moving.any():  # every mover drives at least 0.3 m per frame on its own
                assert np.median(resid[s.moving]) > 0.2
            gap = cKDTree(s.pc2).query(target[static])[0]
            if layout == "pairs":
                assert gap.max() < 1e-4  # frame 2 holds each frame-1 point moved (float32 rounding)
            else:  # a re-scan: the moved surface is sampled again, ~0.1–0.5 m apart at these ranges
                assert np.median(gap) < 0.3 and gap.max() > 1e-3
            assert np.linalg.norm(s.pc1, axis=1).max() < 35.0 + 0.1  # range cut (before the noise)
            assert (s.pc1[:, 1] < 1.73 + 0.1).all()  # camera y down: nothing below the uncast ground
    pairing = {lay: choose_pairing(load_split(str(tmp_path / lay), "auto"), "flownet3d", by_format=False).pairing
               for lay in ("rescan", "pairs")}
    assert pairing == {"rescan": "surface", "pairs": "points"}
    assert not list(tmp_path.glob("*.partial"))


def test_the_same_seed_writes_the_same_split(tmp_path: Path):
    for name in ("a", "b"):
        build_split(BoxWorldConfig(out=str(tmp_path / name), seed=5, scenes=1))
    a, b = np.load(tmp_path / "a" / "000000.npz"), np.load(tmp_path / "b" / "000000.npz")
    for key in ("pos1", "pos2", "gt", "moving"):
        np.testing.assert_array_equal(a[key], b[key])


def test_an_existing_folder_or_a_bad_option_is_one_line(tmp_path: Path, capsys):
    (tmp_path / "taken").mkdir()
    assert main(["--out", str(tmp_path / "taken")]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["--out", str(tmp_path / "x"), "--layout", "grid"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "layout" in err[0]
    assert not (tmp_path / "x").exists()
