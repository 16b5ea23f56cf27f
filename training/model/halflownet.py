"""The scene-flow network: HALFlowNet's design (Wang et al., "Hierarchical Attention Learning of Scene
Flow in 3D Point Clouds") in plain PyTorch, the net the monocular paper trains (docs/design.md §5).

Data flow (default sizes; every number comes from :class:`HALFlowConfig`)::

    pc1, pc2 (8192) ─ shared set convs ─> L0 2048 (k 32) ─> L1 1024 (k 24) ─> L2 256 (k 16) ─┐
    pc2 L2 ─ set conv ─> pc2 L3 64 (k 16)                                                       │
    cost volume L2 (k 32 in pc2, k 4 in pc1) ─ set conv ─> pc1 L3 64 (k 16) ─> L4 16 (k 8)  <───┘
    L3: set-upconv 16→64, coarse flow (linear head); warp pc1 L3, cost volume (k 6 / k 4), refine
    L2, L1: set-upconv + 3-NN interpolated flow, warp, cost volume (k 6 / k 4), refine (residual)
    L0: 3-NN feature propagation of L1's refinement features, MLP, residual flow on the L1 flow

Outputs flows at L0..L3 (2048, 1024, 256, 64 points), finest first, with the indices of those points in
the input pc1. All positions and flows in metres in the input frame (camera frame of frame 1 in
monoflow); internally both clouds are shifted by pc1's mean (``center_input``), which does not change
the flows' frame.

Sampling: ``"fps"`` (farthest point sampling at every level, deterministic) or ``"random"`` — the
released port's first-N: the input is already a random subset in random order, so each level takes the
first n points of the level above (deterministic, nested levels; shuffle the input to resample).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from core.errors import InputError
from training.model.coarse_match import SoftTranslation
from training.model.contract import FlowOutput, Sampling
from training.model.cost_volume import AttentiveCostVolume
from training.model.ego_motion import hold_out_of_view, level_departure, own_departure, rigid_plus_residual
from training.model.flow_head import FlowHead, FlowRefiner
from training.model.halflownet_config import HALFlowConfig, check_eval_norm_stats
from training.model.layers import SharedMLP, scaled
from training.model.rigid_vote import RigidVoteConfig, vote_rigid
from training.model.set_conv import SetConv
from training.model.set_upconv import FeaturePropagation, SetUpConv
from training.model.translation_vote import VoteConfig, vote_translation
from training.pointops import first_n_sample, farthest_point_sample, gather_points, three_nn_interpolate

@dataclass
class _Pyramid:
    """One cloud's encoder levels: centred positions, features, indices into the input cloud, and the
    sample indices into the level above."""

    xyz: list[Tensor]
    feat: list[Tensor]
    idx: list[Tensor]
    samples: list[Tensor]


@dataclass
class _Frame2:
    """One pass's frame-2 encoder levels L0..L2 (centred by ``centre``, before the vote's pre-alignment) and
    what they were computed from: the pc2 and feat2 arguments themselves, the mode and whether autograd ran."""

    pc2: Tensor
    feat2: Tensor | None
    centre: Tensor
    training: bool
    grad: bool
    levels: _Pyramid


@dataclass
class HALFlowSampling(Sampling):
    """:class:`Sampling` with the pass's frame-2 encoder levels: a second pass given this sampling and the
    *same* pc2 and feat2 tensors (the trainer's dynamic pass, ``net(pc1 + sf_s, pc2, sampling=…)``) takes them
    instead of encoding frame 2 again. The encoder sees only offsets between points (and frame 2's own
    features), so the levels do not depend on the centre the pass subtracts, which moves with pc1: they are
    shifted to the second pass's centre. Gradients reach the encoder through both passes, as when it runs
    twice; never with batch norm, whose statistics would then come from another batch."""

    frame2: _Frame2 | None = None


class HALFlowNet(nn.Module):
    """Hierarchical attention scene-flow net; see the module docstring and :class:`HALFlowConfig`."""

    def __init__(self, config: HALFlowConfig | None = None) -> None:
        super().__init__()
        cfg = self.config = config or HALFlowConfig()
        nm, kb = cfg.norm, cfg.knn_backend

        def w(*widths: int) -> list[int]:
            return [scaled(c, cfg.width_scale) for c in widths]

        k = cfg.level_k
        pool = cfg.set_conv_pooling
        # Encoder, shared by both frames at L0..L2.
        self.sa0 = SetConv(cfg.feature_dim, w(16, 16, 32), k[0], pool, nm, kb)
        self.sa1 = SetConv(self.sa0.out_channels, w(32, 32, 64), k[1], pool, nm, kb)
        self.sa2 = SetConv(self.sa1.out_channels, w(64, 64, 128), k[2], pool, nm, kb)
        c0, c1, c2 = self.sa0.out_channels, self.sa1.out_channels, self.sa2.out_channels
        self.sa3_pc2 = SetConv(c2, w(128, 128, 256), k[3], pool, nm, kb)
        c3 = self.sa3_pc2.out_channels

        # First embedding at L2, then the flow branch down to L4.
        self.cost_l2 = AttentiveCostVolume(c2, w(256, 128, 128), w(256, 128), cfg.cost_k_pc2, cfg.cost_k_pc1, nm, kb)
        self.sa3_flow = SetConv(self.cost_l2.out_channels, w(128, 128, 256), k[3], pool, nm, kb)
        self.sa4 = SetConv(self.sa3_flow.out_channels, w(256, 256, 512), k[4], pool, nm, kb)

        # L3: coarse flow, then one warping refinement.
        c3_flow = self.sa3_flow.out_channels
        self.up3 = SetUpConv(c3_flow, self.sa4.out_channels, cfg.upconv_k, w(256, 256, 512), w(512), nm, kb)
        self.head3_coarse = FlowHead(self.up3.out_channels, cfg.zero_flow_heads)
        if cfg.coarse_match:  # a measured coarse translation (a departure, HALFlowConfig.coarse_match)
            self.coarse_translation = SoftTranslation(c2, sigma_m=cfg.coarse_match_sigma_m)
        self.cost3 = AttentiveCostVolume(c3, w(512, 256, 256), w(512, 256), cfg.refine_k, cfg.cost_k_pc1, nm, kb)
        self.refine3 = FlowRefiner(c3_flow, self.cost3.out_channels, self.up3.out_channels, w(512, 256, 256), nm)
        self.head3 = FlowHead(self.refine3.out_channels, cfg.zero_flow_heads)

        # L2 and L1: upsample, warp, cost volume, refine.
        self.up2 = SetUpConv(c2, self.refine3.out_channels, cfg.upconv_k, w(256, 128, 128), w(128), nm, kb)
        self.cost2 = AttentiveCostVolume(c2, w(256, 128, 128), w(256, 128), cfg.refine_k, cfg.cost_k_pc1, nm, kb)
        self.refine2 = FlowRefiner(c2, self.cost2.out_channels, self.up2.out_channels, w(256, 128, 128), nm)
        self.head2 = FlowHead(self.refine2.out_channels, cfg.zero_flow_heads)

        self.up1 = SetUpConv(c1, self.refine2.out_channels, cfg.upconv_k, w(256, 128, 128), w(128), nm, kb)
        self.cost1 = AttentiveCostVolume(c1, w(128, 64, 64), w(128, 64), cfg.refine_k, cfg.cost_k_pc1, nm, kb)
        self.refine1 = FlowRefiner(c1, self.cost1.out_channels, self.up1.out_channels, w(256, 128, 128), nm)
        self.head1 = FlowHead(self.refine1.out_channels, cfg.zero_flow_heads)

        # L0: feature propagation of L1's refinement features, residual flow.
        self.fp0 = FeaturePropagation(c0, self.refine1.out_channels, w(256, 256), nm, kb)
        self.fc0 = SharedMLP(self.fp0.out_channels, w(128), nm)
        self.head0 = FlowHead(self.fc0.out_channels, cfg.zero_flow_heads)
        if cfg.l0_cost_volume:  # a fifth warping level at L0 (a departure, HALFlowConfig.l0_cost_volume)
            self.cost0 = AttentiveCostVolume(c0, w(64, 32, 32), w(64, 32), cfg.refine_k, cfg.cost_k_pc1, nm, kb)
            self.refine0 = FlowRefiner(c0, self.cost0.out_channels, self.fc0.out_channels, w(128, 64, 64), nm)
            self.head0_refine = FlowHead(self.refine0.out_channels, cfg.zero_flow_heads)
        self.set_eval_norm_stats(cfg.eval_norm_stats)

    def set_eval_norm_stats(self, mode: str) -> None:
        """``"running"`` or ``"input"`` statistics for batch norm in eval mode (see :class:`HALFlowConfig`)."""
        check_eval_norm_stats(mode, self.config.norm)
        self.config.eval_norm_stats = mode
        for m in self.modules():
            if isinstance(m, SharedMLP):
                m.input_stats = mode == "input"

    # ------------------------------------------------------------------ helpers

    def _ego(self, cfg: HALFlowConfig, xyz: Tensor, flow: Tensor, frame2: Tensor,
             motion: tuple[Tensor, Tensor] | None = None, surface: float = 0.0, neighbourhood_scale: bool = False
             ) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor | None, tuple[Tensor, Tensor] | None]:
        """The level's flow through the rigid ego-motion + residual head when ``ego_head`` is on, the fitted
        motion's flow ``T̂ p − p``, the gate's gap ``‖f − sg(f')‖²`` (B, n) between the flow that went in
        and the output, differentiable in the former (:mod:`training.losses.gate_pull`), and the gate
        ``m`` (B, n) in [0, 1] (0: held at the rigid flow); None without the head. ``frame2``: the level's
        frame-2 points (for ``ego_gate_spacing``); ``motion``: hold at this (R, t) instead of fitting one;
        ``surface``: the evidence test's off-surface κ (``eval_evidence_surface``; 0 = off);
        ``neighbourhood_scale``: the gate's scale from its neighbourhood medians (``eval_neighbourhood_scale``). Last,
        the fitted (or given) motion (R (B, 3, 3), t (B, 3)), None without the head; ``cfg``: the pass's
        switches (:meth:`HALFlowConfig.at_inference` in eval mode)."""
        if not cfg.ego_head:
            return flow, None, None, None, None
        x = xyz.float()
        out, R, t, _, gate = rigid_plus_residual(x, flow.float(), cfg.ego_sigma, cfg.ego_iterations, cfg.ego_mad_factor,
                                           cfg.ego_planar, cfg.ego_open_gradient, cfg.ego_gate_k,
                                           frame2.float(), cfg.ego_gate_spacing, cfg.ego_open_gradient_k, motion,
                                           cfg.ego_gate_evidence, surface, neighbourhood_scale)
        rigid = x @ R.transpose(1, 2) + t[:, None] - x
        gap = ((flow.float() - out.detach()) ** 2).sum(-1)
        return out.to(flow.dtype), rigid.to(flow.dtype), gap, gate, (R, t)

    def _down(
        self, layer: SetConv, xyz: Tensor, feat: Tensor, n: int, given: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Sample n of ``xyz`` (or take ``given`` indices) and apply a set conv: (centres, features,
        indices into ``xyz``)."""
        if given is not None:
            s = given
        elif self.config.sampling == "fps":
            s = farthest_point_sample(xyz, n)
        else:
            s = first_n_sample(xyz, n)
        centres = gather_points(xyz, s)
        return centres, layer(xyz, feat, centres), s

    def _encode(self, xyz: Tensor, feat: Tensor, given: list[Tensor | None]) -> _Pyramid:
        """L0..L2 of one cloud (or of both stacked on the batch axis)."""
        pyr = _Pyramid([], [], [], [])
        for lvl, layer in enumerate((self.sa0, self.sa1, self.sa2)):
            n = self.config.level_points[lvl]
            xyz, feat, s = self._down(layer, xyz, feat, n, given[lvl])
            pyr.xyz.append(xyz)
            pyr.feat.append(feat)
            pyr.samples.append(s)
            pyr.idx.append(s if not pyr.idx else pyr.idx[-1].gather(1, s))
        return pyr

    def _check_sampling(self, sampling: Sampling, pc1: Tensor, pc2: Tensor) -> None:
        where, pts = "HALFlowNet", self.config.level_points
        clouds = (("pc1", sampling.pc1, pc1.shape[1], 5), ("pc2", sampling.pc2, pc2.shape[1], 4))
        for name, lists, n_in, levels in clouds:
            if len(lists) != levels:
                raise InputError(where, f"sampling.{name} needs {levels} levels, got {len(lists)}")
            sizes = (n_in, *pts)
            for lvl, s in enumerate(lists):
                want = (pc1.shape[0], pts[lvl])
                if not isinstance(s, Tensor) or tuple(s.shape) != want or s.dtype != torch.int64:
                    got = (tuple(s.shape), s.dtype) if isinstance(s, Tensor) else type(s).__name__
                    raise InputError(where, f"sampling.{name}[{lvl}] must be int64 of shape {want}, got {got}")
                if s.device != pc1.device or s.min() < 0 or s.max() >= sizes[lvl]:
                    raise InputError(where, f"sampling.{name}[{lvl}] must index [0, {sizes[lvl]}) on {pc1.device}")

    def _check(self, pc1: Tensor, pc2: Tensor, feat1: Tensor | None, feat2: Tensor | None) -> tuple[Tensor, Tensor]:
        cfg, where = self.config, "HALFlowNet"
        for name, pc in (("pc1", pc1), ("pc2", pc2)):
            if not isinstance(pc, Tensor) or pc.ndim != 3 or pc.shape[2] != 3:
                shape = tuple(pc.shape) if isinstance(pc, Tensor) else type(pc).__name__
                raise InputError(where, f"{name} must be a (B, N, 3) tensor, got {shape}")
            if not pc.is_floating_point():
                raise InputError(where, f"{name} must be floating point, got {pc.dtype}")
            if pc.shape[1] < cfg.level_points[0]:
                raise InputError(
                    where, f"{name} has {pc.shape[1]} points, fewer than level_points[0] = {cfg.level_points[0]}"
                )
        if pc1.shape[0] != pc2.shape[0] or pc1.device != pc2.device:
            raise InputError(
                where,
                f"pc1 {tuple(pc1.shape)} on {pc1.device} and pc2 {tuple(pc2.shape)} on {pc2.device} "
                "differ in batch size or device",
            )
        feats = []
        for name, pc, f in (("feat1", pc1, feat1), ("feat2", pc2, feat2)):
            if f is None:
                f = pc.new_zeros(pc.shape[0], pc.shape[1], cfg.feature_dim)
            elif not isinstance(f, Tensor) or f.shape != (pc.shape[0], pc.shape[1], cfg.feature_dim):
                shape = tuple(f.shape) if isinstance(f, Tensor) else type(f).__name__
                want = (pc.shape[0], pc.shape[1], cfg.feature_dim)
                raise InputError(where, f"{name} must have shape {want} (feature_dim={cfg.feature_dim}), got {shape}")
            feats.append(f.to(pc.dtype))
        return feats[0], feats[1]

    # ------------------------------------------------------------------ forward

    def forward(
        self,
        pc1: Tensor,
        pc2: Tensor,
        feat1: Tensor | None = None,
        feat2: Tensor | None = None,
        sampling: Sampling | None = None,
    ) -> FlowOutput:
        """Scene flow of pc1 towards pc2.

        Args:
            pc1, pc2: (B, N1, 3), (B, N2, 3) points in metres, one common frame (camera frame of frame 1).
            feat1, feat2: (B, N, feature_dim) per-point features (RGB), or None for zeros.
            sampling: reuse another pass's :attr:`FlowOutput.sampling` instead of sampling anew.
        Returns:
            :class:`FlowOutput` with flows at L0..L3 (default 2048, 1024, 256, 64 points).
        """
        feat2_arg = feat2
        feat1, feat2 = self._check(pc1, pc2, feat1, feat2)
        if sampling is not None:
            self._check_sampling(sampling, pc1, pc2)
        given1: list[Tensor | None] = [None] * 5 if sampling is None else list(sampling.pc1)
        given2: list[Tensor | None] = [None] * 4 if sampling is None else list(sampling.pc2)
        cfg = self.config if self.training else self.config.at_inference()
        centre = pc1.mean(dim=1, keepdim=True) if cfg.center_input else pc1.new_zeros(pc1.shape[0], 1, 3)
        x1, x2 = pc1 - centre, pc2 - centre

        prev = getattr(sampling, "frame2", None)
        if (prev is not None and prev.pc2 is pc2 and prev.feat2 is feat2_arg and prev.training == self.training
                and prev.grad == torch.is_grad_enabled() and cfg.norm != "batch"):  # HALFlowSampling: reuse frame 2
            p1 = self._encode(x1, feat1, given1)
            levels = prev.levels
            p2 = _Pyramid([x + (prev.centre - centre) for x in levels.xyz], list(levels.feat), list(levels.idx),
                          list(levels.samples))
        elif pc1.shape[1] == pc2.shape[1]:  # one pass over both clouds: shared weights, half the loops
            given = [None if a is None else torch.cat([a, b]) for a, b in zip(given1, given2)]
            both = self._encode(torch.cat([x1, x2]), torch.cat([feat1, feat2]), given)
            B = pc1.shape[0]
            parts = (both.xyz, both.feat, both.idx, both.samples)
            p1 = _Pyramid(*[[t[:B] for t in ts] for ts in parts])
            p2 = _Pyramid(*[[t[B:] for t in ts] for ts in parts])
        else:
            p1, p2 = self._encode(x1, feat1, given1), self._encode(x2, feat2, given2)
        frame2 = _Frame2(pc2, feat2_arg, centre, self.training, torch.is_grad_enabled(),
                         _Pyramid(list(p2.xyz), list(p2.feat), list(p2.idx), list(p2.samples)))

        shift, turn = None, None
        if cfg.translation_vote:  # pre-align frame 2 by the voted camera translation (encoder features are
            # built from neighbour offsets, so they do not change; every flow gets the shift back at the end)
            vote = VoteConfig(max_translation_m=cfg.translation_vote_max_m)
            if cfg.rigid_vote:  # and rotation: frame 2 moved by the inverse motion, R⁻¹ (q − t) = (q − t) R
                # row-wise; the features keep the offsets of the unturned cloud (a few degrees apart)
                rigid = RigidVoteConfig(vote=vote, range_weighted=cfg.rigid_vote_far,
                                         yaw_search_deg=cfg.rigid_vote_yaw_deg, choose_gap_m=cfg.rigid_vote_gap_m,
                                         forward_starts=cfg.rigid_vote_forward,
                                         density_rounds_m=cfg.rigid_vote_density_m)
                turn, shift = vote_rigid(p1.xyz[0], p2.xyz[0], rigid, x2 if cfg.rigid_vote_dense else None,
                                         -centre[:, 0])
                p2.xyz = [(x - shift[:, None]) @ turn for x in p2.xyz]
            else:
                shift = vote_translation(p1.xyz[0], p2.xyz[0], vote)
                p2.xyz = [x - shift[:, None] for x in p2.xyz]

        n3, n4 = cfg.level_points[3], cfg.level_points[4]
        xyz2_3, feat2_3, s = self._down(self.sa3_pc2, p2.xyz[2], p2.feat[2], n3, given2[3])
        p2.xyz.append(xyz2_3)
        p2.feat.append(feat2_3)
        p2.samples.append(s)
        p2.idx.append(p2.idx[2].gather(1, s))

        # First embedding at L2, flow branch to L3 and L4.
        emb = self.cost_l2(p1.xyz[2], p1.feat[2], p2.xyz[2], p2.feat[2])
        xyz1_3, feat1_3, s = self._down(self.sa3_flow, p1.xyz[2], emb, n3, given1[3])
        p1.xyz.append(xyz1_3)
        p1.feat.append(feat1_3)
        p1.samples.append(s)
        p1.idx.append(p1.idx[2].gather(1, s))
        xyz1_4, feat1_4, s = self._down(self.sa4, xyz1_3, feat1_3, n4, given1[4])
        p1.samples.append(s)

        # L3: coarse flow from the upconv features, warp, cost volume, residual refinement.
        up = self.up3(xyz1_3, xyz1_4, feat1_3, feat1_4)
        coarse = self.head3_coarse(up)
        if cfg.coarse_match:
            coarse = coarse + self.coarse_translation(p1.xyz[2], p1.feat[2], p2.xyz[2], p2.feat[2])[:, None]
        cost = self.cost3(xyz1_3 + coarse, feat1_3, p2.xyz[3], p2.feat[3])
        hidden = self.refine3(coarse, feat1_3, cost, up)
        flow, rigid, gap, gate, _ = self._ego(cfg, xyz1_3, coarse + self.head3(hidden), p2.xyz[3])
        flows, rigids, gaps, gates = [flow], [rigid], [gap], [gate]

        # L2, L1: upsample features and flow, warp, cost volume, residual refinement.
        for lvl, upconv, cv, refiner, head in ((2, self.up2, self.cost2, self.refine2, self.head2),
                                                (1, self.up1, self.cost1, self.refine1, self.head1)):
            xyz, feat = p1.xyz[lvl], p1.feat[lvl]
            up = upconv(xyz, p1.xyz[lvl + 1], feat, hidden)
            coarse = three_nn_interpolate(xyz, p1.xyz[lvl + 1], flow, backend=cfg.knn_backend)
            cost = cv(xyz + coarse, feat, p2.xyz[lvl], p2.feat[lvl])
            hidden = refiner(coarse, feat, cost, up)
            flow, rigid, gap, gate, motion = self._ego(cfg, xyz, coarse + head(hidden), p2.xyz[lvl])
            flows.insert(0, flow)
            rigids.insert(0, rigid)
            gaps.insert(0, gap)
            gates.insert(0, gate)

        # L0: propagate L1's refinement features, residual on the interpolated L1 flow.
        hidden = self.fc0(self.fp0(p1.xyz[0], p1.xyz[1], p1.feat[0], hidden))
        coarse = three_nn_interpolate(p1.xyz[0], p1.xyz[1], flow, backend=cfg.knn_backend)
        flow = coarse + self.head0(hidden)
        gap0, before = None, None
        if cfg.l0_cost_volume:  # warp by that flow, match against frame 2's L0 points, residual refinement
            flow, _, gap0, _, before = self._ego(cfg, p1.xyz[0], flow, p2.xyz[0])
            cost = self.cost0(p1.xyz[0] + flow, p1.feat[0], p2.xyz[0], p2.feat[0])
            flow = flow + self.head0_refine(self.refine0(flow, p1.feat[0], cost, hidden))
        hold = None
        if cfg.held_at_vote:  # frame 2 is pre-aligned by the vote: its motion
            B = flow.shape[0]  # is the identity here
            hold = (torch.eye(3, device=flow.device, dtype=flow.dtype).expand(B, 3, 3), flow.new_zeros(B, 3))
        elif cfg.ego_l0_hold:
            hold = before if cfg.ego_l0_hold_from == "l0" else motion
        evidence2 = p2.xyz[0]
        if cfg.ego_gate_evidence and cfg.eval_evidence_dense and not self.training:  # frame 2's whole input, aligned
            evidence2 = x2 if shift is None else x2 - shift[:, None]
            if turn is not None:
                evidence2 = evidence2 @ turn
        if cfg.eval_own_departure and cfg.held_at_vote and not self.training:
            # the vote-aligned frame: the vote's motion is the identity, so the departure from the net's own motion
            # is the flow the hold reads (HALFlowConfig.eval_own_departure)
            flow = own_departure(p1.xyz[0].float(), flow.float(), cfg.ego_sigma, cfg.ego_iterations,
                                 cfg.ego_mad_factor, cfg.ego_planar).to(flow.dtype)
        if cfg.eval_level_departure and cfg.held_at_vote and not self.training:
            flow = level_departure(flow)  # the vote-aligned frame: the flow is the departure (eval_level_departure)
        surface = 0.0 if self.training else cfg.eval_evidence_surface  # the finest level's gate only
        scale_k = cfg.eval_neighbourhood_scale and not self.training
        flow, rigid, gap, gate, _ = self._ego(cfg, p1.xyz[0], flow, evidence2, hold, surface, scale_k)
        flows.insert(0, flow)
        rigids.insert(0, rigid)
        gaps.insert(0, gap if gap0 is None or gap is None else gap0 + gap)
        gates.insert(0, gate)  # the level's last head call: the one that made its output

        if shift is not None:  # undo the pre-alignment: f ↦ R (p + f) + t − p at each level's points p
            def back(f: Tensor, p: Tensor) -> Tensor:
                if turn is None:
                    return f + shift[:, None]
                return (p + f) @ turn.transpose(1, 2) + shift[:, None] - p

            flows = [back(f, p1.xyz[i]) for i, f in enumerate(flows)]
            rigids = [r if r is None else back(r, p1.xyz[i]) for i, r in enumerate(rigids)]
        if cfg.eval_view_hold and cfg.held_at_vote and not self.training:  # camera frames again: the points whose
            # vote-moved target frame 2 could not have seen depart only with their in-view neighbours (eval_view_hold)
            flows[0], held = hold_out_of_view(p1.xyz[0] + centre, flows[0], rigids[0], pc2, cfg.ego_gate_k,
                                              cfg.ego_sigma)
            gates[0] = gates[0] * (~held).to(gates[0].dtype)
        idx1, idx2 = p1.idx[:4], p2.idx[:4]
        return FlowOutput(
            flows=flows,
            indices=idx1,
            points=[gather_points(pc1, i) for i in idx1],
            indices2=idx2,
            points2=[gather_points(pc2, i) for i in idx2],
            sampling=HALFlowSampling(pc1=p1.samples, pc2=p2.samples, frame2=frame2),
            rigid_flows=[] if rigids[0] is None else rigids,
            gate_gaps=[] if gaps[0] is None else gaps,
            gates=[] if gates[0] is None else gates,
        )


def count_parameters(net: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)
