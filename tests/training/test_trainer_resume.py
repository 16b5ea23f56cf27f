"""Resume after a kill: the same weights, optimiser state and logs as an uninterrupted run (CPU, 1 thread)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from _trainer_fixtures import REPO, child_env, config_flags, tiny_cache, tiny_config  # noqa: F401
from core.errors import InputError
from training.trainer import Trainer

torch.set_num_threads(1)
STEPS = 24


def _cfg(cache, run_dir, **kw):
    return tiny_config(cache, run_dir, steps=STEPS, ckpt_every=3, log_every=1, val_every=8, **kw)


def _fit(cfg, resume=False) -> Trainer:
    trainer = Trainer(cfg, resume=resume)
    trainer.fit()
    trainer.close()
    return trainer


def _kill_after_first_checkpoint(cfg) -> int:
    """Run ``python -m training`` and SIGKILL it once latest.pt exists; the checkpoint's step."""
    ckpt = Path(cfg.run_dir) / "latest.pt"
    proc = subprocess.Popen([sys.executable, "-m", "training", *config_flags(cfg)], cwd=REPO, env=child_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not ckpt.exists():
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "no checkpoint within 120 s"
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    return int(torch.load(ckpt, weights_only=True)["step"])


def test_resume_after_sigkill_reaches_the_uninterrupted_weights(tiny_cache, tmp_path):  # noqa: F811
    straight = _fit(_cfg(tiny_cache, tmp_path / "straight"))
    cfg = _cfg(tiny_cache, tmp_path / "killed")
    killed_at = _kill_after_first_checkpoint(cfg)
    assert 0 < killed_at < STEPS  # the kill really interrupted the run
    resumed = _fit(cfg, resume=True)
    assert resumed.step == straight.step == STEPS

    a, b = straight.model.state_dict(), resumed.model.state_dict()
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k  # bit-identical, no tolerance needed on the CPU with one thread
    sa, sb = straight.optimizer.state_dict()["state"], resumed.optimizer.state_dict()["state"]
    for i in sa:
        assert torch.equal(sa[i]["exp_avg"], sb[i]["exp_avg"]) and torch.equal(sa[i]["exp_avg_sq"], sb[i]["exp_avg_sq"])
    assert resumed.optimizer.param_groups[0]["lr"] == straight.optimizer.param_groups[0]["lr"]

    # logs: every step exactly once, with the uninterrupted run's values (rows after the checkpoint were dropped)
    rows_a = [json.loads(x) for x in (tmp_path / "straight" / "train.jsonl").read_text().splitlines()]
    rows_b = [json.loads(x) for x in (tmp_path / "killed" / "train.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows_b] == list(range(1, STEPS + 1))
    assert [r["loss"] for r in rows_a] == [r["loss"] for r in rows_b]
    val_b = [json.loads(x)["step"] for x in (tmp_path / "killed" / "val.jsonl").read_text().splitlines()]
    assert val_b == [0, 8, 16, 24]
    info = json.loads((tmp_path / "killed" / "config.json").read_text())
    assert info["config"]["resumed_at_step"] == killed_at


def test_resume_with_other_settings_is_refused(tiny_cache, tmp_path):  # noqa: F811
    _fit(tiny_config(tiny_cache, tmp_path, steps=3, ckpt_every=3, data={"val_fraction": 0.0}))
    changed = tiny_config(tiny_cache, tmp_path, steps=6, data={"val_fraction": 0.0}, optim={"lr": 5e-4})
    with pytest.raises(InputError) as err:
        Trainer(changed, resume=True)
    assert "optim.lr 0.002 -> 0.0005" in str(err.value) and str(err.value).startswith(str(tmp_path / "latest.pt"))
    # more steps, other logging and workers are fine
    more = tiny_config(tiny_cache, tmp_path, steps=5, log_every=2, data={"val_fraction": 0.0, "workers": 1})
    trainer = Trainer(more, resume=True)
    assert trainer.step == 3
    trainer.fit()
    assert trainer.step == 5


def test_a_schedule_that_agrees_so_far_may_change_on_resume(tiny_cache, tmp_path):  # noqa: F811
    """A run trained at the constant lr, continued under a step decay whose first decay falls after its checkpoint
    (the demo preset's change of the forty-ninth round): it resumes, and ends bit for bit as the run trained under the
    decay from the start; a decay that would already have fired is refused, naming the option."""
    def cfg(run, steps, **optim):
        return tiny_config(tiny_cache, tmp_path / run, steps=steps, ckpt_every=3, data={"val_fraction": 0.0},
                           optim=optim)

    straight = _fit(cfg("straight", 8, decay_every_samples=10))  # batch 2: the first decay at step 5
    _fit(cfg("resumed", 3))  # the constant lr (200k samples per decay)
    resumed = _fit(cfg("resumed", 8, decay_every_samples=10), resume=True)
    assert resumed.step == straight.step == 8
    assert resumed.optimizer.param_groups[0]["lr"] == pytest.approx(2e-3 * 0.7 ** 1)  # steps 5 … 8: one decay
    a, b = straight.model.state_dict(), resumed.model.state_dict()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    with pytest.raises(InputError, match="optim.decay_every_samples 10 -> 4"):
        Trainer(cfg("resumed", 12, decay_every_samples=4), resume=True)  # would have decayed at step 2

