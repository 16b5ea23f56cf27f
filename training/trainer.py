"""The scene-flow trainer, readable top to bottom.

One step (paper §III): ``f_o = net(pc1, pc2)``; ``f_d = net(pc1 + sf_s, pc2)`` on the same sampled
points; at every pyramid level the four losses (depth consistency, dynamic–static consistency, Chamfer,
Laplacian) are weighted and summed; Adam steps. Checkpoints hold model, optimiser, scheduler, step and
RNG states and are written atomically; ``resume`` continues from ``latest.pt``. A non-finite loss stops
the run with a message and leaves the last good checkpoint in place.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pipeline.errors import InputError, MonoflowError
from training.config import TrainConfig
from training.data import EpochAware, FlowBatch, PairDataset, StepBatches, collate, split_pairs
from training.losses.total import LevelInputs, multi_level_loss
from training.model.halflownet import FlowOutput, HALFlowNet
from training.runtime import checkpoints, distributed
from training.runtime.device import resolve_device
from training.runtime.logs import MetricLogger
from training.runtime.rundir import save_run_info


class TrainingDiverged(MonoflowError):
    """The loss became NaN or infinite."""


def lr_factor(step: int, cfg: TrainConfig) -> float:
    """Multiplier of the base lr at ``step``: decay per ``decay_every_samples`` samples, floored."""
    o = cfg.optim
    samples = step * o.batch_size
    return max(o.decay ** (samples // o.decay_every_samples), o.lr_min / o.lr)


def gather(x: Tensor, idx: Tensor) -> Tensor:
    """``x`` (B, N, C) or (B, N) at ``idx`` (B, n)."""
    if x.dim() == 2:
        return x.gather(1, idx)
    return x.gather(1, idx[..., None].expand(-1, -1, x.shape[-1]))


def forward_two_passes(net, batch: FlowBatch) -> tuple[FlowOutput, FlowOutput]:
    """The overall pass on (pc1, pc2) and the dynamic pass on (pc1 + sf_s, pc2) at the same points."""
    out_o = net(batch.pc1, batch.pc2, batch.feat1, batch.feat2)
    out_d = net(batch.pc1 + batch.static_flow, batch.pc2, batch.feat1, batch.feat2, sample_like=out_o)
    return out_o, out_d


def level_inputs(batch: FlowBatch, out_o: FlowOutput, out_d: FlowOutput) -> list[LevelInputs]:
    """Per pyramid level (finest first): the level's points and flows the losses need."""
    levels = []
    for l, (f_o, f_d) in enumerate(zip(out_o.flows, out_d.flows)):
        idx1, idx2 = out_o.indices[l], out_o.indices2[l]
        levels.append(LevelInputs(pc1=gather(batch.pc1, idx1), pc2=gather(batch.pc2, idx2), flow_o=f_o.float(),
                                  flow_d=f_d.float(), static_flow=gather(batch.static_flow, idx1), K=batch.K,
                                  depth2=batch.depth2))
    return levels


def epe3d(out: FlowOutput, batch: FlowBatch) -> tuple[float, int]:
    """Sum of per-point EPE3D at the finest level and the number of points (for a mean)."""
    gt = gather(batch.gt_flow, out.indices[0])
    err = torch.linalg.norm(out.flows[0].float() - gt, dim=-1)
    return float(err.sum()), int(err.numel())


class Trainer:
    """Builds everything from a :class:`TrainConfig`; :meth:`fit` runs to ``config.steps``."""

    def __init__(self, cfg: TrainConfig, resume: bool = False) -> None:
        from pipeline.cache import CacheReader

        self.cfg = cfg
        self.device = resolve_device(cfg.device)
        self.dist = distributed.init_distributed(self.device)
        if cfg.deterministic:
            torch.use_deterministic_algorithms(True, warn_only=True)
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)
        self.run_dir = Path(cfg.run_dir)
        self.reader = CacheReader(cfg.cache)
        train_idx, val_idx = split_pairs(self.reader, cfg.data.val_fraction)
        self.has_gt = self.reader.has_gt_flow
        if not self.has_gt:
            val_idx, train_idx = [], sorted(train_idx + val_idx)
        self.train_idx, self.val_idx = train_idx, val_idx[: cfg.data.val_pairs_max]
        d = cfg.data
        self.train_set = PairDataset(self.reader, train_idx, d.n_points, cfg.seed, d.colour_features,
                                     d.jitter_deg, d.jitter_m)
        self.val_set = PairDataset(self.reader, self.val_idx, d.n_points, cfg.seed, d.colour_features,
                                   fixed_epoch=-1)
        self.steps = self._total_steps()

        self.model = HALFlowNet(cfg.model).to(self.device)
        self.net = distributed.wrap_model(self.model, self.dist, self.device)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=cfg.optim.lr)
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(self.optimizer, lambda s: lr_factor(s, cfg))
        self.step = 0
        self.best_val: float | None = None
        if resume and (self.run_dir / "latest.pt").exists():
            self._load(self.run_dir / "latest.pt")
        if self.dist.is_main:
            save_run_info(self.run_dir, {"train": asdict(cfg), "train_pairs": len(self.train_idx),
                                         "val_pairs": len(self.val_idx), "cache": str(cfg.cache)})
        self.logger = MetricLogger(self.run_dir, resume_step=self.step if resume else None) if self.dist.is_main else None

    # ------------------------------------------------------------------ set-up helpers
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
        return torch.utils.data.DataLoader(EpochAware(self.train_set), batch_sampler=sampler, collate_fn=collate,
                                           num_workers=workers, persistent_workers=False,
                                           pin_memory=self.device.type == "cuda",
                                           prefetch_factor=4 if workers > 0 else None)

    def _payload(self) -> dict:
        return {"kind": "flow", "model": self.model.state_dict(), "optimizer": self.optimizer.state_dict(),
                "scheduler": self.scheduler.state_dict(), "step": self.step, "best_val": self.best_val,
                "rng": checkpoints.rng_state(), "config": asdict(self.cfg)}

    def _save(self, name: str = "latest.pt") -> None:
        if self.dist.is_main:
            checkpoints.save_checkpoint(self.run_dir / name, self._payload())
        distributed.barrier(self.dist)

    def _load(self, path: Path) -> None:
        ckpt = checkpoints.load_checkpoint(path, kind="flow")
        try:
            self.model.load_state_dict(ckpt["model"])
        except RuntimeError as exc:
            raise InputError(path, f"model does not match this config ({str(exc).splitlines()[0]})") from None
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.scheduler.load_state_dict(ckpt["scheduler"])
        self.step = int(ckpt["step"])
        self.best_val = ckpt.get("best_val")
        checkpoints.set_rng_state(ckpt["rng"])

    # ------------------------------------------------------------------ the loop
    def train_step(self, batch: FlowBatch) -> dict[str, float]:
        """One optimiser step; returns every loss term (per level) plus timings."""
        t0 = time.perf_counter()
        self.net.train()
        amp = self.cfg.amp and self.device.type == "cuda"
        with torch.autocast(device_type=self.device.type, dtype=torch.bfloat16, enabled=amp):
            out_o, out_d = forward_two_passes(self.net, batch)
        t1 = time.perf_counter()
        total, terms = multi_level_loss(level_inputs(batch, out_o, out_d), self.cfg.loss)
        t2 = time.perf_counter()
        if not torch.isfinite(total):
            raise TrainingDiverged(f"non-finite loss at step {self.step + 1} ({terms}); "
                                   f"last good checkpoint kept at {self.run_dir / 'latest.pt'}")
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        if self.cfg.optim.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.optim.grad_clip)
        self.optimizer.step()
        self.scheduler.step()
        t3 = time.perf_counter()
        return {"loss": float(total), **{k: float(v) for k, v in terms.items()},
                "time_forward": t1 - t0, "time_loss": t2 - t1, "time_backward": t3 - t2}

    @torch.no_grad()
    def validate(self) -> dict[str, float]:
        """Mean EPE3D (finest level) and mean total loss on the held-out pairs (fixed draw)."""
        if not self.val_idx:
            return {}
        self.net.eval()
        err_sum, n_pts, loss_sum, n_batches = 0.0, 0, 0.0, 0
        bs = self.cfg.optim.batch_size
        for start in range(0, len(self.val_idx), bs):
            batch = collate([self.val_set[p] for p in range(start, min(start + bs, len(self.val_idx)))]).to(self.device)
            out_o, out_d = forward_two_passes(self.net, batch)
            total, _ = multi_level_loss(level_inputs(batch, out_o, out_d), self.cfg.loss)
            e, n = epe3d(out_o, batch)
            err_sum, n_pts, loss_sum, n_batches = err_sum + e, n_pts + n, loss_sum + float(total), n_batches + 1
        return {"val_epe3d": err_sum / max(n_pts, 1), "val_loss": loss_sum / max(n_batches, 1)}

    def fit(self) -> dict[str, float]:
        """Train to ``self.steps``; returns the last logged row (with validation when available)."""
        from tqdm import tqdm

        cfg = self.cfg
        last: dict[str, float] = {}
        if self.step == 0 and self.val_idx:
            last = {"step": 0, **self.validate()}
            if self.logger:
                self.logger.log(last)
        bar = tqdm(total=self.steps, initial=self.step, desc="train", disable=not (cfg.progress and self.dist.is_main),
                   dynamic_ncols=True)
        t_data = time.perf_counter()
        for batch in self._loader():
            batch = batch.to(self.device)
            data_time = time.perf_counter() - t_data
            row = self.train_step(batch)
            self.step += 1
            bar.update(1)
            row = {"step": self.step, "lr": self.optimizer.param_groups[0]["lr"], "time_data": data_time, **row}
            is_val = self.step % cfg.val_every == 0 or self.step == self.steps
            if self.step % cfg.log_every == 0 or is_val:
                row = distributed.all_reduce_mean(row, self.dist)
                if is_val:
                    row.update(self.validate())
                if self.logger:
                    self.logger.log(row)
                bar.set_postfix(loss=f"{row['loss']:.4f}", **({"epe": f"{row['val_epe3d']:.3f}"} if "val_epe3d" in row else {}))
                last = row
            if self.step % cfg.ckpt_every == 0 or self.step == self.steps:
                self._save()
            t_data = time.perf_counter()
        bar.close()
        return last

    def close(self) -> None:
        distributed.shutdown(self.dist)
