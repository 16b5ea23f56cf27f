"""Benchmark: the demo preset's training step in one process of T threads against P data-parallel processes of
one thread each (:func:`training.runtime.local_ddp.fit_local`, what ``make demo`` trains with).

Each setting trains ``--short`` and then ``--long`` steps from scratch on the same cache; the time per step is
(wall time of the long run − wall time of the short one) / (long − short), so the start-up (imports, spawning,
the first steps' allocations) cancels. Validation and checkpoints are left to the end of the runs (one each).
The cache is the analytic street of :mod:`testkit.demo_scene` (the one ``bench_train.py`` builds), or
``--cache``. Run from the repository root::

    OMP_WAIT_POLICY=PASSIVE .venv/bin/python benchmarks/bench_train_processes.py
    OMP_WAIT_POLICY=PASSIVE .venv/bin/python benchmarks/bench_train_processes.py --cache cache/demo/cache/world_varied/<hash>

Timings on a shared machine are noisy: the settings run in turn, ``--rounds`` times, and every round is printed.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _fit_seconds(cache: str, run_dir: Path, steps: int, processes: int, threads: int) -> float:
    from training.presets import demo_train_config
    from training.runtime.local_ddp import fit_local

    shutil.rmtree(run_dir, ignore_errors=True)
    cfg = demo_train_config(cache, str(run_dir), steps, overrides={
        "progress": False, "val_every": steps, "ckpt_every": steps, "log_every": steps, "threads": threads})
    t = time.perf_counter()
    fit_local(cfg, processes)
    return time.perf_counter() - t


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", default=None, help="a stage-one cache (default: bench_train.py's street cache)")
    p.add_argument("--short", type=int, default=4, help="steps of the short run")
    p.add_argument("--long", type=int, default=24, help="steps of the long run")
    p.add_argument("--threads", type=int, default=2, help="threads of the one-process setting")
    p.add_argument("--processes", type=int, default=2, help="processes of the data-parallel setting")
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--workdir", default=str(REPO / "cache" / "bench_train"))
    args = p.parse_args(argv)
    sys.path.insert(0, str(REPO))
    cache = args.cache
    if cache is None:
        from benchmarks.bench_train import build_cache

        cache = str(build_cache(Path(args.workdir)))
    settings = [(f"1 process, {args.threads} threads", 1, args.threads),
                (f"{args.processes} processes, 1 thread each", args.processes, 1)]
    print(f"\n### Demo preset training step ({platform.machine()}, {os.cpu_count()} cores, load "
          f"{os.getloadavg()[0]:.1f}; seconds per step from {args.long} − {args.short} steps)\n")
    print("| round | " + " | ".join(name for name, _, _ in settings) + " | ratio |")
    print("|---|" + "---:|" * (len(settings) + 1))
    for r in range(args.rounds):
        per_step = []
        for name, procs, threads in settings:
            run = Path(args.workdir) / f"procs-{procs}"
            short = _fit_seconds(cache, run, args.short, procs, threads)
            long = _fit_seconds(cache, run, args.long, procs, threads)
            per_step.append((long - short) / (args.long - args.short))
        print(f"| {r + 1} | " + " | ".join(f"{s:.3f}" for s in per_step) + f" | {per_step[0] / per_step[1]:.2f} |",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
