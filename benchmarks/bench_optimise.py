"""Benchmark: time per scene of the label-free per-scene optimisation — the NSFP baseline (at the demo's
60-step budget, and at its authors' settings stopped when it has used as much time per scene as the demo's
"ours + refinement" row: the comparison at equal time on whatever device runs it), the rigid polish
of the view-pruned net's flow (and of the net's own, without the pruning's second pass) and the test-time
refinement of the polished and of the view-pruned flow
(evaluation/optimise, evaluation/rigid_polish.py, evaluation/view_prune.py) — through the
real protocol (``run_protocol``: same sampled points for every method, one untimed warm-up call, then the
mean over scenes), on CPU and, when one is present, on CUDA.

The scenes are a synthetic world's scene-flow test split (generated into a temporary folder unless
``--split`` is given). The refined net is an untrained demo-size net unless ``--checkpoint`` is given
(time hardly depends on the weights; quality does, so EPE3D is only meaningful with a trained net).
Run from the repository root::

    .venv/bin/python benchmarks/bench_optimise.py                      # 3 scenes, 2048 points, CPU (+ CUDA)
    .venv/bin/python benchmarks/bench_optimise.py --split /tmp/demo/world/sceneflow/flownet3d \\
        --checkpoint /tmp/demo/flow_run_gt/latest.pt --scenes 19 --threads 2
    .venv/bin/python benchmarks/bench_optimise.py ... --nsfp-full   # + NSFP at its authors' settings, unlimited

Prints a Markdown table; timings on a shared machine are noisy, so the load average is printed too.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_eval import _checkpoint, _split, machine_line  # noqa: E402  (same split, checkpoint, header)

if TYPE_CHECKING:
    from evaluation.protocols import MethodResult


def _row(device: str, res: MethodResult, method: object) -> None:
    """One Markdown row: device, method, s per scene, EPE3D, Adam steps of the last scene (or –)."""
    last = getattr(method, "last", None)
    its = str(last.iterations) if last is not None else "–"
    print(f"| {device} | {res.name} | {res.seconds_per_scene:.3f} | {res.metrics['EPE3D']:.3f} | {its} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--split", default="", help="a scene-flow split (default: a generated synthetic one)")
    p.add_argument("--checkpoint", default="", help="trained flow net to refine (default: an untrained demo-size net)")
    p.add_argument("--scenes", type=int, default=3, help="scenes timed per method")
    p.add_argument("--n-points", type=int, default=2048, help="points per cloud (the demo's 2048)")
    p.add_argument("--n-score", type=int, default=512, help="scored points")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--devices", default="cpu,cuda", help="comma list; cuda is skipped when unavailable")
    p.add_argument("--nsfp-full", action="store_true",
                   help="also NSFP at its authors' settings without a time limit (tens of seconds per scene on a CPU)")
    args = p.parse_args(argv)

    import torch

    from evaluation.methods import NetMethod
    from evaluation.optimise import NSFPConfig, NSFPMethod, RefineConfig, RefinedMethod
    from evaluation.protocols import ProtocolConfig, run_protocol
    from evaluation.rigid_polish import rigid_polished
    from evaluation.view_prune import view_pruned

    if args.threads:
        torch.set_num_threads(args.threads)
    print(machine_line(cuda=True))
    devices = [d for d in args.devices.split(",") if d == "cpu" or (d == "cuda" and torch.cuda.is_available())]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        args.scenes = max(1, args.scenes)
        split = _split(args, tmp)  # already cut to args.scenes
        ckpt = args.checkpoint or str(_checkpoint(tmp, "demo", args.n_points, 0.5))
        cfg = ProtocolConfig(n_points=args.n_points, n_score=args.n_score)
        print(f"{len(split)} scenes of {split.root}; {args.n_points} points sampled, {args.n_score} scored; "
              f"net {'trained: ' + args.checkpoint if args.checkpoint else 'untrained (demo size)'}")
        print("\n### Label-free per-scene optimisation, time per scene (mean after one warm-up call)\n")
        print("| device | method | s per scene | EPE3D (m) | iterations (last scene) |")
        print("|---|---|---:|---:|---:|")
        for dev in devices:
            net = NetMethod(ckpt, device=dev, name="ours")
            pruned = view_pruned(net)
            polished = rigid_polished(pruned)  # the demo's "+ view pruning + rigid polish (+ refinement)" rows
            direct = rigid_polished(net)  # the same without the second pass of the view pruning
            # the demo's row: a registered ego-motion is refined with after_registration
            demo = RefinedMethod(polished, RefineConfig.after_registration(device=dev))
            methods = [net, pruned, polished, direct, NSFPMethod(NSFPConfig(device=dev)), demo,
                       RefinedMethod(direct, RefineConfig.after_registration(device=dev)),
                       RefinedMethod(pruned, RefineConfig(device=dev))]
            results = run_protocol(split, methods, cfg, progress=False)
            for res, m in zip(results, methods):
                _row(dev, res, m)
            # NSFP at its authors' settings, given the time per scene the demo's row took (same points)
            demo_row = next(r for r, m in zip(results, methods) if m is demo)
            matched = NSFPMethod(NSFPConfig.published(device=dev, time_budget=demo_row.seconds_per_scene),
                                 name=f"nsfp-full, stopped at the demo's row's {demo_row.seconds_per_scene:.3f} s")
            extra = [matched] + ([NSFPMethod(NSFPConfig.published(device=dev), name="nsfp-full")]
                                 if args.nsfp_full else [])
            for res, m in zip(run_protocol(split, extra, cfg, progress=False), extra):
                _row(dev, res, m)
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
