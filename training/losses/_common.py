"""Shape checks and reductions shared by the losses (private)."""

from __future__ import annotations

import torch
from torch import Tensor

from core.errors import InputError


def check_points(where: str, name: str, t: object, batch: int | None = None, n: int | None = None) -> Tensor:
    """Raise :class:`InputError` unless ``t`` is a floating (B, n, 3) tensor (with the given B, n)."""
    if not isinstance(t, Tensor) or t.ndim != 3 or t.shape[-1] != 3:
        shape = tuple(t.shape) if isinstance(t, Tensor) else type(t).__name__
        raise InputError(where, f"{name} must be a (B, N, 3) tensor, got {shape}")
    if not t.is_floating_point():
        raise InputError(where, f"{name} must be floating point, got {t.dtype}")
    if batch is not None and t.shape[0] != batch:
        raise InputError(where, f"{name} has batch size {t.shape[0]}, expected {batch}")
    if n is not None and t.shape[1] != n:
        raise InputError(where, f"{name} has {t.shape[1]} points, expected {n}")
    return t


def smooth_length(sq: Tensor) -> Tensor:
    """The length ``√(sq + 10⁻⁶) − 10⁻³`` of squared distances ``sq`` (m² → m): within 1 mm of the plain length,
    zero at zero, and with a finite gradient there (the L1 norms of the depth term and the static anchor)."""
    return torch.sqrt(sq + 1e-6) - 1e-3


def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``values`` (B, N) over the points where ``mask`` (B, N) holds, per batch element, then the
    mean over the batch elements that have at least one such point.

    Masked entries are replaced (``torch.where``), never multiplied, so a non-finite value there cannot
    leak into the result or its gradient. With no valid point at all the result is an exact zero that
    is still attached to the graph (its gradient is zero).
    """
    v = torch.where(mask, values, torch.zeros_like(values))
    count = mask.sum(dim=1)
    per_elem = v.sum(dim=1) / count.clamp_min(1).to(v.dtype)
    n_elems = (count > 0).sum().clamp_min(1).to(v.dtype)  # no host sync: stays on the device
    return per_elem.sum() / n_elems
