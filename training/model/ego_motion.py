"""Rigid ego-motion + residual output head (a departure from the paper, ``HALFlowConfig.ego_head``).

In a driving scene most points are static, so their scene flow is the flow of one rigid motion, the
camera's ``T_{1→2}``: ``sf_s(p) = R p + t − p`` (eq. 11's static flow, camera-1 frame in, camera-2 frame
out, metres). A per-point flow regressor does not know this: every static point's flow is estimated on
its own, and an unsupervised Chamfer term (eq. 13) rewards moving each one onto the nearest pc2 sample
rather than along the true motion. This head makes the constraint explicit and keeps it differentiable:

1. fit ``T`` to the net's per-point flow by weighted least squares (Kabsch / Umeyama without scale),
   re-weighting a few times with Cauchy weights ``w = σ² / (σ² + r²)`` of the residual
   ``r = ‖p + f − T p‖`` (iteratively re-weighted least squares: points that move on their own — cars,
   cyclists — lose their say in the ego-motion);
2. output ``f' = (T p − p) + m ⊙ (f − (T p − p))`` with the gate ``m = r⁴ / (σ⁴ + r⁴)``: points whose
   flow agrees with the ego-motion within ≈σ take the rigid flow (their per-point noise averages out
   over the whole cloud), points that disagree keep their own flow (movers). The gate is a sharper step
   than ``1 − w`` so that little of a static point's noise leaks back.

The weights and the gate are computed without gradient; ``T`` is differentiable in the flow (through
the SVD), so every static point's flow still receives the loss's gradient through the fit.

With ``planar`` (``HALFlowConfig.ego_planar``) the motion is restricted to a level camera on a ground
vehicle: a turn about y and a translation in x–z (:func:`weighted_planar_fit`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from core.view import VIEW_MARGIN_DEG, ViewExtent
from training.knn import knn
from training.pointops import group


def weighted_rigid_fit(src: Tensor, dst: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """The rotation R (B, 3, 3) and translation t (B, 3) minimising ``Σ w_i ‖R src_i + t − dst_i‖²``.

    ``src``, ``dst``: (B, N, 3) corresponding points (metres); ``weights``: (B, N) ≥ 0, not all zero.
    Computed in float64 (Kabsch with the reflection fix); differentiable in ``src`` and ``dst``.
    """
    s, d, w = src.double(), dst.double(), weights.double().clamp_min(0)
    w = w / w.sum(dim=1, keepdim=True).clamp_min(1e-12)
    mu_s = (w[..., None] * s).sum(1, keepdim=True)
    mu_d = (w[..., None] * d).sum(1, keepdim=True)
    cov = ((s - mu_s) * w[..., None]).transpose(1, 2) @ (d - mu_d)  # (B, 3, 3) = Σ w (s − μs)(d − μd)ᵀ
    # a tiny isotropic term keeps the singular values apart (the SVD's gradient divides by their gaps)
    cov = cov + 1e-9 * torch.diag(torch.tensor([3.0, 2.0, 1.0], dtype=cov.dtype, device=cov.device))
    U, _, Vh = torch.linalg.svd(cov)
    V = Vh.transpose(1, 2)
    sign = torch.linalg.det(V @ U.transpose(1, 2)).sign()
    D = torch.diag_embed(torch.stack([torch.ones_like(sign), torch.ones_like(sign), sign], -1))
    R = V @ D @ U.transpose(1, 2)
    t = mu_d[:, 0] - (R @ mu_s[:, 0, :, None])[..., 0]
    return R.to(src.dtype), t.to(src.dtype)


def weighted_planar_fit(src: Tensor, dst: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """Like :func:`weighted_rigid_fit`, restricted to a ground vehicle's motion seen by a level camera: a
    turn by θ about the camera's y axis (down) and a translation in its x–z plane (``t_y = 0``).

    Minimises ``Σ w_i ‖R src_i + t − dst_i‖²`` over that family in closed form: with centred x–z
    coordinates ``s``, ``d``, ``θ = atan2(Σ w (s_z d_x − s_x d_z), Σ w (s_x d_x + s_z d_z))``; the y
    components only enter through the constant ``Σ w (s_y − d_y)²``. Float64; differentiable.
    """
    s, d, w = src.double(), dst.double(), weights.double().clamp_min(0)
    w = w / w.sum(dim=1, keepdim=True).clamp_min(1e-12)
    mu_s = (w[..., None] * s).sum(1)
    mu_d = (w[..., None] * d).sum(1)
    cs, cd = s - mu_s[:, None], d - mu_d[:, None]
    a = (w * (cs[..., 0] * cd[..., 0] + cs[..., 2] * cd[..., 2])).sum(1)
    b = (w * (cs[..., 2] * cd[..., 0] - cs[..., 0] * cd[..., 2])).sum(1)
    theta = torch.atan2(b, a + 1e-12)
    c, sn = torch.cos(theta), torch.sin(theta)
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    R = torch.stack([c, zero, sn, zero, one, zero, -sn, zero, c], -1).reshape(-1, 3, 3)
    t = mu_d - (R @ mu_s[..., None])[..., 0]
    t = t * torch.tensor([1.0, 0.0, 1.0], dtype=t.dtype, device=t.device)
    return R.to(src.dtype), t.to(src.dtype)


class EgoSplit(NamedTuple):
    """What :func:`rigid_plus_residual` returns.

    flow (B, N, 3): the head's output flow, metres. R (B, 3, 3), t (B, 3): the fitted rigid motion,
    camera 1 → camera 2. static_weight (B, N) in (0, 1]: the fit's final Cauchy weights (≈1: the point
    moves with the camera; ≈0: it moves on its own). gate (B, N) in [0, 1], no gradient: the output's gate
    ``m`` (0: the point is held at the rigid flow; 1: it keeps its own flow).
    """

    flow: Tensor
    R: Tensor
    t: Tensor
    static_weight: Tensor
    gate: Tensor


def gate_value(r2: Tensor, s2: Tensor | float) -> Tensor:
    """The gate ``m = r⁴ / (σ⁴ + r⁴)`` from squared residuals ``r2`` (m²) and the squared scale ``s2`` (m²):
    0 where a flow agrees with the rigid motion, 1 where it departs well beyond σ."""
    return r2 * r2 / (s2 * s2 + r2 * r2)


def _robust_scale2(r2: Tensor, mad_factor: float, sigma: float) -> Tensor:
    """The squared robust scale (B, 1) of squared residuals ``r2`` (B, N, m²): (``mad_factor`` × 1.4826 × their
    median size)², at least ``sigma``² (1.4826 × the median absolute value estimates a Gaussian's σ)."""
    scale = mad_factor * 1.4826 * r2.sqrt().median(dim=1, keepdim=True).values
    return torch.clamp(scale * scale, min=sigma * sigma)


def rigid_plus_residual(points: Tensor, flow: Tensor, sigma: float = 0.25, iterations: int = 4,
                        mad_factor: float = 0.0, planar: bool = False,
                        open_gradient: bool = False, gate_k: int = 0, frame2: Tensor | None = None,
                        gate_spacing: float = 0.0, open_k: int = 0,
                        motion: tuple[Tensor, Tensor] | None = None, evidence: bool = False,
                        surface: float = 0.0, neighbourhood_scale: bool = False) -> EgoSplit:
    """Split ``flow`` (B, N, 3) at ``points`` (B, N, 3) into a robust rigid motion and a gated residual
    (an :class:`EgoSplit`). ``sigma`` (metres) is the residual
    at which a point counts half static, half moving; with ``mad_factor`` > 0 the scale is instead
    ``max(sigma, mad_factor · 1.4826 · median residual)`` per cloud, re-estimated every round (the
    median absolute residual times 1.4826 estimates a Gaussian's σ robustly); ``iterations`` the
    re-weighting rounds; ``planar``: the motion is a turn about y and a translation in x–z
    (:func:`weighted_planar_fit`); ``open_gradient``: the output's value is unchanged, but every point's
    own flow receives the output's gradient in full, also where the gate holds it at the rigid flow
    (a straight-through gate: ``f' + (1 − m) ⊙ (f − sg(f))``, ``sg`` = stop-gradient). With the gate's
    gradient alone (false), a point whose flow agrees with the ego-motion gets ``m ≈ 0`` of it, so a
    mover whose flow starts at the camera's motion is never pushed away from it. ``gate_k`` > 1: the gate
    reads the component-wise median of the residual vectors over each point's ``gate_k`` nearest points
    (itself included) instead of its own residual, so a point keeps its own flow only where its
    neighbourhood moves with it: a mover's points share their departure from the ego-motion, a static
    point that its flow alone sends astray (a wrong Chamfer match, a point leaving the view) does not.
    The fit's Cauchy weights stay per point. ``gate_spacing`` κ > 0 with ``frame2`` (B, M, 3), the frame-2
    points the level's loss compares with (same frame as ``points + flow``): the gate's scale at each
    point is at least κ × the distance from its rigid target ``T̂ p`` to the nearest frame-2 point, so a
    residual smaller than the local spacing of that sample — which a Chamfer match to the nearest sample
    produces on static points — does not open the gate; the fit is unchanged. ``open_k`` > 1 with
    ``open_gradient``: the straight-through term uses the mean own flow of each point's ``open_k`` nearest
    points instead of its own, ``(1 − m) ⊙ (f̄ − sg(f̄))``, so the gradient a held point passes on is shared
    evenly by its neighbourhood (values unchanged). ``motion`` (R (B, 3, 3), t (B, 3)): hold the points at
    this rigid motion instead of fitting one (no fit, no re-weighting; the scale and the gate as above, from
    the residuals against it) — a motion fitted elsewhere, e.g. at a coarser level. ``evidence`` with
    ``frame2``: the gate is shut wherever the point's own target ``p + f`` is no nearer to a frame-2 point
    than its rigid target ``T̂ p`` (a departure frame 2 does not support). ``surface`` κ > 0 with ``evidence``: the
    gate is also shut where fewer than a quarter of the point's neighbourhood (``gate_k`` nearest points, else the
    point alone) have rigid targets off frame 2's surface (:func:`off_surface`). ``neighbourhood_scale`` with
    ``gate_k`` > 1 and ``mad_factor`` > 0: the gate's robust scale is taken from the statistic it tests — the
    neighbourhood medians' sizes, not the points' own residuals (at least ``sigma``; the fit is unchanged).
    """
    target = points + flow
    weights = torch.ones(points.shape[:2], dtype=points.dtype, device=points.device)
    s2 = torch.full((points.shape[0], 1), sigma * sigma, dtype=points.dtype, device=points.device)
    for _ in range(1 if motion is not None else max(1, iterations)):
        if motion is not None:
            R, t = motion[0].to(points.dtype), motion[1].to(points.dtype)
        else:
            R, t = (weighted_planar_fit if planar else weighted_rigid_fit)(points, target, weights)
        with torch.no_grad():
            moved = points @ R.transpose(1, 2) + t[:, None]
            r2 = ((target - moved) ** 2).sum(-1)
            if mad_factor > 0:  # robust scale: mad_factor × 1.4826 × median residual, at least sigma
                s2 = _robust_scale2(r2, mad_factor, sigma)
            weights = s2 / (s2 + r2)
    rigid = points @ R.transpose(1, 2) + t[:, None] - points
    with torch.no_grad():
        if frame2 is not None and (gate_spacing > 0 or evidence):  # squared distance rigid target → frame 2
            d_rigid, near_rigid = knn(moved, frame2, 1)
        idx = None
        if gate_k > 1:
            _, idx = knn(points, points, min(gate_k, points.shape[1]))
            r2 = (group(target - moved, idx).median(dim=2).values ** 2).sum(-1)
            if neighbourhood_scale and mad_factor > 0:  # three robust deviations of what the gate tests
                s2 = _robust_scale2(r2, mad_factor, sigma)
        if gate_spacing > 0 and frame2 is not None:
            s2 = torch.maximum(s2, gate_spacing * gate_spacing * d_rigid[..., 0])
        gate = gate_value(r2, s2)[..., None]
        if evidence and frame2 is not None:
            d_own, _ = knn(target, frame2, 1)
            gate = gate * (d_own < d_rigid).to(gate.dtype)
            if surface > 0:
                off = off_surface(points, moved, frame2, surface, gate_k, (d_rigid, near_rigid), idx)
                gate = gate * off[..., None].to(gate.dtype)
    out = rigid + gate * (flow - rigid)
    if open_gradient:
        through = flow
        if open_k > 1:  # knn returns indices without grad
            _, near = knn(points, points, min(open_k, points.shape[1]))
            through = group(flow, near).mean(dim=2)
        out = out + (1 - gate) * (through - through.detach())
    return EgoSplit(out, R, t, weights, gate[..., 0])


def off_surface(points: Tensor, targets: Tensor, frame2: Tensor, kappa: float, k: int = 0,
                nearest: tuple[Tensor, Tensor] | None = None, neighbours: Tensor | None = None) -> Tensor:
    """Whether the camera's motion leaves a point's neighbourhood off frame 2's surface: (B, N) bool.

    ``points`` (B, N, 3) and their rigid targets ``targets`` (B, N, 3, ``T̂ p``), ``frame2`` (B, M, 3, M ≥ 2), all
    metres in one frame. A rigid target's gap is its distance to the nearest frame-2 point q, measured in units of
    frame 2's local spacing there (q's distance to its own nearest other frame-2 point). Sampled at that spacing,
    a surface holds no point farther than about one spacing from a sample, so a static point whose target under the
    right camera motion lies on it has a gap of at most about 1; a mover's target, where the mover no longer is, lies
    off it. True where the 75th percentile of the gaps over the point's ``k`` nearest points (itself included; the
    point alone for ``k`` ≤ 1) exceeds ``kappa``: at least a quarter of its neighbourhood lies off the surface, as
    an object's leading or trailing face does while its sides slide along their own surface. A caller that has them
    already passes ``nearest`` (the squared distances and indices, each (B, N, 1), of ``knn(targets, frame2, 1)``) and
    ``neighbours`` (the (B, N, k) indices of ``knn(points, points, k)``). No gradient
    (``HALFlowConfig.eval_evidence_surface``, forty-third round)."""
    if frame2.shape[1] < 2:  # no spacing to measure: no test
        return torch.ones(points.shape[:2], dtype=torch.bool, device=points.device)
    with torch.no_grad():
        d2, near = knn(targets, frame2, 1) if nearest is None else nearest
        s2, _ = knn(frame2, frame2, 2)
        spacing2 = s2[..., 1].gather(1, near[..., 0])
        gap = (d2[..., 0] / spacing2.clamp_min(1e-12)).sqrt()
        if k > 1:
            idx = knn(points, points, min(k, points.shape[1]))[1] if neighbours is None else neighbours
            gap = torch.quantile(group(gap[..., None], idx)[..., 0], 0.75, dim=-1)
        return gap > kappa


def own_departure(points: Tensor, flow: Tensor, sigma: float = 0.25, iterations: int = 4, mad_factor: float = 0.0,
                  planar: bool = False) -> Tensor:
    """``flow − (T̂ p − p)``: each point's departure (B, N, 3, metres) from ``T̂``, the robust rigid fit of ``flow``
    (B, N, 3) at ``points`` (B, N, 3) that :func:`rigid_plus_residual` makes with these settings (Cauchy
    re-weighting, so the points that move on their own lose their say). Zero on points that move with the fitted
    camera motion, a mover's own motion on its points, whatever error the fitted motion itself has: the anchor
    adds these departures to the rigid vote's motion (``HALFlowConfig.eval_own_departure``). No gradient
    through the fit's weights; differentiable in ``flow`` like the fit."""
    split = rigid_plus_residual(points, flow, sigma, iterations, mad_factor, planar)
    return flow - (points @ split.R.transpose(1, 2) + split.t[:, None] - points)


def level_departure(departure: Tensor) -> Tensor:
    """``departure`` (B, N, 3, metres, camera axes: x right, y down, z forward) with its vertical part (y) set to
    zero: a point's departure from the camera's motion kept along the ground, where things that move on their own
    move (``HALFlowConfig.eval_level_departure``). A copy; differentiable in the other two parts."""
    return departure * departure.new_tensor([1.0, 0.0, 1.0])


def hold_out_of_view(points: Tensor, flow: Tensor, rigid: Tensor, frame2: Tensor, k: int = 0, agree: float = 0.1,
                     margin_deg: float = VIEW_MARGIN_DEG) -> tuple[Tensor, Tensor]:
    """Hold the points whose rigid target leaves frame 2's view: ``(flow', held)``.

    ``points`` (B, N, 3): frame-1 points, camera 1; ``flow``, ``rigid`` (B, N, 3): their flow and the camera
    motion's flow ``T p − p`` (camera 1 → camera 2, metres); ``frame2`` (B, M, 3): frame 2's cloud, camera 2.
    A point is outside when its rigid target ``p + rigid`` lies outside the field of view frame 2 itself shows
    (:class:`core.view.ViewExtent`, ``margin_deg`` at each side). Frame 2 could not have seen it, so it holds no
    evidence that the point moved: such a point takes the rigid flow (``held`` (B, N) bool marks these),
    unless its own departure ``flow − rigid`` lies within ``agree`` metres of the component-wise median departure
    of its ``k`` nearest inside points — it departs with them, as a mover's part that leaves the view departs with
    the part that stays — and then takes that median. With ``k`` ≤ 1, or fewer than ``k`` points inside, every
    outside point takes the rigid flow. Inside points keep their flow and are not held. No gradient."""
    with torch.no_grad():
        targets = (points + rigid).detach().cpu().numpy()
        clouds = frame2.detach().cpu().numpy()
        inside = torch.from_numpy(np.stack([ViewExtent.of(c, margin_deg).contains(t)
                                            for c, t in zip(clouds, targets)])).to(flow.device)
        out, held = flow.clone(), ~inside
        for b in range(flow.shape[0]):
            keep = inside[b]
            away = ~keep  # the points outside: held unless they depart with their inside neighbours
            if not bool(away.any()):
                continue
            taken = rigid[b, away]
            if k > 1 and int(keep.sum()) >= k:
                _, near = knn(points[b, away][None], points[b, keep][None], k)
                shared = group((flow[b, keep] - rigid[b, keep])[None], near)[0].median(dim=1).values
                with_them = (flow[b, away] - taken - shared).norm(dim=-1) < agree
                taken = taken + torch.where(with_them[:, None], shared, torch.zeros_like(shared))
                held[b, away] = ~with_them
            out[b, away] = taken
    return out, held
