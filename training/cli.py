"""``monoflow-train``: train the scene-flow net on a stage-one cache.

Example::

    monoflow-train --cache cache/synthetic/<hash> --run_dir runs/demo --steps 200 --model.width_scale 0.25
    monoflow-train --config my_run.toml --resume          # continue from runs/.../latest.pt
    torchrun --nproc_per_node 4 -m training --cache ... --optim.batch_size 20   # data parallel
"""

from __future__ import annotations

import argparse

from pipeline.errors import run_cli


def build_parser() -> argparse.ArgumentParser:
    from pipeline.options import add_dataclass_args
    from training.config import TrainConfig

    p = argparse.ArgumentParser(prog="monoflow-train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--config", help="TOML file with options (flags override it)")
    p.add_argument("--resume", action="store_true", help="continue from <run_dir>/latest.pt when present")
    add_dataclass_args(p, TrainConfig)
    return p


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    from pipeline.options import build_config
    from training.config import TrainConfig
    from training.trainer import Trainer

    cfg = build_config(TrainConfig, args, args.config)
    trainer = Trainer(cfg, resume=args.resume)
    try:
        last = trainer.fit()
    finally:
        trainer.close()
    if trainer.dist.is_main:
        shown = {k: round(v, 5) for k, v in last.items() if k in ("step", "loss", "val_epe3d", "val_loss")}
        print(f"done: {trainer.step} steps in {trainer.run_dir} — {shown}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
