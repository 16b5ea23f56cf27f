"""Self-supervised training of stage one's depth (DispResNet) and pose (PoseResNet) nets (SC-SfMLearner).

``monoflow-train-depth`` (``python -m training.depth``) trains on KITTI-odometry-layout folders (real KITTI
or the synthetic world) and writes checkpoints in the released format, so ``monoflow-preprocess`` loads
them exactly like the released weights. Python API::

    from training.depth import demo_config, train_depth
    ckpts = train_depth(demo_config("cache/synth", "runs/depth-demo"))
    ckpts.disp, ckpts.pose    # dispnet_model_best.pth.tar, exp_pose_model_best.pth.tar

Importing this package is light (no torch); the names below load their modules on first use.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "DepthTrainConfig": "training.depth.config",
    "DepthDataConfig": "training.depth.config",
    "DepthLossConfig": "training.depth.config",
    "DepthModelConfig": "training.depth.config",
    "DepthOptimConfig": "training.depth.config",
    "DepthEvalConfig": "training.depth.config",
    "demo_config": "training.depth.config",
    "tiny_config": "training.depth.config",
    "DepthCheckpoints": "training.depth.trainer",
    "DepthTrainer": "training.depth.trainer",
    "train_depth": "training.depth.trainer",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'training.depth' has no attribute {name!r}")
