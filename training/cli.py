"""``monoflow-train``: train the scene-flow net on a stage-one cache.

Example::

    monoflow-train --cache cache/synthetic/<hash> --run_dir runs/demo --steps 200 --model.width_scale 0.25
    monoflow-train --config my_run.toml --resume          # continue from runs/.../latest.pt
    torchrun --nproc_per_node 4 -m training --cache ... --optim.batch_size 20   # data parallel, global batch 20

Bad input (a corrupt or version-mismatched cache or checkpoint) stops with ``error: <file>: <problem>``
and exit code 2; so does a diverging run (non-finite loss), which keeps its last good checkpoint.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from core.errors import run_cli


def _describe(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="TOML file with options (flags override it)")
    p.add_argument("--resume", action="store_true", help="continue from <run_dir>/latest.pt when present")
    p.add_argument("--overwrite", action="store_true",
                   help="train into a run folder that already holds a run, replacing it (default: refuse)")
    p.add_argument("--n_points", "--n-points", dest="n_points", type=int, default=None, metavar="INT",
                   help="points per cloud in one flag: sets data.n_points, model.n_points and model.level_points "
                        "(the paper's 8192 -> 2048/1024/256/64/16, scaled) unless those are given too")


def _new_parser() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(prog="monoflow-train", allow_abbrev=False, description=__doc__.split("\n\n")[0],
                                   formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)


def model_name_in(argv: list[str] | None) -> str:
    """The net ``argv`` trains: ``--model_name``, else the ``--config`` file's ``model_name``, else the
    default (the ``--model.*`` flags are that net's)."""
    from core.options import load_toml
    from training.model.registry import DEFAULT_NET

    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--config")
    pre.add_argument("--model_name", "--model-name")
    known, _ = pre.parse_known_args(argv or [])
    if known.model_name:
        return known.model_name
    return str((load_toml(known.config) if known.config else {}).get("model_name") or DEFAULT_NET)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser, with one flag per (nested) field of :class:`training.config.TrainConfig`, the ``--model.*``
    ones of the net ``argv`` names (:func:`model_name_in`). Imports no torch (the configs are torch-free),
    so ``--help`` is instant."""
    from core.options import add_dataclass_args
    from training.config import TrainConfig

    p = _new_parser()
    _describe(p)
    add_dataclass_args(p, TrainConfig, values={"model_name": model_name_in(argv)})
    return p


build_help_parser = build_parser  # the name ``--help`` used while the real parser imported torch


def _main(argv: list[str] | None) -> int:
    import sys

    args_in = sys.argv[1:] if argv is None else argv
    args = build_parser(args_in).parse_args(args_in)
    from core.options import build_config
    from training.config import TrainConfig
    from training.trainer import Trainer

    apply_n_points(args, model_name_in(args_in))
    cfg = build_config(TrainConfig, args, args.config)
    check_run_dir(cfg.run_dir, resume=args.resume, overwrite=args.overwrite)
    trainer = Trainer(cfg, resume=args.resume)
    try:
        last = trainer.fit()
    finally:
        trainer.close()
    if trainer.dist.is_main:
        shown = {k: round(float(last[k]), 5) for k in ("loss", "val_epe3d", "val_loss") if k in last}
        print(f"done: {trainer.step} steps in {trainer.run_dir} — {shown}")
        summary = trainer.selection_summary()
        if summary:
            print(summary)
    return 0


def apply_n_points(args: argparse.Namespace, model_name: str | None = None) -> None:
    """``--n_points N``: data.n_points and the net's point fields (model.n_points, and model.level_points for
    HALFlowNet: :meth:`~training.model.contract.FlowNetConfig.points_fields`) from one flag (explicit ones win)."""
    n = getattr(args, "n_points", None)
    if n is None:
        return
    from training.model.registry import DEFAULT_NET, config_class

    name = model_name or getattr(args, "model_name", None) or DEFAULT_NET
    fields: dict[str, Any] = {f"model.{k}": v for k, v in config_class(name).points_fields(n).items()}
    for key, value in {"data.n_points": n, **fields}.items():
        if getattr(args, key, None) is None:
            setattr(args, key, value)


#: Files whose presence means a run folder already holds a run.
RUN_MARKERS = ("latest.pt", "train.csv", "train.jsonl", "best.pt")


def check_run_dir(run_dir: str | Path, resume: bool, overwrite: bool, markers: tuple[str, ...] = RUN_MARKERS) -> None:
    """ConfigError when ``run_dir`` already holds a run and neither ``--resume`` nor ``--overwrite`` was given."""
    from core.errors import ConfigError

    run = Path(run_dir)
    found = [m for m in markers if (run / m).exists()]
    if found and not (resume or overwrite):
        raise ConfigError(f"{run}: already holds a run ({', '.join(found)}); pass --resume to continue it or "
                          "--overwrite to replace it")


def main(argv: list[str] | None = None) -> int:
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
