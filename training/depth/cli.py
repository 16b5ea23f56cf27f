"""``monoflow-train-depth``: self-supervised training of stage one's depth and pose nets (SC-SfMLearner).

Examples::

    monoflow-train-depth --data.root cache/synth --data.val_sequences 02 --run_dir runs/depth --steps 2000
    monoflow-train-depth --preset demo --data.root cache/synth --run_dir runs/depth-demo
    monoflow-train-depth --config depth.toml --resume            # continue from <run_dir>/latest.pt
    monoflow-train-depth --eval_only --data.root cache/synth --data.val_sequences 02 --run_dir runs/depth
    torchrun --nproc_per_node 4 -m training.depth --data.root /data/kitti_odometry --optim.batch_size 16

The official-format checkpoints (``dispnet_checkpoint.pth.tar``, ``exp_pose_checkpoint.pth.tar`` and the
``*_model_best.pth.tar`` pair) in the run folder load into ``monoflow-preprocess`` like the released weights.
Precedence: preset (or defaults) < ``--config`` TOML < flags.
"""

from __future__ import annotations

import argparse
import json
import sys

from core.errors import run_cli

PRESETS = ("demo", "tiny")


def build_parser() -> argparse.ArgumentParser:
    from core.options import add_dataclass_args
    from training.depth.config import DepthTrainConfig

    p = argparse.ArgumentParser(prog="monoflow-train-depth", allow_abbrev=False, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--config", help="TOML file with options (flags override it)")
    p.add_argument("--preset", choices=PRESETS, help="start from a preset: demo (make demo DEPTH=learned) or tiny")
    p.add_argument("--resume", action="store_true", help="continue from <run_dir>/latest.pt when present")
    p.add_argument("--overwrite", action="store_true",
                   help="train into a run folder that already holds a run, replacing it (default: refuse)")
    p.add_argument("--eval_only", action="store_true",
                   help="score checkpoints on data.val_sequences (all sequences when empty) instead of training")
    p.add_argument("--disp_checkpoint", help="--eval_only: depth checkpoint (default: the run folder's best, else last)")
    p.add_argument("--pose_checkpoint", help="--eval_only: pose checkpoint (default: the run folder's best, else last)")
    p.add_argument("--output", help="--eval_only: also write the metrics to this JSON file")
    add_dataclass_args(p, DepthTrainConfig)
    return p


def resolve_config(args: argparse.Namespace):
    """The run's :class:`DepthTrainConfig`: preset (or defaults) < TOML < flags."""
    from core.options import build_config
    from training.depth.config import DepthTrainConfig, demo_config, tiny_config

    preset = None
    if args.preset:
        base = DepthTrainConfig()
        preset = (demo_config if args.preset == "demo" else tiny_config)(base.data.root, base.run_dir)
    return build_config(DepthTrainConfig, args, args.config, base=preset)


def _checkpoint_paths(args, cfg) -> tuple[str, str]:
    from pathlib import Path

    from training.depth.trainer import DISP_BEST, DISP_CHECKPOINT, POSE_BEST, POSE_CHECKPOINT

    run = Path(cfg.run_dir)
    best = (run / DISP_BEST).is_file()
    disp = args.disp_checkpoint or str(run / (DISP_BEST if best else DISP_CHECKPOINT))
    pose = args.pose_checkpoint or str(run / (POSE_BEST if (run / POSE_BEST).is_file() else POSE_CHECKPOINT))
    return disp, pose


def _evaluate(args, cfg) -> int:
    from pipeline.kitti.odometry import find_sequences
    from training.depth.data import check_size, expand_ids
    from training.depth.evaluate import evaluate_checkpoints
    from training.runtime.device import resolve_device

    disp, pose = _checkpoint_paths(args, cfg)
    wanted = tuple(s for s in cfg.data.val_sequences if str(s) != "none")
    seqs = expand_ids(cfg.data.root, wanted) or find_sequences(cfg.data.root)
    hw = check_size(cfg.data.width, cfg.data.height)
    metrics = evaluate_checkpoints(disp, pose, cfg.data.root, seqs, cfg.data.camera, hw, cfg.eval,
                                   resolve_device(cfg.device))
    report = {"disp_checkpoint": disp, "pose_checkpoint": pose, "sequences": seqs, "metrics": metrics}
    text = json.dumps(report, indent=2, sort_keys=True)
    print(text)
    if args.output:
        from pathlib import Path

        Path(args.output).write_text(text + "\n")
    return 0


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    cfg = resolve_config(args)
    if args.eval_only:
        return _evaluate(args, cfg)
    from training.depth.trainer import DepthTrainer

    from training.cli import check_run_dir

    check_run_dir(cfg.run_dir, resume=args.resume, overwrite=args.overwrite,
                  markers=("latest.pt", "train.csv", "dispnet_checkpoint.pth.tar"))
    trainer = DepthTrainer(cfg, resume=args.resume)
    try:
        last = trainer.fit()
        if trainer.step == 0:
            trainer.save()
    finally:
        trainer.close()
    if trainer.dist.is_main:
        shown = {k: round(v, 5) for k, v in last.items()
                 if k in ("loss", "photo", "val_loss", "val_abs_rel", "val_ate", "val_rot_err_deg")}
        ck = trainer.checkpoints()
        print(f"done: {trainer.step} steps in {trainer.run_dir} — {shown}\n"
              f"checkpoints: {ck.disp} {ck.pose}", file=sys.stdout)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
