"""Small shared helpers: device choice, tensors from the evaluation's numpy clouds, seeded MLP."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn


def resolve(device: str) -> torch.device:
    """``"auto"`` → CUDA when available, else CPU; otherwise the named device."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def as_tensor(x: np.ndarray | Tensor, device: torch.device) -> Tensor:
    """(N, 3) numpy or tensor → (1, N, 3) float32 tensor on ``device`` (a copy; the input is left alone)."""
    if isinstance(x, Tensor):
        return x.detach().to(device, torch.float32).reshape(1, -1, 3).clone()
    return torch.tensor(np.asarray(x, dtype=np.float32), device=device).reshape(1, -1, 3)


class FlowMLP(nn.Module):
    """``xyz (…, 3) metres → flow (…, 3) metres``: ``layers`` hidden Linear+ReLU layers of ``hidden`` units
    and a linear output (NSFP's prior: Li et al. 2021, §3, 8 × 128 ReLU by default).

    Initial weights come from a private generator seeded by ``seed`` (PyTorch's default Linear init,
    U(±1/√fan_in)), so two MLPs built with the same seed are identical whatever the global RNG state.
    ``zero_output=True`` starts the output layer at zero (the MLP then predicts zero flow: a residual
    on top of a given flow starts exactly at that flow).
    """

    def __init__(self, layers: int = 8, hidden: int = 128, seed: int = 0, zero_output: bool = False) -> None:
        super().__init__()
        gen = torch.Generator().manual_seed(int(seed))
        dims = [3] + [hidden] * layers
        mods: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:]):
            mods += [nn.Linear(a, b), nn.ReLU()]
        mods.append(nn.Linear(dims[-1], 3))
        self.body = nn.Sequential(*mods)
        with torch.no_grad():
            for m in self.body:
                if isinstance(m, nn.Linear):
                    bound = 1.0 / m.in_features ** 0.5
                    m.weight.copy_(torch.rand(m.weight.shape, generator=gen) * 2 * bound - bound)
                    m.bias.copy_(torch.rand(m.bias.shape, generator=gen) * 2 * bound - bound)
            if zero_output:
                last = self.body[-1]
                assert isinstance(last, nn.Linear)
                last.weight.zero_()
                last.bias.zero_()

    def forward(self, xyz: Tensor) -> Tensor:
        return self.body(xyz)
