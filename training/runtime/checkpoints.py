"""Atomic training checkpoints: model, optimiser, scheduler, step and every RNG state.

Written to ``<name>.tmp-<pid>`` then ``os.replace``d, so a killed run never leaves a half-written
checkpoint, and ``latest.pt`` always names a complete one.
"""

from __future__ import annotations

import os
import random
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import InputError

CHECKPOINT_VERSION = 1


def seed_all(seed: int, deterministic: bool = False) -> None:
    """Seed the Python, numpy and torch RNGs (the ones :func:`rng_state` saves); ``deterministic`` also asks
    torch for deterministic kernels (warning, not failing, where it has none)."""
    import torch

    if deterministic:
        torch.use_deterministic_algorithms(True, warn_only=True)
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def rng_state() -> dict[str, Any]:
    """Python, numpy and torch (CPU, and CUDA when present) RNG states."""
    import torch

    key, keys, pos, has_gauss, cached = np.random.get_state()
    # Only tensors, numbers, strings and tuples: a checkpoint loads with ``weights_only=True`` (no pickled code).
    numpy_state = {"key": str(key), "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)), "pos": int(pos),
                   "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}
    state = {"python": random.getstate(), "numpy": numpy_state, "torch": torch.get_rng_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    import torch

    random.setstate(tuple(state["python"]))
    ns = state["numpy"]
    if isinstance(ns, dict):
        np.random.set_state((ns["key"], ns["keys"].numpy().astype(np.uint32), ns["pos"], ns["has_gauss"],
                             ns["cached_gaussian"]))
    else:
        np.random.set_state(ns)
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_checkpoint(path: str | os.PathLike[str], payload: dict[str, Any]) -> Path:
    """Write ``payload`` (plus the checkpoint version) atomically to ``path``."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    torch.save({"checkpoint_version": CHECKPOINT_VERSION, **payload}, tmp)
    os.replace(tmp, path)
    return path


def load_checkpoint(path: str | os.PathLike[str], kind: str) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint`, checking version and ``kind``.

    ``kind`` is the trainer that wrote it (``"flow"`` or ``"depth"``). Any problem is one
    :class:`InputError` naming the file.
    """
    import pickle

    import torch

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)  # never runs code from the file
    except pickle.UnpicklingError as exc:
        raise InputError(path, "holds objects other than tensors, numbers and strings (a checkpoint of an older "
                               f"monoflow, or not one at all); refused: {str(exc).splitlines()[0][:120]}") from None
    except (RuntimeError, EOFError, ValueError, OSError) as exc:
        raise InputError(path, f"not a readable checkpoint ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})") from None
    if not isinstance(ckpt, dict) or "checkpoint_version" not in ckpt:
        raise InputError(path, "not a monoflow training checkpoint (no checkpoint_version)")
    if ckpt["checkpoint_version"] != CHECKPOINT_VERSION:
        raise InputError(path, f"checkpoint version {ckpt['checkpoint_version']} != supported {CHECKPOINT_VERSION}")
    if ckpt.get("kind") != kind:
        raise InputError(path, f"checkpoint of kind '{ckpt.get('kind')}', expected '{kind}'")
    return ckpt
