"""The scene-flow trainer: it learns, it logs every term, it stops cleanly on bad input and on NaN."""

from __future__ import annotations

import csv
import json

import pytest
import torch

from _trainer_fixtures import tiny_cache, tiny_config  # noqa: F401  (tiny_cache is a fixture)
from core.errors import ConfigError
from training.config import OptimConfig, TrainConfig
from training.trainer import Trainer, TrainingDiverged, lr_factor

torch.set_num_threads(1)


def _cfg_lr(**optim) -> TrainConfig:
    return TrainConfig(optim=OptimConfig(**optim))


def test_lr_factor_decays_0_7_per_200k_samples_with_floor():
    cfg = _cfg_lr(lr=1e-3, decay=0.7, decay_every_samples=200_000, lr_min=1e-4, batch_size=5)
    assert lr_factor(0, cfg) == 1.0
    assert lr_factor(39_999, cfg) == 1.0  # 199 995 samples
    assert lr_factor(40_000, cfg) == pytest.approx(0.7)  # 200 000 samples
    assert lr_factor(80_000, cfg) == pytest.approx(0.49)
    assert lr_factor(6 * 40_000, cfg) == pytest.approx(0.7**6)  # 0.1176 > 0.1
    assert lr_factor(7 * 40_000, cfg) == pytest.approx(0.1)  # 0.7^7 = 0.0824 floored at 1e-4 / 1e-3
    assert lr_factor(10**9, cfg) == pytest.approx(0.1)
    # the decay counts samples, not steps: batch 10 halves the steps per decay
    assert lr_factor(20_000, _cfg_lr(batch_size=10)) == pytest.approx(0.7)
    # a base lr already under the floor is not raised to it
    assert lr_factor(0, _cfg_lr(lr=5e-5, lr_min=1e-4)) == 1.0


def test_lr_factor_can_count_its_period_in_epochs_of_the_training_pairs():
    cfg = _cfg_lr(decay=0.7, decay_every_epochs=10, batch_size=4, lr=1e-3, lr_min=1e-4)
    # 210 pairs: a decay every 2100 samples = 525 steps of 4, whatever decay_every_samples says
    assert lr_factor(524, cfg, train_pairs=210) == 1.0
    assert lr_factor(525, cfg, train_pairs=210) == pytest.approx(0.7)
    assert lr_factor(2000, cfg, train_pairs=210) == pytest.approx(0.7**3)  # 8000 samples: 3 periods
    assert lr_factor(525, cfg, train_pairs=2100) == 1.0  # ten times the pairs, ten times the period
    with pytest.raises(ConfigError, match="training pairs"):
        lr_factor(1, cfg)


def test_the_demo_presets_schedule_first_decays_after_the_demos_steps():
    from training.presets import demo_train_config

    cfg = demo_train_config("cache", "run")  # 500 steps of 4 pairs; the demo world's cache holds 216 pairs
    assert cfg.steps == 500 and cfg.optim.batch_size == 4
    assert lr_factor(cfg.steps, cfg, train_pairs=216) == 1.0  # the demo's net is trained at the constant lr
    assert lr_factor(539, cfg, train_pairs=216) == 1.0 and lr_factor(540, cfg, train_pairs=216) == pytest.approx(0.7)
    assert lr_factor(4 * cfg.steps, cfg, train_pairs=216) == pytest.approx(0.7**3)  # 4x: three decays


def test_schedule_agrees_only_where_every_step_taken_had_the_same_factor():
    from dataclasses import asdict

    from training.trainer import schedule_agrees

    now = _cfg_lr(decay=0.7, decay_every_epochs=10, batch_size=4)  # 216 pairs: first decay at step 540
    saved = asdict(_cfg_lr(decay=0.7, batch_size=4))  # the constant lr (200k samples per decay)
    assert schedule_agrees(saved, now, 500, 2000, 216) and schedule_agrees(saved, now, 539, 2000, 216)
    assert not schedule_agrees(saved, now, 540, 2000, 216)  # the step after the checkpoint would differ
    for damaged in ({"decay_every_samples": 0}, {"decay": "x"}, {"lr_min": None}):
        bad = asdict(_cfg_lr(decay=0.7, batch_size=4))
        bad["optim"].update(damaged)
        assert not schedule_agrees(bad, now, 500, 2000, 216), damaged  # refused, no traceback
    assert not schedule_agrees(saved, now, 10**12, 10**12, 216)  # too long to compare: refused, not a hang


def test_cosine_schedule_runs_from_lr_to_lr_min_over_the_run():
    cfg = _cfg_lr(schedule="cosine", lr=1e-3, lr_min=1e-4)
    cfg.steps = 1000
    assert lr_factor(0, cfg) == 1.0
    assert lr_factor(500, cfg) == pytest.approx(0.55)  # halfway: the mean of 1 and the floor 0.1
    assert lr_factor(1000, cfg) == pytest.approx(0.1) and lr_factor(5000, cfg) == pytest.approx(0.1)
    assert lr_factor(250, cfg) > lr_factor(500, cfg) > lr_factor(750, cfg)
    assert lr_factor(1000, cfg, total_steps=2000) == pytest.approx(0.55)  # the trainer's resolved run length


def _run(cache, run_dir, **kw) -> tuple[Trainer, dict]:
    trainer = Trainer(tiny_config(cache, run_dir, **kw))
    try:
        return trainer, trainer.fit()
    finally:
        trainer.close()


@pytest.fixture(scope="module")
def trained(tiny_cache, tmp_path_factory):  # noqa: F811
    """60 steps (batch 2, lr 1e-3), and the same run with lr 0: the untrained net, same seed, whose batch-norm
    running statistics were updated by the same 60 training forward passes."""
    kw = dict(steps=60, val_every=60, log_every=5, ckpt_every=30, optim={"lr": 1e-3})
    trainer, last = _run(tiny_cache, tmp_path_factory.mktemp("trained"), **kw)
    baseline = Trainer(tiny_config(tiny_cache, tmp_path_factory.mktemp("untrained"), **kw))
    baseline.scheduler.base_lrs = [0.0]  # Adam with lr 0: the weights stay at their initial values
    baseline.optimizer.param_groups[0]["lr"] = 0.0
    init = {k: v.clone() for k, v in baseline.model.state_dict().items()}
    base_last = baseline.fit()
    baseline.close()
    return trainer, last, baseline, base_last, init


def test_short_training_lowers_loss_and_epe_against_the_untrained_net(trained):
    """Why the lr-0 run and not the freshly initialised net in eval mode: at initialisation the batch-norm
    running statistics are mean 0, variance 1, so eval mode does not normalise and the untrained net's
    eval-mode flow is a small constant-ish vector (EPE3D ≈ 0.3 m here, 0.7 m on the street of
    testkit.demo_scene) that no training-mode forward ever produced; one training step replaces those
    statistics. The lr-0 run is the same untrained weights with statistics from the same 60 forward passes,
    so the comparison isolates what the gradient steps learned. Measured (seeds 0, 1, 2): EPE3D 0.62/0.59/
    0.67 m trained vs 1.60/2.26/1.30 m untrained; validation loss 0.44/0.46/0.36 vs 1.27/2.34/0.75."""
    trainer, last, baseline, base_last, init = trained
    assert all(torch.equal(init[k], v) for k, v in baseline.model.state_dict().items() if "running" not in k
               and "num_batches" not in k)
    assert last["val_epe3d"] < 0.7 * base_last["val_epe3d"]
    assert last["val_loss"] < 0.7 * base_last["val_loss"]
    # the training loss at steps 45-60, batch for batch: below the untrained net's
    rows = [json.loads(line) for line in (trainer.run_dir / "train.jsonl").read_text().splitlines()]
    base = [json.loads(line) for line in (baseline.run_dir / "train.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [r["step"] for r in base]
    late = sum(r["loss"] for r in rows[-4:]) / 4
    assert late < 0.7 * sum(r["loss"] for r in base[-4:]) / 4


def test_logs_hold_every_term_per_level_and_config_is_saved(trained):
    trainer = trained[0]
    run = trainer.run_dir
    header = next(csv.reader((run / "train.csv").open()))
    for level in range(4):
        for term in ("depth1", "depth2", "depth", "ds", "chamfer", "laplacian", "weighted"):
            assert f"l{level}/{term}" in header
    for col in ("step", "loss", "lr", "grad_norm", "time_data", "time_forward", "time_loss", "time_backward"):
        assert col in header
    rows = list(csv.DictReader((run / "train.csv").open()))
    assert [int(r["step"]) for r in rows] == list(range(5, 61, 5))
    jrows = [json.loads(line) for line in (run / "train.jsonl").read_text().splitlines()]
    assert len(jrows) == len(rows) and float(rows[-1]["loss"]) == pytest.approx(jrows[-1]["loss"])
    # the level sum of the weighted terms is the total
    assert sum(jrows[-1][f"l{k}/weighted"] for k in range(4)) == pytest.approx(jrows[-1]["loss"], rel=1e-5)
    val = [json.loads(line) for line in (run / "val.jsonl").read_text().splitlines()]
    assert [v["step"] for v in val] == [0, 60]
    saved = json.loads((run / "config.json").read_text())
    assert saved["config"]["train"]["optim"]["lr"] == 1e-3
    assert saved["config"]["train"]["model"]["level_points"] == [128, 64, 32, 16, 8]
    assert saved["config"]["train_pairs"] == 12 and saved["config"]["val_pairs"] == 4
    assert {"torch", "numpy"} <= set(saved["versions"])
    assert (run / "latest.pt").is_file() and (run / "best.pt").is_file()


def test_nan_loss_stops_and_keeps_last_good_checkpoint(tiny_cache, tmp_path, monkeypatch):  # noqa: F811
    import training.trainer as tr

    real = tr.multi_level_loss
    calls = {"n": 0}

    def poisoned(levels, weights):
        calls["n"] += 1
        total, terms = real(levels, weights)
        if calls["n"] == 7:  # the 7th training step (no validation runs in between)
            terms = {**terms, "l2/chamfer": float("nan")}
            return total * float("nan"), terms
        return total, terms

    monkeypatch.setattr(tr, "multi_level_loss", poisoned)
    trainer = Trainer(tiny_config(tiny_cache, tmp_path, steps=10, ckpt_every=5, data={"val_fraction": 0.0}))
    with pytest.raises(TrainingDiverged) as err:
        trainer.fit()
    msg = str(err.value)
    assert "non-finite loss at step 7" in msg and "l2/chamfer" in msg and "latest.pt" in msg
    assert "\n" not in msg
    ckpt = torch.load(tmp_path / "latest.pt", weights_only=True)
    assert ckpt["step"] == 5
    assert all(torch.isfinite(v).all() for v in ckpt["model"].values() if v.is_floating_point())
    assert trainer.step == 6  # six good steps; the seventh never reached the optimiser


@pytest.mark.parametrize("field", ["pc1", "K"])
def test_corrupted_batch_stops_through_the_cli(tiny_cache, tmp_path, monkeypatch, capsys, field):  # noqa: F811
    """NaN points are bad input (named pairs); a NaN intrinsic passes the input check, the depth loss masks
    the points it cannot project (finite loss) but its gradient is NaN, which the trainer catches before the
    optimiser step (else NaN weights would be checkpointed). Either way: one line, exit 2, no checkpoint."""
    import training.data as data
    from _trainer_fixtures import config_flags
    from training.cli import main

    real = data.PairDataset.__getitem__

    def corrupt(self, pos):
        out = real(self, pos)
        out[field] = out[field].copy()
        out[field][:2] = float("nan")
        return out

    monkeypatch.setattr(data.PairDataset, "__getitem__", corrupt)
    cfg = tiny_config(tiny_cache, tmp_path, steps=3, data={"val_fraction": 0.0})
    assert main(config_flags(cfg)) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1
    if field == "pc1":
        assert err.startswith(f"error: {tiny_cache}: non-finite pc1 in pair(s) [")
    else:
        assert "non-finite gradient at step 1 (norm nan)" in err
    assert not (tmp_path / "latest.pt").exists()


def test_cli_bad_cache_and_checkpoint_give_one_line_errors(tiny_cache, tmp_path, capsys):  # noqa: F811
    import shutil

    from _trainer_fixtures import config_flags
    from training.cli import main

    # schema version mismatch
    cache = tmp_path / "cache"
    shutil.copytree(tiny_cache, cache)
    manifest = json.loads((cache / "manifest.json").read_text())
    manifest["schema_version"] = 99
    (cache / "manifest.json").write_text(json.dumps(manifest))
    assert main(config_flags(tiny_config(cache, tmp_path / "r1", steps=1))) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {cache / 'manifest.json'}: cache schema version 99") and "\n" not in err

    # corrupt checkpoint on resume
    run = tmp_path / "r2"
    run.mkdir()
    (run / "latest.pt").write_bytes(b"PK\x03\x04 this is not a checkpoint")
    assert main([*config_flags(tiny_config(tiny_cache, run, steps=1)), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {run / 'latest.pt'}: not a readable checkpoint") and "\n" not in err

    # checkpoint of another version
    torch.save({"checkpoint_version": 0, "kind": "flow"}, run / "latest.pt")
    assert main([*config_flags(tiny_config(tiny_cache, run, steps=1)), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {run / 'latest.pt'}: checkpoint version 0 != supported 1"

    # a depth-trainer checkpoint
    torch.save({"checkpoint_version": 1, "kind": "depth"}, run / "latest.pt")
    assert main([*config_flags(tiny_config(tiny_cache, run, steps=1)), "--resume"]) == 2
    assert "checkpoint of kind 'depth', expected 'flow'" in capsys.readouterr().err


def test_config_combinations_are_checked(tiny_cache, tmp_path):  # noqa: F811
    with pytest.raises(ConfigError, match="data.n_points 100 < model.level_points"):
        Trainer(tiny_config(tiny_cache, tmp_path, data={"n_points": 100}))
    with pytest.raises(ConfigError, match="only 12 training pairs for a batch of 13"):
        Trainer(tiny_config(tiny_cache, tmp_path, optim={"batch_size": 13}))
    with pytest.raises(ConfigError, match="optim.schedule must be one of"):
        Trainer(tiny_config(tiny_cache, tmp_path, optim={"schedule": "linear"}))


def test_best_checkpoint_follows_the_label_free_criterion(trained):
    """``select_by = val_l0`` (default): best.pt holds the step with the lowest finest-level validation loss;
    every validation logs the label-free scores beside EPE3D."""
    trainer, *_ = trained
    rows = [json.loads(line) for line in (trainer.run_dir / "val.jsonl").read_text().splitlines()]
    assert all({"val_l0", "val_cycle", "val_loss", "val_epe3d"} <= set(r) for r in rows)
    best = min((r for r in rows if r["step"] > 0), key=lambda r: r["val_l0"])
    from training.runtime.checkpoints import load_checkpoint

    saved = load_checkpoint(trainer.run_dir / "best.pt", kind="flow")
    assert saved["step"] == best["step"] and saved["best_val"] == pytest.approx(best["val_l0"])
    assert saved["best_step"] == best["step"]


def test_selection_summary_names_the_kept_step_and_the_latest_score(trained):
    """The line ``monoflow-train`` prints after ``done:``: best.pt's step and score, and the latest validation's
    score with its change from the best, from the run's own val.jsonl."""
    trainer, *_ = trained
    rows = [json.loads(line) for line in (trainer.run_dir / "val.jsonl").read_text().splitlines()]
    scored = [r for r in rows if r["step"] > 0]
    best, last = min(scored, key=lambda r: r["val_l0"]), scored[-1]
    line = trainer.selection_summary()
    assert line.startswith(f"best.pt: step {best['step']} (val_l0 {best['val_l0']:.5f})")
    if last["step"] == best["step"]:
        assert line.endswith("it is the latest validation")
    else:
        rise = (last["val_l0"] - best["val_l0"]) / best["val_l0"] * 100
        assert f"the latest validation (step {last['step']}) {last['val_l0']:.5f}, {rise:+.1f} %" in line


def test_unknown_selection_criterion_is_refused(tiny_cache, tmp_path):  # noqa: F811
    with pytest.raises(ConfigError, match="select_by"):
        Trainer(tiny_config(tiny_cache, tmp_path, select_by="val_magic"))


def test_selection_summary_reports_a_rise_after_the_kept_step():
    """A run whose label-free score rose after best.pt's step (the thirty-ninth round's seed-1 run: 0.12137 at
    step 500, 0.15600 at 2000) says by how much; before any validation after step 0 there is no line."""
    from types import SimpleNamespace

    run = SimpleNamespace(cfg=SimpleNamespace(select_by="val_l0"), best_val=0.12137, best_step=500,
                          last_val=(2000, 0.156))
    assert Trainer.selection_summary(run) == (
        "best.pt: step 500 (val_l0 0.12137); the latest validation (step 2000) 0.15600, +28.5 % from it")
    run.best_step = None  # a checkpoint from before best_step was kept
    assert Trainer.selection_summary(run).startswith("best.pt: an earlier step (val_l0 0.12137);")
    assert Trainer.selection_summary(SimpleNamespace(cfg=run.cfg, best_val=None, best_step=None,
                                                     last_val=None)) is None
