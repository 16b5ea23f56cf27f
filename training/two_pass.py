"""The paper's two passes of the net over a batch and what the losses read from them (eqs. 11–17).

The overall pass ``net(pc1, pc2)`` gives the flow ``sf_o``; the dynamic pass ``net(pc1 + sf_s, pc2)`` at the
same sampled points (``sampling=``, :mod:`training.model.contract`) gives ``sf_d``, the flow left once the
camera's static flow ``sf_s`` (eq. 11) is applied. Every pyramid level then hands the losses its points
and both flows (:class:`training.losses.total.LevelInputs`). Camera frames, metres. Used by the trainer,
the label-free validation scores (:mod:`training.selection`) and the objective audit (:mod:`training.audit`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from training.data import FlowBatch
from training.losses.total import LevelInputs
from training.model.contract import FlowNet, FlowOutput
from training.pointops import farthest_point_sample


def gather(x: Tensor, idx: Tensor) -> Tensor:
    """``x`` (B, N, C) or (B, N) at ``idx`` (B, n)."""
    if x.dim() == 2:
        return x.gather(1, idx)
    return x.gather(1, idx[..., None].expand(-1, -1, x.shape[-1]))


def forward_two_passes(net: FlowNet, batch: FlowBatch) -> tuple[FlowOutput, FlowOutput]:
    """The overall pass on (pc1, pc2) and the dynamic pass on (pc1 + sf_s, pc2) at the same points (the
    second pass reuses the first's ``sampling``; :mod:`training.model.contract`)."""
    out_o = net(batch.pc1, batch.pc2, batch.feat1, batch.feat2)
    out_d = net(batch.pc1 + batch.static_flow, batch.pc2, batch.feat1, batch.feat2, sampling=out_o.sampling)
    return out_o, out_d


def independent_levels(pc2_target: Tensor, sizes: list[int]) -> list[Tensor]:
    """``pc2_target`` (B, N, 3) farthest-point sampled to each of ``sizes`` in turn (finest first, each
    level from the one before, as the net samples its own pc2)."""
    out, xyz = [], pc2_target
    for n in sizes:
        xyz = gather(xyz, farthest_point_sample(xyz, n))
        out.append(xyz)
    return out


def level_inputs(batch: FlowBatch, out_o: FlowOutput, out_d: FlowOutput, pc2_target: str = "level",
                 view_mask: bool = False) -> list[LevelInputs]:
    """Per pyramid level (finest first): the level's points and flows the losses need; the pc2 points are
    the level's own (``pc2_target="level"``, the paper), the finest level's (``"finest"``) or a second,
    independent draw sampled to the level's size (``"independent"``; :class:`training.config.LossWeights`).
    ``view_mask``: each level carries the batch's ``view1`` / ``view2`` at its points (the pc2 side only
    with the input's own pc2 points)."""
    if view_mask and (batch.view1 is None or batch.view2 is None):
        raise ValueError("loss.view_mask needs batches with view1 and view2 (PairDataset(view_masks=True))")
    if pc2_target == "independent":
        if batch.pc2_target is None:
            raise ValueError("loss.pc2_target 'independent' needs batches with pc2_target "
                             "(PairDataset(target_draw=True))")
        targets = independent_levels(batch.pc2_target, [int(i.shape[1]) for i in out_o.indices2])
    levels = []
    rigid = out_o.rigid_flows if len(out_o.rigid_flows) == len(out_o.flows) else [None] * len(out_o.flows)
    gap_o, gap_d = ([o.gate_gaps[l] if len(o.gate_gaps) == len(o.flows) else None for l in range(len(o.flows))]
                    for o in (out_o, out_d))
    gates = out_o.gates if len(out_o.gates) == len(out_o.flows) else [None] * len(out_o.flows)
    for l, (f_o, f_d) in enumerate(zip(out_o.flows, out_d.flows)):
        idx1, idx2 = out_o.indices[l], out_o.indices2[0 if pc2_target == "finest" else l]
        pc2 = targets[l] if pc2_target == "independent" else gather(batch.pc2, idx2)
        levels.append(LevelInputs(pc1=gather(batch.pc1, idx1), pc2=pc2, flow_o=f_o.float(),
                                  flow_d=f_d.float(), static_flow=gather(batch.static_flow, idx1), K=batch.K,
                                  depth2=batch.depth2,
                                  view1=gather(batch.view1, idx1) if view_mask else None,
                                  view2=gather(batch.view2, idx2) if view_mask and pc2_target != "independent"
                                  else None,
                                  rigid_o=None if rigid[l] is None else rigid[l].float(),
                                  gap_o=gap_o[l], gap_d=gap_d[l], gate_o=gates[l]))
    return levels


def epe3d(out: FlowOutput, batch: FlowBatch) -> tuple[float, int]:
    """Sum of per-point EPE3D (metres) at the finest level and the number of points (for a mean)."""
    gt = gather(batch.gt_flow, out.indices[0])
    err = torch.linalg.norm(out.flows[0].float() - gt, dim=-1)
    return float(err.sum()), int(err.numel())
