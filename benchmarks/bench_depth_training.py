"""Benchmark: self-supervised depth/pose training throughput (snippets per second), CPU by default.

One training step = DispResNet-18 on the 3 frames of every snippet + PoseResNet-18 on 4 directed pairs +
SC-SfMLearner's loss + backward + Adam, exactly as ``training.depth.trainer`` runs it (data loading excluded:
the snippets are random uint8 frames already in memory). Run from the repository root::

    .venv/bin/python benchmarks/bench_depth_training.py                         # 128×64 and 416×128, batch 4
    .venv/bin/python benchmarks/bench_depth_training.py --sizes 832x256 --device cuda --steps 20

Prints a Markdown table (median step time over ``--steps`` after one warm-up step). Timings on a shared
machine are noisy: the load average is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time


def bench(size: str, batch: int, steps: int, device: str, scale_mode: str, num_scales: int) -> tuple[float, float]:
    import torch

    from pipeline.nets import DispResNet, PoseResNet
    from training.depth.config import DepthLossConfig
    from training.depth.data import SnippetBatch
    from training.depth.losses import snippet_loss
    from training.depth.trainer import forward_snippets, freeze_unused

    W, H = (int(x) for x in size.lower().split("x"))
    dev = torch.device(device)
    torch.manual_seed(0)
    depth, pose = DispResNet(18).to(dev).train(), PoseResNet(18).to(dev).train()
    freeze_unused(depth, pose, num_scales)
    params = [p for m in (depth, pose) for p in m.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=1e-4)
    cfg = DepthLossConfig(num_scales=num_scales, scale_mode=scale_mode)
    g = torch.Generator().manual_seed(0)
    images = torch.randint(0, 256, (batch, 3, 3, H, W), dtype=torch.uint8, generator=g)
    K = torch.tensor([[0.58 * W, 0, W / 2 - 0.5], [0, 1.92 * H, H / 2 - 0.5], [0, 0, 1]]).expand(batch, 3, 3)
    batch_data = SnippetBatch(images=images, K=K.contiguous(), index=torch.arange(batch)).to(dev)
    times = []
    for i in range(steps + 1):
        if dev.type == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        total, _ = snippet_loss(forward_snippets(depth, pose, batch_data), cfg)
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()
        if dev.type == "cuda":
            torch.cuda.synchronize()
        if i:
            times.append(time.perf_counter() - t)
    step = statistics.median(times)
    return step, batch / step


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="128x64,416x128", help="comma-separated WxH working sizes")
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch's default)")
    p.add_argument("--scale_mode", default="upsample", choices=("upsample", "downsample"))
    p.add_argument("--num_scales", type=int, default=1)
    a = p.parse_args()
    import torch

    if a.threads:
        torch.set_num_threads(a.threads)
    print(f"\n### Depth/pose training step, {a.device}, batch {a.batch}, {a.num_scales} scale(s) {a.scale_mode} "
          f"(median of {a.steps})\n")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {platform.processor() or platform.machine()}, "
          f"load average {os.getloadavg()[0]:.2f}\n")
    print("| size | batch | s / step | snippets / s |")
    print("|---|---:|---:|---:|")
    for size in a.sizes.split(","):
        step, rate = bench(size, a.batch, a.steps, a.device, a.scale_mode, a.num_scales)
        print(f"| {size} | {a.batch} | {step:.3f} | {rate:.2f} |", flush=True)


if __name__ == "__main__":
    main()
