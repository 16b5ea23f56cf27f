"""How a trained net gets moving objects wrong: per object and pyramid level, the share of its own motion taken.

A moving object's true flow departs from the camera's motion by its own motion ``d``. Averaged over the
object's points, the net's departure from its own camera motion (the rigid flow its ego head fitted, or held
under the inference anchor) splits into a part along ``d`` and a part across it. The share along,
``s = (f̄ − r̄) · d / ‖d‖²``, is 1 when the net moves the object all the way, 0 when it leaves it with the camera;
the across part is metres of error no scaling explains. Used for docs/learned-flow.md (twenty-second round):
on the demo world the preset's net takes about two thirds of its movers' motion at 500 steps, all of it at
the finest level (the coarse levels' flows never leave the camera's motion). With ``--by-heading`` each level's
row is followed by one per heading class of the objects' own motion (``away`` from the camera, ``toward`` it,
``crossing``; twenty-third round)::

    python -m benchmarks.mover_bias --checkpoint runs/pre-w0-s0/step_000500.pt \\
        --split own=w0/world/sceneflow/flownet3d --split shifted=w0/shifted/sceneflow/flownet3d

Needs a split with per-point ``moving`` and ``instance`` labels (this project's synthetic splits write both)
and a net with an ego head (``model.ego_head``: its rigid flows). Clouds: camera frame of frame 1 (x right,
y down, z forward), metres; each scene's clouds are drawn at ``--n-points`` by the fps protocol
(:func:`evaluation.protocols.prepare_scene`, seed 0: the points ``monoflow-evaluate`` gives every method), and the
net's own level points are scored.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from benchmarks.named_folders import named_folder
from core.errors import ConfigError, run_cli
from evaluation.cli import AS_TRAINED


@dataclass(frozen=True)
class ObjectShare:
    """One moving object at one level: its points, the length of its own motion ``‖d‖`` (m), the share of it
    the net's flow takes along ``d``, the error across ``d`` of its mean flow (m), its points' mean EPE (m) and
    the heading of ``d`` in the ground plane (degrees, ``atan2(d_x, d_z)``: 0 = straight ahead, away from the
    camera, ±180 = toward it, +90 = to the right)."""

    points: int
    motion_m: float
    share: float
    across_m: float
    epe_m: float
    heading_deg: float = 0.0


HEADINGS = ("away", "crossing", "toward")


def heading_class(heading_deg: float) -> str:
    """``away`` within 45° of straight ahead, ``toward`` within 45° of straight back, ``crossing`` otherwise."""
    a = abs(heading_deg)
    return "away" if a < 45.0 else "toward" if a > 135.0 else "crossing"


def object_shares(flow: np.ndarray, rigid: np.ndarray, gt: np.ndarray, moving: np.ndarray,
                  instance: np.ndarray, min_points: int = 3) -> list[ObjectShare]:
    """Per moving object with at least ``min_points`` points: ``flow``, ``rigid`` (the net's camera-motion
    flow) and ``gt`` are (N, 3) metres at the same points; ``moving`` (N,) bool and ``instance`` (N,) ints
    label them. Objects whose own motion is shorter than 1 cm are left out (no direction to project on)."""
    out = []
    moving = np.asarray(moving, dtype=bool)
    for k in np.unique(instance[moving]):
        sel = moving & (instance == k)
        if sel.sum() < min_points:
            continue
        d = (gt[sel] - rigid[sel]).mean(0)
        norm2 = float(d @ d)
        if norm2 < 1e-4:
            continue
        q = (flow[sel] - rigid[sel]).mean(0)
        share = float(q @ d) / norm2
        across = float(np.linalg.norm(q - share * d))
        epe = float(np.linalg.norm(flow[sel] - gt[sel], axis=1).mean())
        heading = float(np.degrees(np.arctan2(d[0], d[2])))
        out.append(ObjectShare(int(sel.sum()), float(np.sqrt(norm2)), share, across, epe, heading))
    return out


def summary(objects: list[ObjectShare]) -> dict[str, float]:
    """Point-weighted means over ``objects`` (and the median share over objects)."""
    if not objects:
        return {"objects": 0, "points": 0}
    w = np.array([o.points for o in objects], dtype=float)
    col = {name: np.array([getattr(o, name) for o in objects]) for name in ("motion_m", "share", "across_m", "epe_m")}
    return {"objects": len(objects), "points": int(w.sum()), **{k: float(np.average(v, weights=w)) for k, v in col.items()},
            "share_median": float(np.median(col["share"]))}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="mover_bias", description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", required=True, help="monoflow-train checkpoint (a net with an ego head)")
    p.add_argument("--split", action="append", default=[], required=True, type=named_folder,
                   help="NAME=FOLDER of a scene-flow test split with moving and instance labels")
    p.add_argument("--n-points", type=int, default=2048, help="points sampled per cloud")
    p.add_argument("--eval-anchor", choices=tuple(AS_TRAINED), default="as-trained",
                   help="the net's inference anchor (model.eval_anchor)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument("--by-heading", action="store_true",
                   help="after each level's row, one per heading class of the objects' own motion (away, crossing, toward)")
    args = p.parse_args(argv)

    def run(_argv=None) -> int:
        import torch

        from evaluation.methods import NetMethod
        from evaluation.protocols import ProtocolConfig, prepare_scene
        from evaluation.readers import load_split

        if args.threads:
            torch.set_num_threads(args.threads)
        anchor = AS_TRAINED[args.eval_anchor]
        method = NetMethod(args.checkpoint, device="cpu", eval_anchor=anchor)
        print("| split | level | objects | points | own motion (m) | share taken (mean / median) | across (m) | "
              "movers' EPE3D (m) |\n|---|---|---|---|---|---|---|---|")
        protocol = ProtocolConfig(protocol="fps", n_points=args.n_points, n_score=method.n_score).validate()
        for name, folder in args.split:
            split = load_split(folder, "auto")
            per_level: dict[int, list[ObjectShare]] = {}
            for i in range(len(split)):
                s = split[i]
                if s.moving is None or s.instance is None:
                    raise ConfigError(f"{folder}: scene {s.name} has no moving/instance labels (mover_bias needs both)")
                scene = prepare_scene(s, protocol, seed=0)
                i1 = scene.index1
                with torch.no_grad():
                    out = method.net(torch.tensor(scene.pc1)[None], torch.tensor(scene.pc2)[None])  # copies: read-only
                if not out.rigid_flows:
                    raise ConfigError(f"{args.checkpoint}: the net reports no rigid flow (mover_bias needs model.ego_head)")
                for lvl in range(len(out.flows)):
                    idx = out.indices[lvl][0].numpy()
                    pts = i1[idx]
                    per_level.setdefault(lvl, []).extend(object_shares(
                        out.flows[lvl][0].float().numpy(), out.rigid_flows[lvl][0].float().numpy(), s.flow[pts],
                        s.moving[pts], s.instance[pts]))
            for lvl, objects in sorted(per_level.items()):
                groups = [(f"L{lvl}", objects)]
                if args.by_heading:
                    groups += [(f"L{lvl} {h}", [o for o in objects if heading_class(o.heading_deg) == h]) for h in HEADINGS]
                for label, group in groups:
                    r = summary(group)
                    if not r["objects"]:
                        print(f"| {name} | {label} | 0 | 0 | | | | |")
                        continue
                    print(f"| {name} | {label} | {r['objects']} | {r['points']} | {r['motion_m']:.3f} | {r['share']:.2f} / "
                          f"{r['share_median']:.2f} | {r['across_m']:.3f} | {r['epe_m']:.3f} |")
        return 0

    return run_cli(run)


if __name__ == "__main__":
    raise SystemExit(main())
