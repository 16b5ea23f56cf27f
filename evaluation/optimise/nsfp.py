"""Neural Scene Flow Prior baseline (Li, Kaesemodel Pontes & Lucey, NeurIPS 2021), fitted per scene.

The flow of every pc1 point is the output of a small MLP of its coordinates, ``f = MLP_θ(p)``; θ is
fitted to the one scene by minimising the truncated bidirectional Chamfer distance between ``pc1 + f``
and ``pc2`` (their eq. 5 with the distance truncation of their implementation), optionally plus the
cycle term of a backward MLP ``g`` evaluated at the warped points. The MLP's spectral bias is the only
smoothness prior. No labels are used; the same sampled clouds as every other method go in, and the flow
of every pc1 point (N, 3) float32 metres comes out (camera frames, x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from evaluation.optimise.common import FlowMLP, as_tensor, resolve
from evaluation.optimise.config import NSFPConfig
from evaluation.optimise.loop import FitResult, minimise
from evaluation.optimise.terms import cycle_term, truncated_chamfer


def fit_nsfp(pc1: np.ndarray | Tensor, pc2: np.ndarray | Tensor, cfg: NSFPConfig | None = None) -> FitResult:
    """Fit the NSFP MLP to one scene: pc1 (N, 3), pc2 (M, 3) metres → :class:`FitResult` (flow (N, 3))."""
    cfg = (cfg or NSFPConfig()).validate()
    dev = resolve(cfg.device)
    p1, p2 = as_tensor(pc1, dev), as_tensor(pc2, dev)
    fwd = FlowMLP(cfg.layers, cfg.hidden, seed=cfg.seed).to(dev)
    params = list(fwd.parameters())
    bwd = None
    if cfg.backward:
        bwd = FlowMLP(cfg.layers, cfg.hidden, seed=cfg.seed + 1).to(dev)
        params += list(bwd.parameters())

    def step() -> tuple[Tensor, Tensor]:
        flow = fwd(p1)
        warped = p1 + flow
        loss = truncated_chamfer(warped, p2, cfg.truncate)
        if bwd is not None:
            back = bwd(warped)
            loss = loss + truncated_chamfer(warped + back, p1, cfg.truncate) + cfg.cycle_weight * cycle_term(flow, back)
        return loss, flow[0]

    return minimise(params, step, cfg)


@dataclass
class NSFPMethod:
    """The NSFP baseline as a :class:`~evaluation.methods.FlowMethod` (colours unused).

    ``last`` holds the :class:`FitResult` of the latest call (iterations, early stop, loss) for reports.
    """

    config: NSFPConfig = field(default_factory=NSFPConfig)
    name: str = "nsfp"
    last: FitResult | None = field(default=None, repr=False)

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        with torch.enable_grad():
            self.last = fit_nsfp(pc1, pc2, self.config)
        return self.last.flow.cpu().numpy().astype(np.float32)
