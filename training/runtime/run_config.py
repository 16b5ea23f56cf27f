"""The run fields both trainers share (scene flow :class:`training.config.TrainConfig`, depth/pose
:class:`training.depth.config.DepthTrainConfig`): one definition, one flag each (``--steps``, ``--seed`` …).
A trainer's config subclasses it and may give a field its own default or help text."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class RunConfig:
    """Where a run writes, how long it trains and how often it logs.

    run_dir: run folder (config.json, train.csv / val.csv, checkpoints; ``latest.pt`` to resume).
    steps: optimiser steps of the run.
    seed: seed of every RNG (Python, numpy, torch).
    device: auto | cpu | cuda[:i] (auto = the GPU when there is one).
    deterministic: ask torch for deterministic kernels (warn only).
    log_every, val_every, ckpt_every: in steps; the last step always validates and checkpoints.
    progress: tqdm progress bar.
    """

    run_dir: str = "runs/run"
    steps: int = 1000
    seed: int = 0
    device: str = "auto"
    deterministic: bool = False
    log_every: int = 10
    val_every: int = 100
    ckpt_every: int = 100
    progress: bool = True
