"""Small streets of points for the tests (camera frame, metres): walls, a facade and poles for the translation and
rigid vote tests; boxes beside a wall for the clustering, augmentation and rigid polish tests."""

from __future__ import annotations

import numpy as np
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


def street(rng: np.random.Generator) -> tuple[np.ndarray, list[np.ndarray]]:
    """Two car-sized boxes of points (0.5 m grids, jittered) 10 m apart, a 30 m wall and two stray points
    (camera frame, metres); the indices of the boxes."""
    grid = np.stack(np.meshgrid(np.arange(0, 2.01, 0.5), np.arange(-1.5, 0.01, 0.5), np.arange(0, 4.01, 0.5),
                                indexing="ij"), -1).reshape(-1, 3)  # 5 x 4 x 9 = 180 points
    box1 = grid + [-1, 0, 9] + rng.uniform(-0.05, 0.05, grid.shape)
    box2 = grid[::2] + [6, 0, 20] + rng.uniform(-0.05, 0.05, grid[::2].shape)
    wall = np.column_stack([np.full(2000, -6.0), rng.uniform(-3, 0, 2000), rng.uniform(0, 30, 2000)])
    stray = np.array([[20.0, -1.0, 40.0], [-20.0, -1.0, 45.0]])
    pts = np.concatenate([box1, box2, wall, stray])
    return pts, [np.arange(180), np.arange(180, 270)]
