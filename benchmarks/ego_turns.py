"""How the net and the registration baselines fare when the camera turns more than in the split: each scene's
frame 2 turned about camera 2's y axis by a few degrees (docs/learned-flow.md, thirty-second round).

Turning frame 2 by ``A`` (a rotation about camera 2's vertical axis through its centre) makes the camera's
motion ``A · T``: a sharper turn of the same drive. Frame 2 stays the split's own second scan (its own
sampling, its movers), so only the camera's turn changes, and the ground truth follows exactly:
``flow' = A (p + flow) − p``. The demo world's test sequences turn little (below a degree per frame), KITTI
up to 2.6° per frame in its 95th percentile; this tool asks what a turn of 2° or 4° does to each method,
on exactly the same points (the ``fps`` protocol, as ``monoflow-evaluate`` draws them)::

    python -m benchmarks.ego_turns --checkpoint demo=cache/demo/flow_run_gt/latest.pt \\
        --split own=cache/demo/world_varied/sceneflow/flownet3d --turns 0,2,-2,4,-4 --scan 0,6

``--scan`` lists values of the net's ``model.rigid_vote_yaw_deg`` (the rigid vote's turn scan, an
inference-only switch; ``NetMethod(turn_scan=…)``, ``monoflow-evaluate run --turn-scan``) to score each net with,
overriding the checkpoint's; the ``rvote`` baseline is scored with the same scans. Camera frames (x right, y down, z forward), metres, degrees.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from benchmarks.named_folders import named_folder
from core.errors import run_cli
from pipeline.synth.world import rot_y


def turned_frame2(sample, deg: float):
    """``sample`` (a :class:`~evaluation.sample.SceneFlowSample`) with frame 2 turned by ``deg`` degrees about
    camera 2's y axis: ``pc2`` and ``p + flow`` rotated alike, the pose (when given) composed. Colours kept."""
    if deg == 0:
        return sample
    A = rot_y(np.deg2rad(deg))  # about camera 2's y axis (x right, y down, z forward)
    pc2 = (sample.pc2.astype(np.float64) @ A.T).astype(np.float32)
    moved = (sample.pc1.astype(np.float64) + sample.flow) @ A.T
    pose = None
    if sample.pose is not None:
        lift = np.eye(4)
        lift[:3, :3] = A
        pose = lift @ sample.pose
    return dataclasses.replace(sample, pc2=pc2, flow=(moved - sample.pc1).astype(np.float32), pose=pose)


def _numbers(values: str, what: str) -> list[float]:
    try:
        return [float(v) for v in values.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what} must be a comma list of numbers, got {values!r}") from None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="ego_turns", description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", action="append", default=[], type=named_folder,
                   help="NAME=FILE of a monoflow-train checkpoint (repeatable; none: baselines only)")
    p.add_argument("--split", action="append", default=[], required=True, type=named_folder,
                   help="NAME=FOLDER of a scene-flow test split (repeatable)")
    p.add_argument("--turns", type=lambda v: _numbers(v, "--turns"), default=[0.0, 2.0, -2.0, 4.0, -4.0],
                   help="degrees added to the camera's turn, comma list")
    p.add_argument("--scan", type=lambda v: _numbers(v, "--scan"), default=[0.0],
                   help="the rigid vote's turn scans (model.rigid_vote_yaw_deg, degrees) to score nets and rvote with")
    p.add_argument("--baselines", default="icp-p2p,rvote", help="comma list: icp-p2p, icp-p2l, fgr, tvote, rvote, zero")
    p.add_argument("--scenes", type=int, default=0, help="the first N scenes of each split (0: all)")
    p.add_argument("--n-points", type=int, default=2048, help="points sampled per cloud")
    p.add_argument("--n-score", type=int, default=0,
                   help="points scored per scene (0: the first net's finest level, else a quarter of --n-points)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = p.parse_args(argv)

    def run(_argv=None) -> int:
        import torch

        from evaluation.baselines.rigid_vote import RigidVoteBaseline
        from evaluation.methods import BaselineMethod, NetMethod, make_baseline
        from evaluation.protocols import ProtocolConfig, run_protocol
        from evaluation.readers import load_split
        from training.model.rigid_vote import RigidVoteConfig

        if args.threads:
            torch.set_num_threads(args.threads)
        methods = []
        for name, path in args.checkpoint:
            for scan in args.scan:
                methods.append(NetMethod(path, device="cpu", name=f"{name}, scan ±{scan:g}°", turn_scan=scan))
        for base in [b.strip() for b in args.baselines.split(",") if b.strip()]:
            if base == "rvote":
                methods += [BaselineMethod(RigidVoteBaseline(RigidVoteConfig(range_weighted=True, yaw_search_deg=scan),
                                                             name=f"rvote, scan ±{scan:g}°")) for scan in args.scan]
            else:
                methods.append(make_baseline(base))
        n_score = args.n_score or next((m.n_score for m in methods if isinstance(m, NetMethod)), args.n_points // 4)
        cfg = ProtocolConfig(protocol="fps", n_points=args.n_points, n_score=n_score)
        print("| split | turn added | method | EPE3D (m) | static | moving |\n|---|---|---|---|---|---|")
        for split_name, folder in args.split:
            split = load_split(folder, "auto")
            scenes = [split[i] for i in range(len(split) if args.scenes <= 0 else min(args.scenes, len(split)))]
            for deg in args.turns:
                results = run_protocol([turned_frame2(s, deg) for s in scenes], methods, cfg, progress=False)
                for r in results:
                    m = r.metrics
                    part = {k: (m[k]["EPE3D"] if isinstance(m.get(k), dict) else float("nan")) for k in ("static", "moving")}
                    print(f"| {split_name} | {deg:+g}° | {r.name} | {m['EPE3D']:.3f} | {part['static']:.3f} | "
                          f"{part['moving']:.3f} |", flush=True)
        return 0

    return run_cli(run)


if __name__ == "__main__":
    raise SystemExit(main())
