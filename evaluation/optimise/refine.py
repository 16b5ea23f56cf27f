"""Test-time refinement of a given scene flow (e.g. the net's) with label-free terms only.

Starting from ``f₀`` (N, 3), minimise (see :class:`~evaluation.optimise.config.RefineConfig`)

    L(f) = L_Cha,trunc(pc1 + f, pc2) + λ_LR · L_LR(pc1 + f) + λ_R · mean ρ_GM(‖f − f_R‖) + λ_S · mean_S ‖f − f₀‖²

with the paper's Chamfer (eq. 13, truncated as in NSFP) and Laplacian (eq. 16) terms from
:mod:`training.losses`, and a rigid prior: ``f_R = (R p + t) − p`` is the rigid motion fitted robustly to
``f₀`` (:func:`~evaluation.optimise.rigid.robust_rigid_fit`); for a static point the true flow *is* the
ego-motion's rigid flow, so pulling towards it averages the net's per-point noise over the whole static
scene, while the bounded Geman–McClure penalty lets moving objects go; and, over the points ``S`` that the start
method marks static (the rigid polish's step 4), a quadratic pull back to their start. ``f`` is either free per point
(``"free"``) or ``f₀ + MLP_θ(p)`` with the MLP's output layer starting at zero (``"mlp"``). Both start
exactly at ``f₀``, so a good initial flow needs few steps — this is what makes refinement cheaper than
fitting NSFP from scratch. Frames: pc1 and flow in camera 1, pc1 + flow and pc2 in camera 2, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor

from evaluation.answers import ask_marked
from evaluation.landing import confirmed
from evaluation.optimise.common import FlowMLP, as_tensor, resolve
from evaluation.optimise.config import RefineConfig
from evaluation.optimise.loop import FitResult, minimise
from evaluation.optimise.rigid import inlier_weights, robust_rigid_fit, so3_exp
from evaluation.optimise.terms import geman_mcclure, laplacian_term, truncated_chamfer
from training.pointops import surface_normals


def refine_flow(pc1: np.ndarray | Tensor, pc2: np.ndarray | Tensor, init: np.ndarray | Tensor,
                cfg: RefineConfig | None = None, static: np.ndarray | Tensor | None = None) -> FitResult:
    """Refine ``init`` (N, 3) for the scene pc1 (N, 3) → pc2 (M, 3), metres; returns a :class:`FitResult`.
    ``static`` (N,) bool, optional: the points the start method marks static, held at ``init`` with
    ``cfg.static_weight`` (none marked: no such term). With ``cfg.confirm_radius`` the points whose start flow
    landings confirm keep it (and only the static ones among them are held)."""
    cfg = (cfg or RefineConfig()).validate()
    dev = resolve(cfg.device)
    p1, p2, f0 = as_tensor(pc1, dev), as_tensor(pc2, dev), as_tensor(init, dev)
    if f0.shape != p1.shape:
        raise ValueError(f"init flow has shape {tuple(f0.shape[1:])}, expected {tuple(p1.shape[1:])}")
    marked = None
    if static is not None:
        marked = (static.detach().cpu().numpy() if isinstance(static, Tensor) else np.asarray(static)).astype(bool)
        marked = marked.reshape(-1)
        if marked.shape[0] != p1.shape[1]:
            raise ValueError(f"static mask has {marked.shape[0]} entries, expected {p1.shape[1]}")
    kept = None  # the points whose start flow landings confirm (cfg.confirm_radius): they keep it
    if cfg.confirm_radius > 0:
        kept = torch.as_tensor(confirmed(p1[0].cpu().numpy(), f0[0].cpu().numpy(), p2[0].cpu().numpy(),
                                         cfg.confirm_radius, cfg.confirm_miss, static=marked), device=dev)
    held = None
    if marked is not None and cfg.static_weight > 0:
        held = torch.as_tensor(marked, device=dev)
        held = held & kept if kept is not None else held
        held = held if bool(held.any()) else None
    pts = p1[0]
    rot0, t0, rigid0 = robust_rigid_fit(pts, f0[0], scale=cfg.rigid_scale)
    params: list[Any]
    if cfg.parametrisation == "free":
        var = f0.clone().requires_grad_(True)
        params = [var]

        def flows() -> tuple[Tensor, Tensor]:
            return var, rigid0[None]
    elif cfg.parametrisation == "mlp":
        mlp = FlowMLP(cfg.layers, cfg.hidden, seed=cfg.seed, zero_output=True).to(dev)
        params = list(mlp.parameters())

        def flows() -> tuple[Tensor, Tensor]:
            return f0 + mlp(p1), rigid0[None]
    else:  # "rigid-mlp": ego-motion (optimised) + the init's non-rigid part + an MLP residual
        resid0 = f0 - rigid0[None]
        resid0 = resid0 * (1 - inlier_weights(resid0, cfg.rigid_scale)).unsqueeze(-1)  # keep only outliers' part
        omega = torch.zeros(3, device=dev, requires_grad=True)
        dt = torch.zeros(3, device=dev, requires_grad=True)
        mlp = FlowMLP(cfg.layers, cfg.hidden, seed=cfg.seed, zero_output=True).to(dev)
        params = [{"params": [omega, dt], "lr": cfg.rigid_lr}, {"params": list(mlp.parameters())}]

        def flows() -> tuple[Tensor, Tensor]:
            rot = so3_exp(omega) @ rot0
            ego = (pts @ rot.T + (t0 + dt) - pts)[None]
            return ego + resid0 + mlp(p1), ego

    normals2 = surface_normals(p2) if cfg.plane > 0 else None  # frame 2 does not move: once per scene

    def step() -> tuple[Tensor, Tensor]:
        flow, rigid = flows()
        warped = p1 + flow
        loss = truncated_chamfer(warped, p2, cfg.truncate, cfg.plane, normals2)
        if cfg.laplacian_weight > 0:
            loss = loss + cfg.laplacian_weight * laplacian_term(warped, p1, p2, cfg.laplacian_k)
        if cfg.rigid_weight > 0:
            loss = loss + cfg.rigid_weight * geman_mcclure(flow - rigid, cfg.rigid_scale)
        if held is not None:
            loss = loss + cfg.static_weight * ((flow[0, held] - f0[0, held]) ** 2).sum(-1).mean()
        return loss, flow[0]

    result = minimise(params, step, cfg)
    if kept is not None:
        result.flow[kept] = f0[0, kept]
    return result


@dataclass
class RefinedMethod:
    """``base`` (any :class:`~evaluation.methods.FlowMethod`, e.g. a ``NetMethod``) followed by
    :func:`refine_flow`; named ``"<base name> + refinement"`` and reported as its own row. Its time per
    scene includes the base method's call. A base that marks static points (its marks' ``"static"``, the rigid
    polish's; :func:`evaluation.answers.ask_marked`) hands them to the refinement (``RefineConfig.static_weight``).
    """

    base: Any
    config: RefineConfig = field(default_factory=RefineConfig)
    name: str = ""
    last: FitResult | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.name = self.name or f"{self.base.name} + refinement"

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        init, marks = ask_marked(self.base, pc1, pc2, color1, color2)  # the base's own marks, not one it wraps
        static = marks.get("static")
        with torch.enable_grad():
            self.last = refine_flow(pc1, pc2, init, self.config, static)
        return self.last.flow.cpu().numpy().astype(np.float32)
