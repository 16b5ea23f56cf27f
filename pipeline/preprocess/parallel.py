"""Running blocks in ``workers`` spawned processes (each builds its own nets and cache writer).

Errors cross the process boundary in a picklable form (:func:`_pack_error` / :func:`_unpack_error`: the
worker's one-line MonoflowError is raised unchanged in the parent). On the first error the blocks already
running finish (so no block is left half-written), the rest are cancelled and that error is raised. Blocks a
worker had to defer (no scale factor yet in its sequence) are finished here, in the parent, with the sequence
median of the factors the workers found.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from core.errors import ConfigError, InputError, MonoflowError
from pipeline.preprocess.block import BlockProcessor, BlockResult, DeferBlock
from pipeline.preprocess.config import PreprocessConfig
from pipeline.preprocess.planning import BlockPlan
from pipeline.preprocess.serial import finish_deferred, process_block
from pipeline.scale import ScaleError

_WORKER: dict[str, Any] = {}  # this worker process's BlockProcessor and CacheWriter (or its setup error)


def _worker_init(config_dict: dict[str, Any], root: str, cache_cfg: dict, source: dict, threads: int,
                 parent_pid: int) -> None:
    """Process-pool initializer: build this worker's nets and writer once (a setup error is kept for later)."""
    from pipeline.cache.writer import CacheWriter
    from pipeline.lifeline import die_with_parent
    from core.options import config_from_dict

    die_with_parent(parent_pid)  # a killed stage one leaves no worker behind
    try:
        config = config_from_dict(PreprocessConfig, config_dict)
        if config.depth == "net" or config.pose == "net":
            import torch

            torch.set_num_threads(max(1, threads))
        _WORKER["processor"] = BlockProcessor(config)
        _WORKER["writer"] = CacheWriter(root, cache_cfg, source)
    except MonoflowError as exc:
        _WORKER["error"] = _pack_error(exc)


def _pack_error(exc: MonoflowError) -> tuple:
    """A picklable form of a MonoflowError (InputError's constructor takes two arguments)."""
    if isinstance(exc, InputError):
        return ("InputError", str(exc.path), exc.problem)
    return (type(exc).__name__, str(exc), None)


def _unpack_error(packed: tuple) -> MonoflowError:
    """The MonoflowError that :func:`_pack_error` packed, rebuilt in the parent."""
    kind, a, b = packed
    if kind == "InputError":
        return InputError(a, b)
    if kind == "ConfigError":
        return ConfigError(a)
    if kind == "ScaleError":
        return ScaleError(a)
    return MonoflowError(a)


def _worker_block(plan: BlockPlan) -> tuple[str, Any]:
    """One block in a worker: ("ok", BlockResult) | ("deferred", plan) | ("error", packed error)."""
    if "error" in _WORKER:
        return ("error", _WORKER["error"])
    try:
        res = process_block(_WORKER["processor"], _WORKER["writer"], plan)
        if isinstance(res, DeferBlock):
            return ("deferred", plan)
        return ("ok", res)
    except MonoflowError as exc:
        return ("error", _pack_error(exc))


def run_parallel(config: PreprocessConfig, root: Path, cache_cfg: dict[str, Any], source: dict[str, Any],
                 todo: list[BlockPlan], done: Callable[[BlockResult], None]) -> None:
    """Process ``todo`` in ``config.workers`` spawned processes, calling ``done`` per finished block; on the
    first error let running blocks finish (so no block is left half-written), cancel the rest and raise it."""
    results, deferred_plans = _run_pool(config, root, cache_cfg, source, todo, done)
    if deferred_plans:  # blocks that met no good factor in their worker: the sequence median, here
        _finish_deferred_here(config, root, cache_cfg, source, results, deferred_plans, done)


def _run_pool(config: PreprocessConfig, root: Path, cache_cfg: dict[str, Any], source: dict[str, Any],
              todo: list[BlockPlan], done: Callable[[BlockResult], None]) -> tuple[list[BlockResult], list[BlockPlan]]:
    """The worker pool over ``todo``: (finished blocks' results, plans the workers deferred)."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    threads = max(1, (os.cpu_count() or 1) // config.workers)
    deferred_plans: list[BlockPlan] = []
    results: list[BlockResult] = []  # kept: their good factors give deferred blocks the sequence median
    args = (dataclasses.asdict(config), str(root), cache_cfg, source, threads, os.getpid())
    error: MonoflowError | None = None
    with ProcessPoolExecutor(config.workers, mp_context=mp.get_context("spawn"), initializer=_worker_init,
                             initargs=args) as pool:
        pending = {pool.submit(_worker_block, plan) for plan in todo}
        try:
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    if fut.cancelled():
                        continue
                    status, payload = fut.result()
                    if status == "ok":
                        results.append(payload)
                        done(payload)
                    elif status == "deferred":
                        deferred_plans.append(payload)
                    elif error is None:
                        error = _unpack_error(payload)
                        for other in pending:
                            other.cancel()
        except BaseException:
            for other in pending:
                other.cancel()
            raise
    if error is not None:
        raise error
    return results, deferred_plans


def _finish_deferred_here(config: PreprocessConfig, root: Path, cache_cfg: dict[str, Any], source: dict[str, Any],
                          results: list[BlockResult], deferred_plans: list[BlockPlan],
                          done: Callable[[BlockResult], None]) -> None:
    """Finish the workers' deferred blocks in this process with the sequence median of their good factors."""
    from pipeline.cache.writer import CacheWriter

    processor = BlockProcessor(config)
    for res in sorted(results, key=lambda r: r.index):
        if not res.carried:
            processor.good_factors.setdefault(res.sequence, []).append(res.scale)
    writer = CacheWriter(root, cache_cfg, source)
    items = [DeferBlock(processor.infer(plan)) for plan in sorted(deferred_plans, key=lambda p: p.global_index)]
    finish_deferred(processor, writer, items, done, Path(root))


__all__ = ["run_parallel"]
