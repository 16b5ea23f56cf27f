"""The paper's unsupervised loss: the four terms at every pyramid level, weighted (eq. 17).

    L_Un = Σ_k α_k (β1 L^k_Depth + β2 L^k_DS + β3 L^k_Cha + β4 L^k_LR)

plus, where ``LossWeights.static_anchor`` > 0 (a departure), ``α_k · static_anchor · L^k_SA``
(:mod:`training.losses.static_anchor`), and where ``LossWeights.ego_motion`` > 0 (a departure),
``α_k · ego_motion · L^k_EM`` (:mod:`training.losses.ego_motion`), and where ``LossWeights.gate_pull`` > 0
(a departure), ``α_k · gate_pull · L^k_GP`` (:mod:`training.losses.gate_pull`), and where
``LossWeights.flow_smooth`` > 0 (a departure), ``α_k · flow_smooth · L^k_FS``
(:mod:`training.losses.flow_smooth`).

Levels are given finest first (2048, 1024, 256, 64 points at the paper's defaults). Every term is a
per-point mean (see each function), so a level's terms are on the same scale whatever its number of
points and α alone sets the balance between levels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from core.errors import ConfigError, InputError
from training.losses._common import check_points
from training.losses.chamfer import chamfer
from training.losses.depth_consistency import DepthSampler, depth_consistency, depth_sampler
from training.losses.dynamic_static import dynamic_static
from training.losses.ego_motion import ego_motion_term
from training.losses.flow_smooth import flow_smoothness
from training.losses.gate_pull import gate_pull
from training.losses.laplacian import laplacian, neighbours
from training.losses.static_anchor import static_anchor, verified_static
from training.pointops import surface_normals
from training.config import LossWeights  # noqa: F401  (re-exported: the loss config)

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
    view1 (B, n) / view2 (B, m), bool or None: the points the Chamfer term averages over (``view_mask``).
    rigid_o (B, n, 3) or None: the flow of the rigid motion the net's ego head fitted in the overall pass
        (:attr:`~training.model.contract.FlowOutput.rigid_flows`; the ego-motion term needs it).
    gap_o / gap_d (B, n) or None: the ego head's gate gaps ``‖f − sg(f')‖²`` (m²) of the overall and the
        dynamic pass (:attr:`~training.model.contract.FlowOutput.gate_gaps`; the gate pull needs them).
    gate_o (B, n) or None: the ego head's gate ``m`` in [0, 1] in the overall pass
        (:attr:`~training.model.contract.FlowOutput.gates`; ``loss.plane_where_held`` needs it).
    """

    pc1: Tensor
    pc2: Tensor
    flow_o: Tensor
    flow_d: Tensor
    static_flow: Tensor
    K: Tensor
    depth2: Tensor
    view1: Tensor | None = None
    view2: Tensor | None = None
    rigid_o: Tensor | None = None
    gap_o: Tensor | None = None
    gap_d: Tensor | None = None
    gate_o: Tensor | None = None


def level_alphas(weights: LossWeights, n_levels: int) -> tuple[float, ...]:
    """Factors α for ``n_levels`` levels, finest first (see :class:`LossWeights`)."""
    if n_levels != len(weights.alpha):
        raise ConfigError(f"{n_levels} levels given but alpha has {len(weights.alpha)} factors: {weights.alpha}")
    return tuple(reversed(weights.alpha)) if weights.alpha_order == "released" else weights.alpha


def level_terms(level: LevelInputs, weights: LossWeights,
                samplers: dict[tuple[int, torch.dtype], tuple[Tensor, DepthSampler]] | None = None
                ) -> dict[str, Tensor]:
    """The enabled unweighted terms of one level: ``depth1``, ``depth2``, ``depth``, ``ds``, ``chamfer``,
    ``laplacian``, ``anchor``, ``ego``, ``pull``, ``smooth`` (scalars; m², the depth terms in metres with
    ``depth_norm="l1"``, the anchor, the ego-motion and the smoothness term in metres). ``samplers``: the depth
    maps already prepared for sampling, by (id of ``depth2``, dtype) with the map itself, shared by the levels of
    one loss (every level's two depth terms sample the batch's one map); filled here."""
    _check_level(level)
    w = weights
    warped = level.pc1 + level.flow_o
    out: dict[str, Tensor] = {}
    samplers = {} if samplers is None else samplers

    def sampler() -> DepthSampler:  # the level's depth map, prepared once for every term that samples it
        key = (id(level.depth2), warped.dtype)
        if key not in samplers or samplers[key][0] is not level.depth2:
            samplers[key] = (level.depth2, depth_sampler(level.depth2, warped.dtype, edges=w.depth_edge_tolerance > 0))
        return samplers[key][1]

    if w.use_depth:
        warped_ds = level.pc1 + level.static_flow + level.flow_d
        kw = dict(variant=w.depth_variant, source_points=level.pc1, eps=w.eps, edge_tolerance=w.depth_edge_tolerance,
                  norm=w.depth_norm, sampler=sampler())
        out["depth1"] = depth_consistency(warped, level.K, level.depth2, **kw)
        out["depth2"] = depth_consistency(warped_ds, level.K, level.depth2, **kw)
        out["depth"] = out["depth1"] + out["depth2"]
    if w.use_ds:
        out["ds"] = dynamic_static(level.flow_o, level.static_flow, level.flow_d)
    plane = (w.use_chamfer and w.chamfer_plane > 0) or (w.use_laplacian and w.laplacian_plane > 0)
    normals2 = surface_normals(level.pc2, backend=w.knn_backend) if plane else None  # one estimate, both terms
    # pc1's neighbourhoods: one search for the Laplacian and the smoothness term
    nbr1 = neighbours(level.pc1, w.laplacian_k, w.knn_backend) if w.use_laplacian or w.flow_smooth > 0 else None
    held = None  # the plane forms' per-point share: 1 − the ego head's gate (held at the rigid flow: 1)
    if w.plane_where_held and plane:
        if level.gate_o is None:
            raise ConfigError("loss.plane_where_held needs a net that reports its gate (model.ego_head true)")
        held = 1 - level.gate_o.detach().float()
    if w.use_chamfer:
        out["chamfer"] = chamfer(warped, level.pc2, w.knn_backend, level.view1, level.view2,
                                 w.chamfer_truncate if w.chamfer_truncate > 0 else math.inf, w.chamfer_plane,
                                 normals2, held)
    if w.use_laplacian:
        out["laplacian"] = laplacian(warped, level.pc1, level.pc2, w.laplacian_k, w.interp_k, w.knn_backend,
                                     w.laplacian_plane, normals2, nbr1, held)
    if w.static_anchor > 0:
        verified = verified_static(level.pc1, level.static_flow, level.K, level.depth2, w.anchor_tol_m,
                                   w.anchor_tol_rel, w.depth_edge_tolerance, sampler())
        out["anchor"] = static_anchor(level.flow_o, level.static_flow, verified)
    if w.ego_motion > 0:
        if level.rigid_o is None:
            raise ConfigError("loss.ego_motion needs a net that reports its fitted ego-motion (model.ego_head true)")
        out["ego"] = ego_motion_term(level.rigid_o, level.static_flow)
    if w.gate_pull > 0:
        if level.gap_o is None or level.gap_d is None:
            raise ConfigError("loss.gate_pull needs a net that reports its gate gaps (model.ego_head true)")
        out["pull"] = gate_pull(level.gap_o) + gate_pull(level.gap_d)
    if w.flow_smooth > 0:
        out["smooth"] = flow_smoothness(level.pc1, level.flow_o - level.static_flow, w.laplacian_k, w.knn_backend,
                                        nbr1)
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
    coarse = weights.coarse()  # the departure terms kept to the finest level are not computed below it
    samplers: dict = {}  # the batch's depth map prepared once for every level (they hold the same tensor)
    for k, (level, alpha) in enumerate(zip(levels, alphas)):
        terms = level_terms(level, weights if k == 0 else coarse, samplers)
        weighted = sum((beta[name] * terms[name] for name in beta if name in terms), level.flow_o.new_zeros(()))
        if "anchor" in terms:
            weighted = weighted + weights.static_anchor * terms["anchor"]
        if "ego" in terms:
            weighted = weighted + weights.ego_motion * terms["ego"]
        if "pull" in terms:
            weighted = weighted + weights.gate_pull * terms["pull"]
        if "smooth" in terms:
            weighted = weighted + weights.flow_smooth * terms["smooth"]
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
