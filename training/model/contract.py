"""What a scene-flow net must offer the trainer and the evaluator (the contract every registered net keeps).

A net is a ``torch.nn.Module`` built from a torch-free dataclass config (:class:`FlowNetConfig`) and
registered by name in :mod:`training.model.registry`. The trainer (:mod:`training.trainer`), the
label-free selection (:mod:`training.selection`), the objective audit and the evaluator
(:class:`evaluation.methods.NetMethod`) rely on exactly this:

* **Call**: ``net(pc1, pc2, feat1=None, feat2=None, sampling=None) -> FlowOutput`` with pc1 (B, N1, 3) and
  pc2 (B, N2, 3) float points in metres in one common frame (camera frame of frame 1: x right, y down,
  z forward), feat1/feat2 (B, N, feature_dim) per-point features or None for zeros. Clouds of any size
  ``N >= config.output_points[0]`` are accepted; N1 may differ from N2.
* **Levels**: :attr:`FlowOutput.flows` holds the flow at every output level, finest first, as many levels
  as the loss has factors α (:class:`training.config.LossWeights`, 4 by default); level l's flow is at the
  frame-1 points :attr:`FlowOutput.indices` [l] (indices into the input pc1, gathered in
  :attr:`FlowOutput.points`), and its frame-2 points for the losses against pc2 are
  :attr:`FlowOutput.indices2` [l] / :attr:`FlowOutput.points2` [l]. Sizes per level: ``config.output_points``.
* **Two passes** (paper §III, eq. 12): the trainer calls ``out_o = net(pc1, pc2, f1, f2)`` and then the
  dynamic pass ``net(pc1 + sf_s, pc2, f1, f2, sampling=out_o.sampling)``; given ``sampling``, the net must
  predict at the same points (equal ``indices`` / ``indices2``), so that the dynamic–static loss compares
  the two flows point by point. What ``sampling`` holds is the net's own business (:class:`Sampling` is
  the usual form: per-level sample indices).
* **No global RNG** in a forward pass (the point sampling is deterministic), so that a resumed run
  reaches the same weights as an uninterrupted one; train/eval mode (batch norm) is the module's.
* **Evaluation**: ``NetMethod`` calls the net in eval mode on one scene (B = 1) and spreads
  ``flows[0]`` from ``points[0]`` to every sampled point; it reads ``config.n_points`` (default sample
  size), ``config.output_points[0]`` (scored points), ``config.feature_dim`` (3 = RGB features) and
  ``config.sampling`` (which protocol scores the net's own points).
* **Checkpoints** hold ``state_dict()`` and ``asdict(config)`` (``config["model"]`` of the run) with the
  registry name (``config["model_name"]``); :func:`training.model.registry.construct_model` rebuilds it.

This module imports no torch (tensor types are annotations only).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from torch import Tensor


@dataclass
class Sampling:
    """Which points each level took, as (B, n_l) int64 indices into the level above (L0: into the input).

    pc1: the levels of frame 1; pc2: the levels of frame 2. Reusing one pass's sampling in another (e.g.
    the dynamic pass ``net(pc1 + sf_s, pc2)`` after ``net(pc1, pc2)``) makes both predict flow at the same
    points, which a consistency loss between the passes needs; FPS on a rigidly moved cloud would pick the
    same points only up to floating-point ties.
    """

    pc1: list[Tensor]
    pc2: list[Tensor]


@dataclass
class FlowOutput:
    """What a flow net's forward returns; every list is finest level first (L0, L1, L2, L3 for HALFlowNet).

    flows: (B, n_l, 3) predicted flow of frame-1 points, metres.
    indices: (B, n_l) int64 indices of those points in the input pc1 (gather pc1, pixel coordinates,
        static flow … with them).
    points: (B, n_l, 3) those pc1 points (= pc1 gathered at indices), input frame.
    indices2 / points2: the same for the frame-2 points of each level (for losses against pc2).
    sampling: the sampling decisions of this pass; pass it to another forward to sample the same points.
    rigid_flows: (B, n_l, 3) per level, the flow ``T̂ p − p`` of the rigid (camera) motion the net fitted
        at those points, for nets that fit one (HALFlowNet with ``ego_head``); empty otherwise.
    gate_gaps: (B, n_l) per level, ``‖f − sg(f')‖²`` (m²) between the flow that entered the ego head and
        its output, summed over the level's head calls and differentiable in the former (the gate pull,
        :mod:`training.losses.gate_pull`); empty for nets without the head.
    gates: (B, n_l) per level, no gradient, the ego head's gate ``m`` in [0, 1] at the call that made the
        level's output (0: the point is held at the fitted rigid flow; 1: it keeps its own flow; the
        plane forms' ``loss.plane_where_held``); empty for nets without the head.
    """

    flows: list[Tensor]
    indices: list[Tensor]
    points: list[Tensor]
    indices2: list[Tensor] = field(default_factory=list)
    points2: list[Tensor] = field(default_factory=list)
    sampling: Any = None
    rigid_flows: list[Tensor] = field(default_factory=list)
    gate_gaps: list[Tensor] = field(default_factory=list)
    gates: list[Tensor] = field(default_factory=list)


@runtime_checkable
class FlowNetConfig(Protocol):
    """A net's architecture: a torch-free dataclass (its fields become ``--model.<field>`` flags).

    n_points: nominal points per input cloud (what the data pipeline draws; ``--n_points`` sets it).
    feature_dim: channels of the per-point input features (3 for RGB; 0 for none).
    sampling: how the finest points are chosen: ``"fps"`` (farthest point sampling) or ``"random"``
        (first-N of the randomly ordered input); the evaluator's hint on which protocol scores them.
    width_scale: multiplies every hidden width (the ablations' size knob; 1 = the net's full size).
    """

    n_points: int
    feature_dim: int
    sampling: str
    width_scale: float

    @property
    def output_points(self) -> tuple[int, ...]:
        """Points of each output level, finest first."""
        ...

    @classmethod
    def points_fields(cls, n_points: int) -> dict[str, Any]:
        """The fields that follow the points per cloud (``--n_points N`` sets them unless given)."""
        ...

    def check_for_training(self) -> None:
        """Combinations the trainer refuses beyond the dataclass's own checks (ConfigError)."""
        ...


@runtime_checkable
class FlowNet(Protocol):
    """A registered flow net: a ``torch.nn.Module`` with a :class:`FlowNetConfig` and the call above."""

    config: FlowNetConfig

    def __call__(self, pc1: Tensor, pc2: Tensor, feat1: Tensor | None = None, feat2: Tensor | None = None,
                 sampling: Any = None) -> FlowOutput: ...
