"""Predictions files: round trip, scoring from the file alone, malformed files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evaluation.metrics import aggregate, scene_metrics
from evaluation.predictions import (
    PredictionWriter,
    ScenePrediction,
    predictions_method,
    read_predictions,
    save_predictions,
    score_predictions,
)
from core.errors import InputError


def _scenes() -> list[ScenePrediction]:
    rng = np.random.default_rng(0)
    a_pts = rng.normal(size=(5, 3)).astype(np.float32)
    a_gt = np.tile(np.float32([0, 0, 1.0]), (5, 1))
    a_pred = a_gt + np.float32([0.1, 0, 0])  # EPE 0.1 everywhere
    b_pts = rng.normal(size=(2, 3)).astype(np.float32)
    b_gt = np.zeros((2, 3), np.float32)
    b_pred = np.float32([[0, 0.5, 0], [0, 0, 0]])  # EPE 0.5 and 0
    return [
        ScenePrediction("seq/000010", a_pts, a_pred, a_gt, moving=np.array([1, 0, 0, 0, 1], bool)),
        ScenePrediction("000002", b_pts, b_pred, b_gt, mask=np.array([True, False])),
    ]


def test_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "preds.h5"
    scenes = _scenes()
    assert save_predictions(path, "icp-p2p", scenes) == path
    assert not list(tmp_path.glob("*.tmp-*"))
    back = read_predictions(path)
    assert [s.name for s in back] == ["seq/000010", "000002"]  # written order, '/' kept in the name
    assert predictions_method(path) == "icp-p2p"
    for orig, got in zip(scenes, back):
        assert got.method == "icp-p2p"
        np.testing.assert_array_equal(got.points, orig.points)
        np.testing.assert_array_equal(got.pred_flow, orig.pred_flow)
        np.testing.assert_array_equal(got.gt_flow, orig.gt_flow)
        for attr in ("moving", "mask"):
            a, b = getattr(orig, attr), getattr(got, attr)
            assert (a is None and b is None) or np.array_equal(a, b)


def test_score_from_file_matches_direct_metrics(tmp_path: Path) -> None:
    path = tmp_path / "preds.h5"
    scenes = _scenes()
    save_predictions(path, "zero", scenes)
    scored = score_predictions(path, with_std=True)
    direct = aggregate([scene_metrics(s.pred_flow, s.gt_flow, s.mask, s.moving) for s in scenes], with_std=True)
    for key in ("EPE3D", "Acc3DS", "Acc3DR", "Outliers3D", "EPE3D_std", "n_scenes", "n_points"):
        assert scored[key] == pytest.approx(direct[key])
    # by hand: scene A EPE 0.1 (five points), scene B scores only its first point (EPE 0.5) -> 0.3
    assert scored["EPE3D"] == pytest.approx(0.3)
    assert scored["n_points"] == 6
    assert scored["moving"]["n_scenes"] == 1 and scored["moving"]["EPE3D"] == pytest.approx(0.1)
    assert scored["method"] == "zero"
    assert set(scored["per_scene"]) == {"seq/000010", "000002"}


def test_writer_rejects_bad_scenes_and_cleans_up(tmp_path: Path) -> None:
    path = tmp_path / "p.h5"
    with pytest.raises(ValueError, match="differ"):
        with PredictionWriter(path, "m") as w:
            w.add("a", np.zeros((3, 3)), np.zeros((2, 3)), np.zeros((3, 3)))
    assert not path.exists() and not list(tmp_path.glob("*.tmp-*"))
    with pytest.raises(ValueError, match="already written"):
        with PredictionWriter(path, "m") as w:
            w.add("a", np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))
            w.add("a", np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))
    save_predictions(path, "m", [])
    with pytest.raises(InputError, match="exists"):
        PredictionWriter(path, "m", overwrite=False)


def test_malformed_files(tmp_path: Path) -> None:
    import h5py

    with pytest.raises(InputError, match="no such file"):
        score_predictions(tmp_path / "missing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    with pytest.raises(InputError, match="junk.h5: not a readable HDF5"):
        read_predictions(junk)
    empty = tmp_path / "empty.h5"
    save_predictions(empty, "m", [])
    with pytest.raises(InputError, match="holds no scenes"):
        score_predictions(empty)
    broken = tmp_path / "broken.h5"
    with h5py.File(broken, "w") as f:
        g = f.create_group("scenes").create_group("s1")
        g.create_dataset("points", data=np.zeros((2, 3)))
        g.create_dataset("pred_flow", data=np.zeros((2, 3)))
    with pytest.raises(InputError, match=r"broken.h5: scene 's1' lacks \['gt_flow'\]"):
        score_predictions(broken)
