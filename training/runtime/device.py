"""Device selection: ``auto`` takes CUDA when present, else the CPU; never a hard-coded GPU index."""

from __future__ import annotations

import os

from core.errors import ConfigError


def resolve_device(name: str = "auto", local_rank: int | None = None):
    """Return a ``torch.device`` for ``auto`` | ``cpu`` | ``cuda`` | ``cuda:N``.

    Under torchrun, ``auto``/``cuda`` pick the process's ``LOCAL_RANK`` GPU.
    """
    import torch

    if local_rank is None:
        local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cpu":
        return torch.device("cpu")
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise ConfigError(f"device '{name}' requested but CUDA is not available (use --device cpu or auto)")
        if name == "cuda":
            return torch.device("cuda", local_rank % max(torch.cuda.device_count(), 1))
        return torch.device(name)
    raise ConfigError(f"unknown device '{name}' (expected auto, cpu, cuda or cuda:N)")
