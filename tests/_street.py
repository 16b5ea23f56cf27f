"""A small street for the vote tests: walls, a facade and poles (shared by the translation and rigid vote tests)."""

from __future__ import annotations

import torch


def walls_and_poles(n: int, seed: int = 0, facade_half_width_m: float = 6.0) -> torch.Tensor:
    """(1, n, 3) points on a left wall (x = −6 m, z 5…35 m), a facade 30 m ahead (|x| ≤ ``facade_half_width_m``)
    and a grid of poles, every third point on each, y in ±1 m; camera frame (x right, y down, z forward),
    metres. ``seed`` draws another sample of the same surfaces."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 3, generator=g)
    kind = torch.arange(n) % 3
    wall_left = torch.stack([torch.full((n,), -6.0), 2 * u[:, 1] - 1, 5 + 30 * u[:, 2]], -1)
    facade = torch.stack([facade_half_width_m * (2 * u[:, 0] - 1), 2 * u[:, 1] - 1, torch.full((n,), 30.0)], -1)
    poles = torch.stack([4 + (u[:, 0] * 4).floor(), 2 * u[:, 1] - 1, 8 + 5 * (u[:, 2] * 4).floor()], -1)
    return torch.where(kind[:, None] == 0, wall_left, torch.where(kind[:, None] == 1, facade, poles))[None]
