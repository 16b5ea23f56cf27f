"""The scene-flow trainer, readable top to bottom.

One step (paper §III): ``f_o = net(pc1, pc2)``; ``f_d = net(pc1 + sf_s, pc2)`` on the same sampled
points; at every pyramid level the four losses (depth consistency, dynamic–static consistency, Chamfer,
Laplacian) are weighted and summed; Adam steps. Checkpoints hold model, optimiser, scheduler, step and
RNG states and are written atomically; ``resume`` continues from ``latest.pt`` and, on the CPU with a
fixed ``threads``, reaches bit-identical weights to an uninterrupted run (the data draws depend only on
(seed, epoch, pair index), and nothing in a step draws from a global RNG). A non-finite loss or gradient
stops the run with a message before the optimiser step, so the last good checkpoint stays in place.

Data parallel (torchrun): ``optim.batch_size`` is the global batch, split evenly over the processes;
DDP averages the gradients, and with ``sync_bn`` (default) batch norm uses the global batch's statistics,
so P processes train like one process with the same global batch (up to float summation order).

Logs in the run folder: ``train.csv``/``train.jsonl`` (every logged step: loss, every loss term per
level ``l{k}/{term}``, lr, gradient norm, timings in seconds) and ``val.csv``/``val.jsonl`` (EPE3D in
metres at the finest level and the total loss on the held-out pairs); ``config.json``; ``latest.pt`` and
``best.pt`` (lowest ``select_by`` score on the held-out pairs; :mod:`training.selection`).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.errors import ConfigError, InputError, TrainingDiverged
from core.options import flatten
from training.choices import SCHEDULES
from training.config import TrainConfig
from training.data import (
    EpochAware,
    FlowBatch,
    LoadFailure,
    PairDataset,
    StepBatches,
    collate,
    loss_draws,
    train_val_split,
)
from training.losses.total import multi_level_loss
from training.model.registry import config_class, construct_model
from training.runtime import checkpoints, distributed
from training.runtime.device import resolve_device
from training.runtime.ema import WeightAverage
from training.runtime.logs import MetricLogger
from training.runtime.rundir import save_run_info
from training.two_pass import forward_two_passes, level_inputs

# Options a resumed run may change without changing the trajectory of the weights.
RESUMABLE_CHANGES = frozenset({
    "cache", "run_dir", "steps", "epochs", "device", "threads", "amp", "deterministic", "log_every",
    "val_every", "ckpt_every", "progress", "select_by", "data.workers", "data.keep_mb", "data.val_pairs_max",
    "model.knn_backend", "loss.knn_backend",
})


def lr_factor(step: int, cfg: TrainConfig, total_steps: int | None = None, train_pairs: int | None = None) -> float:
    """Multiplier of the base lr after ``step`` optimiser steps.

    ``optim.schedule = "step"``: ``decay ** (step · batch_size // decay_every_samples)`` (the paper: 0.7 per
    200k samples), floored so that the lr never falls below ``lr_min`` (a base lr already below ``lr_min``
    is left as it is); with ``optim.decay_every_epochs`` > 0 the period is that many passes over
    ``train_pairs`` pairs instead (rounded, at least one sample). ``"cosine"``:
    ``m + (1 − m) · ½ (1 + cos(π · step / total_steps))`` with ``m = lr_min / lr`` (1 at step 0, m at
    ``total_steps`` and after; ``total_steps`` defaults to ``steps``).
    """
    o = cfg.optim
    floor = min(1.0, o.lr_min / o.lr)
    if o.schedule == "cosine":
        total = max(1, total_steps or cfg.steps)
        return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * min(step, total) / total))
    period = o.decay_every_samples
    if o.decay_every_epochs > 0:
        if not train_pairs:
            raise ConfigError("optim.decay_every_epochs needs the number of training pairs")
        period = max(1, round(o.decay_every_epochs * train_pairs))
    return max(o.decay ** (step * o.batch_size // period), floor)


SCHEDULE_FIELDS = ("schedule", "decay", "decay_every_samples", "decay_every_epochs", "lr_min")
"""``OptimConfig`` fields that act only through :func:`lr_factor`: a resumed run may change them where the factor
they give is the same at every step taken so far (:func:`schedule_agrees`)."""
SCHEDULE_OPTIONS = frozenset(f"optim.{name}" for name in SCHEDULE_FIELDS)
""":data:`SCHEDULE_FIELDS` as dotted option names."""

SCHEDULE_CHECK_STEPS = 2_000_000
"""The longest run :func:`schedule_agrees` compares step by step (a few seconds)."""


def schedule_agrees(saved: dict[str, Any], cfg: TrainConfig, step: int, total_steps: int, train_pairs: int) -> bool:
    """Whether the lr schedule of ``saved`` (an ``asdict(TrainConfig)``) and of ``cfg`` give the same factor at every
    step ``0 … step`` (the steps a checkpoint at ``step`` has taken, and the first one after it, whose lr the loaded
    optimiser already holds), over ``cfg``'s run length and ``train_pairs``. Then the run so far is exactly the run
    ``cfg`` would have trained, and resuming it under ``cfg`` continues that run (e.g. a step decay whose first decay
    falls after the checkpoint)."""
    fields = {name: saved.get("optim", {}).get(name) for name in SCHEDULE_FIELDS}
    if any(v is None for v in fields.values()):
        return False  # an older or damaged file: refused as before
    if all(fields[name] == getattr(cfg.optim, name) for name in SCHEDULE_FIELDS):
        return True  # the same schedule (every resume without a change: no step-by-step check)
    if not 0 <= step <= SCHEDULE_CHECK_STEPS:
        return False  # too long to check step by step: refused as before
    before = replace(cfg, optim=replace(cfg.optim, **fields))
    try:
        return all(lr_factor(s, before, total_steps, train_pairs) == lr_factor(s, cfg, total_steps, train_pairs)
                   for s in range(step + 1))
    except (ConfigError, ArithmeticError, TypeError, ValueError):
        return False


def config_changes(saved: dict[str, Any], current: dict[str, Any], exempt: frozenset[str] = frozenset()) -> list[str]:
    """Options (dotted names) whose values differ between two ``asdict(TrainConfig)`` and that change
    what a resumed run computes (everything but :data:`RESUMABLE_CHANGES` and ``exempt``); options absent from
    either side (added to the code since) are not compared."""
    a, b = flatten(saved), flatten(current)
    skip = RESUMABLE_CHANGES | exempt
    return [f"{k} {a[k]!r} -> {b[k]!r}" for k in sorted(a.keys() & b.keys()) if k not in skip and a[k] != b[k]]


def check_config(cfg: TrainConfig) -> None:
    """Combinations the dataclasses cannot check alone (ConfigError)."""
    if not isinstance(cfg.model, config_class(cfg.model_name)):
        raise ConfigError(f"model_name '{cfg.model_name}' takes a {config_class(cfg.model_name).__name__} as model, "
                          f"got {type(cfg.model).__name__}")
    finest = cfg.model.output_points[0]
    if cfg.data.n_points < finest:
        raise ConfigError(f"data.n_points {cfg.data.n_points} < model.level_points[0] {finest}: "
                          "set --model.n_points/--model.level_points to match the points drawn")
    from training.selection import CRITERIA

    if cfg.select_by not in CRITERIA:
        raise ConfigError(f"select_by must be one of {', '.join(CRITERIA)}, got {cfg.select_by!r}")
    d = cfg.data
    if not (0 <= d.lidar_rings <= 1 and 0 < d.ring_band <= 1 and 0 <= d.density_drop < 1 and d.ground_jitter_m >= 0):
        raise ConfigError("need 0 <= data.lidar_rings <= 1, 0 < data.ring_band <= 1, 0 <= data.density_drop < 1 and "
                          f"data.ground_jitter_m >= 0, got {d.lidar_rings}, {d.ring_band}, {d.density_drop}, "
                          f"{d.ground_jitter_m}")
    scale = tuple(d.ego_speed_scale)
    if len(scale) != 2 or not 0 < scale[0] <= scale[1]:
        raise ConfigError(f"data.ego_speed_scale must be two factors 0 < low <= high, got {d.ego_speed_scale!r}")
    if d.ego_turn_deg < 0 or d.ego_shift_m < 0:
        raise ConfigError(f"data.ego_turn_deg and data.ego_shift_m must be >= 0, got {d.ego_turn_deg}, {d.ego_shift_m}")
    if not 0 <= d.mirror <= 1:
        raise ConfigError(f"data.mirror is a probability in [0, 1], got {d.mirror}")
    if not 0 <= d.synthetic_movers <= 1:
        raise ConfigError(f"data.synthetic_movers is a probability in [0, 1], got {d.synthetic_movers}")
    lengths = tuple(d.synthetic_mover_m)
    if len(lengths) != 2 or not 0 <= lengths[0] <= lengths[1]:
        raise ConfigError(f"data.synthetic_mover_m must be two lengths 0 <= low <= high (metres), got {d.synthetic_mover_m!r}")
    for name in ("log_every", "val_every", "ckpt_every"):
        if getattr(cfg, name) < 1:
            raise ConfigError(f"{name} must be >= 1, got {getattr(cfg, name)}")
    if (cfg.optim.batch_size < 1 or cfg.optim.decay_every_samples < 1 or not cfg.optim.lr > 0
            or not cfg.optim.decay_every_epochs >= 0):
        raise ConfigError(f"optim needs batch_size >= 1, decay_every_samples >= 1, decay_every_epochs >= 0 and "
                          f"lr > 0, got {cfg.optim}")
    if cfg.optim.schedule not in SCHEDULES:  # training.choices
        raise ConfigError(f"optim.schedule must be one of {SCHEDULES}, got {cfg.optim.schedule!r}")
    if not 0 <= cfg.optim.ema_decay < 1:
        raise ConfigError(f"optim.ema_decay must be 0 (off) or in (0, 1), got {cfg.optim.ema_decay}")
    if cfg.threads < 0 or cfg.data.workers < 0:
        raise ConfigError(f"threads and data.workers must be >= 0, got {cfg.threads} and {cfg.data.workers}")
    if cfg.data.n_points != cfg.model.n_points:
        raise ConfigError(f"data.n_points {cfg.data.n_points} != model.n_points {cfg.model.n_points}: the net is "
                          "built (and evaluated) for model.n_points points per cloud; set both")
    cfg.model.check_for_training()
    if not (cfg.epochs > 0 or cfg.steps >= 1) or cfg.epochs < 0:
        raise ConfigError(f"steps must be >= 1 (or epochs > 0), got steps {cfg.steps}, epochs {cfg.epochs}")
    if not 0.0 <= cfg.data.val_fraction < 1.0:
        raise ConfigError(f"data.val_fraction must be in [0, 1), got {cfg.data.val_fraction}")


class Trainer:
    """Builds everything from a :class:`TrainConfig`; :meth:`fit` runs to ``self.steps``."""

    def __init__(self, cfg: TrainConfig, resume: bool = False) -> None:
        from pipeline.cache import CacheReader

        check_config(cfg)
        self.cfg = cfg
        if cfg.threads > 0:
            torch.set_num_threads(cfg.threads)
        self.device = resolve_device(cfg.device)
        self.dist = distributed.init_distributed(self.device)
        checkpoints.seed_all(cfg.seed, cfg.deterministic)
        self.run_dir = Path(cfg.run_dir)
        self.reader = CacheReader(cfg.cache, keep_mb=cfg.data.keep_mb)
        self.train_idx, self.val_idx = self._split()
        d = cfg.data
        self.train_set = PairDataset(self.reader, self.train_idx, d.n_points, cfg.seed, d.colour_features,
                                     d.jitter_deg, d.jitter_m, depth2_kept_only=d.depth2_kept_only,
                                     augment=d.augment(), ego_speed_scale=d.ego_speed_scale,
                                     ego_turn_shift=(d.ego_turn_deg, d.ego_shift_m),
                                     mirror=d.mirror, movers=(d.synthetic_movers, d.synthetic_mover_m),
                                     **loss_draws(cfg.loss))
        self.val_set = PairDataset(self.reader, self.val_idx, d.n_points, cfg.seed, d.colour_features,
                                   fixed_epoch=-1, depth2_kept_only=d.depth2_kept_only,
                                   **loss_draws(cfg.loss))
        self.steps = self._total_steps()
        # checks batch size against the pairs and the processes now rather than at the first step
        StepBatches(len(self.train_idx), cfg.optim.batch_size, cfg.seed, 0, 0, self.dist.rank, self.dist.world_size)

        self.net = distributed.wrap_model(construct_model(cfg.model_name, cfg.model).to(self.device), self.dist,
                                          self.device, sync_bn=cfg.sync_bn)
        self.model = distributed.unwrap(self.net)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=cfg.optim.lr)
        self.average = WeightAverage(self.model, cfg.optim.ema_decay) if cfg.optim.ema_decay > 0 else None
        pairs = len(self.train_idx)
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(self.optimizer,
                                                           lambda s: lr_factor(s, cfg, self.steps, pairs))
        self.step = 0
        self.best_val: float | None = None
        self.best_step: int | None = None  # the step best.pt holds (None: no validation yet, or an older run)
        self.last_val: tuple[int, float] | None = None  # (step, select_by score) of the latest validation
        resumed = resume and (self.run_dir / "latest.pt").exists()
        if resumed:
            self._load(self.run_dir / "latest.pt")
        if self.dist.is_main:
            save_run_info(self.run_dir, {"train": asdict(cfg), "train_pairs": len(self.train_idx),
                                         "val_pairs": len(self.val_idx), "cache": str(cfg.cache),
                                         "world_size": self.dist.world_size, "resumed_at_step": self.step})
        keep = self.step if resumed else None
        self.logger = MetricLogger(self.run_dir, "train", resume_step=keep) if self.dist.is_main else None
        self.val_logger = MetricLogger(self.run_dir, "val", resume_step=keep) if self.dist.is_main else None

    # ------------------------------------------------------------------ set-up helpers
    def _split(self) -> tuple[list[int], list[int]]:
        return train_val_split(self.reader, self.cfg.data.val_fraction, self.cfg.data.val_pairs_max)

    def _total_steps(self) -> int:
        cfg = self.cfg
        if cfg.epochs and cfg.epochs > 0:
            return int(math.ceil(cfg.epochs * len(self.train_idx) / cfg.optim.batch_size))
        return cfg.steps

    def _loader(self):
        cfg = self.cfg
        sampler = StepBatches(len(self.train_idx), cfg.optim.batch_size, cfg.seed, self.step, self.steps,
                              self.dist.rank, self.dist.world_size)
        workers = cfg.data.workers
        # own generator: creating the iterator must not draw from the global torch RNG (resume equality)
        return torch.utils.data.DataLoader(EpochAware(self.train_set, carry_errors=True), batch_sampler=sampler,
                                           collate_fn=collate, num_workers=workers, persistent_workers=False,
                                           pin_memory=self.device.type == "cuda",
                                           prefetch_factor=4 if workers > 0 else None,
                                           generator=torch.Generator().manual_seed(cfg.seed))

    @property
    def inference_model(self) -> torch.nn.Module:
        """The net validation and checkpoints' ``model`` entry hold: the weight average when it is on."""
        return self.average.module if self.average is not None else self.model

    def _payload(self) -> dict:
        """``model`` holds the weights every reader of a checkpoint uses (the average when ``optim.ema_decay``
        is on); the trained weights, which resuming needs, are then under ``trained_model`` and the
        average's update count under ``average_updates``."""
        out = {"kind": "flow", "model": self.inference_model.state_dict(), "optimizer": self.optimizer.state_dict(),
               "scheduler": self.scheduler.state_dict(), "step": self.step, "best_val": self.best_val,
               "best_step": self.best_step,
               "rng": checkpoints.rng_state(), "config": asdict(self.cfg)}
        if self.average is not None:
            out["trained_model"] = self.model.state_dict()
            out["average_updates"] = self.average.updates
        return out

    def _save(self, name: str = "latest.pt") -> None:
        if self.dist.is_main:
            checkpoints.save_checkpoint(self.run_dir / name, self._payload())
        distributed.barrier(self.dist)

    def _load(self, path: Path) -> None:
        ckpt = checkpoints.load_checkpoint(path, kind="flow")
        try:
            agrees = schedule_agrees(ckpt["config"], self.cfg, int(ckpt["step"]), self.steps, len(self.train_idx))
            changed = config_changes(ckpt["config"], asdict(self.cfg), SCHEDULE_OPTIONS if agrees else frozenset())
            if changed:
                raise InputError(path, f"written by a run with other settings ({'; '.join(changed)}); "
                                       "resume with the same settings or use a new run_dir")
            if self.average is not None:
                self.model.load_state_dict(ckpt["trained_model"])
                self.average.load_state_dict({"weights": ckpt["model"], "updates": ckpt["average_updates"]})
            else:
                self.model.load_state_dict(ckpt["model"])
            self.optimizer.load_state_dict(ckpt["optimizer"])
            self.scheduler.load_state_dict(ckpt["scheduler"])
            self.step = int(ckpt["step"])
            self.best_val = ckpt.get("best_val")
            self.best_step = ckpt.get("best_step")
            checkpoints.set_rng_state(ckpt["rng"])
        except KeyError as exc:
            raise InputError(path, f"checkpoint lacks {exc}") from None
        except (RuntimeError, ValueError, TypeError) as exc:
            text = " ".join(str(exc).split())
            raise InputError(path, f"does not fit this run ({type(exc).__name__}: {text[:200]})") from None

    def _sync(self) -> None:
        """Wait for the GPU, so that the step's phases are timed correctly (no-op on the CPU)."""
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    # ------------------------------------------------------------------ the loop
    def _stop_if_not_finite(self, what: str, value: float, detail: str) -> None:
        finite = math.isfinite(value)
        if self.dist.enabled:  # every rank must stop together, or the others hang in the next collective
            finite = distributed.all_reduce_mean({"finite": float(finite)}, self.dist)["finite"] == 1.0
        if not finite:
            latest = self.run_dir / "latest.pt"
            kept = f"last good checkpoint kept at {latest}" if latest.is_file() else "no checkpoint written yet"
            raise TrainingDiverged(f"non-finite {what} at step {self.step + 1} ({detail}); training stopped, {kept}")

    def _check_batch(self, batch: FlowBatch) -> None:
        """Non-finite points or features in the cache stop the run naming the pairs (the kNN would fail
        deep inside scipy otherwise)."""
        for name in ("pc1", "pc2", "static_flow", "feat1", "feat2"):
            t = getattr(batch, name)
            if not bool(torch.isfinite(t).all()):
                rows = (~torch.isfinite(t)).flatten(1).any(1).cpu()
                raise InputError(self.cfg.cache, f"non-finite {name} in pair(s) {batch.index[rows].tolist()}")

    def train_step(self, batch: FlowBatch) -> dict[str, float]:
        """One optimiser step; returns the loss, every loss term per level, the gradient norm and the
        time (seconds) of forward (both passes), losses, backward and optimiser step."""
        t0 = time.perf_counter()
        self._check_batch(batch)
        self.net.train()
        amp = self.cfg.amp and self.device.type == "cuda"
        with torch.autocast(device_type=self.device.type, dtype=torch.bfloat16, enabled=amp):
            out_o, out_d = forward_two_passes(self.net, batch)
        self._sync()
        t1 = time.perf_counter()
        total, terms = multi_level_loss(level_inputs(batch, out_o, out_d, self.cfg.loss.pc2_target, self.cfg.loss.view_mask), self.cfg.loss)
        t2 = time.perf_counter()
        bad = [k for k, v in terms.items() if not math.isfinite(v)]
        self._stop_if_not_finite("loss", float(total.detach()), "terms " + ", ".join(bad) if bad else "total")
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        params = [p for p in self.model.parameters() if p.grad is not None]
        if self.cfg.optim.grad_clip > 0:
            norm = torch.nn.utils.clip_grad_norm_(params, self.cfg.optim.grad_clip)
        else:
            norm = torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(p.grad) for p in params]))
        grad_norm = float(norm)
        t3 = time.perf_counter()
        self._stop_if_not_finite("gradient", grad_norm, f"norm {grad_norm}")
        self.optimizer.step()
        self.scheduler.step()
        if self.average is not None:
            self.average.update(self.model)
        self._sync()
        t4 = time.perf_counter()
        return {"loss": float(total.detach()), **terms, "grad_norm": grad_norm,
                "time_forward": t1 - t0, "time_loss": t2 - t1, "time_backward": t3 - t2, "time_optim": t4 - t3}

    @torch.no_grad()
    def validate(self) -> dict[str, float]:
        """Scores on the held-out pairs (a fixed draw), in eval mode (:func:`training.selection.validation_sums`);
        under DDP the batches are shared among the processes."""
        from training.selection import scores_from_sums, validation_sums

        if not self.val_idx:
            return {}
        model = self.inference_model
        was_training = model.training
        model.eval()
        bs = self.cfg.optim.batch_size
        starts = list(range(0, len(self.val_idx), bs))[self.dist.rank::self.dist.world_size]
        batches = ([self.val_set[p] for p in range(s, min(s + bs, len(self.val_idx)))] for s in starts)
        sums = validation_sums(model, batches, self.cfg.loss, self.device)
        model.train(was_training)
        if self.dist.enabled:  # means of the per-rank sums; their ratios are the global ratios
            red = distributed.all_reduce_mean({str(k): v for k, v in enumerate(sums)}, self.dist)
            sums = np.array([red[str(k)] for k in range(len(sums))])
        return scores_from_sums(sums)

    def _after_validation(self, val: dict[str, float]) -> None:
        if not val:
            return
        if self.val_logger:
            self.val_logger.log({"step": self.step, **val})
        key = self.cfg.select_by
        if key not in val:
            return
        if self.step == 0:  # the untrained net is scored, never kept
            return
        self.last_val = (self.step, float(val[key]))
        if self.best_val is None or val[key] < self.best_val:
            self.best_val = val[key]
            self.best_step = self.step
            self._save("best.pt")

    def selection_summary(self) -> str | None:
        """One line on what the label-free checkpoint choice kept: best.pt's step and ``select_by`` score, and
        how the run's latest validation compares with it (docs/learned-flow.md, thirty-ninth round: a run whose
        finest-level validation loss rose from its best while its training loss fell had got worse on every test
        split). None before the first validation after step 0."""
        if self.best_val is None or self.last_val is None:
            return None
        key, (step, score) = self.cfg.select_by, self.last_val
        at = f"step {self.best_step}" if self.best_step is not None else "an earlier step"
        line = f"best.pt: {at} ({key} {self.best_val:.5f})"
        if step == self.best_step:
            return line + "; it is the latest validation"
        rise = (score - self.best_val) / abs(self.best_val) * 100 if self.best_val else float("inf")
        return line + f"; the latest validation (step {step}) {score:.5f}, {rise:+.1f} % from it"

    def fit(self) -> dict[str, float]:
        """Train to ``self.steps``; returns the last logged row (with validation when available)."""
        from tqdm import tqdm

        cfg = self.cfg
        last: dict[str, float] = {}
        if self.step == 0 and self.val_idx:
            val = self.validate()
            self._after_validation(val)
            last = {"step": 0, **val}
        bar = tqdm(total=self.steps, initial=self.step, desc="train", disable=not (cfg.progress and self.dist.is_main),
                   dynamic_ncols=True)
        t_data = time.perf_counter()
        for batch in self._loader():
            if isinstance(batch, LoadFailure):
                raise batch.error()
            batch = batch.to(self.device)
            data_time = time.perf_counter() - t_data
            row = self.train_step(batch)
            self.step += 1
            bar.update(1)
            row = {"step": self.step, "lr": self.optimizer.param_groups[0]["lr"], "time_data": data_time, **row}
            is_val = self.step % cfg.val_every == 0 or self.step == self.steps
            is_ckpt = self.step % cfg.ckpt_every == 0 or self.step == self.steps
            if self.step % cfg.log_every == 0 or is_val:
                row = distributed.all_reduce_mean(row, self.dist)
                if self.logger:
                    self.logger.log(row)
                last = row
            if is_val:  # before the checkpoint, so that latest.pt holds the updated best_val
                val = self.validate()
                self._after_validation(val)
                last = {**last, **val}
            if is_ckpt:
                self._save()
            if "loss" in last:
                bar.set_postfix(loss=f"{last['loss']:.4f}",
                                **({"epe": f"{last['val_epe3d']:.3f}"} if "val_epe3d" in last else {}))
            t_data = time.perf_counter()
        bar.close()
        return last

    def close(self) -> None:
        distributed.shutdown(self.dist)
