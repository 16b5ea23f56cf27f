"""The self-supervised depth/pose trainer (SC-SfMLearner's recipe), readable top to bottom.

One step: the depth net sees the three frames of every snippet in one batch, the pose net the four
directed pairs (t→t−1, t→t+1, t−1→t, t+1→t) in one batch; :func:`training.depth.losses.snippet_loss`
weighs photometric, geometry-consistency and smoothness terms; Adam steps both nets.

Outputs in ``run_dir``: ``latest.pt`` (full training state: both nets, optimiser, step, best score, RNG —
``training.runtime.checkpoints`` kind ``depth``), the official-format files ``dispnet_checkpoint.pth.tar`` /
``exp_pose_checkpoint.pth.tar`` (``{'epoch', 'state_dict'}``, loadable by ``pipeline.nets.load_depth_net`` /
``load_pose_net`` exactly like SC-SfMLearner's released weights) at every checkpoint, ``*_model_best.pth.tar``
at the best validation, ``train.csv``/``train.jsonl`` (every ``log_every`` steps) and ``val.csv``/``val.jsonl`` logs, ``config.json`` and ``metrics.json`` (the
validation of the untrained nets and the last one).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from core.errors import ConfigError, InputError, TrainingDiverged
from core.geometry import pose_vec_to_mat
from pipeline.nets import DispResNet, PoseResNet, load_imagenet_encoder, normalize_image, save_checkpoint
from training.data import EpochAware, StepBatches
from training.depth.config import DepthTrainConfig
from training.depth.data import SnippetBatch, SnippetDataset, check_size, collate, open_sequences, resolve_splits
from training.depth.evaluate import evaluate_nets
from training.depth.losses import SnippetInputs, snippet_loss
from training.runtime import checkpoints, distributed
from training.runtime.device import resolve_device
from training.runtime.logs import MetricLogger
from training.runtime.rundir import save_run_info, write_json_atomic

DISP_CHECKPOINT = "dispnet_checkpoint.pth.tar"
POSE_CHECKPOINT = "exp_pose_checkpoint.pth.tar"
DISP_BEST = "dispnet_model_best.pth.tar"
POSE_BEST = "exp_pose_model_best.pth.tar"
VAL_LOSS_SNIPPETS = 16  # validation snippets scored for the photometric loss (fixed, unaugmented)


@dataclass
class DepthCheckpoints:
    """Official-format checkpoints of a finished run: the best-validation pair when validation ran, else the last.

    ``metrics`` holds the validation of the untrained nets (``initial``) and of the last step (``final``).
    """

    disp: Path
    pose: Path
    best: bool
    run_dir: Path
    metrics: dict = field(default_factory=dict)


def forward_snippets(depth_net, pose_net, batch: SnippetBatch, antisymmetric: bool = False) -> SnippetInputs:
    """Run both nets on a batch: every frame through the depth net, four directed pairs through the pose net.

    antisymmetric: the losses see ``v(a, b) = (net(a, b) − net(b, a)) / 2`` for each pair and its reverse, so
    a reversed pair always gets the opposite motion; the symmetric remainder ``(net(a, b) + net(b, a)) / 2``
    is returned in ``pose_symmetric`` for the loss to drive to zero (see ``DepthLossConfig.pose_antisymmetric``).
    """
    imgs = batch.images.float()  # (B, 3, 3, H, W), 0..255
    B, F3 = imgs.shape[:2]
    norm = normalize_image(imgs.flatten(0, 1))
    out = depth_net(norm)
    scales = out if isinstance(out, (list, tuple)) else [out]
    disps = [[d.view(B, F3, *d.shape[1:])[:, f] for d in scales] for f in range(F3)]
    n = norm.view(B, F3, *norm.shape[1:])
    tgt, prev, nxt = n[:, 1], n[:, 0], n[:, 2]
    vec = pose_net(torch.cat([tgt, tgt, prev, nxt]), torch.cat([prev, nxt, tgt, tgt])).float()
    symmetric = None
    if antisymmetric:  # rows: t→t−1, t→t+1 | t−1→t, t+1→t
        there, back = vec[:2 * B], vec[2 * B:]
        symmetric = (there + back) / 2
        half = (there - back) / 2
        vec = torch.cat([half, -half])
    T = pose_vec_to_mat(vec)
    poses = [(T[0:B], T[2 * B:3 * B]), (T[B:2 * B], T[3 * B:4 * B])]
    images = [imgs[:, f] / 255.0 for f in range(F3)]
    return SnippetInputs(images=images, disps=disps, poses=poses, K=batch.K.float(), pose_symmetric=symmetric)


def freeze_unused(depth_model: DispResNet, pose_model: PoseResNet, num_scales: int) -> list[str]:
    """Stop gradients to parameters the loss never uses; returns their names.

    The encoders' ImageNet classifier ``fc`` is never run, and with ``num_scales`` < 4 the coarser disparity
    heads are computed but not scored. Without gradients Adam leaves them at their initial values exactly as
    the released code does; freezing them also lets DDP run without ``find_unused_parameters``. They stay
    in the state dict, so checkpoints keep the official layout.
    """
    frozen = []
    modules = {"depth.encoder.fc": depth_model.encoder.encoder.fc, "pose.encoder.fc": pose_model.encoder.encoder.fc}
    for s in range(max(num_scales, 1), 4):
        modules[f"depth.disp_head_{s}"] = depth_model.decoder.decoder[10 + s]
    for name, module in modules.items():
        for pname, p in module.named_parameters():
            p.requires_grad_(False)
            frozen.append(f"{name}.{pname}")
    return frozen


class DepthTrainer:
    """Builds everything from a :class:`DepthTrainConfig`; :meth:`fit` runs to ``config.steps``."""

    def __init__(self, cfg: DepthTrainConfig, resume: bool = False) -> None:
        self.cfg = cfg
        self.hw = check_size(cfg.data.width, cfg.data.height)
        if cfg.steps < 0:
            raise ConfigError(f"steps must be >= 0, got {cfg.steps}")
        self.device = resolve_device(cfg.device)
        self.dist = distributed.init_distributed(self.device)
        checkpoints.seed_all(cfg.seed, cfg.deterministic)
        self.run_dir = Path(cfg.run_dir)

        train_ids, val_ids = resolve_splits(cfg.data)
        strict = cfg.data.strict_pose_count
        self.train_seqs = open_sequences(cfg.data.root, train_ids, cfg.data.camera, strict)
        self.val_seqs = open_sequences(cfg.data.root, val_ids, cfg.data.camera, strict)
        self.train_set = SnippetDataset(self.train_seqs, cfg.data, cfg.seed, augment=True)
        if len(self.train_set) < cfg.optim.batch_size:
            raise InputError(cfg.data.root, f"only {len(self.train_set)} training snippets for a batch of "
                             f"{cfg.optim.batch_size} (sequences {', '.join(train_ids)})")
        if cfg.optim.batch_size % self.dist.world_size:
            raise ConfigError(f"batch size {cfg.optim.batch_size} is not divisible by the "
                              f"{self.dist.world_size} processes")
        self.val_set = SnippetDataset(self.val_seqs, cfg.data, cfg.seed, augment=False) if self.val_seqs else None

        self.depth_model = DispResNet(cfg.model.depth_layers).to(self.device)
        self.pose_model = PoseResNet(cfg.model.pose_layers).to(self.device)
        if cfg.model.imagenet_weights:
            load_imagenet_encoder(self.depth_model, cfg.model.imagenet_weights)
            load_imagenet_encoder(self.pose_model, cfg.model.imagenet_weights)
        self.frozen = freeze_unused(self.depth_model, self.pose_model, cfg.loss.num_scales)
        self.depth_net = distributed.wrap_model(self.depth_model, self.dist, self.device)
        self.pose_net = distributed.wrap_model(self.pose_model, self.dist, self.device)
        o = cfg.optim
        self.optimizer = torch.optim.Adam(
            [{"params": [p for p in self.depth_model.parameters() if p.requires_grad]},
             {"params": [p for p in self.pose_model.parameters() if p.requires_grad]}],
            lr=o.lr, betas=(o.beta1, o.beta2), weight_decay=o.weight_decay)
        self.step = 0
        self.best_val: float | None = None
        self.initial_val: dict[str, float] = {}
        if resume and (self.run_dir / "latest.pt").exists():
            self._load(self.run_dir / "latest.pt")
        if self.dist.is_main:
            save_run_info(self.run_dir, {"train": asdict(cfg), "train_sequences": train_ids, "val_sequences": val_ids,
                                         "train_snippets": len(self.train_set),
                                         "val_snippets": 0 if self.val_set is None else len(self.val_set)})
        keep = self.step if resume else None
        self.logger = MetricLogger(self.run_dir, "train", resume_step=keep) if self.dist.is_main else None
        self.val_logger = MetricLogger(self.run_dir, "val", resume_step=keep) if self.dist.is_main else None

    # ------------------------------------------------------------------ checkpoints
    @property
    def steps_per_epoch(self) -> int:
        return max(len(self.train_set) // self.cfg.optim.batch_size, 1)

    @property
    def epoch(self) -> int:
        """Data epochs begun so far (the official files' ``epoch`` field)."""
        return int(math.ceil(self.step / self.steps_per_epoch))

    def _payload(self) -> dict:
        return {"kind": "depth", "depth_net": self.depth_model.state_dict(), "pose_net": self.pose_model.state_dict(),
                "optimizer": self.optimizer.state_dict(), "step": self.step, "best_val": self.best_val,
                "initial_val": self.initial_val, "rng": checkpoints.rng_state(), "config": asdict(self.cfg)}

    def save(self, best: bool = False) -> None:
        """``latest.pt`` plus the official-format files (and the ``*_model_best`` pair when ``best``)."""
        if self.dist.is_main:
            save_checkpoint(self.run_dir / DISP_CHECKPOINT, self.depth_model, self.epoch)
            save_checkpoint(self.run_dir / POSE_CHECKPOINT, self.pose_model, self.epoch)
            if best:
                save_checkpoint(self.run_dir / DISP_BEST, self.depth_model, self.epoch)
                save_checkpoint(self.run_dir / POSE_BEST, self.pose_model, self.epoch)
            checkpoints.save_checkpoint(self.run_dir / "latest.pt", self._payload())
        distributed.barrier(self.dist)

    def _load(self, path: Path) -> None:
        ckpt = checkpoints.load_checkpoint(path, kind="depth")
        try:
            self.depth_model.load_state_dict(ckpt["depth_net"])
            self.pose_model.load_state_dict(ckpt["pose_net"])
        except RuntimeError as exc:
            raise InputError(path, f"nets do not match this config ({str(exc).splitlines()[0]})") from None
        try:
            self.optimizer.load_state_dict(ckpt["optimizer"])
        except ValueError as exc:
            raise InputError(path, f"optimiser state does not match this config ({exc})") from None
        self.step = int(ckpt["step"])
        self.best_val = ckpt.get("best_val")
        self.initial_val = ckpt.get("initial_val") or {}
        checkpoints.set_rng_state(ckpt["rng"])

    # ------------------------------------------------------------------ the loop
    def _loader(self):
        cfg = self.cfg
        sampler = StepBatches(len(self.train_set), cfg.optim.batch_size, cfg.seed, self.step, cfg.steps,
                              self.dist.rank, self.dist.world_size)
        workers = cfg.data.workers
        return torch.utils.data.DataLoader(EpochAware(self.train_set), batch_sampler=sampler, collate_fn=collate,
                                           num_workers=workers, pin_memory=self.device.type == "cuda",
                                           prefetch_factor=4 if workers > 0 else None)

    def train_step(self, batch: SnippetBatch) -> dict[str, float]:
        """One optimiser step on a batch; returns the loss terms and timings."""
        t0 = time.perf_counter()
        self.depth_net.train()
        self.pose_net.train()
        inputs = forward_snippets(self.depth_net, self.pose_net, batch.to(self.device), self.cfg.loss.pose_antisymmetric)
        total, terms = snippet_loss(inputs, self.cfg.loss)
        t1 = time.perf_counter()
        if not torch.isfinite(total):
            raise TrainingDiverged(f"non-finite loss at step {self.step + 1} ({terms}); "
                                   f"last good checkpoint kept at {self.run_dir / 'latest.pt'}")
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        self.optimizer.step()
        t2 = time.perf_counter()
        return {"loss": float(total.detach()), **terms, "time_forward": t1 - t0, "time_backward": t2 - t1}

    @torch.no_grad()
    def validation_loss(self, n_max: int = VAL_LOSS_SNIPPETS) -> dict[str, float]:
        """Mean loss terms (eval mode, no augmentation) over up to ``n_max`` evenly spread validation snippets."""
        if self.val_set is None or len(self.val_set) == 0:
            return {}
        self.depth_model.eval()
        self.pose_model.eval()
        picks = np.unique(np.linspace(0, len(self.val_set) - 1, min(n_max, len(self.val_set))).round().astype(int))
        sums: dict[str, float] = {}
        bs = self.cfg.optim.batch_size
        for start in range(0, len(picks), bs):
            batch = collate([self.val_set[int(p)] for p in picks[start:start + bs]]).to(self.device)
            inputs = forward_snippets(self.depth_model, self.pose_model, batch, self.cfg.loss.pose_antisymmetric)
            total, terms = snippet_loss(inputs, self.cfg.loss)
            for k, v in {"loss": float(total), **terms}.items():
                sums[k] = sums.get(k, 0.0) + v * batch.images.shape[0]
        return {f"val_{k}": v / len(picks) for k, v in sums.items()}

    def validate(self) -> dict[str, float]:
        """Validation loss plus depth and pose metrics on the validation sequences (main process only)."""
        if not self.val_seqs:
            return {}
        out = self.validation_loss()
        metrics = evaluate_nets(self.depth_model, self.pose_model, self.val_seqs, self.hw, self.cfg.eval, self.device,
                                batch_size=max(self.cfg.optim.batch_size, 4))
        out.update({f"val_{k}": v for k, v in metrics.items()})
        return out

    def score(self, row: dict[str, float]) -> float | None:
        """Lower is better; ``config.select_by`` (``auto``: depth AbsRel with depth ground truth, else pose ATE-5
        with a poses file, else the validation loss)."""
        key = self.cfg.select_by
        if key == "auto":
            for k in ("val_abs_rel", "val_ate", "val_loss"):
                if row.get(k) is not None and math.isfinite(row[k]):
                    return row[k]
            return None
        value = row.get(f"val_{key}")
        if value is None:
            raise ConfigError(f"select_by {key!r}: validation has no '{key}' (have: "
                              f"{', '.join(k[4:] for k in row if k.startswith('val_'))})")
        return value

    def fit(self) -> dict[str, float]:
        """Train to ``config.steps``; returns the last logged row (with validation when available)."""
        from tqdm import tqdm

        cfg = self.cfg
        last: dict[str, float] = {}
        if self.step == 0 and self.val_seqs and self.dist.is_main:
            self.initial_val = {"step": 0, **self.validate()}
            last = dict(self.initial_val)
            if self.val_logger:
                self.val_logger.log(last)
        bar = tqdm(total=cfg.steps, initial=self.step, desc="train-depth", dynamic_ncols=True,
                   disable=not (cfg.progress and self.dist.is_main))
        t_data = time.perf_counter()
        for batch in self._loader():
            data_time = time.perf_counter() - t_data
            row = self.train_step(batch)
            self.step += 1
            bar.update(1)
            row = {"step": self.step, "epoch": self.epoch, "lr": self.optimizer.param_groups[0]["lr"],
                   "time_data": data_time, **row}
            is_val = bool(self.val_seqs) and (self.step % cfg.val_every == 0 or self.step == cfg.steps)
            is_ckpt = self.step % cfg.ckpt_every == 0 or self.step == cfg.steps or is_val
            best = False
            if self.step % cfg.log_every == 0 or is_val or self.step == cfg.steps:
                reduced = distributed.all_reduce_mean(row, self.dist)
                row = {k: reduced[k] for k in row}  # keep the column order (the reduction sorts keys)
                if is_val and self.dist.is_main:
                    val = {"step": self.step, **self.validate()}
                    score = self.score(val)
                    if score is not None and (self.best_val is None or score < self.best_val):
                        self.best_val, best = score, True
                    if self.val_logger:
                        self.val_logger.log(val)
                    row.update(val)
                if self.logger:
                    self.logger.log({k: v for k, v in row.items() if not k.startswith("val_")})
                bar.set_postfix(loss=f"{row['loss']:.4f}",
                                **({"absrel": f"{row['val_abs_rel']:.3f}"} if "val_abs_rel" in row else {}))
                last = row
            if is_ckpt:
                self.save(best=best)
            t_data = time.perf_counter()
        bar.close()
        if self.dist.is_main:
            write_json_atomic(self.run_dir / "metrics.json", {"initial": self.initial_val, "final": last,
                                                              "best_score": self.best_val, "steps": self.step})
        return last

    def close(self) -> None:
        distributed.shutdown(self.dist)

    def checkpoints(self) -> DepthCheckpoints:
        best = (self.run_dir / DISP_BEST).is_file() and (self.run_dir / POSE_BEST).is_file()
        disp, pose = (DISP_BEST, POSE_BEST) if best else (DISP_CHECKPOINT, POSE_CHECKPOINT)
        metrics = {}
        if (self.run_dir / "metrics.json").is_file():
            metrics = json.loads((self.run_dir / "metrics.json").read_text())
        return DepthCheckpoints(disp=self.run_dir / disp, pose=self.run_dir / pose, best=best, run_dir=self.run_dir,
                                metrics=metrics)


def train_depth(config: DepthTrainConfig, resume: bool = False) -> DepthCheckpoints:
    """Train the depth and pose nets; return the official-format checkpoints stage one should load.

    Those are the ``*_model_best`` pair when validation sequences were given, else the last
    ``*_checkpoint`` pair. With ``steps == 0`` the untrained nets are written (and validated).
    """
    trainer = DepthTrainer(config, resume=resume)
    try:
        trainer.fit()
        if trainer.step == 0 or not (trainer.run_dir / DISP_CHECKPOINT).is_file():
            trainer.save(best=bool(trainer.val_seqs) and trainer.best_val is None)
    finally:
        trainer.close()
    return trainer.checkpoints()
