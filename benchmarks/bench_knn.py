"""Benchmark: kNN backends at the net's sizes on CPU, FPS, and the scene-flow net's CPU forward time.

Prints Markdown tables (median of ``--repeats`` runs, milliseconds). Run from the repository root::

    .venv/bin/python benchmarks/bench_knn.py              # everything
    .venv/bin/python benchmarks/bench_knn.py --skip-net   # kNN and FPS only

Timings on a shared machine are noisy: the machine's load is printed with the tables.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable

# (label, queries M, references N, k): every kNN the net does at the paper's sizes, plus the 8192 case.
KNN_CASES: list[tuple[str, int, int, int]] = [
    ("8192 → 8192 (full cloud)", 8192, 8192, 32),
    ("set conv L0: 2048 in 8192", 2048, 8192, 32),
    ("set conv L1: 1024 in 2048", 1024, 2048, 24),
    ("set conv L2: 256 in 1024", 256, 1024, 16),
    ("set conv L3: 64 in 256", 64, 256, 16),
    ("set conv L4: 16 in 64", 16, 64, 8),
    ("cost volume L2: 256 in 256", 256, 256, 32),
    ("cost volume L1: 1024 in 1024", 1024, 1024, 6),
]


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * statistics.median(times)


def bench_knn(repeats: int, batch: int) -> None:
    import torch

    from training.knn import knn

    g = torch.Generator().manual_seed(0)
    extent = torch.tensor([20.0, 3.0, 35.0])  # a camera-frame box, metres
    print(f"\n### kNN on CPU, batch {batch} (median of {repeats}, ms)\n")
    print("| case | M | N | k | kdtree | cdist+topk | ratio |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for label, m, n, k in KNN_CASES:
        ref = torch.rand(batch, n, 3, generator=g) * extent
        query = ref[:, torch.randperm(n, generator=g)[:m]]
        kd = _median_ms(lambda: knn(query, ref, k, "kdtree"), repeats)
        dense = _median_ms(lambda: knn(query, ref, k, "torch"), repeats)
        print(f"| {label} | {m} | {n} | {k} | {kd:.2f} | {dense:.2f} | {dense / kd:.1f}× |")


def bench_fps(repeats: int) -> None:
    import torch

    from training.pointops import farthest_point_sample

    print(f"\n### Farthest point sampling on CPU (median of {repeats}, ms)\n")
    print("| batch | N → n | ms |")
    print("|---:|---|---:|")
    for batch, n, m in ((2, 8192, 2048), (10, 8192, 2048), (2, 2048, 1024)):
        pts = torch.rand(batch, n, 3) * 30
        print(f"| {batch} | {n} → {m} | {_median_ms(lambda: farthest_point_sample(pts, m), repeats):.1f} |")


def bench_net(repeats: int) -> None:
    import torch

    from training.model.halflownet import count_parameters
    from training.model.halflownet_config import HALFlowConfig
    from training.model.registry import construct_model

    print(f"\n### HALFlowNet forward on CPU, batch 1, 8192 points (median of {repeats}, ms)\n")
    print("| sampling | mode | ms |")
    print("|---|---|---:|")
    g = torch.Generator().manual_seed(0)
    pc1 = torch.rand(1, 8192, 3, generator=g) * torch.tensor([20.0, 3.0, 35.0])
    pc2 = pc1 + torch.tensor([0.0, 0.0, -0.5])
    rgb = torch.rand(1, 8192, 3, generator=g)
    for sampling in ("fps", "random"):
        net = construct_model("halflownet", HALFlowConfig(sampling=sampling))
        net.eval()
        with torch.no_grad():
            ms = _median_ms(lambda: net(pc1, pc2, rgb, rgb), repeats)
        print(f"| {sampling} | eval, no_grad | {ms:.0f} |")
        net.train()

        def step() -> None:
            out = net(pc1, pc2, rgb, rgb)
            sum(f.square().mean() for f in out.flows).backward()

        print(f"| {sampling} | train, forward+backward | {_median_ms(step, repeats):.0f} |")
    print(f"\nparameters at width_scale 1.0: {count_parameters(net):,}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per case (median reported)")
    parser.add_argument("--batch", type=int, default=1, help="batch size of the kNN cases")
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads and KD-tree workers (default: all cores for both)"
    )
    parser.add_argument("--skip-net", action="store_true", help="skip the network forward timing")
    args = parser.parse_args(argv)

    import scipy
    import torch

    import training.knn

    if args.threads:
        torch.set_num_threads(args.threads)
        training.knn.KDTREE_WORKERS = args.threads
    print(
        f"torch {torch.__version__}, scipy {scipy.__version__}, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, torch threads {torch.get_num_threads()}, KD-tree workers "
        f"{training.knn.kdtree_workers(training.knn.PARALLEL_MIN_NEIGHBOURS)}, load average {os.getloadavg()[0]:.2f}"
    )
    bench_knn(args.repeats, args.batch)
    bench_fps(args.repeats)
    if not args.skip_net:
        bench_net(args.repeats)
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
