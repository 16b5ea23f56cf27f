"""Depth consistency loss (paper §III-B, eqs. 7–10).

A point of frame t moved by a scene flow, ``p̄ = p1 + f``, is expressed in **camera-2** coordinates:
scene flow includes the ego-motion (static flow ``sf_s = (R p1 + t) − p1``, docs/design.md §2), so ``p1 + f``
is where the point is seen from the camera at t+1. If the flow is right, ``p̄`` lies on the surface
that frame t+1's depth map ``D_{t+1}`` sees:

* eq. 7  — project: ``(u', v') = π(K p̄)``, with depth ``z̄ = p̄_z``;
* eq. 8  — bilinearly interpolate ``D̂ = D_{t+1}(u', v')``;
* eq. 9  — back-project at the same pixel: ``p̂ = D̂ · K⁻¹ [u', v', 1]ᵀ``;
* eq. 10 — penalise ``‖p̄ − p̂‖²``.

Since ``p̄ = z̄ · K⁻¹ [u', v', 1]ᵀ`` too, the paper's residual is ``(D̂ − z̄) · K⁻¹ [u', v', 1]ᵀ``: a
depth error along the viewing ray, zero for a flow that slides a point along the seen surface.

Units: points in metres (camera-2 frame), pixels with the origin at the top-left pixel's centre, so
``grid_sample`` runs with ``align_corners=True`` and normalised coordinates ``2u/(W−1) − 1``. The loss
is in m².
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from core.errors import InputError
from core.geometry import backproject, project
from training.losses._common import check_points, masked_mean, smooth_length
from training.choices import DEPTH_VARIANTS, DepthVariant  # noqa: F401  (re-exported)

# A bilinear sample counts as valid only if (almost) all its weight falls on valid depth pixels.
_VALID_WEIGHT = 1.0 - 1e-4
# Pixels by which a projection may fall outside [0, W−1] × [0, H−1] through rounding and still count.
_BORDER_TOL = 1e-3


@dataclass(frozen=True)
class DepthSampler:
    """``D_{t+1}`` prepared once for every projection that samples it (eq. 8; the trainer's two depth terms at
    every level sample the same map): ``maps`` (B, 2, H, W), the depth in metres (0 where unknown) and its
    validity (1/0), in the points' dtype; ``spread`` (B, H−1, W−1), each 2×2 pixel window's relative depth
    spread max/min − 1 (inf where a pixel is unknown), or None when not asked for."""

    maps: Tensor
    spread: Tensor | None


def depth_sampler(depth2: Tensor, dtype: torch.dtype, edges: bool = False) -> DepthSampler:
    """:class:`DepthSampler` of ``depth2`` (B, H, W) metres, ≤ 0 or non-finite where unknown; ``edges``: also
    the windows' spread (for ``edge_tolerance``)."""
    depth_ok = torch.isfinite(depth2) & (depth2 > 0)
    d2 = torch.where(depth_ok, depth2, torch.zeros_like(depth2)).to(dtype)
    maps = torch.stack([d2, depth_ok.to(dtype)], dim=1)  # (B, 2, H, W): depth and its validity
    return DepthSampler(maps, _window_spread(d2) if edges else None)


def depth_consistency_residuals(
    points_warped: Tensor,
    K: Tensor,
    depth2: Tensor,
    variant: DepthVariant = "paper",
    source_points: Tensor | None = None,
    eps: float = 1e-3,
    edge_tolerance: float = 0.0,
    sampler: DepthSampler | None = None,
) -> tuple[Tensor, Tensor]:
    """Per-point squared residuals ``‖p̄ − p̂‖²`` (B, N) in m² and the mask (B, N) of points that count.

    Args:
        points_warped: (B, N, 3) ``p̄ = p1 + f`` in camera-2 coordinates, metres.
        K: (B, 3, 3) intrinsics of frame t+1 (the same camera as frame t).
        depth2: (B, H, W) depth map ``D_{t+1}`` in metres; pixels ≤ 0 or non-finite are invalid.
        variant: ``"paper"`` (eqs. 7–10, the default) or ``"released"`` (the released code's
            behaviour, kept for ablation; see :func:`depth_consistency`).
        source_points: (B, N, 3) ``p1`` in camera-1 coordinates; required by ``"released"`` only (its
            back-projection uses the pixel ``p1`` came from, ``π(K p1)``).
        eps: points with depth ``z ≤ eps`` (metres) are behind the camera and masked.
        edge_tolerance: when > 0, a point is masked where the four depth pixels its bilinear sample
            draws on differ by more than this fraction (max/min − 1): there the interpolated depth lies
            on no surface (it mixes a foreground edge with the background behind it), and a squared
            residual of tens of metres would dominate the mean. 0 = the paper's plain bilinear sample.
        sampler: ``depth2`` already prepared (:func:`depth_sampler`, in the points' dtype, with the spread when
            ``edge_tolerance`` > 0); the same result, without preparing the map again.

    Masks (both variants): ``z̄ ≤ eps``; an interpolated depth that draws weight from an invalid pixel.
    ``"paper"`` also masks points projecting outside the image (pixel centres span [0, W−1] × [0, H−1],
    with 1e-3 px of slack for rounding at border pixels); ``"released"`` instead clamps (u', v') to that
    border. The released variant also masks a source point with ``z ≤ eps``. Residuals at masked points are finite and
    carry no gradient into the points.
    """
    where = "depth_consistency"
    check_points(where, "points_warped", points_warped)
    B, N, _ = points_warped.shape
    if not isinstance(K, Tensor) or K.shape != (B, 3, 3):
        raise InputError(where, f"K must be a ({B}, 3, 3) tensor, got {tuple(K.shape) if isinstance(K, Tensor) else K!r}")
    if not isinstance(depth2, Tensor) or depth2.ndim != 3 or depth2.shape[0] != B:
        raise InputError(where, f"depth2 must be a ({B}, H, W) tensor, got {tuple(depth2.shape) if isinstance(depth2, Tensor) else depth2!r}")
    H, W = int(depth2.shape[1]), int(depth2.shape[2])
    if H < 2 or W < 2:
        raise InputError(where, f"depth2 must be at least 2×2 pixels, got {H}×{W}")
    if variant not in DEPTH_VARIANTS:
        raise InputError(where, f"variant must be one of {DEPTH_VARIANTS}, got {variant!r}")
    if variant == "released":
        if source_points is None:
            raise InputError(where, "variant 'released' needs source_points (p1 in camera-1 coordinates)")
        check_points(where, "source_points", source_points, B, N)

    dtype = points_warped.dtype
    K = K.to(dtype)
    uv, z = project(points_warped, K, eps=eps)
    valid = z > eps
    lo = uv.new_zeros(2)
    hi = uv.new_tensor([W - 1.0, H - 1.0])
    if variant == "paper":
        # Inside, up to a rounding tolerance: a point projecting onto a border pixel centre stays in.
        valid = valid & ((uv >= lo - _BORDER_TOL) & (uv <= hi + _BORDER_TOL)).all(-1)
    # Clamp to the border: the paper variant only moves points within the tolerance; the released
    # variant samples every outside point at the nearest border pixel (gradient 0 across the border).
    uv_sample = torch.maximum(torch.minimum(uv, hi), lo)
    # Masked points sample the image centre instead of a possibly huge coordinate: finite, no gradient.
    centre = uv.new_tensor([(W - 1) / 2.0, (H - 1) / 2.0]).expand_as(uv)
    uv_sample = torch.where(valid.unsqueeze(-1), uv_sample, centre)

    if sampler is None or sampler.maps.dtype != dtype or (edge_tolerance > 0 and sampler.spread is None):
        sampler = depth_sampler(depth2, dtype, edges=edge_tolerance > 0)
    grid = torch.stack([2.0 * uv_sample[..., 0] / (W - 1) - 1.0, 2.0 * uv_sample[..., 1] / (H - 1) - 1.0], -1)
    grid = grid.unsqueeze(1)  # (B, 1, N, 2)
    sampled = F.grid_sample(sampler.maps, grid, mode="bilinear", padding_mode="zeros", align_corners=True)[:, :, 0]
    d_hat, weight_ok = sampled[:, 0], sampled[:, 1]  # (B, N) each
    valid = valid & (weight_ok.detach() >= _VALID_WEIGHT)
    if edge_tolerance > 0:
        valid = valid & ~_straddles_edge(sampler.spread, uv_sample.detach(), edge_tolerance)

    if variant == "paper":
        p_hat = backproject(d_hat, K, uv=torch.where(valid.unsqueeze(-1), uv, centre))  # at (u', v') itself
    else:
        uv_src, z_src = project(source_points.to(dtype), K, eps=eps)
        valid = valid & (z_src > eps)
        p_hat = backproject(d_hat, K, uv=uv_src.detach())
    res2 = ((points_warped - p_hat) ** 2).sum(-1)
    return torch.where(valid, res2, torch.zeros_like(res2)), valid


def _window_spread(depth: Tensor) -> Tensor:
    """(B, H−1, W−1): each 2×2 window (top-left anchored) of ``depth`` (B, H, W)'s max/min − 1, inf where its
    least pixel is not positive."""
    with torch.no_grad():
        win = depth.unsqueeze(1)
        hi = F.max_pool2d(win, 2, stride=1)[:, 0]
        lo = -F.max_pool2d(-win, 2, stride=1)[:, 0]
        return torch.where(lo > 0, hi / lo.clamp(min=1e-6) - 1.0, torch.full_like(hi, float("inf")))


def _straddles_edge(spread: Tensor, uv: Tensor, tolerance: float) -> Tensor:
    """(B, N) True where the 2×2 depth pixels around ``uv`` (B, N, 2) span more than ``tolerance`` (relative);
    ``spread`` (B, H−1, W−1) from :func:`_window_spread`."""
    B, H, W = spread.shape[0], spread.shape[1] + 1, spread.shape[2] + 1
    with torch.no_grad():
        u0 = uv[..., 0].floor().clamp(0, W - 2).long()
        v0 = uv[..., 1].floor().clamp(0, H - 2).long()
        flat = spread.reshape(B, -1).gather(1, v0 * (W - 1) + u0)
    return flat > tolerance


def depth_consistency(
    points_warped: Tensor,
    K: Tensor,
    depth2: Tensor,
    variant: DepthVariant = "paper",
    source_points: Tensor | None = None,
    eps: float = 1e-3,
    edge_tolerance: float = 0.0,
    norm: str = "l2",
    sampler: DepthSampler | None = None,
) -> Tensor:
    """Depth consistency loss (eq. 10), one of ``L_Depth1`` / ``L_Depth2``:

        L = mean_{p̄ valid} ‖p̄ − D_{t+1}(u', v') · K⁻¹ [u', v', 1]ᵀ‖²,   (u', v') = π(K p̄)

    averaged over a batch element's valid points, then over the batch elements that have any (the
    paper writes Σ; a mean keeps the level factors α meaningful across levels of 2048 … 64 points).
    ``L_Depth = L_Depth1 + L_Depth2`` with ``p̄ = p1 + f_o`` resp. ``p1 + sf_s + f_d``
    (:func:`training.losses.total.multi_level_loss` adds them). Scalar in m² with ``norm="l2"`` (the paper's
    form), in metres with ``norm="l1"`` (the default of :class:`~training.losses.total.LossWeights`).

    ``variant="released"`` (ablation) reproduces what the released code does instead:

    * it samples ``D_{t+1}`` at (u', v') but back-projects at the *source* pixel ``(u1, v1) = π(K p1)``:
      ``p̂ = D̂ · K⁻¹ [u1, v1, 1]ᵀ``. Then ``p̄ − p̂ = (z̄ − D̂) r1 + z̄ (r' − r1)`` with ``r = K⁻¹[u, v, 1]ᵀ``:
      beside the paper's depth error it penalises ``z̄ · K⁻¹ [u' − u1, v' − v1, 0]ᵀ``, the point's image
      motion in metres. That term is not zero for the true flow whenever the pixel moves (ego-motion,
      moving objects); it pulls flows toward motion along the source pixel's viewing ray;
    * it clamps (u', v') to the image border instead of masking points that leave the image, so they
      are compared with the border's depth.

    ``norm="l1"`` penalises the residual's length instead of its square (metres, not m²): at the true
    flow a few percent of points are hidden in frame t+1 behind a nearer surface (occlusions the 0.5
    consistency filter of stage one lets through) and leave residuals of metres; squared, those few
    dominate the mean and its gradient (measured on the demo world: median residual 1.4 mm, yet 4 % of
    points over 1 m and a mean squared residual of 6 m²). The released code uses an L1 norm too.

    This function's own default is the squared norm (``norm="l2"``); the trainer's default
    (``LossWeights.depth_norm``) is ``"l1"``. Not reproduced here (they belong to the trainer's ablations, not
    to this function): the released code's use of the depth terms at the finest level only, and its
    ``L_Depth2`` comparing the re-projected point with ``p1 + f_o`` rather than with ``p1 + sf_s + f_d``.
    ``sampler``: ``depth2`` already prepared (:func:`depth_sampler`), as in :func:`depth_consistency_residuals`.
    """
    res2, valid = depth_consistency_residuals(points_warped, K, depth2, variant, source_points, eps, edge_tolerance,
                                              sampler)
    if norm == "l1":  # robust: the residual's length (smoothed at 1 mm so the gradient stays finite at 0)
        res2 = torch.where(valid, smooth_length(res2), torch.zeros_like(res2))
    elif norm != "l2":
        raise InputError("depth_consistency", f"norm must be 'l2' or 'l1', got {norm!r}")
    return masked_mean(res2, valid)
