"""The paper's unsupervised loss: the four terms at every pyramid level, weighted (eq. 17).

    L_Un = Σ_k α_k (β1 L^k_Depth + β2 L^k_DS + β3 L^k_Cha + β4 L^k_LR)

Levels are given finest first (2048, 1024, 256, 64 points at the paper's defaults). Every term is a
per-point mean (see each function), so a level's terms are on the same scale whatever its number of
points and α alone sets the balance between levels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from pipeline.errors import ConfigError, InputError
from training.knn import KnnBackend
from training.losses._common import check_points
from training.losses.chamfer import chamfer
from training.losses.depth_consistency import DEPTH_VARIANTS, DepthVariant, depth_consistency
from training.losses.dynamic_static import dynamic_static
from training.losses.laplacian import laplacian

AlphaOrder = Literal["released", "paper"]
ALPHA_ORDERS: tuple[str, ...] = ("released", "paper")


@dataclass
class LossWeights:
    """Weights and switches of the unsupervised loss.

    beta: (depth, dynamic-static, Chamfer, Laplacian) = (β1, β2, β3, β4), paper §IV-B.
    alpha: (α1, α2, α3, α4) as the paper lists them. The paper does not say which end of the pyramid
        α1 belongs to. ``alpha_order="released"`` (default) follows the released code, which gives the
        largest factor to the finest level: finest-first weights are ``reversed(alpha)`` = (0.16, 0.08,
        0.04, 0.02). ``"paper"`` reads α_k as level k counted from the finest: (0.02, 0.04, 0.08, 0.16).
    use_*: switch a term off for the loss ablations (it is then neither computed nor logged).
    depth_variant: ``"paper"`` | ``"released"`` (see :func:`depth_consistency`).
    laplacian_k, interp_k: neighbours of the Laplacian (10) and of its interpolation (5).
    eps: depth (metres) at or below which a warped point counts as behind the camera.
    depth_edge_tolerance: depth consistency ignores points whose bilinear depth sample straddles a depth
        edge (2×2 pixels spanning more than this fraction); 0 = plain bilinear sampling (the paper).
    depth_norm: ``l1`` (the residual's length, default) or ``l2`` (its square, the paper's form).
    knn_backend: "auto" | "kdtree" | "torch" neighbour search of the Laplacian terms (see training.knn).
    """

    beta: tuple[float, float, float, float] = (0.1, 0.1, 1.0, 0.3)
    alpha: tuple[float, ...] = (0.02, 0.04, 0.08, 0.16)
    alpha_order: AlphaOrder = "released"
    use_depth: bool = True
    use_ds: bool = True
    use_chamfer: bool = True
    use_laplacian: bool = True
    depth_variant: DepthVariant = "paper"
    laplacian_k: int = 10
    interp_k: int = 5
    eps: float = 1e-3
    depth_edge_tolerance: float = 0.05
    depth_norm: str = "l1"
    knn_backend: KnnBackend = "auto"

    def __post_init__(self) -> None:
        self.beta = tuple(float(b) for b in self.beta)  # type: ignore[assignment]
        self.alpha = tuple(float(a) for a in self.alpha)
        if len(self.beta) != 4:
            raise ConfigError(f"beta must have 4 weights (depth, ds, chamfer, laplacian), got {self.beta}")
        if not self.alpha:
            raise ConfigError("alpha must have at least one level factor")
        if any(w < 0 for w in self.beta + self.alpha):
            raise ConfigError(f"loss weights must be non-negative, got beta={self.beta} alpha={self.alpha}")
        if self.alpha_order not in ALPHA_ORDERS:
            raise ConfigError(f"alpha_order must be one of {ALPHA_ORDERS}, got {self.alpha_order!r}")
        if self.depth_variant not in DEPTH_VARIANTS:
            raise ConfigError(f"depth_variant must be one of {DEPTH_VARIANTS}, got {self.depth_variant!r}")
        if self.laplacian_k < 1 or self.interp_k < 1:
            raise ConfigError(f"laplacian_k and interp_k must be ≥ 1, got {self.laplacian_k}, {self.interp_k}")


@dataclass
class LevelInputs:
    """One pyramid level's tensors for the loss (points of frame t at this level, n of them).

    pc1 (B, n, 3): frame-t points, camera-1 frame, metres.
    pc2 (B, m, 3): frame-(t+1) points at this level, camera-2 frame.
    flow_o (B, n, 3): overall flow net(pc1, pc2); pc1 + flow_o is in camera-2 coordinates.
    flow_d (B, n, 3): dynamic flow net(pc1 + sf_s, pc2).
    static_flow (B, n, 3): sf_s = (R p1 + t) − p1 at pc1 (the one fed to the second pass).
    K (B, 3, 3): intrinsics at the depth map's resolution.
    depth2 (B, H, W): D_{t+1}, metres, ≤ 0 where unknown.
    """

    pc1: Tensor
    pc2: Tensor
    flow_o: Tensor
    flow_d: Tensor
    static_flow: Tensor
    K: Tensor
    depth2: Tensor


def level_alphas(weights: LossWeights, n_levels: int) -> tuple[float, ...]:
    """Factors α for ``n_levels`` levels, finest first (see :class:`LossWeights`)."""
    if n_levels != len(weights.alpha):
        raise ConfigError(f"{n_levels} levels given but alpha has {len(weights.alpha)} factors: {weights.alpha}")
    return tuple(reversed(weights.alpha)) if weights.alpha_order == "released" else weights.alpha


def level_terms(level: LevelInputs, weights: LossWeights) -> dict[str, Tensor]:
    """The enabled unweighted terms of one level: ``depth1``, ``depth2``, ``depth``, ``ds``, ``chamfer``,
    ``laplacian`` (scalars; m², the depth terms in metres with ``depth_norm="l1"``)."""
    _check_level(level)
    w = weights
    warped = level.pc1 + level.flow_o
    out: dict[str, Tensor] = {}
    if w.use_depth:
        warped_ds = level.pc1 + level.static_flow + level.flow_d
        kw = dict(variant=w.depth_variant, source_points=level.pc1, eps=w.eps, edge_tolerance=w.depth_edge_tolerance,
                  norm=w.depth_norm)
        out["depth1"] = depth_consistency(warped, level.K, level.depth2, **kw)
        out["depth2"] = depth_consistency(warped_ds, level.K, level.depth2, **kw)
        out["depth"] = out["depth1"] + out["depth2"]
    if w.use_ds:
        out["ds"] = dynamic_static(level.flow_o, level.static_flow, level.flow_d)
    if w.use_chamfer:
        out["chamfer"] = chamfer(warped, level.pc2, w.knn_backend)
    if w.use_laplacian:
        out["laplacian"] = laplacian(warped, level.pc1, level.pc2, w.laplacian_k, w.interp_k, w.knn_backend)
    return out


def multi_level_loss(levels: list[LevelInputs], weights: LossWeights) -> tuple[Tensor, dict[str, float]]:
    """``L_Un = Σ_k α_k (β1 L^k_Depth + β2 L^k_DS + β3 L^k_Cha + β4 L^k_LR)`` (eq. 17) over ``levels``
    (finest first).

    Returns the scalar loss (with graph) and, for logging, floats keyed ``"l{k}/{term}"`` (unweighted
    terms: depth1, depth2, depth, ds, chamfer, laplacian — the enabled ones), ``"l{k}/weighted"``
    (α_k · Σ β·L of that level) and ``"total"``. The floats are read from the device in one transfer.
    """
    if not levels:
        raise InputError("multi_level_loss", "no levels given")
    alphas = level_alphas(weights, len(levels))
    beta = dict(zip(("depth", "ds", "chamfer", "laplacian"), weights.beta))
    total: Tensor | None = None
    logged: dict[str, Tensor] = {}
    for k, (level, alpha) in enumerate(zip(levels, alphas)):
        terms = level_terms(level, weights)
        weighted = sum((beta[name] * terms[name] for name in beta if name in terms), level.flow_o.new_zeros(()))
        weighted = alpha * weighted
        total = weighted if total is None else total + weighted
        for name, value in terms.items():
            logged[f"l{k}/{name}"] = value.detach()
        logged[f"l{k}/weighted"] = weighted.detach()
    assert total is not None
    logged["total"] = total.detach()
    values = torch.stack(list(logged.values())).tolist()
    return total, dict(zip(logged.keys(), values))


def _check_level(level: LevelInputs) -> None:
    where = "multi_level_loss"
    check_points(where, "pc1", level.pc1)
    B, n, _ = level.pc1.shape
    for name in ("flow_o", "flow_d", "static_flow"):
        check_points(where, name, getattr(level, name), B, n)
    check_points(where, "pc2", level.pc2, B)
