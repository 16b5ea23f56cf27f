"""The names of options that configs check, torch-free so that the configs (and ``--help``) load without
torch: the kNN backends (:mod:`training.knn`), the depth-consistency variants
(:mod:`training.losses.depth_consistency`), the orders of the level factors α (:mod:`training.losses.total`) and
the pc2 points each level's Chamfer and Laplacian compare with (:func:`training.two_pass.level_inputs`) and
the learning-rate schedules (:func:`training.trainer.lr_factor`) and the flow net's
normalisation layers (:class:`training.model.layers.SharedMLP`)."""

from __future__ import annotations

from typing import Literal

KnnBackend = Literal["auto", "kdtree", "torch"]
BACKENDS: tuple[str, ...] = ("auto", "kdtree", "torch")

DepthVariant = Literal["paper", "released"]
DEPTH_VARIANTS: tuple[str, ...] = ("paper", "released")

AlphaOrder = Literal["released", "paper"]
ALPHA_ORDERS: tuple[str, ...] = ("released", "paper")

Pc2Target = Literal["level", "finest", "independent"]
PC2_TARGETS: tuple[str, ...] = ("level", "finest", "independent")

LrSchedule = Literal["step", "cosine"]
SCHEDULES: tuple[str, ...] = ("step", "cosine")

NormKind = Literal["batch", "layer", "none"]
NORMS: tuple[str, ...] = ("batch", "layer", "none")
