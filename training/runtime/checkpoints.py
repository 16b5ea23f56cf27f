"""Atomic training checkpoints: model, optimiser, scheduler, step and every RNG state.

Written to ``<name>.tmp-<pid>`` then ``os.replace``d, so a killed run never leaves a half-written
checkpoint, and ``latest.pt`` always names a complete one; temp files of dead writers are removed by the
next save. Read with ``torch.load(weights_only=True)``: a checkpoint holds tensors and plain Python data
only (the numpy RNG state is saved as a tensor), so loading one never runs code from the file.
"""

from __future__ import annotations

import io
import os
import random
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import InputError

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


def _numpy_state_to_plain(state: tuple) -> dict[str, Any]:
    """numpy's legacy RNG state as tensors and plain data (loadable with ``weights_only=True``)."""
    import torch

    name, keys, pos, has_gauss, cached = state
    return {"name": str(name), "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)), "pos": int(pos),
            "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}


def _numpy_state_from_plain(state: Any) -> tuple:
    """Inverse of :func:`_numpy_state_to_plain`; a tuple (checkpoints written before it) passes through."""
    if not isinstance(state, dict):
        return state
    keys = np.asarray(state["keys"].numpy(), dtype=np.uint32)
    return (state["name"], keys, state["pos"], state["has_gauss"], state["cached_gaussian"])


def rng_state() -> dict[str, Any]:
    """Python, numpy and torch (CPU, and CUDA when present) RNG states, as tensors and plain data."""
    import torch

    state = {"python": random.getstate(), "numpy": _numpy_state_to_plain(np.random.get_state()),
             "torch": torch.get_rng_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    import torch

    random.setstate(state["python"])
    np.random.set_state(_numpy_state_from_plain(state["numpy"]))
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_checkpoint(path: str | os.PathLike[str], payload: dict[str, Any]) -> Path:
    """Write ``payload`` (plus the checkpoint version) atomically to ``path``."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_tmp(path)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    buf = io.BytesIO()  # serialised in memory, written by us: a full disk is then a plain OSError
    torch.save({"checkpoint_version": CHECKPOINT_VERSION, **payload}, buf)
    try:
        with open(tmp, "wb") as f:
            f.write(buf.getbuffer())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(path, f"cannot write checkpoint ({exc.strerror or exc}); "
                               "the previous checkpoint, if any, is unchanged") from None
    return path


def remove_stale_tmp(path: str | os.PathLike[str]) -> list[Path]:
    """Remove ``<path>.tmp-<pid>`` files left by writers that no longer run (:func:`core.processes.writer_gone`);
    return what was removed."""
    from core.processes import writer_gone

    path = Path(path)
    removed = []
    if not path.parent.is_dir():
        return removed
    prefix = f"{path.name}.tmp-"
    for p in path.parent.iterdir():
        rest = p.name[len(prefix):] if p.name.startswith(prefix) else ""
        if rest.isdigit() and (int(rest) == os.getpid() or writer_gone(int(rest), p)):
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed


def _numpy_globals() -> list[Any]:
    """The numpy types of checkpoints written before the RNG state was saved as a tensor: plain arrays,
    rebuilt without running code from the file."""
    core = getattr(np, "_core", None) or np.core
    return [core.multiarray._reconstruct, np.ndarray, np.dtype, type(np.dtype(np.uint32))]


def load_checkpoint(path: str | os.PathLike[str], kind: str) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint`, checking version and ``kind``.

    ``kind`` is the trainer that wrote it (``"flow"`` or ``"depth"``). Any problem is one
    :class:`InputError` naming the file.
    """
    from core.safeload import load_weights_only

    ckpt = load_weights_only(path, _numpy_globals())
    if not isinstance(ckpt, dict) or "checkpoint_version" not in ckpt:
        raise InputError(path, "not a monoflow training checkpoint (no checkpoint_version)")
    if ckpt["checkpoint_version"] != CHECKPOINT_VERSION:
        raise InputError(path, f"checkpoint version {ckpt['checkpoint_version']} != supported {CHECKPOINT_VERSION}")
    if ckpt.get("kind") != kind:
        raise InputError(path, f"checkpoint of kind '{ckpt.get('kind')}', expected '{kind}'")
    return ckpt


def nonfinite_entries(state: dict[str, Any]) -> list[str]:
    """Names of the floating-point tensors of a state dict holding NaN or inf."""
    import torch

    return [k for k, v in state.items()
            if isinstance(v, torch.Tensor) and v.is_floating_point() and not bool(torch.isfinite(v).all())]
