"""Dynamic-static consistency loss (paper §III-C, eq. 12)."""

from __future__ import annotations

from torch import Tensor

from training.losses._common import check_points


def dynamic_static(flow_o: Tensor, static_flow: Tensor, flow_d: Tensor) -> Tensor:
    """``L_DS = mean_i ‖f_o,i − (sf_s,i + f_d,i)‖²`` (eq. 12), m².

    ``f_o`` = net(pc1, pc2) is the overall flow, ``sf_s = (R p1 + t) − p1`` the static flow of the camera
    motion and ``f_d`` = net(pc1 + sf_s, pc2) the dynamic flow; all (B, N, 3), metres, defined at the
    same N points of frame t. The squared norm is summed over x, y, z and averaged over the points and
    the batch (the paper writes Σ; the mean keeps α comparable across levels).
    """
    check_points("dynamic_static", "flow_o", flow_o)
    B, N, _ = flow_o.shape
    check_points("dynamic_static", "static_flow", static_flow, B, N)
    check_points("dynamic_static", "flow_d", flow_d, B, N)
    return ((flow_o - (static_flow + flow_d)) ** 2).sum(-1).mean()
