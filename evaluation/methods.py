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

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from pipeline.errors import ConfigError, InputError


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
        from pipeline.geometry import static_flow

        if pose is None:
            raise ConfigError("the 'static' baseline needs a split with poses (T_1→2 per scene); this one has none")
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"pose must have shape (4, 4), got {pose.shape}")
        return static_flow(as_cloud("points", pc1), pose, as_float32=True)


class NetMethod:
    """A scene-flow net restored from a ``monoflow-train`` checkpoint (``latest.pt``, kind ``"flow"``).

    The architecture comes from the checkpoint's ``config["model"]`` (HALFlowConfig fields); colours are
    the per-point features when the run trained with ``config["data"]["colour_features"]`` and the split
    has them, else zeros (:attr:`uses_colour`).
    """

    def __init__(self, checkpoint: str | Path, device: str = "auto", name: str | None = None) -> None:
        import torch

        from training.model.halflownet import HALFlowConfig, HALFlowNet
        from training.runtime.checkpoints import load_checkpoint, nonfinite_entries
        from training.runtime.device import resolve_device

        path = Path(checkpoint)
        ckpt = load_checkpoint(path, kind="flow")
        try:
            cfg = ckpt["config"]
            self.config = HALFlowConfig(**cfg["model"])
            state = ckpt["model"]
        except (KeyError, TypeError) as exc:
            raise InputError(path, f"checkpoint lacks the trainer's layout (config.model, model): {exc!r}") from None
        except ConfigError as exc:
            raise InputError(path, f"checkpoint's model config is invalid: {exc}") from None
        bad = nonfinite_entries(state) if isinstance(state, dict) else []
        if bad:
            raise InputError(path, f"non-finite weights (NaN or inf) in {', '.join(bad[:4])}"
                                   + (f" and {len(bad) - 4} more" if len(bad) > 4 else ""))
        self.uses_colour = bool((cfg.get("data") or {}).get("colour_features", True)) and self.config.feature_dim == 3
        self.device = resolve_device(device)
        self.net = HALFlowNet(self.config)
        try:
            self.net.load_state_dict(state)
        except RuntimeError as exc:
            raise InputError(path, f"weights do not match the model config ({str(exc).splitlines()[0]})") from None
        self.net = self.net.to(self.device).eval()
        self.run_config = cfg  # the run's whole config (evaluation.scenes reads what it trained on)
        self.step = int(ckpt.get("step", 0))
        self.checkpoint = path
        self.name = name or f"ours ({path.parent.name}, step {self.step})"
        self._torch = torch

    @property
    def n_points(self) -> int:
        """Points per cloud the net was trained on (the protocol's default ``n_points``)."""
        return self.config.n_points

    @property
    def n_score(self) -> int:
        """Level-0 points (the default ``n_score`` of the ``fps`` / ``released`` protocols)."""
        return self.config.level_points[0]

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
            flow = three_nn_interpolate(p1, out.points[0], out.flows[0].float())
        return flow[0].cpu().numpy().astype(np.float32)


def refined(method: FlowMethod, config: Any = None) -> FlowMethod:
    """``method`` followed by label-free test-time refinement (:class:`evaluation.optimise.RefinedMethod`),
    named ``"<method name> + refinement"``: a separate row, the method's own row is left as it is."""
    from evaluation.optimise import RefineConfig, RefinedMethod

    return RefinedMethod(method, config or RefineConfig())


BASELINES = ("zero", "static", "icp-p2p", "icp-p2l", "fgr", "nsfp")


def make_baseline(name: str) -> FlowMethod:
    """One of :data:`BASELINES`, with its default settings (``static`` needs a split with poses; ``nsfp``
    is Neural Scene Flow Prior fitted per scene, :class:`evaluation.optimise.NSFPMethod`)."""
    from evaluation.baselines.fgr import FGRBaseline
    from evaluation.baselines.icp import ICPBaseline, ICPConfig
    from evaluation.baselines.zero import ZeroFlowBaseline

    if name == "zero":
        return BaselineMethod(ZeroFlowBaseline())
    if name == "static":
        return StaticPoseMethod()
    if name == "icp-p2p":
        return BaselineMethod(ICPBaseline(ICPConfig(method="point_to_point")))
    if name == "icp-p2l":
        return BaselineMethod(ICPBaseline(ICPConfig(method="point_to_plane")))
    if name == "fgr":
        return BaselineMethod(FGRBaseline())
    if name == "nsfp":
        from evaluation.optimise import NSFPMethod

        return NSFPMethod()  # per-scene MLP prior fitted with a truncated Chamfer loss (evaluation/optimise)
    raise ConfigError(f"unknown baseline '{name}' (choose from {', '.join(BASELINES)})")
