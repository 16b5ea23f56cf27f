"""Flow smoothness: neighbouring frame-t points depart alike from the camera's motion (a departure,
``LossWeights.flow_smooth``; docs/learned-flow.md, fifteenth round).

    L_FS = mean_i (1/k) Σ_{j ∈ N(i)} ‖r_i − r_j‖,   r = f_o − sf_s        (metres)

``N(i)`` are the k nearest other frame-t points of the level (the Laplacian term's neighbourhood,
``LossWeights.laplacian_k``), ``f_o`` the overall flow and ``sf_s`` stage one's static flow (the camera's
motion, as the second pass uses it), so ``r`` is the flow's departure from the camera's motion: zero on
static points, a mover's own motion on its points. The length is smoothed at 1 mm
(:func:`~training.losses._common.smooth_length`) so that its gradient is finite where two departures agree.

Why it is here: every other term the flow is trained with compares the warped cloud with frame (t+1)'s
*sample* — the Chamfer distance (eq. 13), the Laplacian (eq. 16) and, through a bilinear lookup, the
depth term (eq. 7). Each is least somewhere that depends on where the samples fell, and a net that sees
frame (t+1) can learn to follow that: the fourteenth round's pull audit measured it on the true static
flow. This term reads frame t and stage one's pose alone: its least value does not move with frame
(t+1)'s sampling, so longer training cannot fit it to the samples. At the true flow it is zero wherever
neighbouring points share their motion, and it costs the truth only at motion boundaries. Measured on the
departure rather than on the flow itself, a turning camera's flow (which differs between neighbours by
about a centimetre per degree at half a metre) costs nothing either: the length's unit gradient would
otherwise pull on every static point.

What it costs a mover: a point with a share ρ of its k neighbours across a motion boundary is pulled
towards them with at most ``2 w ρ / n`` (each length's gradient is a unit vector, and the pair counts in
both points' sums), against the Chamfer term's ``≈ 4 e / n`` towards its target at distance ``e`` (β3 = 1,
both directions), so it settles at most ``e ≈ w ρ / 2`` short of it; at ``w = 0.3`` and half its
neighbours across, about 7 cm. The length, not
the square, keeps that bound independent of how fast the mover is (a total-variation penalty keeps
edges). Camera-1 frame, metres. Label-free.
"""

from __future__ import annotations

from torch import Tensor

from training.knn import KnnBackend
from training.losses._common import check_points, smooth_length
from training.losses.laplacian import neighbours
from training.pointops import group


def flow_smoothness(pc1: Tensor, departure: Tensor, k: int = 10, backend: KnnBackend = "auto",
                    neighbours1: Tensor | None = None) -> Tensor:
    """``L_FS`` for ``departure`` (B, n, 3; ``f_o − sf_s``, metres) at ``pc1`` (B, n, 3) over each point's
    ``k`` nearest other points of ``pc1`` (no gradient through the neighbourhoods; ``neighbours1``: those
    indices, :func:`~training.losses.laplacian.neighbours`, when the caller already has them). A scalar in
    metres; zero with fewer than two points."""
    check_points("flow_smoothness", "pc1", pc1)
    check_points("flow_smoothness", "departure", departure, pc1.shape[0], pc1.shape[1])
    idx = neighbours(pc1, k, backend) if neighbours1 is None else neighbours1  # (B, n, k')
    if idx.shape[-1] == 0:
        return departure.sum() * 0.0
    diff = group(departure, idx) - departure.unsqueeze(2)  # (B, n, k', 3)
    return smooth_length((diff * diff).sum(-1)).mean()
