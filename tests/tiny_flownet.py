"""A second flow net, as small as a net can be: the example that adding a net takes one module and one
registry line (``register_flow_net("tiny", TinyFlowConfig, TinyFlowNet)``, see tests/training/test_flow_registry.py).

Flow of every frame-1 point = the offset between the two clouds' means plus a per-point MLP of the centred
point and its features; the four output levels are nested first-N subsets of the input (the ``"random"``
sampling of :mod:`training.model.halflownet`), frame 2 likewise. It keeps :mod:`training.model.contract`:
levels finest first, indices into the inputs, ``sampling=`` reuses another pass's points, no global RNG.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from core.errors import ConfigError
from training.model.contract import FlowOutput, Sampling


@dataclass
class TinyFlowConfig:
    """Architecture of :class:`TinyFlowNet`.

    n_points: points per input cloud.
    level_points: points of the four output levels, finest first (the first n of the input).
    width_scale: hidden width = 32 × width_scale (at least 4).
    feature_dim: channels of the per-point features (3 for RGB; 0 for none).
    sampling: always "random" (first-N levels).
    """

    n_points: int = 256
    level_points: tuple[int, ...] = (128, 64, 32, 16)
    width_scale: float = 1.0
    feature_dim: int = 3
    sampling: str = "random"

    def __post_init__(self) -> None:
        self.level_points = tuple(int(n) for n in self.level_points)
        pts = (self.n_points, *self.level_points)
        if len(self.level_points) != 4 or any(a < b for a, b in zip(pts, pts[1:])) or min(pts) < 1:
            raise ConfigError(f"tiny net: need 4 positive, non-increasing level_points <= n_points, got {pts}")
        if self.sampling != "random":
            raise ConfigError(f"tiny net: sampling must be 'random', got {self.sampling!r}")

    @property
    def output_points(self) -> tuple[int, ...]:
        return self.level_points

    @classmethod
    def points_fields(cls, n_points: int) -> dict[str, Any]:
        return {"n_points": n_points, "level_points": tuple(max(1, n_points >> k) for k in (1, 2, 3, 4))}

    def check_for_training(self) -> None:
        """Nothing beyond ``__post_init__``."""


class TinyFlowNet(nn.Module):
    """Mean offset + per-point MLP; see the module docstring."""

    def __init__(self, config: TinyFlowConfig | None = None) -> None:
        super().__init__()
        self.config = config or TinyFlowConfig()
        width = max(4, round(32 * self.config.width_scale))
        self.mlp = nn.Sequential(nn.Linear(3 + self.config.feature_dim, width), nn.ReLU(), nn.Linear(width, 3))

    def forward(self, pc1: Tensor, pc2: Tensor, feat1: Tensor | None = None, feat2: Tensor | None = None,
                sampling: Sampling | None = None) -> FlowOutput:
        B = pc1.shape[0]
        if sampling is None:
            def first(n: int) -> Tensor:
                return torch.arange(n, device=pc1.device).expand(B, n)

            sampling = Sampling(pc1=[first(n) for n in self.config.level_points],
                                pc2=[first(min(n, pc2.shape[1])) for n in self.config.level_points])
        if feat1 is None:
            feat1 = pc1.new_zeros(B, pc1.shape[1], self.config.feature_dim)
        offset = pc2.mean(1, keepdim=True) - pc1.mean(1, keepdim=True)
        flow = offset + self.mlp(torch.cat([pc1 - pc1.mean(1, keepdim=True), feat1.to(pc1.dtype)], dim=-1))

        def at(x: Tensor, idx: Tensor) -> Tensor:
            return x.gather(1, idx[..., None].expand(-1, -1, x.shape[-1]))

        return FlowOutput(flows=[at(flow, i) for i in sampling.pc1], indices=list(sampling.pc1),
                          points=[at(pc1, i) for i in sampling.pc1], indices2=list(sampling.pc2),
                          points2=[at(pc2, i) for i in sampling.pc2], sampling=sampling)
