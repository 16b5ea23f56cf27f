"""``kill -9`` at random points (seeded), then resume: stage one ends with a cache byte-identical to an
uninterrupted run's, training with bit-identical weights. The kill points are drawn among the blocks /
steps of the run, plus a random delay of up to 50 ms so that some land in the middle of a write."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from _faults import REPO
from _trainer_fixtures import child_env, config_flags, tiny_cache, tiny_config  # noqa: F401
from test_preprocess import tree_bytes

pytestmark = pytest.mark.slow
SEED = 12


def _kill_when(cmd: list[str], env: dict, ready, timeout: float = 240) -> bool:
    """Start ``cmd``; SIGKILL it once ``ready()`` is true (plus a random delay up to 50 ms). Whether it was
    still running when killed (False: it finished first, which a rerun must also handle)."""
    rng = random.Random(" ".join(cmd) + str(SEED))
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + timeout
        while proc.poll() is None and not ready():
            assert time.monotonic() < deadline, "kill point not reached in time"
            time.sleep(0.005)
        time.sleep(rng.uniform(0, 0.05))
        alive = proc.poll() is None
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        return alive
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)


def _stage_one(root: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "pipeline", "--root", str(root), "--depth", "gt", "--pose", "gt", "--size", "native",
            "--block_size", "1", "--progress", "false", "--out", str(out)]


def test_stage_one_killed_at_random_points_resumes_to_identical_bytes(synth_root: Path, tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = tmp_path / "killed"
    rng = random.Random(SEED)
    killed = 0
    for after in sorted(rng.sample(range(0, 7), 3)):  # kill once `after` blocks are finished
        killed += _kill_when(_stage_one(synth_root, out), env,
                             lambda: len(list(out.glob("*/*/blocks/00/*/zarr.json"))) >= after)
    assert killed >= 1  # at least one kill interrupted a run
    done = subprocess.run(_stage_one(synth_root, out), cwd=REPO, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-2000:]
    clean = tmp_path / "clean"
    full = subprocess.run(_stage_one(synth_root, clean), cwd=REPO, env=env, capture_output=True, text=True, timeout=240)
    assert full.returncode == 0, full.stderr[-2000:]
    (root,), (clean_root,) = list(out.glob("*/*")), list(clean.glob("*/*"))
    assert tree_bytes(root) == tree_bytes(clean_root)


def test_training_killed_at_random_steps_resumes_to_identical_weights(tiny_cache: Path, tmp_path: Path) -> None:  # noqa: F811
    from training.trainer import Trainer

    torch.set_num_threads(1)
    steps = 12

    def cfg(run: Path):
        return tiny_config(tiny_cache, run, steps=steps, ckpt_every=2, val_every=6)

    straight = Trainer(cfg(tmp_path / "straight"))
    straight.fit()
    straight.close()
    run = tmp_path / "killed"
    log = run / "train.jsonl"
    rng = random.Random(SEED)
    cmd = [sys.executable, "-m", "training", *config_flags(cfg(run)), "--resume"]
    killed = 0
    for after in sorted(rng.sample(range(1, steps - 1), 2)):  # kill once `after` steps are logged
        killed += _kill_when(cmd, child_env(), lambda: log.is_file() and len(log.read_text().splitlines()) >= after)
    assert killed >= 1
    done = subprocess.run(cmd, cwd=REPO, env=child_env(), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    a = straight.model.state_dict()
    b = torch.load(run / "latest.pt", weights_only=True)["model"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    steps_logged = [json.loads(x)["step"] for x in log.read_text().splitlines()]
    assert steps_logged == list(range(1, steps + 1))
