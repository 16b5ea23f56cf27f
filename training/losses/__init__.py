"""The paper's four unsupervised losses (eqs. 7–16) and their multi-level weighted sum (eq. 17).

All points are (B, N, 3) tensors in metres; a warped point ``p1 + f`` is in camera-2 coordinates.
Every loss is a per-point mean (then a batch mean): squared distances in m² (Chamfer, Laplacian, dynamic–static,
depth consistency with ``depth_norm="l2"``) or distances in metres (depth consistency with the default ``"l1"``).
"""

from training.losses.chamfer import chamfer, nearest_sq_dist
from training.losses.depth_consistency import (
    DEPTH_VARIANTS,
    DepthVariant,
    depth_consistency,
    depth_consistency_residuals,
)
from training.losses.dynamic_static import dynamic_static
from training.losses.laplacian import laplacian, laplacian_coordinates, neighbours
from training.losses.total import LevelInputs, LossWeights, level_alphas, level_terms, multi_level_loss

__all__ = [
    "DEPTH_VARIANTS",
    "DepthVariant",
    "LevelInputs",
    "LossWeights",
    "chamfer",
    "depth_consistency",
    "depth_consistency_residuals",
    "dynamic_static",
    "laplacian",
    "laplacian_coordinates",
    "level_alphas",
    "level_terms",
    "multi_level_loss",
    "nearest_sq_dist",
    "neighbours",
]
