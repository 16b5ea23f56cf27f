"""Ego-motion term: the net's fitted camera motion against stage one's (a departure,
``LossWeights.ego_motion``; docs/learned-flow.md, seventh round).

With the rigid ego-motion head (``HALFlowConfig.ego_head``) every level's flow is split into one rigid
motion ``T̂`` fitted to the net's flow and a gated residual (:mod:`training.model.ego_motion`); the net
reports that motion's flow ``r_i = T̂ p_i − p_i`` at every point (:attr:`FlowOutput.rigid_flows`). Stage
one knows the camera's motion, and eq. 11's static flow ``sf_s = (R p1 + t) − p1`` is its flow at every
frame-t point, static or not. This term compares the two over all points:

    L_EM = mean_i ‖r_i − sf_s,i‖        (metres)

Unlike the static-flow anchor (:mod:`training.losses.static_anchor`), which regresses the output flow at
the points the camera's motion explains, it never pulls a point's own flow: a mover keeps whatever flow the
paper's terms give it, and only the motion the head calls the camera's is told what it is. Label-free: it
uses the pose stage one already used for ``sf_s``. Camera frames, metres.
"""

from __future__ import annotations

from torch import Tensor

from training.losses._common import check_points, smooth_length


def ego_motion_term(rigid_flow: Tensor, static_flow: Tensor) -> Tensor:
    """``L_EM = mean ‖r − sf_s‖`` over every point and batch element (metres; the length is smoothed at
    1 mm so that its gradient is finite at 0). ``rigid_flow``, ``static_flow``: (B, N, 3), metres."""
    check_points("ego_motion_term", "rigid_flow", rigid_flow)
    B, N, _ = rigid_flow.shape
    check_points("ego_motion_term", "static_flow", static_flow, B, N)
    return smooth_length(((rigid_flow - static_flow) ** 2).sum(-1)).mean()
