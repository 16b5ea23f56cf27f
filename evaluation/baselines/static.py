"""Pose-only static flow: the flow every point would have if the scene were rigid and only the camera moved.

``sf_s = (R p + t) − p`` with ``T_{1→2} = [R | t]`` mapping camera-1 to camera-2 coordinates (docs/design.md §2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evaluation.baselines.base import as_cloud
from pipeline import geometry


def static_flow(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(N, 3) float32 static flow of camera-1 ``points`` (metres) under ``pose`` = ``T_{1→2}`` (4×4).

    Computed in float64 by :func:`pipeline.geometry.static_flow`, the function stage one uses.
    """
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"pose must have shape (4, 4), got {pose.shape}")
    return geometry.static_flow(as_cloud("points", points), pose).astype(np.float32)


@dataclass
class StaticPoseBaseline:
    """The static flow of a known ``T_{1→2}``; build one per sample (pc2 is ignored)."""

    pose: np.ndarray
    name: str = "static-pose"

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        return static_flow(pc1, self.pose)
