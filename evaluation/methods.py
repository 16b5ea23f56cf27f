"""Everything that predicts flow, behind one interface, so that each method sees the same points.

A method is called as ``method(pc1, pc2, color1, color2) -> flow`` on the *sampled* clouds of a scene
(camera frames of frames 1 and 2, metres; colours RGB in [0, 1] or None) and returns the flow of every
pc1 point, (N, 3) float32 metres. The trained net predicts at its level-0 points and its flow is spread
to the other sampled points by 3-NN inverse-distance interpolation (exact at the level-0 points).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from pipeline.errors import ConfigError


class FlowMethod(Protocol):
    name: str

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray, color1: np.ndarray | None,
                 color2: np.ndarray | None) -> np.ndarray: ...


@dataclass
class BaselineMethod:
    """Adapts a ``baseline(pc1, pc2) -> flow`` (zero, ICP, FGR) to :class:`FlowMethod`."""

    baseline: object

    @property
    def name(self) -> str:
        return self.baseline.name

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        return np.asarray(self.baseline(pc1, pc2), dtype=np.float32)


class NetMethod:
    """A scene-flow net restored from a ``monoflow-train`` checkpoint (``latest.pt``)."""

    def __init__(self, checkpoint: str | Path, device: str = "auto", name: str | None = None) -> None:
        import torch

        from training.model.halflownet import HALFlowConfig, HALFlowNet
        from training.runtime.checkpoints import load_checkpoint
        from training.runtime.device import resolve_device

        ckpt = load_checkpoint(checkpoint, kind="flow")
        cfg = ckpt["config"]
        self.config = HALFlowConfig(**cfg["model"])
        self.colour = bool(cfg.get("data", {}).get("colour_features", True))
        self.device = resolve_device(device)
        self.net = HALFlowNet(self.config).to(self.device).eval()
        self.net.load_state_dict(ckpt["model"])
        self.step = int(ckpt["step"])
        self.name = name or f"ours ({Path(checkpoint).parent.name}, step {self.step})"
        self._torch = torch

    @property
    def n_points(self) -> int:
        return self.config.n_points

    @property
    def n_score(self) -> int:
        return self.config.level_points[0]

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        torch = self._torch
        from training.pointops import three_nn_interpolate

        def t(x):
            return torch.as_tensor(np.asarray(x, np.float32), device=self.device)[None]

        f1 = t(color1) if (self.colour and color1 is not None) else t(np.zeros_like(pc1))
        f2 = t(color2) if (self.colour and color2 is not None) else t(np.zeros_like(pc2))
        with torch.no_grad():
            out = self.net(t(pc1), t(pc2), f1, f2)
            flow = three_nn_interpolate(t(pc1), out.points[0], out.flows[0].float())
        return flow[0].cpu().numpy().astype(np.float32)


BASELINES = ("zero", "icp-p2p", "icp-p2l", "fgr")


def make_baseline(name: str) -> BaselineMethod:
    """One of :data:`BASELINES`, with its default settings."""
    from evaluation.baselines.fgr import FGRBaseline
    from evaluation.baselines.icp import ICPBaseline, ICPConfig
    from evaluation.baselines.zero import ZeroFlowBaseline

    if name == "zero":
        return BaselineMethod(ZeroFlowBaseline())
    if name == "icp-p2p":
        return BaselineMethod(ICPBaseline(ICPConfig(method="point_to_point")))
    if name == "icp-p2l":
        return BaselineMethod(ICPBaseline(ICPConfig(method="point_to_plane")))
    if name == "fgr":
        return BaselineMethod(FGRBaseline())
    raise ConfigError(f"unknown baseline '{name}' (choose from {', '.join(BASELINES)})")
