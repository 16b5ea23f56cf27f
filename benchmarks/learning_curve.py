"""Learning curves of the scene-flow net: train once, score snapshots on held-out test splits.

Trains one run in chunks (``--steps 500,1000,2000``: resumes the same run to each milestone, which the
trainer makes bit-identical to an uninterrupted run on the CPU), keeps a snapshot per milestone and
scores it with the evaluation protocol on every ``--split`` (EPE3D overall, static and moving points, in
metres), next to the label-free checkpoint-selection signals the trainer logs (validation loss at the
finest level and over all levels). The registration baselines are scored once per split on the same
points. Results go to ``<out>/curve.csv`` and ``curve.json`` and are printed as a table.

Example (the demo's settings, 4x its steps)::

    python -m benchmarks.learning_curve --cache cache/demo/cache/synthetic/<hash> \\
        --split demo=cache/demo/world/sceneflow/flownet3d --out runs/curve --steps 500,1000,2000

Extra training options go after ``--set`` as dotted ``key=value`` pairs (``--set model.ego_head=false``),
applied to the paper's form, or with ``--start demo`` to the demo preset (``--start demo --set
loss.plane_where_held=true`` is one candidate against the preset).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
from dataclasses import asdict
from pathlib import Path

from benchmarks.named_folders import key_value, named_folder


def _coerce(text: str):
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    if "," in text:
        return tuple(_coerce(t) for t in text.split(","))
    return text


def demo_train_config(cache: str, run_dir: str, n_points: int = 2048, width_scale: float = 0.5, seed: int = 0,
                      overrides: dict | None = None, start: str = "paper"):
    """The run's :class:`~training.config.TrainConfig` at the demo's sizes plus ``overrides``. ``start="paper"``:
    the paper's form (no ego head, no augmentation), so a curve switches departures on one by one;
    ``start="demo"``: the demo preset as ``make demo`` trains it (training/presets.py), so a candidate
    is one ``--set`` on top of it. Both load in the training process without a progress bar."""
    from training.presets import demo_train_config as preset

    quiet = {"data.workers": 0, "progress": False}  # neither changes the result (the trainer's resume checks)
    if start == "demo":
        return preset(cache, run_dir, 1, n_points, width_scale, seed, {**quiet, **(overrides or {})})
    if start != "paper":
        raise ValueError(f"start must be 'paper' or 'demo', not {start!r}")
    paper = {"model.ego_head": False, "model.eval_norm_stats": "running", "data.lidar_rings": 0.0,
             "data.density_drop": 0.0, "data.ground_jitter_m": 0.0, "data.ego_speed_scale": (1.0, 1.0),
             **quiet, "model.ego_open_gradient": False, "model.zero_flow_heads": False,
             "loss.gate_pull": 0.0, "loss.chamfer_truncate": 0.0, "loss.chamfer_plane": 0.0,
             "loss.laplacian_plane": 0.0, "loss.flow_smooth": 0.0, "model.rigid_vote": False,
             "model.ego_l0_hold": False, "model.ego_gate_evidence": False, "model.eval_anchor": False,
             "model.rigid_vote_dense": False, "model.rigid_vote_far": False, "model.eval_gate_k": 0,
             "model.rigid_vote_yaw_deg": 0.0, "model.eval_evidence_dense": False, "model.rigid_vote_gap_m": 0.0,
             "model.rigid_vote_forward": False, "model.rigid_vote_density_m": 0.0, "model.eval_own_departure": False,
             "model.eval_view_hold": False, "model.eval_level_departure": False,
             "model.eval_evidence_surface": 0.0}
    return preset(cache, run_dir, 1, n_points, width_scale, seed, {**paper, **(overrides or {})})


def score_splits(methods, splits: dict[str, object], n_points: int, n_score: int, seeds=(0,),
                 protocol: str = "fps") -> dict:
    """``{split: {method: summary row}}`` under ``protocol`` (the paper's, ``fps``, unless told) at the net's point
    counts."""
    from evaluation.protocols import ProtocolConfig, run_protocol, summary_rows

    cfg = ProtocolConfig(protocol=protocol, n_points=n_points, n_score=n_score, seeds=tuple(seeds), warmup=False)
    out = {}
    for name, split in splits.items():
        rows = summary_rows(run_protocol(split, methods, cfg, progress=False))
        out[name] = {r["method"]: r for r in rows}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="learning_curve", description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", required=True, help="stage-one cache folder")
    p.add_argument("--split", action="append", required=True, type=named_folder,
                   help="NAME=FOLDER of a FlowNet3D-format test split")
    p.add_argument("--out", required=True, help="run folder (resumes when it exists)")
    p.add_argument("--steps", default="500,1000,2000", help="comma list of milestones (optimiser steps)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-points", type=int, default=2048)
    p.add_argument("--width-scale", type=float, default=0.5)
    p.add_argument("--baselines", default="icp-p2p,fgr", help="scored once per split ('' for none)")
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--variants", default="as-trained",
                   help="comma list of test-time settings to score each snapshot under: 'as-trained', or '+'-joined "
                        "switches 'ego' (model.ego_head on), 'planar' / 'sixdof' "
                        "(model.ego_planar), 'input' / 'running' "
                        "(model.eval_norm_stats), "
                        "'prune' (two-pass view pruning, evaluation/view_prune.py), 'polish' (rigid polish, "
                        "evaluation/rigid_polish.py; after 'prune' when both are given)")
    p.add_argument("--start", choices=("paper", "demo"), default="paper",
                   help="settings --set applies to: the paper's form (departures off) or the demo preset")
    p.add_argument("--set", nargs="*", default=[], type=key_value, help="dotted TrainConfig overrides key=value")
    args = p.parse_args(argv)

    import torch

    from core.errors import InputError
    from evaluation.methods import NetMethod, make_baseline
    from evaluation.rigid_polish import rigid_polished
    from evaluation.view_prune import view_pruned
    from evaluation.readers import load_split
    from training.selection import score_checkpoint
    from training.trainer import Trainer

    if args.threads:
        torch.set_num_threads(args.threads)
    overrides = {k: _coerce(v) for k, v in args.set}
    try:
        splits = {name: load_split(folder, "auto") for name, folder in args.split}
    except InputError as exc:
        print(f"learning_curve: {exc}")
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    milestones = sorted(int(s) for s in args.steps.split(","))
    run_dir = out / "run"
    rows: list[dict] = []
    cfg = None
    for m in milestones:
        cfg = demo_train_config(args.cache, str(run_dir), args.n_points, args.width_scale, args.seed, overrides,
                                args.start)
        cfg.steps, cfg.val_every, cfg.ckpt_every, cfg.log_every = m, 100, 100, 50
        snap = out / f"step_{m:06d}.pt"
        if not snap.exists():
            trainer = Trainer(cfg, resume=True)
            try:
                trainer.fit()
            finally:
                trainer.close()
            shutil.copyfile(run_dir / "latest.pt", snap)
        nets = []
        for variant in args.variants.split(","):  # the same weights under other test-time settings
            net = NetMethod(snap, name=variant)
            if "ego" in variant.split("+"):
                net.net.config.ego_head = True
            for motion, planar in (("planar", True), ("sixdof", False)):
                if motion in variant.split("+"):
                    net.net.config.ego_planar = planar
            if "input" in variant.split("+"):
                net.net.set_eval_norm_stats("input")
            if "running" in variant.split("+"):
                net.net.set_eval_norm_stats("running")
            if "prune" in variant.split("+"):
                net = view_pruned(net)
                net.name = variant
            if "polish" in variant.split("+"):
                net = rigid_polished(net)
                net.name = variant
            nets.append(net)
        scores = score_splits(nets, splits, cfg.data.n_points, cfg.model.output_points[0])
        row = {"step": m}
        for split_name, by_method in scores.items():
            for net in nets:
                r = by_method[net.name]
                tag = f"{split_name}:{net.name}"
                for key in ("EPE3D", "EPE3D_static", "EPE3D_moving", "Acc3DS", "Outliers3D"):
                    if key in r:
                        row[f"{tag}/{key}"] = r[key]
        row.update(score_checkpoint(cfg, snap))  # label-free selection scores (and val EPE3D) of the snapshot
        rows.append(row)
        print(json.dumps(row), flush=True)
    base_file = out / "baselines.json"
    names = [b for b in args.baselines.split(",") if b]
    if names and not base_file.exists() and cfg is not None:
        scores = score_splits([make_baseline(b) for b in names], splits, cfg.data.n_points, cfg.model.output_points[0])
        base_file.write_text(json.dumps(scores, indent=1))
    baselines = json.loads(base_file.read_text()) if base_file.exists() else {}
    keys = sorted({k for r in rows for k in r})
    with open(out / "curve.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    (out / "curve.json").write_text(json.dumps({"rows": rows, "baselines": baselines,
                                                "config": asdict(cfg) if cfg else None}, indent=1))
    for split_name, by_method in baselines.items():
        for name, r in by_method.items():
            print(f"{split_name} {name}: EPE3D {r['EPE3D']:.4f} static {r.get('EPE3D_static', float('nan')):.4f} "
                  f"moving {r.get('EPE3D_moving', float('nan')):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
