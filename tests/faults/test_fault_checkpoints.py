"""A checkpoint that would run code when unpickled is refused with one line by every entry point that
loads checkpoints, and runs nothing (the marker file its unpickling would create never appears)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _faults import assert_one_error_line, run_cli, write_malicious_checkpoint
from _trainer_fixtures import config_flags, tiny_cache, tiny_config  # noqa: F401

from training.runtime.checkpoints import load_checkpoint


def test_loader_refuses_and_runs_nothing(tmp_path: Path) -> None:
    from core.errors import InputError

    marker = tmp_path / "pwned"
    evil = write_malicious_checkpoint(tmp_path / "latest.pt", marker)
    with pytest.raises(InputError) as err:
        load_checkpoint(evil, kind="flow")
    assert "refused" in str(err.value) and "\n" not in str(err.value)
    assert not marker.exists()


def test_evaluate_refuses(tmp_path: Path) -> None:
    split = tmp_path / "split"
    split.mkdir()
    rng = np.random.default_rng(0)
    pts = rng.uniform(-5, 5, (300, 3)).astype(np.float32)
    np.savez(split / "000000.npz", pos1=pts, pos2=pts + 0.1, gt=np.full((300, 3), 0.1, np.float32))
    marker = tmp_path / "pwned"
    evil = write_malicious_checkpoint(tmp_path / "run" / "latest.pt", marker)
    proc = run_cli("evaluation", ["run", "--split", split, "--checkpoint", evil, "--baselines", "zero",
                                  "--out", tmp_path / "out", "--no-progress"])
    assert_one_error_line(proc, str(evil))
    assert not marker.exists()


def test_train_resume_refuses(tiny_cache: Path, tmp_path: Path) -> None:  # noqa: F811
    marker = tmp_path / "pwned"
    cfg = tiny_config(tiny_cache, tmp_path / "run", steps=2)
    evil = write_malicious_checkpoint(tmp_path / "run" / "latest.pt", marker)
    proc = run_cli("training", [*config_flags(cfg), "--resume"])
    assert_one_error_line(proc, str(evil))
    assert not marker.exists()


def test_train_depth_resume_refuses(tmp_path: Path) -> None:
    from _depth_fixtures import depth_world

    world = depth_world(tmp_path / "world", frames=6, test_frames=0, seed=1, parked_cars=1)
    marker = tmp_path / "pwned"
    evil = write_malicious_checkpoint(tmp_path / "run" / "latest.pt", marker, kind="depth")
    proc = run_cli("training.depth", ["--preset", "tiny", "--data.root", world, "--run_dir", tmp_path / "run",
                                      "--resume"])
    assert_one_error_line(proc, str(evil))
    assert not marker.exists()


def test_stage_one_refuses(synth_root: Path, tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    evil = write_malicious_checkpoint(tmp_path / "dispnet.pth.tar", marker)
    proc = run_cli("pipeline", ["--root", synth_root, "--depth", "net", "--depth_checkpoint", evil, "--pose", "gt",
                                "--size", "128x48", "--device", "cpu", "--out", tmp_path / "cache",
                                "--progress", "false"])
    assert_one_error_line(proc, str(evil))
    assert not marker.exists()


def test_checkpoints_of_the_previous_format_still_load(tmp_path: Path) -> None:
    """Before, the numpy RNG state was saved as numpy's own tuple (an ndarray inside): still readable with
    weights_only (plain arrays only), and it restores the same numpy stream."""
    import random

    import torch

    from training.runtime.checkpoints import rng_state, set_rng_state

    np.random.seed(5)
    old = {"checkpoint_version": 1, "kind": "flow", "step": 3,
           "rng": {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}}
    expected = np.random.random_sample(4)
    torch.save(old, tmp_path / "old.pt")
    set_rng_state(load_checkpoint(tmp_path / "old.pt", kind="flow")["rng"])
    assert np.array_equal(np.random.random_sample(4), expected)
    state = rng_state()  # the new format: a tensor and plain numbers
    assert isinstance(state["numpy"]["keys"], torch.Tensor)
    after = np.random.random_sample(3)
    set_rng_state(state)
    assert np.array_equal(np.random.random_sample(3), after)
