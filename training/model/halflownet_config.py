"""The architecture of :class:`~training.model.halflownet.HALFlowNet` as a torch-free dataclass (the
``--model.*`` flags of ``monoflow-train``; registered as ``"halflownet"`` in :mod:`training.model.registry`).
Keeps the :class:`~training.model.contract.FlowNetConfig` contract."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar

from core.errors import ConfigError
from training.choices import BACKENDS, NORMS

N_LEVELS = 5  # L0..L4; flows come out at L0..L3

ANCHOR_SWITCHES: dict[str, Any] = {"rigid_vote": True, "ego_l0_hold": True, "ego_l0_hold_from": "vote",
                                   "ego_gate_evidence": True}
"""What ``HALFlowConfig.eval_anchor`` turns on for an inference pass (:meth:`HALFlowConfig.at_inference`)."""


@dataclass
class HALFlowConfig:
    """Architecture of :class:`HALFlowNet`.

    n_points: nominal points per input cloud (what the data pipeline samples); the net accepts any
        N >= level_points[0].
    level_points / level_k: points and set-conv neighbours at L0..L4.
    cost_k_pc2 / cost_k_pc1: neighbours in frame 2 (point-to-patch) and frame 1 (patch-to-patch) of
        the first cost volume (L2); refine_k replaces cost_k_pc2 in the refinement cost volumes.
    width_scale: multiplies every hidden width (0.25 for fast tests).
    sampling: "fps" | "random" (first-N, see module docstring).
    feature_dim: channels of the per-point input features (3 for RGB; 0 for none).
    knn_backend: "auto" | "kdtree" | "torch" (see training.knn).
    upconv_k: neighbours of the set-upconv layers (HALFlowNet: 8).
    set_conv_pooling: "max" (HALFlowNet) | "attentive".
    norm: the normalisation after every hidden linear layer: ``"batch"`` (HALFlowNet's batch norm, running
        statistics at inference), ``"layer"`` (each point's features over their channels: no batch or running
        statistics, so a LiDAR test cloud is normalised as the camera training clouds were), ``"none"``.
    center_input: shift both clouds by pc1's mean before the net (the released port does).
    l0_cost_volume: add a warping refinement at L0 as at L1–L3 — warp L0's flow (through the ego head when
        on), a cost volume against frame 2's L0 points (refine_k / cost_k_pc1 neighbours), a residual flow.
        HALFlowNet matches last at L1; at small inputs (the demo's 2048 points: L1 = 256) that is coarser
        than the L0 points that are scored. False = the paper's form (L0 by feature propagation alone).
    coarse_match: add to the coarsest (L3) flow a camera translation measured by soft matching of the two
        clouds' L2 points (:mod:`training.model.coarse_match`), whose response to a shift is one by
        construction, so that the regressed coarse flow only corrects it; false = the paper's form (the
        coarse flow regressed alone). A departure (docs/learned-flow.md, ninth round).
    coarse_match_sigma_m: metres; the distance prior of that matching (twice KITTI's largest motion per frame).
    translation_vote: before the first embedding, shift frame 2's points back by the camera translation that
        a vote over all offsets between the two clouds' L0 points finds (:mod:`training.model.translation_vote`,
        no learning, no gradient), and add it to every output flow: the net regresses the flow left after
        that pre-alignment, and its response to a change of speed is one as far as the vote is right;
        false = the paper's form. A departure (docs/learned-flow.md, tenth round).
    translation_vote_max_m: metres; the vote's search cube is ±this along every camera axis.
    rigid_vote: with ``translation_vote``, pre-align by the camera's whole rigid motion instead of its
        translation: the vote, then trimmed nearest-neighbour rigid matching of the two clouds' L0 points
        (:mod:`training.model.rigid_vote`, no learning, no gradient); frame 2's points are moved by the
        inverse motion, and every output flow ``f`` becomes ``R (p + f) + t − p``. The net regresses what the
        camera's rotation and translation leave, so it need not learn to read a turn from the training
        worlds' few; false = the translation alone. A departure (docs/learned-flow.md, eighteenth round).
    rigid_vote_dense: the rigid vote's trimmed rounds match frame 1's L0 points against frame 2's whole
        input cloud instead of its L0 points (the histogram vote and the choice among its hypotheses stay
        on the L0 points). Between two sparse independent samples a nearest neighbour lies about one
        sample spacing off the true correspondent; against the denser cloud it lies closer
        (docs/learned-flow.md, twenty-first round). Needs ``rigid_vote`` or ``eval_anchor``; false = the L0
        points alone (as the eighteenth to twentieth rounds ran).
    rigid_vote_far: the rigid vote picks among its hypotheses by the frame-1 points each explains weighted
        by their distance from the camera instead of counted alike: a wrong motion shows most at range, and
        in dense traffic the movers crowd the near field (:class:`~training.model.rigid_vote.RigidVoteConfig`
        ``range_weighted``; twenty-first round). Needs ``rigid_vote`` or ``eval_anchor``; false = counted alike.
    rigid_vote_yaw_deg: degrees; the rigid vote first scans the camera's turn about its y axis within ±this
        (2° steps, then ±1° around the best), the turn under which the most frame-1 points agree on one translation, and starts its
        trimmed rounds there (:class:`~training.model.rigid_vote.RigidVoteConfig` ``yaw_search_deg``): from
        no turn they reach about a degree, KITTI turns up to 2.6° per frame in its 95th percentile
        (docs/learned-flow.md, thirty-second round). Needs ``rigid_vote`` or ``eval_anchor``; 0 = no scan.
    rigid_vote_gap_m: metres; the rigid vote picks among its hypotheses the motion that brings frame 1's L0
        points nearest to frame 2's whole input (with ``rigid_vote_dense``; else its L0 points): the mean
        distance to the nearest point, each truncated at this (:class:`~training.model.rigid_vote.RigidVoteConfig`
        ``choose_gap_m``). Within one L0 sample spacing a big mover's motion can explain as many points as the
        camera's; the mean gap still tells them apart (docs/learned-flow.md, thirty-fifth round). Needs
        ``rigid_vote`` or ``eval_anchor``; 0 = by the points each explains (``rigid_vote_far``'s weights).
    rigid_vote_forward: the rigid vote also starts each of its hypotheses with the translation along the camera's
        optical axis alone (x and y set to zero), beside the hypothesis itself, and its choice picks among both
        (:class:`~training.model.rigid_vote.RigidVoteConfig` ``forward_starts``). In traffic crossing the view
        the histogram's maxima can all lie to the side of the camera's translation, and the rounds from there
        settle in a turn paired with a sideways shift (docs/learned-flow.md, thirty-seventh round). Inference
        only in the demo preset; needs ``rigid_vote`` or ``eval_anchor``; false = the vote's hypotheses alone.
    rigid_vote_density_m: the rigid vote also refines each of its starts by rounds in which every frame-1 point
        weighs one over the number of frame-1 points within this radius (metres) of it, beside the rounds that
        weigh each alike, and its choice picks among both (:class:`~training.model.rigid_vote.RigidVoteConfig`
        ``density_rounds_m``). Where cars ahead are sampled more densely than the street they drive along, the
        uniform rounds drift towards their motion (docs/learned-flow.md, thirty-eighth round). Inference only in
        the demo preset (0.62 m); needs ``rigid_vote`` or ``eval_anchor``; 0 = the uniform rounds alone.
    ego_head: after every level's flow, fit one rigid motion (the camera's) to it robustly and let points
        that agree with it take its flow, the others keep their own (:mod:`training.model.ego_motion`);
        false = the paper's per-point flow regressor. A departure from the paper (README).
    ego_sigma: metres; the smallest residual scale of the head: a point whose flow differs from the
        fitted ego-motion by this much counts half static, half moving (Cauchy re-weighting and gate).
    ego_mad_factor: the scale actually used is max(ego_sigma, ego_mad_factor × 1.4826 × the median
        residual of the cloud) — a robust estimate of the net's own noise (3 = the usual outlier limit in
        standard deviations), so that a noisy net does not call its static points moving; 0 = ego_sigma.
    ego_iterations: re-weighting rounds of the robust rigid fit.
    ego_l0_hold: with ``ego_head`` and ``l0_cost_volume``: the ego head after the L0 cost volume does not
        refit the camera's motion, it holds the points at the motion fitted just before that cost volume (to
        the flow propagated from L1), and only points whose refined flow departs from it keep their own — so
        the finest matching can move what the gate lets go (movers) but not the camera; false = it refits
        (eighteenth round: on the real scan the L0 cost volume lengthened the camera's translation).
    ego_l0_hold_from: which motion ``ego_l0_hold`` holds: ``"l0"`` the one fitted just before the L0 cost
        volume, ``"l1"`` the one L1's ego head fitted (so nothing of the L0 level, neither its feature
        propagation nor its cost volume, moves the camera; nineteenth round), ``"vote"`` the pre-alignment's
        own motion (the translation or rigid vote: no level of the net moves the camera; twentieth round).
    ego_planar: restrict the fitted camera motion to a ground vehicle's with a level camera — a turn about
        the camera's y axis and a translation in its x–z plane (no pitch, roll or vertical motion), 3 of 6
        degrees of freedom (:func:`~training.model.ego_motion.weighted_planar_fit`). On LiDAR clouds, a
        thin slab of elevations, the 6-DoF fit trades pitch against vertical translation.
    ego_open_gradient: the head's gate holds a point's flow at the fitted ego-motion's where the two agree,
        and passes the loss's gradient to the point's own flow only in the gate's proportion, so a mover
        whose flow starts at the camera's motion gets almost none of the Chamfer term's pull; true = every
        point's own flow gets the whole gradient (straight-through), the output's value unchanged; false =
        the gate's gradient (:func:`~training.model.ego_motion.rigid_plus_residual`).
    ego_open_gradient_k: with ``ego_open_gradient``, k > 1: the straight-through part of a point's gradient
        is shared evenly among its k nearest points (itself included) instead of reaching its own flow
        alone, so a held point's own flow follows the pull its neighbourhood agrees on: a mover cluster's
        common pull passes whole, the nearest-sample pulls of static points, which point every way, mostly
        cancel (docs/learned-flow.md, thirteenth round). 0 = each point's own. Values unchanged; a departure.
    ego_gate_k: 0 = the head's gate reads each point's own residual from the fitted ego-motion; k > 1 = the
        component-wise median residual of its k nearest points (itself included), so that a point keeps its
        own flow only where its neighbourhood departs from the ego-motion with it (movers are rigid
        clusters; a static point whose own flow went astray is not). No gradient; a departure.
    ego_gate_spacing: κ ≥ 0; > 0: the gate's scale at a point is at least κ × the distance from its rigid
        target to the nearest of the level's frame-2 points, so that an own flow that departs from the
        ego-motion by less than the local spacing of frame 2's sample (what a Chamfer match to the nearest
        sample gives a static point) does not pass the gate; 0 = the scale alone. No gradient; a departure
        (docs/learned-flow.md, twelfth round).
    ego_gate_evidence: a point keeps its own flow only where frame 2 supports it: its own target ``p + f``
        must lie nearer to the level's frame-2 points than its rigid target ``T̂ p`` does (nearest-point
        distances, metres); elsewhere the gate is shut whatever the residual. A departure that explains frame
        2 no better than the camera's motion (a static point the net calls moving) is not taken. No
        gradient; a departure (nineteenth round).
    zero_flow_heads: every flow head (the last linear layer of each level's flow) starts at zero weights and
        bias, so the untrained net outputs no flow — with ``translation_vote``, exactly the voted camera
        translation — and learns departures from it; false = PyTorch's default initialisation (the
        paper's), whose first flows are random, of the order of the features' scale.
    eval_norm_stats: at inference (eval mode), batch norm uses ``"running"`` statistics (collected in
        training, the paper's form) or the statistics of the ``"input"`` itself — the clouds of the call,
        so call it with one scene at a time (test-time normalisation, AdaBN): the net was trained on
        camera clouds, and a LiDAR test cloud's features have other statistics. Training is unchanged.
    eval_anchor: at inference (eval mode: validation, evaluation, the refinement's start) anchor the flow to
        the camera's measured motion — turn on ``rigid_vote``, ``ego_l0_hold`` with ``ego_l0_hold_from`` =
        ``"vote"`` and ``ego_gate_evidence`` for the pass — so a point takes the rigid vote's motion unless
        the net's own flow departs from it and frame 2 supports the departure (movers); training steps run
        with the switches as set (trained with the hold, the movers did not learn stably; twentieth round).
        Needs ``translation_vote``, ``ego_head`` and ``l0_cost_volume``. A departure; false = inference as
        trained.
    eval_gate_k: with ``eval_anchor``, k > 1: at inference the gate reads the component-wise median residual
        of each point's k nearest points (``ego_gate_k``'s rule, which replaces ``ego_gate_k`` for the pass),
        so a static point whose own flow snapped onto a nearer frame-2 sample stays at the vote's motion
        while a mover, a cluster that departs together, keeps its flow; training steps as set. 0 = the
        gate as trained. No gradient; a departure (twenty-second round).
    eval_evidence_dense: with ``eval_anchor`` (or ``ego_gate_evidence``): at inference the evidence test at the
        finest level (``ego_gate_evidence``: a departure is taken only where the point's own target lies nearer
        to frame 2 than its rigid target does) reads frame 2's whole input, in the frame its L0 sample is in,
        instead of that sample (``level_points[0]`` farthest points: one in four of a 2048-point cloud, one in
        sixteen of an 8192-point one). Against a sparse sample a rigid target that is right still lies up to
        half the sample's spacing from its nearest point, so a static point's stray flow that lands nearer one
        passes; against the whole cloud the right rigid target lies on frame 2's surface. Inference only, no
        gradient; false = the L0 sample (thirty-fourth round).
    eval_own_departure: with ``eval_anchor`` (or ``ego_l0_hold`` from ``"vote"``): at inference a finest-level point's departure is measured from the
        net's own camera motion — the robust rigid fit of its finest-level flow (the ego head's fit, ``ego_sigma``,
        ``ego_mad_factor``, ``ego_iterations``, ``ego_planar``) — instead of from the rigid vote's, and then added
        to the vote's motion; the gate and the evidence test read that departure. Where the net's camera motion
        is off the vote's by δ, every static point otherwise departs by about δ: the gate's scale (three robust
        standard deviations of the residuals) grows with δ and shuts on movers, and the movers that pass carry δ.
        Inference only, no gradient; a departure; false = departures from the vote's motion (thirty-ninth round).
    eval_view_hold: with ``eval_anchor`` (or ``ego_l0_hold`` from ``"vote"``): at inference a finest-level point
        whose target under the vote's camera motion lies outside the field of view frame 2's own input shows
        (:class:`core.view.ViewExtent`: its azimuth sector less 0.5° at each side, its elevation range, its
        reach) takes the vote's motion, unless its own departure lies within ``ego_sigma`` of the component-wise
        median departure of its ``eval_gate_k`` nearest points in view, and then that median: frame 2 could not
        have seen it, so it holds no evidence of the point's motion, and its own flow can only have been matched to
        something else (near walls leaving the view "departed" 0.7–3 m onto frame 2's nearest points), while a
        mover's part that leaves the view departs with the part that stays.
        :func:`training.model.ego_motion.hold_out_of_view`. Inference only, no gradient; a departure; false =
        every point's own departure (fortieth round).
    eval_level_departure: with ``eval_anchor`` (or ``ego_l0_hold`` from ``"vote"``): at inference a finest-level
        point's departure from the camera's motion (from the net's own motion with ``eval_own_departure``, else
        from the vote's) keeps only its part along the ground: its vertical part (camera y, in the vote-aligned
        frame) is dropped before the gate and the evidence test read it. Things on the ground move along it, and a
        departure's vertical part is the net's error: on one of three runs its movers sank with training (mean
        vertical error +0.04–0.05 m after 500 steps, +0.09–0.11 m after 2000, up to 0.19 m on cars 32 m ahead; where
        the training puts it was not traced). :func:`training.model.ego_motion.level_departure`. Inference only, no
        gradient; a departure; false = the whole departure (forty-second round).
    eval_evidence_surface: κ ≥ 0; > 0 with the evidence test (``ego_gate_evidence``, which ``eval_anchor`` turns
        on): at inference the finest level's departure is also taken only where the camera's motion leaves the
        point's neighbourhood off frame 2's surface — at least a quarter of its ``eval_gate_k`` (else
        ``ego_gate_k``) nearest points have rigid targets farther than κ × frame 2's local spacing from frame 2's
        nearest point (:func:`training.model.ego_motion.off_surface`). A surface sampled at some spacing holds no
        point farther than about one spacing from a sample, so a static point's right rigid target has a gap of
        at most about 1, and a flow snapped to a nearer sample (which the evidence test alone accepts on dense
        or coarsely sampled clouds) is not taken; a mover's leading and trailing faces lie off it. Reads the
        evidence test's frame 2 (its whole input with ``eval_evidence_dense``). Inference only, no gradient; a
        departure; 0 = the evidence test alone (forty-third round).
    eval_neighbourhood_scale: with ``eval_anchor`` (and ``eval_gate_k`` > 1; else it changes nothing): at inference
        the finest level's gate compares each point's neighbourhood-median departure with three robust deviations of
        those medians (``ego_mad_factor`` × 1.4826 × their median size, at least ``ego_sigma``) instead of three
        robust deviations of the points' own departures, which a noisy net's static points widen while the median
        over 16 neighbours averages their noise away: one run's gate scale doubled with training (0.20 → 0.39 m) and
        shut on a third of its departing movers (``rigid_plus_residual(neighbourhood_scale=True)``). Inference only,
        no gradient; a departure; false = the points' own (forty-third round).
    """

    n_points: int = 8192
    level_points: tuple[int, ...] = (2048, 1024, 256, 64, 16)
    level_k: tuple[int, ...] = (32, 24, 16, 16, 8)
    cost_k_pc2: int = 32
    cost_k_pc1: int = 4
    refine_k: int = 6
    width_scale: float = 1.0
    sampling: str = "fps"
    feature_dim: int = 3
    knn_backend: str = "auto"
    upconv_k: int = 8
    set_conv_pooling: str = "max"
    norm: str = "batch"
    center_input: bool = True
    l0_cost_volume: bool = False
    coarse_match: bool = False
    coarse_match_sigma_m: float = 5.0
    translation_vote: bool = False
    translation_vote_max_m: float = 3.0
    rigid_vote: bool = False
    rigid_vote_dense: bool = False
    rigid_vote_far: bool = False
    rigid_vote_yaw_deg: float = 0.0
    rigid_vote_gap_m: float = 0.0
    rigid_vote_forward: bool = False
    rigid_vote_density_m: float = 0.0
    ego_head: bool = False
    ego_sigma: float = 0.1
    ego_mad_factor: float = 3.0
    ego_iterations: int = 4
    ego_planar: bool = False
    ego_l0_hold: bool = False
    ego_l0_hold_from: str = "l0"
    ego_open_gradient: bool = False
    zero_flow_heads: bool = False
    ego_open_gradient_k: int = 0
    ego_gate_k: int = 0
    ego_gate_spacing: float = 0.0
    ego_gate_evidence: bool = False
    eval_norm_stats: str = "running"
    eval_anchor: bool = False
    eval_gate_k: int = 0
    eval_evidence_dense: bool = False
    eval_own_departure: bool = False
    eval_view_hold: bool = False
    eval_level_departure: bool = False
    eval_evidence_surface: float = 0.0
    eval_neighbourhood_scale: bool = False

    def __post_init__(self) -> None:
        self.level_points = tuple(int(n) for n in self.level_points)
        self.level_k = tuple(int(k) for k in self.level_k)
        if len(self.level_points) != N_LEVELS or len(self.level_k) != N_LEVELS:
            raise ConfigError(
                f"level_points and level_k need {N_LEVELS} entries, got {self.level_points} and {self.level_k}"
            )
        pts = (self.n_points, *self.level_points)
        if any(a <= b for a, b in zip(pts, pts[1:])) or min(pts) < 1:
            raise ConfigError(f"n_points and level_points must be positive and strictly decreasing, got {pts}")
        for name in ("cost_k_pc2", "cost_k_pc1", "refine_k", "upconv_k"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        if min(self.level_k) < 1:
            raise ConfigError(f"level_k must be >= 1, got {self.level_k}")
        if not self.coarse_match_sigma_m > 0:
            raise ConfigError(f"coarse_match_sigma_m must be > 0, got {self.coarse_match_sigma_m}")
        if not self.translation_vote_max_m > 0:
            raise ConfigError(f"translation_vote_max_m must be > 0, got {self.translation_vote_max_m}")
        if self.ego_l0_hold and not (self.ego_head and self.l0_cost_volume):
            raise ConfigError("model.ego_l0_hold holds the L0 ego head at a motion fitted before the L0 cost volume: "
                              "it needs model.ego_head and model.l0_cost_volume true")
        if self.ego_l0_hold_from not in ("l0", "l1", "vote"):
            raise ConfigError(f"model.ego_l0_hold_from must be 'l0', 'l1' or 'vote', got {self.ego_l0_hold_from!r}")
        if self.ego_l0_hold_from == "vote" and not self.translation_vote:
            raise ConfigError("model.ego_l0_hold_from 'vote' holds the vote's motion: it needs model.translation_vote")
        if self.rigid_vote and not self.translation_vote:
            raise ConfigError("model.rigid_vote extends the translation vote: it needs model.translation_vote true")
        for name in ("rigid_vote_dense", "rigid_vote_far", "rigid_vote_forward"):
            if getattr(self, name) and not (self.rigid_vote or self.eval_anchor):
                raise ConfigError(f"model.{name} changes the rigid vote: it needs model.rigid_vote or "
                                  "model.eval_anchor")
        if not 0 <= self.rigid_vote_yaw_deg < 90:
            raise ConfigError(f"model.rigid_vote_yaw_deg must be in [0, 90), got {self.rigid_vote_yaw_deg}")
        if self.rigid_vote_yaw_deg and not (self.rigid_vote or self.eval_anchor):
            raise ConfigError("model.rigid_vote_yaw_deg changes the rigid vote: it needs model.rigid_vote or "
                              "model.eval_anchor")
        for name in ("rigid_vote_gap_m", "rigid_vote_density_m"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"model.{name} must be >= 0 m, got {getattr(self, name)}")
            if getattr(self, name) and not (self.rigid_vote or self.eval_anchor):
                raise ConfigError(f"model.{name} changes the rigid vote: it needs model.rigid_vote or "
                                  "model.eval_anchor")
        if self.eval_gate_k < 0:
            raise ConfigError(f"model.eval_gate_k must be >= 0, got {self.eval_gate_k}")
        if self.eval_gate_k and not self.eval_anchor:
            raise ConfigError("model.eval_gate_k sets the anchor's gate at inference: it needs model.eval_anchor")
        if self.eval_own_departure and not (self.eval_anchor or self.held_at_vote):
            raise ConfigError("model.eval_own_departure measures the anchor's departures: it needs model.eval_anchor "
                              "(or the finest level held at the vote's motion)")
        if self.eval_view_hold and not (self.eval_anchor or self.held_at_vote):
            raise ConfigError("model.eval_view_hold holds the anchor's departures of points that leave the view: it "
                              "needs model.eval_anchor (or the finest level held at the vote's motion)")
        if self.eval_level_departure and not (self.eval_anchor or self.held_at_vote):
            raise ConfigError("model.eval_level_departure levels the anchor's departures: it needs model.eval_anchor "
                              "(or the finest level held at the vote's motion)")
        if self.eval_neighbourhood_scale and not self.eval_anchor:
            raise ConfigError("model.eval_neighbourhood_scale sets the anchor's gate scale from its neighbourhood "
                              "medians: it needs model.eval_anchor")
        if not self.eval_evidence_surface >= 0:
            raise ConfigError(f"model.eval_evidence_surface must be >= 0, got {self.eval_evidence_surface}")
        if self.eval_evidence_surface and not (self.eval_anchor or self.ego_gate_evidence):
            raise ConfigError("model.eval_evidence_surface extends the evidence test: it needs model.eval_anchor or "
                              "model.ego_gate_evidence")
        if self.eval_evidence_dense and not (self.eval_anchor or self.ego_gate_evidence):
            raise ConfigError("model.eval_evidence_dense changes the evidence test: it needs model.eval_anchor or "
                              "model.ego_gate_evidence")
        if self.eval_anchor and not (self.translation_vote and self.ego_head and self.l0_cost_volume):
            raise ConfigError("model.eval_anchor turns on the rigid vote and the L0 hold at inference: it needs "
                              "model.translation_vote, model.ego_head and model.l0_cost_volume true")
        if not self.width_scale > 0:
            raise ConfigError(f"width_scale must be > 0, got {self.width_scale}")
        if self.sampling not in ("fps", "random"):
            raise ConfigError(f"sampling must be 'fps' or 'random', got {self.sampling!r}")
        if self.feature_dim < 0:
            raise ConfigError(f"feature_dim must be >= 0, got {self.feature_dim}")
        if self.knn_backend not in BACKENDS:
            raise ConfigError(f"knn_backend must be one of {BACKENDS}, got {self.knn_backend!r}")
        if not self.ego_sigma > 0 or self.ego_iterations < 1 or self.ego_mad_factor < 0:
            raise ConfigError(f"need ego_sigma > 0, ego_mad_factor >= 0 and ego_iterations >= 1, got {self.ego_sigma}, "
                              f"{self.ego_mad_factor}, {self.ego_iterations}")
        if self.ego_open_gradient_k < 0:
            raise ConfigError(f"ego_open_gradient_k must be >= 0, got {self.ego_open_gradient_k}")
        if self.ego_gate_k < 0 or self.ego_gate_spacing < 0:
            raise ConfigError(f"ego_gate_k and ego_gate_spacing must be >= 0, got {self.ego_gate_k}, "
                              f"{self.ego_gate_spacing}")
        if self.norm not in NORMS:
            raise ConfigError(f"norm must be one of {NORMS}, got {self.norm!r}")
        check_eval_norm_stats(self.eval_norm_stats, self.norm)
        if self.set_conv_pooling not in ("max", "attentive"):
            raise ConfigError(f"set_conv_pooling must be 'max' or 'attentive', got {self.set_conv_pooling!r}")

    legacy_fields: ClassVar[tuple[str, ...]] = ("batch_norm",)
    """Fields of older runs that :meth:`from_saved` reads (``training.model.registry`` accepts them in a checkpoint)."""

    @classmethod
    def from_saved(cls, fields: dict[str, Any]) -> "HALFlowConfig":
        """The config of a saved run's ``model`` dict; a run saved before ``norm`` replaced the boolean
        ``batch_norm`` field (true = ``"batch"``, false = ``"none"``) reads as it trained."""
        fields = dict(fields)
        batch_norm = fields.pop("batch_norm", None)
        if batch_norm is not None and "norm" not in fields:
            fields["norm"] = "batch" if batch_norm else "none"
        return cls(**fields)

    def at_inference(self) -> "HALFlowConfig":
        """The switches an inference pass runs with: this config, with ``eval_anchor``'s three turned on (and
        the gate's neighbourhood of ``eval_gate_k``)."""
        if not self.eval_anchor:
            return self
        return replace(self, **ANCHOR_SWITCHES, **({"ego_gate_k": self.eval_gate_k} if self.eval_gate_k else {}))

    def without_anchor(self) -> "HALFlowConfig":
        """This config with ``eval_anchor`` off and the inference options that act only through it dropped:
        ``eval_gate_k``; ``eval_own_departure``, ``eval_view_hold`` and ``eval_level_departure`` where the finest
        level is not held at the vote's motion; ``rigid_vote_dense`` / ``rigid_vote_far`` / ``rigid_vote_yaw_deg`` /
        ``rigid_vote_gap_m`` / ``rigid_vote_forward`` / ``rigid_vote_density_m`` where no rigid vote is left and
        ``eval_evidence_dense`` / ``eval_evidence_surface`` where no evidence test is."""
        keep_vote = self.rigid_vote
        return replace(self, eval_anchor=False, eval_gate_k=0,
                       eval_own_departure=self.eval_own_departure and self.held_at_vote,
                       eval_view_hold=self.eval_view_hold and self.held_at_vote,
                       eval_level_departure=self.eval_level_departure and self.held_at_vote,
                       eval_evidence_dense=self.eval_evidence_dense and self.ego_gate_evidence,
                       eval_evidence_surface=self.eval_evidence_surface if self.ego_gate_evidence else 0.0,
                       eval_neighbourhood_scale=False,
                       rigid_vote_dense=self.rigid_vote_dense and keep_vote,
                       rigid_vote_far=self.rigid_vote_far and keep_vote,
                       rigid_vote_yaw_deg=self.rigid_vote_yaw_deg if keep_vote else 0.0,
                       rigid_vote_gap_m=self.rigid_vote_gap_m if keep_vote else 0.0,
                       rigid_vote_forward=self.rigid_vote_forward and keep_vote,
                       rigid_vote_density_m=self.rigid_vote_density_m if keep_vote else 0.0)

    @property
    def held_at_vote(self) -> bool:
        """Whether the finest level is held at the rigid vote's motion (``ego_l0_hold`` from ``"vote"``), as
        ``eval_anchor``'s inference pass holds it."""
        return self.ego_l0_hold and self.ego_l0_hold_from == "vote"

    @property
    def output_points(self) -> tuple[int, ...]:
        """Points of the output levels L0..L3, finest first (the flows come out there)."""
        return self.level_points[:N_LEVELS - 1]

    @classmethod
    def points_fields(cls, n_points: int) -> dict[str, Any]:
        """``n_points`` and the paper's level sizes scaled to it (:func:`level_points_for`)."""
        return {"n_points": n_points, "level_points": level_points_for(n_points)}

    def check_for_training(self) -> None:
        """Every level's set conv must find ``level_k`` neighbours among the points of the level above."""
        sources = (self.n_points, *self.level_points)  # level l groups neighbours among these points
        over = [f"level {i}: {k} > {n}" for i, (k, n) in enumerate(zip(self.level_k, sources)) if k > n]
        if over:
            raise ConfigError(f"model.level_k larger than the points it picks neighbours from ({'; '.join(over)})")


def check_eval_norm_stats(mode: str, norm: str) -> None:
    """ConfigError unless ``mode`` is an ``eval_norm_stats`` value that the net's ``norm`` can use (the input's
    own statistics need batch norm); shared by the config and :meth:`HALFlowNet.set_eval_norm_stats`."""
    if mode not in ("running", "input"):
        raise ConfigError(f"eval_norm_stats must be 'running' or 'input', got {mode!r}")
    if mode == "input" and norm != "batch":
        raise ConfigError(f"eval_norm_stats 'input' needs norm 'batch', got {norm!r}")


def level_points_for(n_points: int) -> tuple[int, ...]:
    """The paper's level sizes (2048/1024/256/64/16 for 8192 inputs), scaled to ``n_points``; for small
    inputs the coarsest level keeps 4 points and each finer level at least twice the next coarser one,
    so the levels stay strictly decreasing (256 → 64/32/16/8/4). Needs ``n_points >= 128``."""
    levels = [int(n_points * f) for f in (0.25, 0.125, 1 / 32, 1 / 128, 1 / 512)]
    levels[4] = max(4, levels[4])
    for i in range(3, -1, -1):
        levels[i] = max(levels[i], 2 * levels[i + 1])
    return tuple(levels)
