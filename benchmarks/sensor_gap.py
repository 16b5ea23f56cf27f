"""Where a flow net's test error comes from: the unseen sequence, the sensor, or the ego-motion.

Scores checkpoints under the ``fps`` protocol (the net's point counts) on

* ``cam-val`` — held-out camera-cloud pairs of a training cache (stage one's clouds, labelled);
* ``cam-test`` — a cache built by stage one from the *test* sequence (the same scenes as the LiDAR split,
  seen by the training sensor), when ``--test-cache`` is given;
* every ``--split NAME=FOLDER`` (LiDAR scene-flow splits),

with ICP and FGR on the same points, and reports for every split the rigid ego-motion implied by the net's
flow on static points (Kabsch fit; camera-1 → camera-2 frame, metres): its translation length against the
true one, the error of the translation and rotation, and their signed means per axis (x right, y down,
z forward; rotation as Euler angles about x = pitch, y = yaw, z = roll), which show a bias where a plain
mean error cannot. ``--per-level`` repeats the ego-motion check for the flow of every pyramid level (L3, the
coarsest, to L0), each interpolated onto the scored points, with its EPE3D on static points: which level
leaves the error behind. ``--speed-scales 0.5,1.5,2`` adds the camera-cloud pairs (cam-test, else cam-val) with
the camera's motion rescaled as training's ``data.ego_speed_scale`` does (frame t's cloud moved, frame t+1
and the targets kept): how the net's translation follows the true one when only the speed changes, the same
scenes. Used for docs/learned-flow.md ("Second round", "Seventh round", "Ninth round")::

    python -m benchmarks.sensor_gap --checkpoint runs/curve/step_000500.pt,runs/curve/step_001000.pt \\
        --cache w/cache/world/<hash> --test-cache w/cache06/world/<hash> --split own=w/world/sceneflow/flownet3d
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.named_folders import named_folder


def cache_samples(reader, indices: list[int] | None, tag: str, speed_scale: float = 1.0) -> list:
    """Labelled camera-cloud pairs of a stage-one cache (a :class:`pipeline.cache.CacheReader`) as scene-flow
    samples (camera frames, metres). With ``speed_scale`` ≠ 1 each pair's camera motion is rescaled by
    :func:`training.augment.speed_scaled_view` (frame t's points moved to ``A p``, the flow targets in frame
    t+1 kept, so the true flow becomes ``p + f − A p``)."""
    from core.geometry import transform_points
    from evaluation.sample import SceneFlowSample
    from training.augment import speed_scaled_view

    out = []
    for i in (range(len(reader)) if indices is None else indices):
        s = reader[i]
        if s.gt_flow is None:
            continue
        pc1 = s.pc1.astype(np.float64)
        moved = pc1 if speed_scale == 1.0 else transform_points(speed_scaled_view(s.T, speed_scale), pc1)
        out.append(SceneFlowSample(name=f"{tag}{i:05d}", pc1=moved.astype(np.float32), pc2=s.pc2.astype(np.float32),
                                   flow=(pc1 + s.gt_flow - moved).astype(np.float32),
                                   moving=None if s.moving is None else np.asarray(s.moving, bool)))
    return out


def static_motion(points: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion (R (3, 3), t (3,), metres) that best maps ``points`` onto ``points + flow``
    (unweighted Kabsch, float64)."""
    import torch

    from training.model.ego_motion import weighted_rigid_fit

    t = lambda x: torch.tensor(x[None], dtype=torch.float64)  # noqa: E731
    R, tr = weighted_rigid_fit(t(points), t(points + flow), torch.ones(1, len(points), dtype=torch.float64))
    return R[0].numpy(), tr[0].numpy()


def ego_errors(method, split, cfg) -> dict[str, float]:
    """Mean |t_true|, |t_net|, translation error (m) and rotation error (degrees) of the rigid motion fitted
    to the net's flow and to the true flow on each scene's static points, and the signed mean error per
    axis: ``dt_x``, ``dt_y``, ``dt_z`` (m, net − true, camera-1 → camera-2 frame) and ``dr_pitch``,
    ``dr_yaw``, ``dr_roll`` (degrees, Euler angles of ``R_trueᵀ R_net`` about x, y, z)."""
    from core.geometry import matrix_to_euler, rotation_angle
    from evaluation.protocols import prepare_scene

    rows = []
    for sample in split:
        if sample.moving is None:
            continue
        scene = prepare_scene(sample, cfg, cfg.seeds[0])
        flow = method(scene.pc1, scene.pc2)
        static = ~sample.moving[scene.index1]
        Rg, tg = static_motion(scene.pc1[static], sample.flow[scene.index1][static])
        Rn, tn = static_motion(scene.pc1[static], flow[static])
        rows.append([np.linalg.norm(tg), np.linalg.norm(tn), np.linalg.norm(tn - tg),
                     np.degrees(float(rotation_angle(Rg.T @ Rn))), *(tn - tg),
                     *np.degrees(matrix_to_euler(Rg.T @ Rn))])
    keys = ("t_true", "t_net", "t_err", "rot_err_deg", "dt_x", "dt_y", "dt_z", "dr_pitch", "dr_yaw", "dr_roll")
    mean = np.mean(rows, axis=0) if rows else np.full(len(keys), np.nan)
    return dict(zip(keys, map(float, mean)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="sensor_gap", description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", required=True, help="comma list of flow checkpoints")
    p.add_argument("--cache", required=True, help="the training cache (its held-out pairs are cam-val)")
    p.add_argument("--test-cache", help="stage one run on the test sequence (cam-test)")
    p.add_argument("--split", action="append", default=[], type=named_folder,
                   help="NAME=FOLDER of a LiDAR scene-flow split")
    p.add_argument("--max-scenes", type=int, default=40)
    p.add_argument("--per-level", action="store_true",
                   help="also the ego-motion of every level's flow (coarsest first), on the LiDAR splits")
    p.add_argument("--speed-scales", default="",
                   help="comma list of factors: also the camera-cloud pairs (cam-test, else cam-val) with the "
                        "camera's motion rescaled by each")
    args = p.parse_args(argv)

    from benchmarks.learning_curve import score_splits
    from core.errors import InputError
    from evaluation.methods import NetMethod, make_baseline
    from evaluation.protocols import ProtocolConfig
    from evaluation.readers import load_split
    from pipeline.cache import CacheReader
    from training.config import DataConfig
    from training.data import train_val_split

    nets = [NetMethod(c, name=f"net {c}") for c in args.checkpoint.split(",")]
    held = {**vars(DataConfig()), **(nets[0].run_config.get("data") or {})}  # what the first net's run held out
    reader = CacheReader(args.cache)
    _, val = train_val_split(reader, held["val_fraction"], held["val_pairs_max"])
    splits = {"cam-val": cache_samples(reader, val[: args.max_scenes], "v")}
    test_reader = CacheReader(args.test_cache) if args.test_cache else None
    if test_reader is not None:
        splits["cam-test"] = cache_samples(test_reader, None, "t")[: args.max_scenes]
    # the speed-scaled pairs: the test sequence's camera clouds when given, else the held-out training pairs
    base, source, picked = (("cam-test", test_reader, None) if test_reader is not None
                            else ("cam-val", reader, val[: args.max_scenes]))
    for factor in filter(None, args.speed_scales.split(",")):
        splits[f"{base}x{factor}"] = cache_samples(source, picked, "s", float(factor))[: args.max_scenes]
    try:
        for name, folder in args.split:
            splits[name] = list(load_split(folder, "auto"))[: args.max_scenes]
    except InputError as exc:
        print(f"sensor_gap: {exc}")
        return 2
    n_points, n_score = nets[0].n_points, nets[0].n_score
    scores = score_splits(nets + [make_baseline("icp-p2p"), make_baseline("fgr")], splits, n_points, n_score)
    cfg = ProtocolConfig(protocol="fps", n_points=n_points, n_score=n_score, seeds=(0,), warmup=False).validate()
    for name, split in splits.items():
        for method, r in scores[name].items():
            print(f"{name:10s} n={len(split):3d} {method:40s} EPE3D {r['EPE3D']:.3f} "
                  f"static {r.get('EPE3D_static', float('nan')):.3f} moving {r.get('EPE3D_moving', float('nan')):.3f}")
        for net in nets:
            e = ego_errors(net, split, cfg)
            print(f"{name:10s} {net.name:40s} ego-motion: |t| true {e['t_true']:.2f} m, net {e['t_net']:.2f} m, "
                  f"error {e['t_err']:.3f} m, rotation error {e['rot_err_deg']:.3f} deg; mean signed error "
                  f"t ({e['dt_x']:+.3f}, {e['dt_y']:+.3f}, {e['dt_z']:+.3f}) m, pitch {e['dr_pitch']:+.3f}, "
                  f"yaw {e['dr_yaw']:+.3f}, roll {e['dr_roll']:+.3f} deg", flush=True)
        if args.per_level and not name.startswith("cam-"):
            for net in nets:
                print_levels(net, name, split, cfg)
    return 0


def gate_shares(net, split, cfg) -> list[tuple[float, float]]:
    """Per pyramid level (finest first), the share of static and of moving points whose ego-head gate is open
    (> 0.5: the point keeps its own flow, the net calls it moving), over the protocol's sampled frame-1
    points at that level; nan where the split has no such points or the net no ego head."""
    import torch

    from evaluation.protocols import prepare_scene

    counts: dict[int, np.ndarray] = {}
    t = lambda x: torch.tensor(np.asarray(x, dtype=np.float32), device=net.device)[None]  # noqa: E731
    for sample in split:
        scene = prepare_scene(sample, cfg, cfg.seeds[0])
        with torch.no_grad():
            out = net.net(t(scene.pc1), t(scene.pc2))
        moving = (np.zeros(len(scene.pc1), bool) if sample.moving is None
                  else np.asarray(sample.moving, bool)[scene.index1])
        for lvl, (gate, idx) in enumerate(zip(out.gates, out.indices)):
            open_, mv = gate[0].cpu().numpy() > 0.5, moving[idx[0].cpu().numpy()]
            c = counts.setdefault(lvl, np.zeros(4))
            c += [(open_ & ~mv).sum(), (~mv).sum(), (open_ & mv).sum(), mv.sum()]
    share = lambda a, b: a / b if b else float("nan")  # noqa: E731
    return [(share(c[0], c[1]), share(c[2], c[3])) for _, c in sorted(counts.items())]


def print_levels(net, split_name: str, split, cfg) -> None:
    """One line per pyramid level of ``net`` (coarsest first): the ego-motion check of that level's flow and
    its EPE3D on static points (metres), both on the points the protocol scores."""
    from benchmarks.learning_curve import score_splits
    from evaluation.methods import NetMethod

    levels = [NetMethod(net.checkpoint, name=f"L{lvl}", level=lvl) for lvl in range(len(net.config.output_points))]
    scores = score_splits(levels, {split_name: split}, cfg.n_points, cfg.n_score)[split_name]
    gates = gate_shares(net, split, cfg)  # empty without an ego head
    for m in reversed(levels):
        e = ego_errors(m, split, cfg)
        opened = (f", gate open on {gates[m.level][0]:.1%} of static and {gates[m.level][1]:.1%} of moving points"
                  if m.level < len(gates) else "")
        print(f"{split_name:10s} {net.name:40s} {m.name}: |t| {e['t_net']:.2f} m (true {e['t_true']:.2f}), "
              f"error {e['t_err']:.3f} m, rotation error {e['rot_err_deg']:.3f} deg, static EPE3D "
              f"{scores[m.name].get('EPE3D_static', float('nan')):.3f}{opened}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
