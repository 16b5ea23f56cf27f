"""Gate pull: a restoring force on the own flow that the ego head's gate holds back (a departure,
``LossWeights.gate_pull``; docs/learned-flow.md, twelfth round).

The ego head (:mod:`training.model.ego_motion`) outputs ``f' = rigid + m ⊙ (f − rigid)``: where a point's
own flow ``f`` agrees with the fitted camera motion the gate ``m`` is ≈ 0 and the output is the rigid flow.
With the straight-through gate (``HALFlowConfig.ego_open_gradient``) such a point's own flow still receives
the output's whole gradient, but its value no longer reaches the output: nothing pulls it back, the noise
of the Chamfer matches accumulates in it over the steps, and once it has strayed past the gate's scale σ
the gate lets it through (the eleventh round's collapse at 4× the steps). This term is that missing pull:

    L_GP = mean_i ‖f_i − sg(f'_i)‖²        (m², summed over the level's ego-head calls)

``sg`` = stop-gradient, so only the own flow is moved, towards what the head outputs. Where the gate is
open (a mover) ``f' ≈ f`` and the term vanishes; where it is closed it pulls ``f`` back to the rigid flow
with the same m² scale and per-point mean as the Chamfer term (eq. 13).

How far it holds a static point: where the gate is closed the output does not move with the own flow, so
the Chamfer term's pull on the output towards the point's nearest frame-2 sample ``q`` (at distance ``d``)
never fades, and reaches the own flow in full through the straight-through gate; summed over its two
directions it is ``4 (f' − q) / n``. The pull ``2 w (f − f') / n`` balances it at ``‖f − f'‖ = 2 d / w``
(``tests/training/test_gate_pull.py``). At ``w = 1`` a static point's own flow goes *past* its nearest
sample — about half a metre at the finest level's 512 points — and the gate, whose scale follows the
median departure, lets the points with the larger ``d`` through: the static error that grew with the steps
in the twelfth round. ``w = 4`` holds it at ``d / 2`` (docs/learned-flow.md, thirteenth round). A mover pulls
its own flow ``D`` off the rigid flow and, once ``D`` is past the gate's scale, opens the gate, where the
term vanishes. Label-free: it uses only the net's own outputs. Camera frames, metres.
"""

from __future__ import annotations

from torch import Tensor

from core.errors import InputError


def gate_pull(gap_sq: Tensor) -> Tensor:
    """``L_GP``: the mean of ``gap_sq`` (B, N), the squared distances ‖f − sg(f')‖² (m²) between each point's
    own flow and the ego head's output (:attr:`~training.model.contract.FlowOutput.gate_gaps`)."""
    if not isinstance(gap_sq, Tensor) or gap_sq.ndim != 2 or not gap_sq.is_floating_point():
        shape = tuple(gap_sq.shape) if isinstance(gap_sq, Tensor) else type(gap_sq).__name__
        raise InputError("gate_pull", f"gap_sq must be a floating (B, N) tensor, got {shape}")
    return gap_sq.mean()
