"""The one optimisation loop shared by the NSFP baseline and the test-time refinement: Adam on a
label-free scene loss, an iteration budget, early stopping on the loss, and the flow at the best loss.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable

import torch
from torch import Tensor

from evaluation.optimise.config import LoopConfig


@dataclass
class FitResult:
    """What :func:`minimise` found.

    flow: (N, 3) flow at the lowest loss seen, metres (detached).
    loss: that lowest loss, m².
    iterations: Adam steps taken (≤ ``cfg.iterations``).
    stopped_early: True when the patience or the time budget ran out before the iteration budget.
    seconds: wall time of the loop, s.
    history: loss of every step, m².
    """

    flow: Tensor
    loss: float
    iterations: int
    stopped_early: bool
    seconds: float
    history: list[float]


def minimise(params: Iterable[Tensor] | Iterable[dict], step: Callable[[], tuple[Tensor, Tensor]],
             cfg: LoopConfig) -> FitResult:
    """Run Adam(lr = ``cfg.lr``) on ``params`` (tensors, or Adam parameter groups with their own ``lr``)
    for at most ``cfg.iterations`` steps.

    ``step()`` returns ``(loss, flow)`` for the current parameters (the loss a scalar tensor with grad).
    Early stopping: the loop ends once ``cfg.patience`` consecutive steps have not lowered the best loss
    by more than ``cfg.min_delta`` (``patience = 0``: never), or after the first step that ends more than
    ``cfg.time_budget`` seconds after the loop began (0: no limit). The flow returned is the one evaluated at the
    lowest loss, so stopping late never makes the answer worse by the loss's own measure.
    """
    params = list(params)
    opt = torch.optim.Adam(params, lr=cfg.lr)
    best_loss, best_flow, stale, history = float("inf"), None, 0, []
    t0 = time.perf_counter()
    it = 0
    stopped = False
    for it in range(1, cfg.iterations + 1):
        opt.zero_grad(set_to_none=True)
        loss, flow = step()
        value = float(loss.detach())
        history.append(value)
        if value < best_loss - cfg.min_delta or best_flow is None:
            best_loss, best_flow, stale = value, flow.detach().clone(), 0
        else:
            if value < best_loss:  # better, but by less than min_delta: keep the flow, still count as stale
                best_loss, best_flow = value, flow.detach().clone()
            stale += 1
        if (cfg.patience and stale >= cfg.patience) or (cfg.time_budget and time.perf_counter() - t0 > cfg.time_budget):
            stopped = it < cfg.iterations
            break
        loss.backward()
        opt.step()
    assert best_flow is not None
    return FitResult(best_flow, best_loss, it, stopped, time.perf_counter() - t0, history)
