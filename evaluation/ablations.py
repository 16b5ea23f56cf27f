"""The paper's ablations as one command: Table II (drop each loss) and Table III (ground / sky kept).

Every variant is preprocessed (Table III changes stage one's filters), trained with the same budget and
seed, and scored on the same test split with the same protocol; the tables have the shape of Table I.

    monoflow-evaluate ablations --world cache/demo/world --out runs/ablations --steps 300

Stage one runs on the world's *training* sequences only (a synthetic world's ``synth.json`` names its
test sequence, whose scene-flow pairs form the test split; they are never trained on). Work is reused
when rerun: a cache is keyed by its stage-one config (pipeline's config hash), a run folder by
everything that shapes its training (cache, budget, seed, net, loss switches), so identical variants —
Table II's full model and Table III's "without ground or sky" — share one run, and a rerun with the same
settings evaluates the existing checkpoints instead of training again.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from core.errors import ConfigError
from training.model.halflownet_config import level_points_for  # noqa: F401  (re-exported for the tests and tools)
from training.model.registry import DEFAULT_NET, config_class

# Table II (paper order): each row drops one of the four losses; the last is the full loss.
LOSS_VARIANTS: dict[str, dict[str, bool]] = {
    "DSC + Cha + LR (w/o Depth)": {"use_depth": False},
    "Depth + Cha + LR (w/o DSC)": {"use_ds": False},
    "Depth + DSC + LR (w/o Cha)": {"use_chamfer": False},
    "Depth + DSC + Cha (w/o LR)": {"use_laplacian": False},
    "Depth + DSC + Cha + LR (full)": {},
}
# Table III: "with ground" keeps the ground (only sky removed); "with sky" keeps the sky (only ground
# removed); "without ground or sky" is the full pipeline. Stage one's other filters (LiDAR range,
# occlusion) stay on in every row, as in the paper.
FILTER_VARIANTS: dict[str, dict[str, bool]] = {
    "with ground": {"ground": False},
    "with sky": {"far": False},
    "without ground or sky": {},
}
TABLES = ("II", "III")


@dataclass
class AblationConfig:
    """One ablation study. Sizes: ``size`` is stage one's working image size (WxH); ``n_points`` the
    points per cloud in training and evaluation; ``width_scale`` the net's width (1 = paper); ``model_name``
    the flow net (:mod:`training.model.registry`)."""

    world: str = "cache/demo/world"
    split: str = ""  # default: <world>/sceneflow/flownet3d
    out: str = "runs/ablations"
    tables: tuple[str, ...] = TABLES
    sequences: tuple[str, ...] = ()  # default: the world's training sequences (synth.json), else all
    steps: int = 200
    seed: int = 0
    size: str = "416x128"
    depth: str = "gt"
    pose: str = "gt"
    n_points: int = 2048
    width_scale: float = 0.25
    model_name: str = DEFAULT_NET
    batch_size: int = 4
    max_scenes: int = 0
    device: str = "auto"

    def validate(self) -> "AblationConfig":
        unknown = [t for t in self.tables if t not in TABLES]
        if unknown or not self.tables:
            raise ConfigError(f"--tables takes II and/or III, got {','.join(self.tables) or 'nothing'}")
        if self.steps < 1 or self.batch_size < 1 or self.max_scenes < 0:
            raise ConfigError("steps and batch size must be >= 1 and max scenes >= 0")
        if self.n_points < 128:
            raise ConfigError(f"n_points must be >= 128 (five levels down to 4 points), got {self.n_points}")
        config_class(self.model_name)  # an unknown net is refused before any work
        return self


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", default="cache/demo/world", help="KITTI-layout dataset root (synthetic world)")
    p.add_argument("--split", default="", help="test split (default <world>/sceneflow/flownet3d)")
    p.add_argument("--out", default="runs/ablations", help="folder for the tables, runs and caches of the variants")
    p.add_argument("--tables", default="II,III", help="II (losses), III (ground/sky), or both")
    p.add_argument("--sequences", default="",
                   help="training sequences, comma list (default: the world's training sequences per synth.json)")
    p.add_argument("--steps", type=int, default=200, help="training steps per variant (the budget)")
    p.add_argument("--seed", type=int, default=0, help="training and sampling seed of every variant")
    p.add_argument("--size", default="416x128", help="stage-one working size")
    p.add_argument("--depth", default="gt", help="stage-one depth source")
    p.add_argument("--pose", default="gt", help="stage-one pose source")
    p.add_argument("--n-points", type=int, default=2048, help="points per cloud in training and evaluation")
    p.add_argument("--width-scale", type=float, default=0.25, help="net width multiplier (1 = paper)")
    p.add_argument("--model-name", default=DEFAULT_NET,
                   help="the flow net every variant trains, by its registered name (training.model.registry)")
    p.add_argument("--batch-size", type=int, default=4, help="training pairs per optimiser step")
    p.add_argument("--max-scenes", type=int, default=0, help="evaluate only the first N test scenes (0 = all)")
    p.add_argument("--device", default="auto", help="auto | cpu | cuda[:i] (auto = the GPU when there is one)")


def training_sequences(cfg: AblationConfig) -> tuple[str, ...]:
    """``cfg.sequences``, else the training sequences a synthetic world's ``synth.json`` lists, else () (all)."""
    if cfg.sequences:
        return cfg.sequences
    meta = Path(cfg.world) / "synth.json"
    if not meta.is_file():
        return ()
    info = json.loads(meta.read_text())
    seqs = info.get("sequences") or {}
    train = tuple(sorted(k for k, v in seqs.items() if isinstance(v, dict) and v.get("split") == "train"))
    if not train:
        raise ConfigError(f"{meta} lists no training sequence; pass --sequences")
    return train


def preprocess_variant(cfg: AblationConfig, filters: dict[str, bool], out_root: Path) -> Path:
    """Stage one on ``cfg.world``'s training sequences with some filters switched off; returns the cache
    folder (stage one skips finished blocks, so a rerun costs only the check)."""
    from pipeline.filters import FilterConfig
    from pipeline.preprocess import PreprocessConfig, run_preprocess

    pcfg = PreprocessConfig(root=cfg.world, sequences=training_sequences(cfg), depth=cfg.depth, pose=cfg.pose,
                            size=cfg.size, filters=FilterConfig(**filters), out=str(out_root / "cache"),
                            progress=False, device=cfg.device)
    return Path(run_preprocess(pcfg).cache_root)


def train_config(cfg: AblationConfig, cache: Path, run_dir: Path, loss_switches: dict[str, bool]):
    """The :class:`~training.config.TrainConfig` of one variant."""
    from training.config import DataConfig, LossWeights, OptimConfig, TrainConfig

    net = config_class(cfg.model_name)
    return TrainConfig(cache=str(cache), run_dir=str(run_dir), steps=cfg.steps, seed=cfg.seed, device=cfg.device,
                       log_every=max(1, cfg.steps // 10), val_every=cfg.steps, ckpt_every=max(1, cfg.steps // 4),
                       progress=False,
                       data=DataConfig(n_points=cfg.n_points, workers=0),
                       optim=OptimConfig(batch_size=cfg.batch_size),
                       model_name=cfg.model_name,
                       model=net(**net.points_fields(cfg.n_points), width_scale=cfg.width_scale),
                       loss=LossWeights(**loss_switches))


def run_folder(cfg: AblationConfig, cache: Path, loss_switches: dict[str, bool], runs_root: Path,
               filters: dict[str, bool] | None = None) -> Path:
    """``runs_root/<losses>[-keep-<filters>]-<hash>``: the hash covers everything that shapes the training
    (the cache folder stands for its stage-one config), so a folder is reused only by a variant that
    would train exactly the same way; the readable part only names it."""
    tcfg = train_config(cfg, cache, Path("."), loss_switches)
    key = asdict(tcfg)
    key.pop("run_dir")
    if key["model_name"] == DEFAULT_NET:  # the folders of runs made before nets had names keep theirs
        key.pop("model_name")
    key["cache"] = str(Path(cache).resolve())
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:10]
    off = [k.removeprefix("use_") for k, v in loss_switches.items() if not v]
    what = "no-" + "-".join(off) if off else "full"
    kept = [{"far": "sky"}.get(k, k) for k, v in (filters or {}).items() if not v]
    if kept:
        what += "-keep-" + "-".join(kept)
    return runs_root / f"{what}-{digest}"


def train_variant(cfg: AblationConfig, cache: Path, run_dir: Path, loss_switches: dict[str, bool]) -> tuple[Path, bool]:
    """Train one variant (continuing a run folder's checkpoint when there is one); returns
    (``latest.pt``, whether an existing finished checkpoint was reused without training)."""
    from training.trainer import Trainer

    trainer = Trainer(train_config(cfg, cache, run_dir, loss_switches), resume=True)
    try:
        reused = trainer.step >= trainer.steps
        if not reused:
            trainer.fit()
    finally:
        trainer.close()
    return run_dir / "latest.pt", reused


def evaluate_variant(cfg: AblationConfig, checkpoint: Path, name: str, split) -> dict[str, Any]:
    """The fps protocol (the net's level-0 points) at the variant's point counts, seed ``cfg.seed``; one row."""
    from evaluation.methods import NetMethod
    from evaluation.protocols import ProtocolConfig, run_protocol, summary_rows

    net = NetMethod(checkpoint, device=cfg.device, name=name)
    pcfg = ProtocolConfig(protocol="fps", n_points=net.n_points, n_score=net.n_score, seeds=(cfg.seed,))
    return summary_rows(run_protocol(split, [net], pcfg, progress=False))[0]


def config_from_args(args: argparse.Namespace) -> AblationConfig:
    def csv(text: str) -> tuple[str, ...]:
        return tuple(t.strip() for t in text.split(",") if t.strip())

    return AblationConfig(world=args.world, split=args.split, out=args.out, tables=csv(args.tables),
                          sequences=csv(args.sequences), steps=args.steps, seed=args.seed, size=args.size,
                          depth=args.depth, pose=args.pose, n_points=args.n_points, width_scale=args.width_scale,
                          model_name=args.model_name, batch_size=args.batch_size, max_scenes=args.max_scenes,
                          device=args.device).validate()


def run_ablations(args: argparse.Namespace | AblationConfig) -> int:
    """Run the requested tables; writes ``<out>/table-ii``, ``<out>/table-iii`` (results.md/json/csv) and
    ``<out>/ablations.md``, and prints the tables."""
    import dataclasses

    from evaluation.readers import load_split
    from evaluation.report import markdown_table, write_reports

    cfg = args.validate() if isinstance(args, AblationConfig) else config_from_args(args)
    out = Path(cfg.out)
    if not Path(cfg.world).is_dir():
        from core.errors import InputError

        raise InputError(cfg.world, "no such dataset folder (--world)")
    split_path = cfg.split or str(Path(cfg.world) / "sceneflow" / "flownet3d")
    split = load_split(split_path)
    if cfg.max_scenes:
        split = dataclasses.replace(split, entries=split.entries[: cfg.max_scenes])
    caches: dict[str, Path] = {}
    variants: list[dict[str, Any]] = []

    def cache_for(filters: dict[str, bool]) -> Path:
        key = json.dumps(filters, sort_keys=True)
        if key not in caches:
            caches[key] = preprocess_variant(cfg, filters, out)
        return caches[key]

    evaluated: dict[Path, dict[str, Any]] = {}

    def variant(table: str, name: str, filters: dict[str, bool], switches: dict[str, bool]) -> dict[str, Any]:
        cache = cache_for(filters)
        run_dir = run_folder(cfg, cache, switches, out / "runs", filters)
        if run_dir not in evaluated:
            ckpt, reused = train_variant(cfg, cache, run_dir, switches)
            evaluated[run_dir] = {**evaluate_variant(cfg, ckpt, name, split), "reused": reused}
        row = {**evaluated[run_dir], "method": name}
        variants.append({"table": table, "name": name, "filters": filters, "loss": switches, "cache": str(cache),
                         "run": str(run_dir), "reused_checkpoint": row["reused"]})
        print(f"  table {table}: {name} — EPE3D {row['EPE3D']:.4f} ({run_dir.name}"
              f"{', reused' if row['reused'] else ''})", flush=True)
        return row

    tables: list[tuple[str, str, list[dict[str, Any]]]] = []
    if "II" in cfg.tables:
        rows = [variant("II", name, {}, switches) for name, switches in LOSS_VARIANTS.items()]
        tables.append(("table-ii", "Table II — losses", rows))
    if "III" in cfg.tables:
        rows = [variant("III", name, filters, {}) for name, filters in FILTER_VARIANTS.items()]
        tables.append(("table-iii", "Table III — ground / sky", rows))
    text = ""
    for folder, title, rows in tables:
        full_title = f"{title} ({cfg.steps} steps each, seed {cfg.seed}, {len(split)} scenes of {split_path})"
        clean = [{k: v for k, v in r.items() if k != "reused"} for r in rows]
        mine = [v for v in variants if f"table-{v['table'].lower()}" == folder]
        details = {"ablation": asdict(cfg), "training_sequences": list(training_sequences(cfg)) or "all",
                   "variants": mine}
        write_reports(out / folder, clean, details, full_title)
        text += markdown_table(clean, full_title) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "ablations.md").write_text(text)
    print(text + f"reports in {out}/")
    return 0
