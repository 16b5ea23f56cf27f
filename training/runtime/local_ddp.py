"""Data-parallel training on this machine's own cores, without ``torchrun``: ``P`` processes of one thread each.

Why: the net's step is thousands of small operations, which a second intra-op thread barely speeds up; on the
demo's 2-core box two processes of one thread each ran the demo preset 1.17–1.26× faster than one process of
two threads (1.49 against 1.74 s per step; 1.56 against 1.96 s before the vote's and the dynamic pass's
speed-ups; BENCHMARKS.md). The run is the same one: the global batch is split evenly over the processes, every
pair's draws depend only on (seed, epoch, pair) and DDP averages the gradients, so ``P`` processes train like
one process with that batch up to float summation order (``tests/training/test_trainer_ddp.py`` pins the first
step; the demo's net trained either way scored within a millimetre on every row: docs/learned-flow.md).

The processes meet through a file in a fresh temporary folder (gloo, no network port to collide on), every
collective waits at most ``timeout_s``, and the children load their data in-process (``data.workers`` 0: a
loader process per rank would put four busy processes on two cores). A child's error comes back to the caller as
one line (a :class:`~core.errors.MonoflowError` keeps its text); the other child is then stopped.
"""

from __future__ import annotations

import json
import os
import tempfile
import traceback
from dataclasses import replace
from datetime import timedelta
from pathlib import Path
from typing import Any

from core.errors import MonoflowError
from training.config import TrainConfig


class ChildFailed(MonoflowError):
    """A training process stopped with an error (its one-line message)."""


def _to_the_end(trainer, validate_first: bool) -> tuple[dict | None, dict]:
    """``(first, last)`` of :func:`fit_local` from a built :class:`~training.trainer.Trainer`: the validation
    row before the first step (``validate_first`` and at step 0), then the fit's last row, or only a
    validation row when the run is already finished."""
    first = trainer.validate() if validate_first and trainer.step == 0 else None
    last = trainer.fit() if trainer.step < trainer.steps else trainer.validate()
    return first, last


def _child(rank: int, cfg: TrainConfig, processes: int, folder: str, resume: bool, validate_first: bool,
           timeout_s: float) -> None:
    import torch.distributed as dist

    os.environ.update(WORLD_SIZE=str(processes), RANK=str(rank), LOCAL_RANK=str(rank))
    out = Path(folder) / f"result-{rank}.json"
    try:
        dist.init_process_group("gloo", init_method=f"file://{Path(folder) / 'store'}", rank=rank,
                                world_size=processes, timeout=timedelta(seconds=timeout_s))
        from training.trainer import Trainer

        trainer = Trainer(cfg, resume=resume)
        try:
            first, last = _to_the_end(trainer, validate_first)
        finally:
            trainer.close()
        result: dict[str, Any] = {"first": first, "last": last}
    except MonoflowError as exc:
        result = {"error": str(exc)}
    except Exception as exc:  # a bug: keep where it happened, the caller prints one line and the file
        result = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, default=float))
    tmp.replace(out)
    if "error" in result:
        raise SystemExit(1)  # the spawner stops the other process instead of leaving it at a barrier


def fit_local(cfg: TrainConfig, processes: int, resume: bool = False, validate_first: bool = False,
              timeout_s: float = 600.0) -> tuple[dict | None, dict]:
    """Train ``cfg`` in ``processes`` data-parallel processes on this machine (one thread each, data loaded
    in-process; ``processes`` 1: in this process, with ``cfg``'s own threads and loader workers) and return
    rank 0's ``(first, last)``: the validation row before the first step (when
    ``validate_first`` and the run starts at step 0; else None) and :meth:`Trainer.fit`'s last row (the
    validation row when the run was already finished). ``resume`` as :class:`~training.trainer.Trainer`'s.
    ``optim.batch_size`` must divide by ``processes``. ``timeout_s``: the most any collective waits for the
    other processes. Raises :class:`ChildFailed` with the first failing process's message."""
    import torch.multiprocessing as mp

    if processes < 1:
        raise ValueError(f"fit_local needs at least 1 process, got {processes}")
    if processes == 1:
        from training.trainer import Trainer

        trainer = Trainer(cfg, resume=resume)
        try:
            return _to_the_end(trainer, validate_first)
        finally:
            trainer.close()
    cfg = replace(cfg, threads=1, data=replace(cfg.data, workers=0))
    with tempfile.TemporaryDirectory(prefix="monoflow-ddp-") as folder:
        try:
            mp.start_processes(_child, args=(cfg, processes, folder, resume, validate_first, timeout_s),
                               nprocs=processes, join=True, start_method="spawn")
        except mp.ProcessExitedException:
            pass  # the child's own message is in its result file
        results = {}
        for rank in range(processes):
            path = Path(folder) / f"result-{rank}.json"
            if path.exists():
                results[rank] = json.loads(path.read_text())
    for rank in sorted(results):
        if "error" in results[rank]:
            raise ChildFailed(f"training process {rank}: {results[rank]['error']}")
    if 0 not in results:
        raise ChildFailed("training process 0 stopped before it could report (killed, or it could not start: its "
                          "own error, if any, is printed above; spawned processes need the caller in a file, not stdin)")
    return results[0]["first"], results[0]["last"]
