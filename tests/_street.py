"""A small street of points for the clustering, augmentation and polish tests (camera frame, metres)."""

from __future__ import annotations

import numpy as np


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
