"""Shared check of the optional loss terms (tests of training/losses/): each enters every level's weighted
sum as ``α_k · weight · term``, and is neither computed nor logged when its weight is 0."""

from __future__ import annotations

from typing import Callable

import numpy as np

from training.losses import LevelInputs, LossWeights, level_alphas, multi_level_loss


def check_enters_every_level(levels: Callable[[], list[LevelInputs]], field: str, key: str, weight: float,
                             **base) -> dict[str, float]:
    """Compare the loss with ``LossWeights(**base)`` and with ``field=weight`` added on ``levels()``: no
    ``l{k}/{key}`` is logged without it, and the totals differ by ``Σ_k α_k · weight · l{k}/{key}``.
    Returns the logged terms of the run with it."""
    plain, terms = multi_level_loss(levels(), LossWeights(**base))
    assert not any(k.endswith(f"/{key}") for k in terms)
    with_term, terms_w = multi_level_loss(levels(), LossWeights(**{field: weight}, **base))
    n = sum(1 for k in terms_w if k.endswith(f"/{key}"))
    assert n == len(base.get("alpha", LossWeights().alpha))
    alphas = level_alphas(LossWeights(**base), n)
    added = sum(a * weight * terms_w[f"l{k}/{key}"] for k, a in enumerate(alphas))
    np.testing.assert_allclose(with_term.item() - plain.item(), added, rtol=1e-5)
    return terms_w
