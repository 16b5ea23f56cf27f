"""Benchmark: evaluation time per scene on CPU — the scene-flow net (paper size at 8192 points, the demo's
size, and the demo preset without and with its inference anchor) and the ICP / FGR baselines — through the real protocol (``run_protocol``: same sampled
points for every method, one untimed warm-up call, then the mean over scenes).

The scenes are a synthetic world's scene-flow test split (generated into a temporary folder unless
``--split`` is given). The nets are untrained (time does not depend on the weights) and restored from
checkpoints in the trainer's layout, as ``monoflow-evaluate`` does. Run from the repository root::

    .venv/bin/python benchmarks/bench_eval.py                    # 3 scenes, everything
    .venv/bin/python benchmarks/bench_eval.py --scenes 5 --threads 1
    .venv/bin/python benchmarks/bench_eval.py --split path/to/kitti_rm_ground

Prints a Markdown table; timings on a shared machine are noisy, so the load average is printed too.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _checkpoint(folder: Path, name: str, n_points: int, width_scale: float, preset: bool = False) -> Path:
    """An untrained net saved as the trainer saves one: the paper's form at ``n_points`` and ``width_scale``,
    or with ``preset`` the demo preset's (``training/presets.py``: ego head, votes, inference anchor)."""
    from dataclasses import asdict

    import torch

    from training.config import DataConfig, TrainConfig
    from training.model.halflownet_config import HALFlowConfig, level_points_for
    from training.model.registry import construct_model
    from training.presets import demo_train_config
    from training.runtime.checkpoints import save_checkpoint

    torch.manual_seed(0)
    if preset:
        cfg = demo_train_config("", str(folder / name), n_points=n_points, width_scale=width_scale)
        model = cfg.model
    else:
        model = HALFlowConfig(n_points=n_points, level_points=level_points_for(n_points), width_scale=width_scale)
        cfg = TrainConfig(model=model, data=DataConfig(n_points=n_points))
    net = construct_model(cfg.model_name, model)
    return save_checkpoint(folder / name / "latest.pt", {"kind": "flow", "model": net.state_dict(), "step": 0,
                                                         "config": asdict(cfg)})


def _split(args, tmp: Path):
    from evaluation.readers import load_split

    if args.split:
        split = load_split(args.split)
    else:
        from pipeline.synth.config import SynthConfig
        from pipeline.synth.generator import generate

        t0 = time.perf_counter()
        root = tmp / "world"
        generate(SynthConfig(n_sequences=0, test_frames=args.scenes + 1), root)
        print(f"(synthetic test split generated in {time.perf_counter() - t0:.0f} s: default 416x128 world)")
        split = load_split(root / "sceneflow" / "flownet3d")
    return dataclasses.replace(split, entries=split.entries[: args.scenes])


def machine_line(cuda: bool = False) -> str:
    """The header line of a timing table: torch, CPU, threads (and CUDA when asked), the load average now."""
    import torch

    return (f"torch {torch.__version__}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
            f"torch threads {torch.get_num_threads()}, " + (f"CUDA {torch.cuda.is_available()}, " if cuda else "")
            + f"load average {os.getloadavg()[0]:.2f}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--split", default="", help="a scene-flow split (default: a generated synthetic one)")
    p.add_argument("--scenes", type=int, default=3, help="scenes timed per method")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--skip-paper-net", action="store_true", help="leave out the paper-size net (slowest)")
    args = p.parse_args(argv)

    import numpy as np
    import torch

    from evaluation.methods import NetMethod, make_baseline
    from evaluation.protocols import ProtocolConfig, prepare_scene, run_protocol

    if args.threads:
        torch.set_num_threads(args.threads)
    print(machine_line())
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        split = _split(args, tmp)
        sizes = [len(s.pc1) for s in split]
        print(f"{len(split)} scenes of {split.root}: pc1 has {min(sizes)}–{max(sizes)} points")
        cases = []  # (label, methods, protocol config)
        if not args.skip_paper_net:
            paper = NetMethod(_checkpoint(tmp, "paper", 8192, 1.0), device="cpu", name="net, paper size (width 1)")
            cases.append(("8192 / 2048", [paper], ProtocolConfig(n_points=8192, n_score=2048)))
        demo = NetMethod(_checkpoint(tmp, "demo", 2048, 0.5), device="cpu", name="net, demo size (width 0.5)")
        preset = _checkpoint(tmp, "preset", 2048, 0.5, preset=True)  # the inference anchor's cost, both ways
        anchored = [NetMethod(preset, device="cpu", eval_anchor=a, name=f"net, demo preset{' anchored' if a else ''}")
                    for a in (False, True)]
        cases.append(("2048 / 512", [demo, *anchored], ProtocolConfig(n_points=2048, n_score=512)))
        baselines = [make_baseline(b) for b in ("icp-p2p", "icp-p2l", "fgr")]
        cases.append(("8192 / 2048", baselines, ProtocolConfig(n_points=8192, n_score=2048)))
        print("\n### Evaluation time per scene, CPU (fps protocol; mean over scenes after one warm-up call)\n")
        print("| method | points sampled / scored | s per scene | EPE3D (m) |")
        print("|---|---|---:|---:|")
        for label, methods, cfg in cases:
            for res in run_protocol(split, methods, cfg, progress=False):
                print(f"| {res.name} | {label} | {res.seconds_per_scene:.3f} | {res.metrics['EPE3D']:.3f} |",
                      flush=True)
        t0 = time.perf_counter()
        for s in split:
            prepare_scene(s, ProtocolConfig(n_points=8192, n_score=2048), 0)
        per = (time.perf_counter() - t0) / len(split)
        print(f"| (protocol: sampling + FPS of the scored points) | 8192 / 2048 | {per:.3f} | – |")
        n_params = sum(int(np.prod(t.shape)) for t in demo.net.state_dict().values())
        print(f"\ndemo net: {n_params / 1e6:.2f} M parameters"
              + ("" if args.skip_paper_net else
                 f"; paper net: {sum(int(np.prod(t.shape)) for t in paper.net.state_dict().values()) / 1e6:.2f} M"))
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
