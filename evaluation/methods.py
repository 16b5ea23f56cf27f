"""Everything that predicts flow, behind one interface, so that each method sees the same points.

A method is called as ``method(pc1, pc2, color1, color2) -> flow`` on the *sampled* clouds of a scene
(camera frames of frames 1 and 2, metres; colours RGB in [0, 1] or None; read-only arrays) and returns
the flow of every pc1 point, (N, 3) float32 metres. A method with ``needs_pose = True`` is also given
``pose=`` the scene's ``T_{1→2}`` (4×4, or None when the split has none).

The trained net predicts at its level-0 points; its flow is spread to the other sampled points by 3-NN
inverse-distance interpolation, which is exact at the level-0 points. Those are the points the ``fps``
protocol scores for a net trained with ``sampling="fps"`` and the points ``released`` scores (the first
rows) for one trained with ``sampling="random"``; elsewhere the scored flow is interpolated
(``docs/evaluation-protocols.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np

from core.errors import ConfigError


class FlowMethod(Protocol):
    name: str

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray, color1: np.ndarray | None,
                 color2: np.ndarray | None) -> np.ndarray: ...


@dataclass
class BaselineMethod:
    """Adapts a ``baseline(pc1, pc2) -> flow`` (zero, ICP, FGR) to :class:`FlowMethod` (colours unused)."""

    baseline: Any
    name: str = ""

    def __post_init__(self) -> None:
        self.name = self.name or self.baseline.name

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        return np.asarray(self.baseline(pc1, pc2), dtype=np.float32)


@dataclass
class StaticPoseMethod:
    """The pose-only static flow ``(R p + t) − p`` of the scene's own ``T_{1→2}`` (needs a split with poses)."""

    name: str = "static-pose"
    needs_pose: bool = True

    def __call__(self, pc1, pc2, color1=None, color2=None, pose: np.ndarray | None = None) -> np.ndarray:
        from evaluation.baselines.base import as_cloud
        from core.geometry import static_flow

        if pose is None:
            raise ConfigError("the 'static' baseline needs a split with poses (T_1→2 per scene); this one has none")
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"pose must have shape (4, 4), got {pose.shape}")
        return static_flow(as_cloud("points", pc1), pose, as_float32=True)


class NetMethod:
    """A scene-flow net restored from a ``monoflow-train`` checkpoint (``latest.pt``, kind ``"flow"``).

    The net is the registered one the checkpoint names (``config["model_name"]``, HALFlowNet for older
    checkpoints; :mod:`training.model.registry`) with the architecture of its ``config["model"]``; colours
    are the per-point features when the run trained with ``config["data"]["colour_features"]`` and the
    split has them, else zeros (:attr:`uses_colour`). ``level`` picks the pyramid level whose flow is
    returned (0, the finest, for every score; a coarser one, interpolated onto the input points, for
    diagnostics such as ``benchmarks.sensor_gap --per-level``). ``eval_anchor`` (true / false) overrides the
    checkpoint's inference-only switch ``model.eval_anchor`` (:class:`~training.model.halflownet_config.HALFlowConfig`;
    None: as trained), so one trained net can be scored both ways; an override that changes it is named in
    the row (", anchored" / ", not anchored"). ``turn_scan`` (degrees) likewise overrides the inference-only
    ``model.rigid_vote_yaw_deg`` (the rigid vote's turn scan, docs/learned-flow.md, thirty-second round; 0 =
    off), so a net trained before the scan existed can be scored with it; a change is named (", turn scan ±6°").
    ``evidence_dense`` (true / false) overrides the inference-only ``model.eval_evidence_dense`` (the anchor's
    evidence test against frame 2's whole input; thirty-fourth round), named (", dense evidence" / ", L0 evidence").
    ``vote_gap`` (metres, 0 = off) overrides the inference-only ``model.rigid_vote_gap_m`` (the rigid vote's choice
    by the mean gap to frame 2; thirty-fifth round), named (", vote by gap 0.3 m" / ", vote by count").
    ``vote_forward`` (true / false) overrides the inference-only ``model.rigid_vote_forward`` (the rigid vote's
    hypotheses also started along the optical axis; thirty-seventh round), named (", forward starts" / ", no forward
    starts"). ``vote_density`` (metres, 0 = off) overrides the inference-only ``model.rigid_vote_density_m`` (the rigid
    vote's starts also refined with each point weighed by its neighbourhood's density; thirty-eighth round), named
    (", density rounds 0.62 m" / ", uniform rounds"). ``own_departure`` (true / false) overrides the inference-only
    ``model.eval_own_departure`` (the anchor's departures measured from the net's own camera motion; thirty-ninth
    round), named (", own departures" / ", departures from the vote"). ``view_hold`` (true / false) overrides the
    inference-only ``model.eval_view_hold`` (a point whose rigid target leaves frame 2's view is held at the vote's
    motion unless it departs with its in-view neighbours; fortieth round), named (", view hold" / ", no view hold").
    ``level_departure`` (true / false) overrides the inference-only ``model.eval_level_departure`` (a point's departure
    kept along the ground, its vertical part dropped; forty-second round), named (", level departures" / ", whole
    departures"). ``evidence_surface`` (κ, 0 = off) overrides the inference-only ``model.eval_evidence_surface`` (a
    departure taken only where the camera's motion leaves the point's neighbourhood off frame 2's surface; forty-third
    round), named (", off-surface evidence κ" / ", evidence test alone"). ``neighbourhood_scale`` (true / false) overrides
    the inference-only ``model.eval_neighbourhood_scale`` (the anchor's gate scale taken from the neighbourhood-median
    departures it tests; forty-third round), named (", neighbourhood scale" / ", points' scale")."""

    def __init__(self, checkpoint: str | Path, device: str = "auto", name: str | None = None,
                 level: int = 0, eval_anchor: bool | None = None, turn_scan: float | None = None,
                 evidence_dense: bool | None = None, vote_gap: float | None = None,
                 vote_forward: bool | None = None, vote_density: float | None = None,
                 own_departure: bool | None = None, view_hold: bool | None = None,
                 level_departure: bool | None = None, evidence_surface: float | None = None,
                 neighbourhood_scale: bool | None = None) -> None:
        import torch

        from training.model.registry import restore_flow_net
        from training.runtime.checkpoints import load_checkpoint
        from training.runtime.device import resolve_device

        path = Path(checkpoint)
        ckpt = load_checkpoint(path, kind="flow")
        self.model_name, self.config, net = restore_flow_net(ckpt, path)
        suffix = ""

        def override(field: str, value, lacks: str, change) -> bool:
            """Set the inference-only ``field`` to ``value`` by ``change(config)`` when it differs; True if it did.
            A net without the field, or a setting its config refuses, is one error naming the checkpoint."""
            if value is None or value == getattr(self.config, field, None):
                return False
            if not hasattr(self.config, field):
                raise ConfigError(f"{path}: the {self.model_name} net has no {lacks}")
            try:
                self.config = net.config = change(self.config)
            except ConfigError as e:
                raise ConfigError(f"{path}: {e}") from None
            return True

        if override("eval_anchor", eval_anchor, "inference anchor (eval_anchor)",
                    lambda c: replace(c, eval_anchor=True) if eval_anchor else c.without_anchor()):
            suffix = ", anchored" if eval_anchor else ", not anchored"
        # the inference-only fields set as given: (field, value, its type, what a net without it lacks, the row's
        # note for the value when it changes the config)
        for field, value, kind, lacks, note in (
                ("rigid_vote_yaw_deg", turn_scan, float, "rigid vote to scan turns for",
                 lambda v: f", turn scan ±{v:g}°"),
                ("eval_evidence_dense", evidence_dense, bool, "inference anchor's evidence test (eval_evidence_dense)",
                 lambda v: ", dense evidence" if v else ", L0 evidence"),
                ("rigid_vote_gap_m", vote_gap, float, "rigid vote to choose by its gap",
                 lambda v: f", vote by gap {v:g} m" if v else ", vote by count"),
                ("rigid_vote_forward", vote_forward, bool, "rigid vote to start along the optical axis",
                 lambda v: ", forward starts" if v else ", no forward starts"),
                ("rigid_vote_density_m", vote_density, float, "rigid vote to weigh its rounds by density",
                 lambda v: f", density rounds {v:g} m" if v else ", uniform rounds"),
                ("eval_own_departure", own_departure, bool, "anchor to measure departures from its own motion",
                 lambda v: ", own departures" if v else ", departures from the vote"),
                ("eval_view_hold", view_hold, bool, "anchor to hold the points that leave the view",
                 lambda v: ", view hold" if v else ", no view hold"),
                ("eval_level_departure", level_departure, bool, "anchor to level its departures",
                 lambda v: ", level departures" if v else ", whole departures"),
                ("eval_evidence_surface", evidence_surface, float, "evidence test to read frame 2's surface",
                 lambda v: f", off-surface evidence {v:g}" if v else ", evidence test alone"),
                ("eval_neighbourhood_scale", neighbourhood_scale, bool, "anchor to scale its gate by its neighbourhoods",
                 lambda v: ", neighbourhood scale" if v else ", points' scale")):
            if override(field, value, lacks, lambda c, f=field, v=value, k=kind: replace(c, **{f: k(v)})):
                suffix += note(value)
        cfg = ckpt["config"]
        self.uses_colour = bool((cfg.get("data") or {}).get("colour_features", True)) and self.config.feature_dim == 3
        self.device = resolve_device(device)
        self.net = net.to(self.device).eval()
        self.run_config = cfg  # the run's whole config (evaluation.scenes reads what it trained on)
        self.step = int(ckpt.get("step", 0))
        self.checkpoint = path
        self.name = name or f"ours ({path.parent.name}, step {self.step}{suffix})"
        self.level = int(level)
        if not 0 <= self.level < len(self.config.output_points):
            raise ValueError(f"{path}: level {level} is not one of the net's levels 0..{len(self.config.output_points) - 1}")
        self._torch = torch

    @property
    def n_points(self) -> int:
        """Points per cloud the net was trained on (the protocol's default ``n_points``)."""
        return self.config.n_points

    @property
    def n_score(self) -> int:
        """Points of the net's finest level (the default ``n_score`` of the ``fps`` / ``released`` protocols)."""
        return self.config.output_points[0]

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        torch = self._torch
        from training.pointops import three_nn_interpolate

        def t(x):
            return torch.tensor(np.asarray(x, dtype=np.float32), device=self.device)[None]

        use = self.uses_colour and color1 is not None and color2 is not None
        f1, f2 = (t(color1), t(color2)) if use else (None, None)  # None: the net's zero features
        with torch.no_grad():
            p1 = t(pc1)
            out = self.net(p1, t(pc2), f1, f2)
            flow = three_nn_interpolate(p1, out.points[self.level], out.flows[self.level].float())
        return flow[0].cpu().numpy().astype(np.float32)


def refined(method: FlowMethod, config: Any = None, pairing: str = "surface") -> FlowMethod:
    """``method`` followed by label-free test-time refinement (:class:`evaluation.optimise.RefinedMethod`),
    named ``"<method name> + refinement"``: a separate row, the method's own row is left as it is. Without
    ``config``, :meth:`RefineConfig.for_start`: a method whose ego-motion is already registered
    (``registered_ego``, the rigid polish) is refined with :meth:`RefineConfig.after_registration`, any other
    with the defaults; ``pairing="points"`` (frame 2 holds frame 1's own points) drops the plane form and the
    rigid pull, and the row is named ``"… + refinement (point pairs)"``. A given ``config`` is used as it is
    (``pairing`` then only checked)."""
    from evaluation.optimise import RefineConfig, RefinedMethod

    chosen = RefineConfig.for_start(bool(getattr(method, "registered_ego", False)), pairing)
    row = RefinedMethod(method, chosen if config is None else config)
    if config is None and pairing == "points":
        row.name += " (point pairs)"
    return row


# ---------------------------------------------------------------------------------------------- registry
# Every method by name: a stand-alone method is built from nothing (``make()``), a wrapper from the method
# it refines (``make(method)``). The trained nets come from checkpoints (:class:`NetMethod`, their
# architecture from training.model.registry).


@dataclass(frozen=True)
class MethodEntry:
    """How to build one named method: ``make()`` (stand-alone) or ``make(method)`` (``wraps``); ``note`` is
    what ``--baselines`` help says about it."""

    make: Callable[..., FlowMethod]
    wraps: bool = False
    note: str = ""


def _icp(kind: str) -> FlowMethod:
    from evaluation.baselines.icp import ICPBaseline, ICPConfig

    return BaselineMethod(ICPBaseline(ICPConfig(method=kind)))


def _zero() -> FlowMethod:
    from evaluation.baselines.zero import ZeroFlowBaseline

    return BaselineMethod(ZeroFlowBaseline())


def _fgr() -> FlowMethod:
    from evaluation.baselines.fgr import FGRBaseline

    return BaselineMethod(FGRBaseline())


def _tvote() -> FlowMethod:
    from evaluation.baselines.translation_vote import TranslationVoteBaseline

    return BaselineMethod(TranslationVoteBaseline())


def _rvote() -> FlowMethod:
    from evaluation.baselines.rigid_vote import RigidVoteBaseline

    return BaselineMethod(RigidVoteBaseline())


def _nsfp() -> FlowMethod:
    from evaluation.optimise import NSFPMethod

    return NSFPMethod()  # per-scene MLP prior fitted with a truncated Chamfer loss (evaluation/optimise)


def _nsfp_full() -> FlowMethod:
    from evaluation.optimise import NSFPConfig, NSFPMethod

    return NSFPMethod(NSFPConfig.published(), name="nsfp-full")  # the authors' settings: the bar at full strength


def _view_pruned(method: FlowMethod) -> FlowMethod:
    from evaluation.view_prune import view_pruned

    return view_pruned(method)  # label-free two-pass inference (evaluation/view_prune.py)


def _rigid_polished(method: FlowMethod) -> FlowMethod:
    from evaluation.rigid_polish import rigid_polished

    return rigid_polished(method)  # ego-motion and movers sharpened by robust ICP (evaluation/rigid_polish.py)


_METHODS: dict[str, MethodEntry] = {
    "zero": MethodEntry(_zero),
    "static": MethodEntry(StaticPoseMethod, note="splits with poses"),
    "icp-p2p": MethodEntry(lambda: _icp("point_to_point")),
    "icp-p2l": MethodEntry(lambda: _icp("point_to_plane")),
    "fgr": MethodEntry(_fgr),
    "tvote": MethodEntry(_tvote, note="one translation voted from all point-pair offsets"),
    "rvote": MethodEntry(_rvote, note="the voted translation refined to a rigid motion by trimmed matching"),
    "nsfp": MethodEntry(_nsfp, note="60 steps: the demo's budget"),
    "nsfp-full": MethodEntry(_nsfp_full, note="NSFP at its authors' settings: up to 5000 steps, patience 70, "
                                              "backward MLP; tens of seconds per scene on a CPU"),
    "refine": MethodEntry(refined, wraps=True, note="label-free test-time refinement of another method"),
    "view-prune": MethodEntry(_view_pruned, wraps=True,
                              note="two passes, the second without the points leaving pc2's view"),
    "rigid-polish": MethodEntry(_rigid_polished, wraps=True,
                              note="the method's ego-motion and movers sharpened by robust ICP started from its flow"),
}


def register_method(name: str, make: Callable[..., FlowMethod], wraps: bool = False, note: str = "") -> None:
    """Make a method available by ``name`` (``--baselines name`` when stand-alone); a taken name is refused."""
    entry = MethodEntry(make, wraps, note)
    if _METHODS.get(name, entry) != entry:
        raise ConfigError(f"method '{name}' is already registered")
    _METHODS[name] = entry


def method_names(wrappers: bool = False) -> tuple[str, ...]:
    """The stand-alone methods (``wrappers=False``) or the wrappers, in registration order."""
    return tuple(n for n, e in _METHODS.items() if e.wraps == wrappers)


def baselines_help() -> str:
    """``zero, static (splits with poses), icp-p2p, …``: the stand-alone methods for ``--baselines``."""
    return ", ".join(f"{n} ({_METHODS[n].note})" if _METHODS[n].note else n for n in method_names())


BASELINES = method_names()  # the built-in stand-alone methods


def make_method(name: str, inner: FlowMethod | None = None) -> FlowMethod:
    """The method ``name`` with its default settings; a wrapper (``refine``) wraps ``inner``."""
    entry = _METHODS.get(name)
    if entry is None or entry.wraps != (inner is not None):
        kind = "wrapper" if inner is not None else "baseline"
        raise ConfigError(f"unknown {kind} '{name}' (choose from {', '.join(method_names(inner is not None))})")
    return entry.make(inner) if entry.wraps else entry.make()


def make_baseline(name: str) -> FlowMethod:
    """A stand-alone method (:func:`method_names`) with its default settings (``static`` needs a split with
    poses; ``nsfp`` is Neural Scene Flow Prior fitted per scene, :class:`evaluation.optimise.NSFPMethod`)."""
    return make_method(name)
