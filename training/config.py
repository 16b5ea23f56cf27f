"""Configuration of a scene-flow training run (saved as ``config.json`` in the run folder)."""

from __future__ import annotations

from dataclasses import dataclass, field

from training.losses.total import LossWeights
from training.model.halflownet import HALFlowConfig


@dataclass
class DataConfig:
    """What the trainer reads from a stage-one cache.

    n_points: points sampled per cloud per step (seeded by (seed, epoch, pair index), so results do not
        depend on the number of loader workers).
    val_fraction: the last fraction of each sequence's pairs held out for validation (label-free scores,
        and EPE3D where the cache holds ground-truth flow); 0 disables validation.
    val_pairs_max: at most this many held-out pairs are scored at each validation.
    colour_features: use RGB in [0, 1] as the per-point features (else zeros). Off by default: the KITTI
        scene-flow test splits (FlowNet3D, HPLFlowNet) carry no colours, so a net trained with them meets zeros
        there (monoflow-evaluate warns).
    jitter_deg / jitter_m: the second pass's static flow is moved by a random rigid motion of at most
        these angles (degrees, per axis) and translations (metres, per axis) — the released code's
        augmentation; 0 disables it.
    workers: DataLoader worker processes (0 = load in the training process).
    depth2_kept_only: the depth-consistency loss samples D_{t+1} only at frame-(t+1) pixels that survived
        stage one's filters (ground, sky, LiDAR range, occlusion), i.e. the surfaces pc2 holds; other pixels
        count as invalid and the points landing there are masked. False = the whole depth map (the
        released code). Without it, a point can satisfy depth consistency by sliding onto the road, which
        the ground filter removed from pc2 (see the note in BENCHMARKS.md / the trainer tests).
    lidar_rings: probability per training pair of keeping only points near LiDAR-like scan rings
        (:mod:`training.augment`); 0 = off.
    ring_band: share of a ring spacing (0.3–0.5°) that a ring keeps (0.5 keeps about half the points).
    density_drop: frame t+1 loses a random share of up to this fraction of its points; 0 = off.
    ground_jitter_m: metres; both frames lose points below a cut drawn up to this far above the lowest
        points, as a test split's height-threshold ground removal would; 0 = off.
    ego_speed_scale: (low, high); each training pair's camera motion is rescaled by a factor drawn
        log-uniformly in this range (rotation angle and translation alike; frame t's cloud is moved, frame
        t+1 and its depth map stay, :func:`training.augment.speed_scaled_view`), so the net learns camera
        speeds beyond the ones its sequences drove at (KITTI: 0–2.5 m per frame); (1, 1) = off.
    """

    n_points: int = 8192
    val_fraction: float = 0.1
    val_pairs_max: int = 64
    colour_features: bool = False
    jitter_deg: float = 0.0
    jitter_m: float = 0.0
    workers: int = 2
    depth2_kept_only: bool = False
    lidar_rings: float = 0.0
    ring_band: float = 0.5
    density_drop: float = 0.0
    ground_jitter_m: float = 0.0
    ego_speed_scale: tuple[float, float] = (1.0, 1.0)

    def augment(self) -> dict:
        """The keyword arguments of :func:`training.augment.augment_masks` for training pairs."""
        return {"lidar_rings": self.lidar_rings, "ring_band": self.ring_band, "density_drop": self.density_drop,
                "ground_jitter_m": self.ground_jitter_m}


def level_points_for(n_points: int) -> tuple[int, ...]:
    """The paper's level sizes (2048/1024/256/64/16 for 8192 inputs), scaled to ``n_points``; for small
    inputs the coarsest level keeps 4 points and each finer level at least twice the next coarser one,
    so the levels stay strictly decreasing (256 → 64/32/16/8/4). Needs ``n_points >= 128``."""
    levels = [int(n_points * f) for f in (0.25, 0.125, 1 / 32, 1 / 128, 1 / 512)]
    levels[4] = max(4, levels[4])
    for i in range(3, -1, -1):
        levels[i] = max(levels[i], 2 * levels[i + 1])
    return tuple(levels)


@dataclass
class OptimConfig:
    """Adam with the paper's step decay: lr · decay^(samples // decay_every), floored at lr_min.

    lr: initial learning rate.
    decay: factor applied every ``decay_every_samples`` training samples.
    decay_every_samples: training pairs seen between two decays.
    lr_min: the learning rate never goes below this.
    batch_size: pairs per optimiser step (global, over all processes).
    grad_clip: clip the gradient norm to this (0 = no clipping).
    """

    lr: float = 1e-3
    decay: float = 0.7
    decay_every_samples: int = 200_000
    lr_min: float = 1e-4
    batch_size: int = 5
    grad_clip: float = 0.0


@dataclass
class TrainConfig:
    """A whole run. ``steps`` counts optimiser steps (global batches of ``optim.batch_size`` pairs).

    epochs: when > 0, overrides ``steps`` (ceil(epochs · training pairs / batch size)).
    threads: torch intra-op threads of each training process (0 = leave torch's default); on a small
        machine with loader workers, fewer threads than cores avoids oversubscription.
    sync_bn: under DDP, batch norm uses the statistics of the global batch (so P processes with a global
        batch B train like one process with B); false = per-process statistics, as plain DDP does.
    deterministic: ``torch.use_deterministic_algorithms`` (warn only); on the CPU a run is repeatable
        with a fixed ``threads`` either way.
    log_every / val_every / ckpt_every: in steps; the last step always validates and checkpoints.
    select_by: the held-out score ``best.pt`` minimises: ``val_l0`` (the finest level's loss, needs no
        labels), ``val_loss`` (the whole multi-level loss) or ``val_epe3d`` (needs ground-truth flow;
        synthetic data only). See :mod:`training.selection`.
    cache: stage-one cache folder (<out>/<dataset>/<config-hash>, written by monoflow-preprocess).
    run_dir: run folder (config.json, train.csv / val.csv, latest.pt, best.pt); an existing one is refused
        unless --resume or --overwrite.
    steps: optimiser steps of the run (global batches of optim.batch_size pairs).
    seed: seed of every RNG (Python, numpy, torch) and of the point sampling.
    device: auto | cpu | cuda[:i] (auto = the GPU when there is one).
    amp: mixed-precision training (CUDA).
    progress: tqdm progress bar.
    """

    cache: str = "cache/synthetic"
    run_dir: str = "runs/flow"
    steps: int = 1000
    epochs: float = 0.0
    seed: int = 0
    device: str = "auto"
    threads: int = 0
    amp: bool = False
    sync_bn: bool = True
    deterministic: bool = False
    log_every: int = 10
    val_every: int = 100
    ckpt_every: int = 100
    progress: bool = True
    select_by: str = "val_l0"
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    model: HALFlowConfig = field(default_factory=HALFlowConfig)
    loss: LossWeights = field(default_factory=LossWeights)
