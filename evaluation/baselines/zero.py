"""Zero flow: predicts that nothing moves (the floor every method must beat)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evaluation.baselines.base import as_cloud


@dataclass
class ZeroFlowBaseline:
    """``flow = 0`` for every pc1 point."""

    name: str = "zero"

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        return np.zeros_like(as_cloud("pc1", pc1), dtype=np.float32)
