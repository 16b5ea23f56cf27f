"""Bad input and contradictory options end with one line naming the file (or the options) and what is
wrong, never a traceback; contradictions are refused before any work."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from _trainer_fixtures import config_flags, tiny_cache, tiny_config  # noqa: F401

from pipeline.cli import main as preprocess_main
from training.cli import main as train_main

torch.set_num_threads(1)
DEAD_PID = 4_999_999  # above Linux's largest pid_max (2**22): never a live process


def _one_line(capsys, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)
    return err


def _world_copy(synth_root: Path, tmp_path: Path) -> Path:
    world = tmp_path / "world"
    shutil.copytree(synth_root, world)
    return world


def _stage_one(world: Path, tmp_path: Path, *extra: str) -> int:
    return preprocess_main(["--root", str(world), "--depth", "gt", "--pose", "gt", "--block_size", "4",
                            "--out", str(tmp_path / "cache"), "--progress", "false", *extra])


def test_calib_with_a_zero_projection_matrix(synth_root: Path, tmp_path: Path, capsys) -> None:
    world = _world_copy(synth_root, tmp_path)
    calib = world / "sequences" / "00" / "calib.txt"
    lines = [("P2: " + " ".join(["0"] * 12)) if ln.startswith("P2:") else ln for ln in calib.read_text().splitlines()]
    calib.write_text("\n".join(lines) + "\n")
    assert _stage_one(world, tmp_path) == 2
    _one_line(capsys, str(calib), "P2")


def test_truncated_ground_truth_flow_file(synth_root: Path, tmp_path: Path, capsys) -> None:
    world = _world_copy(synth_root, tmp_path)
    npz = world / "sequences" / "00" / "flow3d_2" / "000001.npz"
    npz.write_bytes(npz.read_bytes()[:200])
    assert _stage_one(world, tmp_path) == 2
    _one_line(capsys, str(npz), "not a readable .npz")


def test_requested_one_frame_sequence_is_refused(synth_root: Path, tmp_path: Path, capsys) -> None:
    world = _world_copy(synth_root, tmp_path)
    one = world / "sequences" / "01"
    shutil.copytree(world / "sequences" / "00", one)
    for sub in ("image_2", "depth_2", "velodyne", "flow3d_2"):
        for f in sorted((one / sub).iterdir())[1:]:
            f.unlink()
    poses = (world / "poses" / "00.txt").read_text().splitlines()
    (world / "poses" / "01.txt").write_text(poses[0] + "\n")
    times = (one / "times.txt").read_text().splitlines()
    (one / "times.txt").write_text(times[0] + "\n")
    assert _stage_one(world, tmp_path, "--sequences", "00,01") == 2
    _one_line(capsys, str(one / "image_2"), "1 frame(s)")


@pytest.mark.parametrize("flag,value,needle", [("--filters.far_max_z", "-1", "far_max_z"),
                                               ("--filters.lidar_max_range", "0", "lidar_max_range")])
def test_filter_thresholds_that_drop_everything(synth_root: Path, tmp_path: Path, capsys, flag, value, needle) -> None:
    assert _stage_one(synth_root, tmp_path, flag, value) == 2
    _one_line(capsys, needle)
    assert not (tmp_path / "cache").exists()  # refused before anything was written


def test_abbreviated_flags_are_refused(synth_root: Path, tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        _stage_one(synth_root, tmp_path, "--block_siz", "3")
    assert stop.value.code == 2
    with pytest.raises(SystemExit) as stop:
        train_main(["--cache", str(tmp_path), "--data.n_point", "5"])
    assert stop.value.code == 2
    assert "unrecognized arguments: --data.n_point" in capsys.readouterr().err


@pytest.mark.parametrize("override,needle", [
    ({"data": {"n_points": 200}}, "data.n_points 200 != model.n_points 256"),
    ({"model": {"level_k": (8, 8, 8, 8, 40)}}, "level 4: 40 > 16"),
    ({"steps": -5}, "steps must be >= 1"),
])
def test_contradictory_training_options(tiny_cache: Path, tmp_path: Path, capsys, override, needle) -> None:  # noqa: F811
    cfg = tiny_config(tiny_cache, tmp_path / "run", **override)
    assert train_main(config_flags(cfg)) == 2
    _one_line(capsys, needle)
    assert not (tmp_path / "run" / "latest.pt").exists()


def test_diverging_learning_rate_is_one_line(tiny_cache: Path, tmp_path: Path, capsys) -> None:  # noqa: F811
    cfg = tiny_config(tiny_cache, tmp_path / "run", steps=6, optim={"lr": 1e30})
    assert train_main(config_flags(cfg)) == 2
    _one_line(capsys, "non-finite")


def test_divergence_without_a_checkpoint_says_so(tiny_cache: Path, tmp_path: Path, monkeypatch) -> None:  # noqa: F811
    import training.trainer as tr
    from training.trainer import Trainer, TrainingDiverged

    real = tr.multi_level_loss

    def poisoned(levels, weights):
        total, terms = real(levels, weights)
        return total * float("nan"), terms

    monkeypatch.setattr(tr, "multi_level_loss", poisoned)
    trainer = Trainer(tiny_config(tiny_cache, tmp_path, steps=4, ckpt_every=2, data={"val_fraction": 0.0}))
    with pytest.raises(TrainingDiverged) as err:
        trainer.fit()
    trainer.close()
    assert "no checkpoint written yet" in str(err.value) and "kept" not in str(err.value)
    assert not (tmp_path / "latest.pt").exists()


def test_stale_checkpoint_temp_files_are_removed(tiny_cache: Path, tmp_path: Path) -> None:  # noqa: F811
    run = tmp_path / "run"
    run.mkdir()
    stale = run / f"latest.pt.tmp-{DEAD_PID}"
    stale.write_bytes(b"half a checkpoint")
    mine = run / f"latest.pt.tmp-{os.getppid()}"  # a live writer's (here: our parent's pid) is left alone
    mine.write_bytes(b"being written")
    assert train_main(config_flags(tiny_config(tiny_cache, run, steps=2, ckpt_every=1))) == 0
    assert not stale.exists() and mine.exists()
    assert (run / "latest.pt").is_file()


def test_evaluate_checkpoint_with_a_nan_weight(tmp_path: Path, capsys) -> None:
    from test_eval_cli import save_tiny_checkpoint

    from evaluation.cli import main as evaluate_main
    from training.runtime.checkpoints import load_checkpoint, save_checkpoint

    good = save_tiny_checkpoint(tmp_path / "good.pt")
    ck = load_checkpoint(good, kind="flow")
    key = next(k for k, v in ck["model"].items() if v.is_floating_point() and v.numel() > 1)
    ck["model"][key].view(-1)[0] = float("nan")
    bad = save_checkpoint(tmp_path / "bad.pt", {k: v for k, v in ck.items() if k != "checkpoint_version"})
    split = tmp_path / "split"
    split.mkdir()
    pts = np.random.default_rng(0).uniform(-5, 5, (300, 3)).astype(np.float32)
    np.savez(split / "000000.npz", pos1=pts, pos2=pts + 0.1, gt=np.full((300, 3), 0.1, np.float32))
    rc = evaluate_main(["run", "--split", str(split), "--checkpoint", str(bad), "--baselines", "",
                        "--out", str(tmp_path / "out"), "--no-progress"])
    assert rc == 2
    _one_line(capsys, str(bad), "non-finite weights", key)


def test_tiny_scene_is_scored_with_a_note(tmp_path: Path, capsys) -> None:
    from evaluation.cli import main as evaluate_main

    split = tmp_path / "split"
    split.mkdir()
    pts = np.array([[0.0, 0.0, 5.0], [1.0, 0.0, 6.0], [0.0, 1.0, 7.0]], np.float32)
    np.savez(split / "000000.npz", pos1=pts, pos2=pts + 0.1, gt=np.full((3, 3), 0.1, np.float32))
    rc = evaluate_main(["run", "--split", str(split), "--baselines", "zero", "--n-points", "128", "--n-score", "64",
                        "--out", str(tmp_path / "out"), "--no-progress"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "note: 1 scene(s) have fewer frame-1 points than the 64 scored" in err and "000000 (3)" in err
