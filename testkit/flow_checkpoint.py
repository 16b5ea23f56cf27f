"""A tiny, randomly initialised scene-flow net saved as a monoflow-train checkpoint (tests, benchmarks)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path


def tiny_flow_checkpoint(path: str | Path, seed: int = 0, colour: bool = True, n_points: int = 256,
                         **model: object) -> Path:
    """``path`` holding a seeded HALFlowNet at test size (n_points points, 128 at level 0, width 0.25), in the
    layout NetMethod and monoflow-predict read (kind "flow", config.model, config.data, model); ``model``:
    further :class:`HALFlowConfig` fields (``ego_head=True`` …)."""
    import torch

    from training.model.halflownet_config import HALFlowConfig
    from training.model.registry import construct_model
    from training.runtime.checkpoints import save_checkpoint

    cfg = HALFlowConfig(n_points=n_points, level_points=(128, 64, 32, 16, 8), level_k=(8, 8, 8, 8, 4),
                        cost_k_pc2=8, width_scale=0.25, **model)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = construct_model("halflownet", cfg)
    return save_checkpoint(Path(path), {"kind": "flow", "model": net.state_dict(), "step": 0,
                                        "config": {"model_name": "halflownet", "model": asdict(cfg),
                                                   "data": {"colour_features": colour}}})
