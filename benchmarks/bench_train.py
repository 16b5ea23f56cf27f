"""Benchmark: one scene-flow training step, split into data, forward, losses, backward and optimiser step;
the loader's overhead; peak memory.

Two sizes (each in its own process, so peak RSS is that size's):

* ``paper``: 8192 points per cloud, batch 5, the full-width net (levels 2048/1024/256/64/16) — on a CPU
  only a few steps;
* ``demo``: what ``make demo`` trains: 2048 points, batch 4, width ×0.5, levels scaled.

The cache is the analytic street of :mod:`testkit.demo_scene` at 832×256 (≈100 k kept points per
cloud after its stand-in filters), written once to ``--workdir``. Loader overhead = mean step time with the
trainer's DataLoader reading the zarr cache ÷ mean step time on the same batches already in memory
(target ≤ 1.1). Peak memory: the process's peak RSS (ru_maxrss, includes torch), and tracemalloc's peak of
Python-level allocations (numpy arrays of the loader; torch's allocations are not traced). Run from the
repository root::

    .venv/bin/python benchmarks/bench_train.py                      # both sizes, CPU
    .venv/bin/python benchmarks/bench_train.py --size demo --steps 8 --workers 2 --threads 2
    .venv/bin/python benchmarks/bench_train.py --size paper --device cuda --steps 20
    .venv/bin/python benchmarks/bench_train.py --size demo --model ego_head=true l0_cost_volume=true  # the demo preset's net

Timings on a shared machine are noisy: load average and thread counts are printed with the table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SIZES = {
    "paper": dict(n_points=8192, batch=5, width_scale=1.0, level_points=(2048, 1024, 256, 64, 16)),
    "demo": dict(n_points=2048, batch=4, width_scale=0.5, level_points=None),  # levels: level_points_for(2048)
}
IMAGE = (256, 832)  # height, width
PAIRS = 16


def build_cache(workdir: Path) -> Path:
    """The 832×256 street cache (2 blocks of 8 pairs, with GT flow), reused when present."""
    from pipeline.cache import CacheWriter, cache_root
    from testkit.demo_scene import street_block

    config = {"size": [IMAGE[1], IMAGE[0]], "bench": "train"}
    root = cache_root(workdir, "street", config)
    if (root / "manifest.json").exists():
        return root
    w = CacheWriter(root, config, {"dataset": "demo_scene street"})
    for b in range(PAIRS // 8):
        if not w.has_block("00", b):
            w.write_block(street_block("00", b, 8, IMAGE[0], IMAGE[1]))
    w.finalize({"00": PAIRS // 8})
    return root


def _config(cache: Path, run_dir: Path, size: str, args):
    from training.config import DataConfig, OptimConfig, TrainConfig
    from training.model.halflownet_config import HALFlowConfig

    s = SIZES[size]
    levels = s["level_points"]
    if levels is None:
        levels = tuple(max(4, int(s["n_points"] * f)) for f in (0.25, 0.125, 1 / 32, 1 / 128, 1 / 512))
    return TrainConfig(cache=str(cache), run_dir=str(run_dir), steps=args.steps + 1, device=args.device,
                       threads=args.threads, amp=args.amp, log_every=10**6, val_every=10**6, ckpt_every=10**6,
                       progress=False, data=DataConfig(n_points=s["n_points"], workers=args.workers, val_fraction=0.0),
                       optim=OptimConfig(batch_size=s["batch"]),
                       model=HALFlowConfig(**{"n_points": s["n_points"], "level_points": levels,
                                              "width_scale": s["width_scale"], **_model_overrides(args.model)}))


def _model_overrides(items: list[str]) -> dict:
    """``["ego_head=true", "ego_sigma=0.2"]`` → HALFlowConfig fields (the learning curve's value parsing)."""
    from benchmarks.learning_curve import _coerce

    return {key: _coerce(value) for key, _, value in (item.partition("=") for item in items)}


def run_size(size: str, args) -> dict:
    """Time ``args.steps`` steps (after one warm-up) from the cache, then the same batches from memory."""
    import torch

    from training.data import LoadFailure
    from training.trainer import Trainer

    cache = build_cache(Path(args.workdir))
    tracemalloc.start()
    trainer = Trainer(_config(cache, Path(args.workdir) / f"run-{size}", size, args))
    keep: list = []
    phases: dict[str, list[float]] = {k: [] for k in ("data", "forward", "loss", "backward", "optim", "step")}
    t_data = time.perf_counter()
    for i, batch in enumerate(trainer._loader()):
        if isinstance(batch, LoadFailure):
            raise batch.error()
        batch = batch.to(trainer.device)
        data = time.perf_counter() - t_data
        row = trainer.train_step(batch)
        keep.append(batch)
        if i > 0:  # the first step warms up allocators, threads and the workers
            for k in ("forward", "loss", "backward", "optim"):
                phases[k].append(row[f"time_{k}"])
            phases["data"].append(data)
            phases["step"].append(time.perf_counter() - t_data)
        t_data = time.perf_counter()
    _, py_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    in_memory = []
    for batch in keep[1:]:
        t = time.perf_counter()
        trainer.train_step(batch)
        in_memory.append(time.perf_counter() - t)
    trainer.close()
    mean = {k: statistics.mean(v) for k, v in phases.items()}
    gpu_peak = torch.cuda.max_memory_allocated() / 2**20 if trainer.device.type == "cuda" else None
    return {"size": size, "steps": len(phases["step"]), **{f"{k}_s": v for k, v in mean.items()},
            "in_memory_step_s": statistics.mean(in_memory), "loader_overhead": mean["step"] / statistics.mean(in_memory),
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "tracemalloc_peak_mib": py_peak / 2**20,
            "gpu_peak_mib": gpu_peak, "threads": torch.get_num_threads(), "workers": args.workers,
            "device": str(trainer.device)}


def _table(results: list[dict]) -> None:
    print(f"\n### Training step ({platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}; mean of the timed steps after one warm-up, seconds)\n")
    print("| size | device | steps | data | forward (2 passes) | losses | backward | optim | step | in-memory step "
          "| loader overhead | peak RSS MiB | tracemalloc peak MiB | GPU peak MiB |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in results:
        gpu = f"{r['gpu_peak_mib']:.0f}" if r["gpu_peak_mib"] is not None else "–"
        print(f"| {r['size']} | {r['device']}, {r['threads']} thr, {r['workers']} workers | {r['steps']} "
              f"| {r['data_s']:.3f} | {r['forward_s']:.3f} | {r['loss_s']:.3f} | {r['backward_s']:.3f} "
              f"| {r['optim_s']:.3f} | {r['step_s']:.3f} | {r['in_memory_step_s']:.3f} | {r['loader_overhead']:.3f} "
              f"| {r['peak_rss_mib']:.0f} | {r['tracemalloc_peak_mib']:.0f} | {gpu} |")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", choices=("paper", "demo", "both"), default="both")
    p.add_argument("--steps", type=int, default=3, help="timed steps (one more runs first as warm-up)")
    p.add_argument("--workers", type=int, default=1, help="DataLoader workers")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch's default)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--amp", action="store_true", help="bf16 autocast (CUDA only)")
    p.add_argument("--workdir", default=str(REPO / "cache" / "bench_train"))
    p.add_argument("--json", action="store_true", help="print one JSON line per size instead of the table")
    p.add_argument("--model", nargs="*", default=[], help="HALFlowConfig fields key=value (e.g. l0_cost_volume=true)")
    args = p.parse_args(argv)
    sys.path.insert(0, str(REPO))
    if args.size != "both":
        result = run_size(args.size, args)
        print(json.dumps(result) if args.json else "", flush=True)
        if not args.json:
            _table([result])
        return 0
    results = []
    for size in ("demo", "paper"):  # one process each: ru_maxrss is a per-process peak
        cmd = [sys.executable, __file__, "--size", size, "--json", "--steps", str(args.steps), "--workers",
               str(args.workers), "--threads", str(args.threads), "--device", args.device, "--workdir", args.workdir,
               "--model", *args.model]
        if args.amp:
            cmd.append("--amp")
        out = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=True)
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    _table(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
