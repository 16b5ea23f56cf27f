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
import ast
import dataclasses
from pathlib import Path

from pipeline.errors import run_cli

_PACKAGE_ROOT = Path(__file__).resolve().parents[1]


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


def build_parser() -> argparse.ArgumentParser:
    """The parser, with one flag per (nested) field of :class:`training.config.TrainConfig`."""
    from pipeline.options import add_dataclass_args
    from training.config import TrainConfig

    p = _new_parser()
    _describe(p)
    add_dataclass_args(p, TrainConfig)
    return p


# ---------------------------------------------------------------------------------------------- --help
# TrainConfig nests HALFlowConfig and LossWeights, whose modules import torch (≈2 s). ``--help`` only
# needs field names and defaults, so it reads them from the source (ast, nothing executed) and builds the
# same flags on look-alike dataclasses; tests/test_trainer_cli.py checks both parsers agree flag by flag.


def _module_file(module: str) -> Path:
    path = _PACKAGE_ROOT.joinpath(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def _classes(module: str) -> tuple[dict[str, ast.ClassDef], dict[str, str]]:
    """A module's top-level class definitions and where its ``from X import Name`` names come from."""
    tree = ast.parse(_module_file(module).read_text())
    classes = {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}
    imported = {a.asname or a.name: n.module for n in tree.body if isinstance(n, ast.ImportFrom) and n.module
                for a in n.names}
    return classes, imported


def _lookalike(name: str, module: str):
    """A dataclass with the fields and defaults of dataclass ``name`` of ``module``, built from source."""
    classes, imported = _classes(module)
    if name not in classes:
        return _lookalike(name, imported[name])
    fields = []
    for node in classes[name].body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value is not None):
            continue
        value = node.value
        if isinstance(value, ast.Call) and getattr(value.func, "id", "") == "field":
            factory = next(k.value.id for k in value.keywords if k.arg == "default_factory")
            nested = _lookalike(factory, module)
            fields.append((node.target.id, nested, dataclasses.field(default_factory=nested)))
        else:
            default = ast.literal_eval(value)
            fields.append((node.target.id, type(default), dataclasses.field(default=default)))
    # the docstring travels along: the help texts come from it (pipeline.options.field_docs)
    return dataclasses.make_dataclass(name, fields, namespace={"__doc__": ast.get_docstring(classes[name])})


def build_help_parser() -> argparse.ArgumentParser:
    """The parser of :func:`build_parser` (same flags, same help text), built without importing torch."""
    from pipeline.options import add_dataclass_args

    p = _new_parser()
    _describe(p)
    add_dataclass_args(p, _lookalike("TrainConfig", "training.config"))
    return p


def _main(argv: list[str] | None) -> int:
    import sys

    args_in = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help") for a in args_in):
        try:
            parser = build_help_parser()
        except (ValueError, KeyError, StopIteration, SyntaxError, OSError, TypeError):
            parser = build_parser()  # a default the source reader cannot evaluate: the slow, exact way
        parser.parse_args(["--help"])  # prints and exits
    args = build_parser().parse_args(argv)
    from pipeline.options import build_config
    from training.config import TrainConfig
    from training.trainer import Trainer

    apply_n_points(args)
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
    return 0


def apply_n_points(args: argparse.Namespace) -> None:
    """``--n_points N``: data.n_points, model.n_points and model.level_points from one flag (explicit ones win)."""
    n = getattr(args, "n_points", None)
    if n is None:
        return
    from training.config import level_points_for

    for key, value in (("data.n_points", n), ("model.n_points", n), ("model.level_points", level_points_for(n))):
        if getattr(args, key, None) is None:
            setattr(args, key, value)


#: Files whose presence means a run folder already holds a run.
RUN_MARKERS = ("latest.pt", "train.csv", "train.jsonl", "best.pt")


def check_run_dir(run_dir: str | Path, resume: bool, overwrite: bool, markers: tuple[str, ...] = RUN_MARKERS) -> None:
    """ConfigError when ``run_dir`` already holds a run and neither ``--resume`` nor ``--overwrite`` was given."""
    from pipeline.errors import ConfigError

    run = Path(run_dir)
    found = [m for m in markers if (run / m).exists()]
    if found and not (resume or overwrite):
        raise ConfigError(f"{run}: already holds a run ({', '.join(found)}); pass --resume to continue it or "
                          "--overwrite to replace it")


def main(argv: list[str] | None = None) -> int:
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
