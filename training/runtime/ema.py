"""An exponential moving average of a net's weights (Polyak averaging), the copy a run evaluates.

After every optimiser step each floating-point parameter and buffer ``w`` of the averaged copy becomes
``d · w + (1 − d) · w_trained``, with ``d = min(decay, (1 + n) / (10 + n))`` after ``n`` updates (the
short warm-up keeps the first steps' random weights from lingering); integer buffers (batch norm's
step counter) are copied. Batch-norm running statistics are averaged like the weights, so the copy is a
complete net in eval mode. The trained weights keep driving the optimisation; only validation,
checkpoints' inference weights and everything downstream of them read the average.
"""

from __future__ import annotations

import copy

import torch
from torch import nn


class WeightAverage:
    """The averaged copy of ``model`` (its own module, same class and config, on the same device)."""

    def __init__(self, model: nn.Module, decay: float) -> None:
        if not 0.0 < decay < 1.0:
            raise ValueError(f"decay must be in (0, 1), got {decay}")
        self.decay = float(decay)
        self.module = copy.deepcopy(model)
        self.module.requires_grad_(False)
        self.updates = 0

    def factor(self) -> float:
        """The averaging factor ``d`` of the next update."""
        return min(self.decay, (1.0 + self.updates) / (10.0 + self.updates))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        d = self.factor()
        trained = model.state_dict()
        for name, avg in self.module.state_dict().items():
            new = trained[name].detach()
            if avg.dtype.is_floating_point:
                avg.mul_(d).add_(new.to(avg.dtype), alpha=1.0 - d)
            else:
                avg.copy_(new)
        self.updates += 1

    def state_dict(self) -> dict:
        return {"weights": self.module.state_dict(), "updates": self.updates}

    def load_state_dict(self, state: dict) -> None:
        self.module.load_state_dict(state["weights"])
        self.updates = int(state["updates"])
