"""Static-flow anchor: the camera's rigid flow as the target of the points it explains (a departure,
``LossWeights.static_anchor``; docs/learned-flow.md, sixth round).

Stage one knows the camera's motion ``T_{t→t+1}`` (the pose net, the dataset's poses or odometry: the same
pose eq. 11's static flow ``sf_s = (R p1 + t) − p1`` comes from), and frame t+1's depth map. A frame-t point
whose static target ``p1 + sf_s`` lands on the surface that ``D_{t+1}`` sees is explained by the camera's
motion alone; for such a point ``sf_s`` *is* its flow, up to the depth map's error. The paper uses ``sf_s``
only inside the dynamic–static consistency (eq. 12), which relates two passes of the net and does not
say what either should be; the Chamfer term (eq. 13) rewards moving each point onto the nearest pc2 sample,
which on sparse clouds is not where the point goes (docs/learned-flow.md: the net's ego-motion is short and
half a degree off on LiDAR clouds). This term regresses the overall flow ``f_o`` onto ``sf_s`` at the
verified points:

    L_SA = mean_{i verified} ‖f_o,i − sf_s,i‖        (metres, a length: robust to the few wrong labels)

Verification is label-free: ``‖(D̂ − z̄) K⁻¹ [u', v', 1]ᵀ‖ ≤ max(tol_m, tol_rel · z̄)``, the distance along
the viewing ray between ``p1 + sf_s`` (depth ``z̄`` in camera 2, pixel ``(u', v')``) and the surface the depth
map ``D̂`` shows there (eqs. 7–10's residual, :func:`depth_consistency_residuals`, which also drops points
leaving the image or straddling a depth edge). A point on an object that moves
along its own surface (a long car driving slowly) can pass; most movers change the depth they project to
and fail. Camera frames, metres.
"""

from __future__ import annotations

import torch
from torch import Tensor

from training.losses._common import check_points, masked_mean, smooth_length
from training.losses.depth_consistency import DepthSampler, depth_consistency_residuals


def verified_static(pc1: Tensor, static_flow: Tensor, K: Tensor, depth2: Tensor, tol_m: float = 0.1,
                    tol_rel: float = 0.02, edge_tolerance: float = 0.05,
                    sampler: DepthSampler | None = None) -> Tensor:
    """(B, N) bool: the frame-t points ``pc1`` (camera 1) whose static target ``pc1 + static_flow`` (camera 2,
    metres) lies within ``max(tol_m, tol_rel · depth)`` of the depth ``depth2`` (B, H, W) sees there (along
    the ray), inside the image and off depth edges. ``sampler``: ``depth2`` already prepared (the loss's, shared
    with the depth terms); the same result. No gradient."""
    with torch.no_grad():
        target = (pc1 + static_flow).detach()
        res2, valid = depth_consistency_residuals(target, K, depth2, edge_tolerance=edge_tolerance, sampler=sampler)
        tol = torch.clamp(tol_rel * target[..., 2].abs(), min=tol_m)
        return valid & (res2 <= tol * tol)


def static_anchor(flow_o: Tensor, static_flow: Tensor, verified: Tensor) -> Tensor:
    """``L_SA = mean ‖f_o − sf_s‖`` over the ``verified`` (B, N) points, per batch element then over the
    elements that have any (metres; the length is smoothed at 1 mm so that its gradient is finite at 0).
    ``flow_o``, ``static_flow``: (B, N, 3), metres."""
    check_points("static_anchor", "flow_o", flow_o)
    B, N, _ = flow_o.shape
    check_points("static_anchor", "static_flow", static_flow, B, N)
    return masked_mean(smooth_length(((flow_o - static_flow) ** 2).sum(-1)), verified)
