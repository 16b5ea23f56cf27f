"""``monoflow-evaluate``: score trained nets and baselines on a scene-flow test split.

Examples::

    monoflow-evaluate run --split cache/demo/world/sceneflow/flownet3d --checkpoint runs/demo/latest.pt \\
        --baselines zero,icp-p2p,fgr --out runs/demo/eval
    monoflow-evaluate run --split KITTI_processed_occ_final --protocol hplflownet \\
        --mapping train_mapping.txt --baselines icp-p2l --seeds 0,1,2
    monoflow-evaluate run --split kitti_rm_ground --protocol released --scenes kitti_t --checkpoint ft.pt
    monoflow-evaluate run --split cache/demo/world/sceneflow/flownet3d --checkpoint runs/demo/latest.pt \\
        --baselines icp-p2p,nsfp --refine                  # + NSFP and "ours + refinement" rows
    monoflow-evaluate score runs/demo/eval/predictions-*.h5     # recompute metrics from saved predictions
    monoflow-evaluate ablations --world cache/demo/world --out runs/ablations --steps 200
    monoflow-evaluate curves runs/demo                  # runs/demo/curves.png from train.csv / val.csv

Flags use the project's style (``--n_points``); the dashed spellings (``--n-points``) are accepted too.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from evaluation.pairing import PAIRINGS
from evaluation.protocols import ALIASES, DEFAULT_POINTS, PROTOCOLS, ProtocolConfig
from evaluation.readers.flags import add_reader_flags, open_split
from evaluation.readers.registry import REGISTRY
from core.errors import ConfigError, run_cli


def _csv(text: str) -> list[str]:
    return [t for t in (x.strip() for x in text.split(",")) if t]


def _number(flag: str, text: str, unit: str = "degrees") -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{flag} must be 'as-trained' or a number of {unit}, got {text!r}") from None


AS_TRAINED = {"as-trained": None, "on": True, "off": False}
"""An inference-only switch forced on or off for each checkpoint, or left as it trained (None: NetMethod's default)."""

NET_SWITCHES = {
    "eval_anchor": "each checkpoint's inference anchor (model.eval_anchor: the rigid vote, the finest level "
                   "held at the vote's camera motion, the evidence gate): as trained, or forced on / off, so a "
                   "net can be scored both ways; a forced setting that differs is named in the row",
    "vote_forward": "each checkpoint's rigid vote also starts its hypotheses along the camera's optical axis "
                    "(model.rigid_vote_forward, inference only; needs the anchor or the rigid vote): on, off, "
                    "or as trained, so a net trained before the option existed can use it; a change is named "
                    "in the row",
    "own_departure": "each checkpoint's anchor measures a point's departure from the net's own camera motion (its "
                     "rigid fit of the finest level's flow) and adds it to the vote's motion "
                     "(model.eval_own_departure, inference only; needs the anchor): on, off (departures from the "
                     "vote's motion), or as trained; a change is named in the row",
    "view_hold": "each checkpoint's anchor holds a finest-level point whose target under the vote's camera "
                 "motion leaves frame 2's view at the vote's motion, unless its own departure lies within "
                 "ego_sigma of its nearest in-view points' median departure, which it then takes "
                 "(model.eval_view_hold, inference only; needs the anchor): on, off, or as trained; a change "
                 "is named in the row",
    "level_departure": "each checkpoint's anchor keeps a finest-level point's departure from the camera's motion "
                       "along the ground, its vertical part (camera y) dropped (model.eval_level_departure, "
                       "inference only; needs the anchor): on, off (the whole departure), or as trained; a change is "
                       "named in the row",
    "neighbourhood_scale": "each checkpoint's anchor compares a finest-level point's 16-neighbour median departure with "
                           "three robust deviations of those medians rather than of the points' own departures "
                           "(model.eval_neighbourhood_scale, inference only; needs the anchor, and changes nothing with "
                           "a gate over k <= 1 neighbours): on, off, or as trained; a change is named in the row",
    "evidence_dense": "each checkpoint's evidence test at the finest level (model.eval_evidence_dense, inference "
                      "only; needs the anchor): frame 2's whole input (on) or its L0 sample (off), or as trained; a "
                      "change is named in the row",
}
"""The net's inference-only switches that ``run`` sets for every checkpoint: ``--<field>`` on, off or as-trained,
passed as :class:`evaluation.methods.NetMethod`'s keyword of that name; each one's ``--help`` text."""

POLISH_OFF = {"rigid_objects": "no object step", "object_search": "no object search",
              "score_in_view": "all points scored", "ego_check": "no ego check",
              "object_whole_extent": "extent rule alone", "level_starts": "whole departures",
              "hold_vertical": "six-degree registration"}
"""The rigid polish's switches that ``run`` can turn off, and what the row's name then says."""

POLISH_HELP = {
    "rigid_objects": "the rigid polish's step 6 (RigidPolishConfig.rigid_objects): every object-sized cluster "
                     "moves rigidly, by its median motion or its two-way ICP fit; off = the fifth round's polish, "
                     "its row named '<net> + rigid polish (no object step)'",
    "object_search": "the rigid polish's step 6b (RigidPolishConfig.object_search): an object that the camera's "
                     "motion leaves off frame 2, or of at least 32 points, is also fitted from the translation that "
                     "a histogram of offsets to the frame-2 points around it favours (within 2.5 m, along the "
                     "ground); off = from its median motion alone, the row named '<net> + rigid polish (no object "
                     "search)'",
    "score_in_view": "the rigid polish's object score (RigidPolishConfig.score_in_view) counts only the points that "
                     "every motion compared keeps inside frame 2's own field of view; off = every point, the row "
                     "named '<net> + rigid polish (all points scored)'",
    "ego_check": "the rigid polish's steps 1b and 3b (RigidPolishConfig.ego_check): the camera motion fitted "
                 "to the net's flow weighed against the rigid vote's, and a registration that explains less of "
                 "the scene refused, both by the share of frame 1 explained (each occupied 1 m cube counting "
                 "once); off = the net's motion and its registration as they come, the row named '<net> + "
                 "rigid polish (no ego check)'",
    "object_whole_extent": "the rigid polish's object rule (RigidPolishConfig.object_whole_extent): a cluster wholly "
                           "inside frame 1's view, both its ends seen, is an object up to 12 m long (a van, a "
                           "lorry, a bus), one that reaches the view's edge up to 6 m; off = 6 m for every cluster, "
                           "the row named '<net> + rigid polish (extent rule alone)'",
    "level_starts": "the rigid polish's object fits (RigidPolishConfig.level_starts) start from the method's "
                    "departure from the camera's motion along the ground, its vertical part dropped (a re-scan's "
                    "rings put a fit started a beam's spacing off on the wrong ring); off = the whole departure, "
                    "the row named '<net> + rigid polish (whole departures)'",
    "hold_vertical": "the rigid polish's registration (RigidPolishConfig.hold_vertical) fits the camera's motion in "
                     "the ground plane alone (its turn about the vertical axis, its translation along x and z) and "
                     "keeps the net's height, pitch and roll where the start's pairs hold some direction weakly "
                     "(with the ground removed few surfaces face up or down, and the wall normals' small vertical "
                     "parts slid the registration vertically); off = all six degrees of freedom, the row named "
                     "'<net> + rigid polish (six-degree registration)'",
}
"""Each of those switches' ``--help`` text."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="monoflow-evaluate", allow_abbrev=False, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = p.add_subparsers(dest="command")
    r = sub.add_parser("run", allow_abbrev=False, help="evaluate checkpoints and baselines on a split")
    r.add_argument("--split", required=True, help="test split folder (FlowNet3D npz, HPLFlowNet, OpenSceneFlow h5)")
    add_reader_flags(r)  # --format and each format's --<format>.<option> (evaluation/readers/flags.py)
    r.add_argument("--checkpoint", action="append", default=[], help="monoflow-train checkpoint (repeatable)")
    from evaluation.methods import baselines_help

    r.add_argument("--baselines", default="zero,icp-p2p,icp-p2l,fgr",
                   help=f"comma list of {baselines_help()} ('' for none)")
    r.add_argument("--protocol", default="fps", choices=(*PROTOCOLS, *ALIASES),
                   help="which points are scored (docs/evaluation-protocols.md): released = first n-score of the "
                        "seeded random sample (3DUnMonoFlow), fps = n-score farthest-point samples (the level-0 "
                        "points of an fps-sampling net; 'paper' is its old name), hplflownet = all 8192 of the "
                        "142 mapped scenes (needs --mapping), flownet3d = all 16384 sampled, full = every input "
                        "point")
    r.add_argument("--n-points", type=int, default=None,
                   help="points sampled per cloud (default: the net's, else 8192; flownet3d 16384)")
    r.add_argument("--n-score", type=int, default=None,
                   help="scored points of released / fps (default: the net's level 0, else 2048)")
    r.add_argument("--mapping", default=None,
                   help="KITTI devkit train_mapping.txt: keep only the scenes with a raw-data recording "
                        "(needed by --protocol hplflownet)")
    r.add_argument("--scenes", default="all",
                   help="all | first:N | last:N | kitti_t (last 50 of the 150 KITTI_o scenes), over the sorted "
                        "scene names after --mapping")
    r.add_argument("--view-prune", action="store_true",
                   help="also score each checkpoint run twice, the second time without the frame-1 points whose "
                        "rigid motion leaves pc2's view, as its own row '<net> + view pruning' "
                        "(evaluation/view_prune.py)")
    r.add_argument("--rigid-polish", action="store_true",
                   help="also score each checkpoint with its ego-motion and its movers' motions sharpened by robust "
                        "ICP started from its flow, as its own row '<net> + rigid polish' (evaluation/rigid_polish.py); "
                        "with --view-prune it polishes the view-pruned flow")
    for field in POLISH_OFF:  # the rigid polish's on/off switches, each named after its config field
        r.add_argument("--" + field.replace("_", "-"), default="on", choices=("on", "off"), help=POLISH_HELP[field])
    r.add_argument("--refine", action="store_true",
                   help="also score each checkpoint followed by label-free test-time refinement, as its own row "
                        "'<net> + refinement' (evaluation/optimise); with --view-prune / --rigid-polish it refines "
                        "their flow: '<net> + view pruning + rigid polish + refinement'")
    r.add_argument("--pairing", "--refine-pairing", dest="pairing", default="auto", choices=("auto", *PAIRINGS),
                   help="what frame 2 holds, for --view-prune, --rigid-polish and --refine: 'surface' = another "
                        "sampling of the same surfaces (LiDAR re-scans, clouds from frame 2's depth); 'points' = frame "
                        "1's own points moved, as in splits built from correspondences (HPLFlowNet's stereoKITTI, "
                        "FlyingThings3D, FlowNet3D's kitti_rm_ground): no point left the view, so the view pruning is "
                        "left out; the polish refuses a registration that moves frame 1 away from frame 2's points "
                        "and refits its camera motion onto the points that land exactly on frame 2's "
                        "(RigidPolishConfig.for_pairing); the refinement keeps the polished flow where such landings "
                        "confirm it and pairs the rest point to point (RefineConfig.for_start); those rows are named "
                        "'(point pairs)'. auto = 'points' for a format that stores frame 2 as frame 1's points "
                        "(hplflownet) or a split whose stored flow carries frame 1's points onto frame 2's points "
                        "(evaluation.pairing), else 'surface'. --refine-pairing is its former name")
    for field, text in NET_SWITCHES.items():  # on / off / as trained, each named after NetMethod's keyword
        r.add_argument("--" + field.replace("_", "-"), default="as-trained", choices=tuple(AS_TRAINED), help=text)
    r.add_argument("--turn-scan", default="as-trained",
                   help="degrees: each checkpoint's turn scan before the rigid vote (model.rigid_vote_yaw_deg, "
                        "inference only; needs the anchor or the rigid vote): as trained, or a number (0 = off, 6 = "
                        "the demo preset's), so a net trained before the scan existed can use it; a change is named "
                        "in the row")
    r.add_argument("--vote-gap", default="as-trained",
                   help="metres: each checkpoint's rigid vote picks among its hypotheses the motion with the least "
                        "mean gap to frame 2, each gap truncated here (model.rigid_vote_gap_m, inference only; needs "
                        "the anchor or the rigid vote): as trained, or a number (0 = by the points each explains, "
                        "0.3 = the demo preset's); a change is named in the row")
    r.add_argument("--vote-density", default="as-trained",
                   help="metres: each checkpoint's rigid vote also refines its starts with every frame-1 point "
                        "weighed by one over the number of frame-1 points within this radius of it "
                        "(model.rigid_vote_density_m, inference only; needs the anchor or the rigid vote): as "
                        "trained, or a number (0 = off, 0.62 = the demo preset's); a change is named in the row")
    r.add_argument("--evidence-surface", default="as-trained",
                   help="spacings: each checkpoint's evidence test also takes a finest-level departure only where at "
                        "least a quarter of the point's neighbourhood has rigid targets farther than this many of frame "
                        "2's local spacings from frame 2 (model.eval_evidence_surface, inference only; needs the "
                        "anchor): as trained, or a number (0 = off, 1.5 = the demo preset's); a change is named in "
                        "the row")
    r.add_argument("--seeds", default="0", help="comma list of sampling seeds (mean ± std over them)")
    r.add_argument("--max-scenes", type=int, default=0, help="only the first N scenes (0 = all)")
    r.add_argument("--device", default="auto", help="auto | cpu | cuda[:i] (auto = the GPU when there is one)")
    r.add_argument("--out", default="runs/eval", help="folder for results.md/json/csv")
    r.add_argument("--save-predictions", action="store_true",
                   help="also write predictions-<method>.h5 (scored points, predicted and true flow per scene)")
    r.add_argument("--plots", action="store_true",
                   help="bar chart and top-down error views, one colour scale per panel (needs matplotlib)")
    r.add_argument("--plots-scene", default="",
                   help="scene shown by --plots (a name of the split, or its 0-based index); default: the first")
    r.add_argument("--no-warmup", action="store_true",
                   help="time the first call too (default: one untimed warm-up call per method)")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    s = sub.add_parser("score", allow_abbrev=False, help="recompute metrics from a predictions file")
    s.add_argument("predictions", nargs="+", help="predictions-*.h5 files written by run --save-predictions")
    c = sub.add_parser("curves", allow_abbrev=False, help="training curves (loss terms, validation metrics) of a run folder as PNG")
    c.add_argument("run_dir", nargs="+", help="monoflow-train or monoflow-train-depth run folder(s) with train.csv")
    c.add_argument("--out", default="", help="PNG path (one run folder only); default <run_dir>/curves.png")
    a = sub.add_parser("ablations", allow_abbrev=False, help="train and evaluate the paper's Table II / III variants")
    from evaluation.ablations import add_arguments

    add_arguments(a)
    from core.options import add_underscore_aliases

    return add_underscore_aliases(p)


def _ints(text: str, what: str) -> tuple[int, ...]:
    try:
        return tuple(int(t) for t in _csv(text))
    except ValueError:
        raise ConfigError(f"{what} must be a comma list of integers, got {text!r}") from None


def _stacked(net, wrappers: list[str], polish_off: tuple[str, ...] = (), pairing: str = "surface") -> list:
    """``net`` and one row per wrapper, each wrapping the previous row (``view-prune``, ``rigid-polish``, then
    ``refine``: the refinement starts from the polished view-pruned flow, named '<net> + view pruning + rigid
    polish + refinement'). ``polish_off``: :data:`POLISH_OFF` switches of the polish turned off, named so
    ('<net> + rigid polish (no object step)'); ``pairing``: what frame 2 holds (``--pairing``), for the polish
    (:meth:`RigidPolishConfig.for_pairing`) and the refinement (:func:`evaluation.methods.refined`), each row then
    named '(point pairs)' where it differs."""
    from evaluation.methods import make_method, refined
    from evaluation.rigid_polish import RigidPolishConfig

    rows = [net]
    for w in wrappers:
        row = refined(rows[-1], pairing=pairing) if w == "refine" else make_method(w, rows[-1])
        if w == "rigid-polish":
            row.config = RigidPolishConfig.for_pairing(pairing)
            notes = [POLISH_OFF[k] for k in polish_off] + (["point pairs"] if pairing == "points" else [])
            if polish_off:
                row.config = dataclasses.replace(row.config, **{k: type(getattr(row.config, k))() for k in polish_off})
            if notes:
                row.name += f" ({', '.join(notes)})"
        rows.append(row)
    return rows


def _unique_names(methods: list) -> None:
    """Give methods that share a name (two checkpoints of same-named runs) distinct names: ' #2', ' #3'."""
    seen: dict[str, int] = {}
    for m in methods:
        base = m.name
        seen[base] = seen.get(base, 0) + 1
        if seen[base] > 1:
            m.name = f"{base} #{seen[base]}"


def protocol_title(cfg: ProtocolConfig, n_scenes: int, split: str, selection: dict | None = None) -> str:
    """The report header: scene count (and how they were chosen), protocol, scored-point rule, seeds."""
    selection = selection or {}
    how = []
    if selection.get("mapping"):
        total = selection["split_scenes"]
        how.append(f"{total - len(selection.get('dropped_by_mapping', []))} of {total} have a raw-data mapping")
    if selection.get("scenes", "all") != "all":
        how.append(f"--scenes {selection['scenes']}")
    scenes = f"{n_scenes} scenes" + (f" ({'; '.join(how)})" if how else "")
    return (f"{scenes} of {split} — protocol {cfg.protocol}: scored {cfg.scored_rule()}; "
            f"seeds {list(cfg.seeds)}")


def _run(args) -> int:
    import re
    import sys

    from evaluation.methods import NetMethod, make_method
    from evaluation.protocols import run_protocol, summary_rows
    from evaluation.report import markdown_table, write_reports

    if args.plots:
        from evaluation.plots import _matplotlib

        _matplotlib()  # a missing optional extra is reported before any work
    from evaluation.pairing import choose_pairing
    from evaluation.scenes import check_not_trained_on, mapped_scenes, select_scenes

    seeds = _ints(args.seeds, "--seeds")
    protocol = ALIASES.get(args.protocol, args.protocol)
    if protocol != args.protocol:
        print(f"note: protocol '{args.protocol}' is the old name of '{protocol}' (farthest-point scored points)",
              file=sys.stderr)
    if protocol == "hplflownet" and not args.mapping:
        raise ConfigError("--protocol hplflownet needs --mapping (the KITTI devkit's train_mapping.txt): HPLFlowNet "
                          "scores only the scenes with a raw-data recording")
    split = open_split(args)  # --split in --format, with its --<format>.<option> flags
    if args.max_scenes < 0:
        raise ConfigError(f"--max-scenes must be >= 0, got {args.max_scenes}")
    selection: dict = {"scenes": args.scenes, "split_scenes": len(split)}
    names = split.names
    if args.mapping:
        names, dropped = mapped_scenes(names, args.mapping)
        selection.update(mapping=str(args.mapping), dropped_by_mapping=dropped)
        if not names:
            raise ConfigError(f"no scene of {args.split} has a non-empty line in {args.mapping}")
    names = select_scenes(names, args.scenes)
    if args.max_scenes:  # a shorter view of the split; scenes are still read one at a time
        names = names[: args.max_scenes]
    if len(names) != len(split):
        keep = set(names)
        split = dataclasses.replace(split, entries=[e for e in split.entries if e.name in keep])
    scenes = split
    first = scenes[0]
    switches = {field: AS_TRAINED[getattr(args, field)] for field in NET_SWITCHES}
    turn_scan = None if args.turn_scan == "as-trained" else _number("--turn-scan", args.turn_scan)
    vote_gap = None if args.vote_gap == "as-trained" else _number("--vote-gap", args.vote_gap, "metres")
    density = None if args.vote_density == "as-trained" else _number("--vote-density", args.vote_density, "metres")
    surface = (None if args.evidence_surface == "as-trained"
               else _number("--evidence-surface", args.evidence_surface, "spacings"))
    nets = [NetMethod(c, device=args.device, turn_scan=turn_scan, vote_gap=vote_gap, vote_density=density,
                      evidence_surface=surface, **switches)
            for c in args.checkpoint]
    for n in nets:
        check_not_trained_on(n.checkpoint, n.run_config, args.split, split.names)
    baselines = list(dict.fromkeys(_csv(args.baselines)))
    stacking = args.view_prune or args.rigid_polish or args.refine
    if args.pairing != "auto" and not stacking:
        raise ConfigError("--pairing sets how --view-prune, --rigid-polish and --refine read frame 2: add one of them")
    if stacking and not nets:
        raise ConfigError("--refine, --view-prune and --rigid-polish wrap a net: give at least one --checkpoint")
    pairing = args.pairing
    if pairing == "auto" and stacking:  # read the split's construction only where a wrapper uses it
        choice = choose_pairing(scenes, split.fmt, REGISTRY[split.fmt].frame2_holds_frame1)
        pairing = choice.pairing
        if pairing == "points":
            print(f"note: {args.split}: {choice.reason}; the stack pairs points (--pairing surface for the re-scan "
                  "settings)", file=sys.stderr)
    if pairing == "points" and args.view_prune:
        print("note: --view-prune is left out: frame 2 holds frame 1's own points, so none of them left the view",
              file=sys.stderr)
    named = {b: make_method(b) for b in baselines}
    methods = [*nets, *named.values()]
    if not methods:
        raise ConfigError("nothing to evaluate: give --checkpoint and/or --baselines")
    _unique_names(methods)
    wrappers = [w for w, on in (("view-prune", args.view_prune and pairing != "points"),
                                ("rigid-polish", args.rigid_polish), ("refine", args.refine)) if on]
    if wrappers:  # after the nets got distinct names; the wrapped rows right after each net's own row
        off = tuple(k for k in POLISH_OFF if getattr(args, k) == "off")
        methods = [x for m in methods
                   for x in (_stacked(m, wrappers, off, pairing) if any(m is n for n in nets) else [m])]
    for m in methods:  # the per-scene optimisation (nsfp, refinement: LoopConfig.device) runs on --device too
        if hasattr(getattr(m, "config", None), "device"):
            m.config.device = args.device
    for b, m in named.items():
        if getattr(m, "needs_pose", False) and first.pose is None:
            raise ConfigError(f"baseline '{b}' needs T_1→2 per scene; the scenes of {args.split} have no pose")
    sizes = {(n.n_points, n.n_score) for n in nets}
    if len(sizes) > 1 and (args.n_points is None or args.n_score is None):
        raise ConfigError(f"checkpoints expect different point counts {sorted(sizes)}: pass --n-points and --n-score")
    n_points, n_score = sizes.pop() if sizes else (DEFAULT_POINTS[protocol], 2048)
    if protocol in ("hplflownet", "flownet3d"):  # these fix the sample size; the net runs on any size
        n_points = DEFAULT_POINTS[protocol]
    cfg = ProtocolConfig(protocol=protocol, n_points=args.n_points or n_points,
                         n_score=args.n_score or n_score, seeds=seeds, warmup=not args.no_warmup).validate()
    for n in nets:
        if cfg.n_points < n.n_score:
            raise ConfigError(f"{n.name} needs at least {n.n_score} points per cloud, "
                              f"--n-points is {cfg.n_points}")
        if n.uses_colour and first.color1 is None:
            print(f"WARNING: {n.name} was trained with colour features but {args.split} has no colours: it gets "
                  "zeros instead, which it never saw in training (train with --data.colour_features false for "
                  "such splits)", file=sys.stderr)
        own = {"fps": "fps", "random": "released"}.get(n.config.sampling)
        if protocol in ("fps", "released") and own != protocol:
            print(f"note: {n.name} samples its level 0 by '{n.config.sampling}', so its flow at the points "
                  f"'{protocol}' scores is interpolated (its own points: --protocol {own})", file=sys.stderr)
    out = Path(args.out)
    writers: dict = {}
    first_scene: dict = {}

    shown_scene = _plot_scene(split.names, args.plots_scene) if args.plots else first.name

    def on_prediction(name, pred):
        if name in writers:
            writers[name].add(pred.name, pred.points, pred.pred_flow, pred.gt_flow, pred.moving)
        if args.plots and pred.name == shown_scene:
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
    title = protocol_title(cfg, len(scenes), str(args.split), selection)
    details = {"protocol": dict(cfg.__dict__), "scored_points": cfg.scored_rule(), "selection": selection,
               "split": str(args.split), "format": split.fmt,
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

        paths = write_plots(out, rows, scenes, methods, cfg, scene_index=split.names.index(shown_scene),
                            predictions=first_scene)
        print("plots: " + ", ".join(str(p) for p in paths))
    return 0


def _plot_scene(names: list[str], wanted: str) -> str:
    """The scene ``--plots-scene`` names (a scene name or a 0-based index); the first when empty."""
    if not wanted:
        return names[0]
    if wanted in names:
        return wanted
    if wanted.isdigit() and int(wanted) < len(names):
        return names[int(wanted)]
    raise ConfigError(f"--plots-scene {wanted!r}: no such scene (the split has {len(names)}: "
                      f"{', '.join(names[:5])}{', ...' if len(names) > 5 else ''})")


def _curves(args) -> int:
    from evaluation.pictures import training_curves

    if args.out and len(args.run_dir) > 1:
        raise ConfigError("--out names one PNG: give one run folder with it")
    for run in args.run_dir:
        print(training_curves(run, args.out or None))
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
    if args.command == "curves":
        return _curves(args)
    from evaluation.ablations import run_ablations

    return run_ablations(args)


def main(argv: list[str] | None = None) -> int:
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
