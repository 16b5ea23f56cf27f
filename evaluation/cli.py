"""``monoflow-evaluate``: score trained nets and baselines on a scene-flow test split.

Examples::

    monoflow-evaluate run --split cache/demo/world/sceneflow/flownet3d --checkpoint runs/demo/latest.pt \\
        --baselines zero,icp-p2p,fgr --out runs/demo/eval
    monoflow-evaluate run --split KITTI_processed_occ_final --format hplflownet --baselines icp-p2l --seeds 0,1,2
    monoflow-evaluate score runs/demo/eval/predictions-*.h5     # recompute metrics from saved predictions
    monoflow-evaluate ablations --world cache/demo/world --out runs/ablations --steps 200
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from pipeline.errors import ConfigError, run_cli


def _csv(text: str) -> list[str]:
    return [t for t in (x.strip() for x in text.split(",")) if t]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="monoflow-evaluate", allow_abbrev=False, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = p.add_subparsers(dest="command")
    r = sub.add_parser("run", allow_abbrev=False, help="evaluate checkpoints and baselines on a split")
    r.add_argument("--split", required=True, help="test split folder (FlowNet3D npz, HPLFlowNet, OpenSceneFlow h5)")
    r.add_argument("--format", default="auto", help="auto | flownet3d | hplflownet | opensceneflow")
    r.add_argument("--checkpoint", action="append", default=[], help="monoflow-train checkpoint (repeatable)")
    r.add_argument("--baselines", default="zero,icp-p2p,icp-p2l,fgr",
                   help="comma list of zero, static (splits with poses), icp-p2p, icp-p2l, fgr ('' for none)")
    r.add_argument("--protocol", default="paper", choices=("paper", "full"))
    r.add_argument("--n-points", type=int, default=None, help="points sampled per cloud (default: the net's, else 8192)")
    r.add_argument("--n-score", type=int, default=None, help="scored points, paper protocol (default: net's L0, else 2048)")
    r.add_argument("--seeds", default="0", help="comma list of sampling seeds (mean ± std over them)")
    r.add_argument("--max-scenes", type=int, default=0, help="only the first N scenes (0 = all)")
    r.add_argument("--device", default="auto")
    r.add_argument("--out", default="runs/eval", help="folder for results.md/json/csv")
    r.add_argument("--save-predictions", action="store_true",
                   help="also write predictions-<method>.h5 (scored points, predicted and true flow per scene)")
    r.add_argument("--plots", action="store_true", help="bar chart and top-down error views (needs matplotlib)")
    r.add_argument("--no-warmup", action="store_true",
                   help="time the first call too (default: one untimed warm-up call per method)")
    r.add_argument("--no-progress", action="store_true")
    s = sub.add_parser("score", allow_abbrev=False, help="recompute metrics from a predictions file")
    s.add_argument("predictions", nargs="+")
    a = sub.add_parser("ablations", allow_abbrev=False, help="train and evaluate the paper's Table II / III variants")
    from evaluation.ablations import add_arguments

    add_arguments(a)
    return p


def _ints(text: str, what: str) -> tuple[int, ...]:
    try:
        return tuple(int(t) for t in _csv(text))
    except ValueError:
        raise ConfigError(f"{what} must be a comma list of integers, got {text!r}") from None


def _unique_names(methods: list) -> None:
    """Give methods that share a name (two checkpoints of same-named runs) distinct names: ' #2', ' #3'."""
    seen: dict[str, int] = {}
    for m in methods:
        base = m.name
        seen[base] = seen.get(base, 0) + 1
        if seen[base] > 1:
            m.name = f"{base} #{seen[base]}"


def _run(args) -> int:
    import dataclasses
    import re
    import sys

    from evaluation.methods import NetMethod, make_baseline
    from evaluation.protocols import ProtocolConfig, run_protocol, summary_rows
    from evaluation.readers import load_split
    from evaluation.report import markdown_table, write_reports

    if args.plots:
        from evaluation.plots import _matplotlib

        _matplotlib()  # a missing optional extra is reported before any work
    seeds = _ints(args.seeds, "--seeds")
    split = load_split(args.split, args.format)
    if args.max_scenes < 0:
        raise ConfigError(f"--max-scenes must be >= 0, got {args.max_scenes}")
    if args.max_scenes:  # a shorter view of the split; scenes are still read one at a time
        split = dataclasses.replace(split, entries=split.entries[: args.max_scenes])
    scenes = split
    first = scenes[0]
    nets = [NetMethod(c, device=args.device) for c in args.checkpoint]
    baselines = list(dict.fromkeys(_csv(args.baselines)))
    methods = [*nets, *[make_baseline(b) for b in baselines]]
    if not methods:
        raise ConfigError("nothing to evaluate: give --checkpoint and/or --baselines")
    _unique_names(methods)
    if "static" in baselines and first.pose is None:
        raise ConfigError(f"baseline 'static' needs T_1→2 per scene; the scenes of {args.split} have no pose")
    sizes = {(n.n_points, n.n_score) for n in nets}
    if len(sizes) > 1 and (args.n_points is None or args.n_score is None):
        raise ConfigError(f"checkpoints expect different point counts {sorted(sizes)}: pass --n-points and --n-score")
    n_points, n_score = sizes.pop() if sizes else (8192, 2048)
    cfg = ProtocolConfig(protocol=args.protocol, n_points=args.n_points or n_points,
                         n_score=args.n_score or n_score, seeds=seeds, warmup=not args.no_warmup).validate()
    for n in nets:
        if cfg.n_points < n.config.level_points[0]:
            raise ConfigError(f"{n.name} needs at least {n.config.level_points[0]} points per cloud, "
                              f"--n-points is {cfg.n_points}")
        if n.uses_colour and first.color1 is None:
            print(f"note: {n.name} was trained with colour features; {args.split} has no colours, so it gets "
                  "zeros", file=sys.stderr)
    out = Path(args.out)
    writers: dict = {}
    first_scene: dict = {}

    def on_prediction(name, pred):
        if name in writers:
            writers[name].add(pred.name, pred.points, pred.pred_flow, pred.gt_flow, pred.moving)
        if args.plots and pred.name == first.name:
            first_scene[name] = pred

    if args.save_predictions:
        from evaluation.predictions import PredictionWriter

        out.mkdir(parents=True, exist_ok=True)
        for m in methods:
            slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", m.name).strip("_")
            writers[m.name] = PredictionWriter(out / f"predictions-{slug}.h5", m.name)
    t0 = time.perf_counter()
    try:
        results = run_protocol(scenes, methods, cfg, on_prediction=on_prediction, progress=not args.no_progress)
    except BaseException:
        for w in writers.values():
            w.abort()
        raise
    for w in writers.values():
        w.close()
    rows = summary_rows(results)
    title = (f"{len(scenes)} scenes of {args.split} — protocol {cfg.protocol}, {cfg.n_points} points sampled, "
             f"{cfg.n_score if cfg.protocol == 'paper' else 'all'} scored, seeds {list(cfg.seeds)}")
    details = {"protocol": dict(cfg.__dict__), "split": str(args.split), "format": split.fmt,
               "scenes": split.names,
               "checkpoints": {n.name: str(n.checkpoint) for n in nets},
               "per_seed": {r.name: r.per_seed for r in results},
               "per_scene": {r.name: r.per_scene for r in results},
               "seconds": time.perf_counter() - t0}
    write_reports(out, rows, details, title)
    print(markdown_table(rows, title))
    print(f"reports in {out}/results.{{md,json,csv}}" + (f", predictions in {out}/predictions-*.h5" if writers else ""))
    if args.plots:
        from evaluation.plots import write_plots

        paths = write_plots(out, rows, scenes, methods, cfg, predictions=first_scene)
        print("plots: " + ", ".join(str(p) for p in paths))
    return 0


def _score(args) -> int:
    from evaluation.predictions import predictions_method, score_predictions
    from evaluation.report import markdown_table

    rows = []
    for path in args.predictions:
        m = score_predictions(path)
        row = {"method": m.get("method") or predictions_method(path),
               **{k: m[k] for k in ("EPE3D", "Acc3DS", "Acc3DR", "Outliers3D")}}
        for subset in ("static", "moving"):
            if subset in m:
                row[f"EPE3D_{subset}"] = m[subset]["EPE3D"]
        rows.append(row)
    print(markdown_table(rows, "scores recomputed from saved predictions"))
    return 0


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    if args.command == "run":
        return _run(args)
    if args.command == "score":
        return _score(args)
    from evaluation.ablations import run_ablations

    return run_ablations(args)


def main(argv: list[str] | None = None) -> int:
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
