"""Objective audit: does the unsupervised loss point at the true flow?

For pairs of a stage-one cache that hold ground-truth flow (the synthetic world's), evaluates every term
of the paper's loss (eq. 17: depth consistency eqs. 7–10, dynamic–static eq. 12, Chamfer eq. 13,
Laplacian eq. 14) at every pyramid level for a set of candidate flows of the same points:

* ``gt``: the true flow;
* ``gt+noise<σ>``: the true flow plus i.i.d. Gaussian noise of σ metres per axis;
* ``gt∘rigid``: the true flow followed by a wrong rigid motion (``rigid_deg`` about the camera's y axis
  and ``rigid_m`` along z, i.e. a misjudged ego-motion);
* ``static``: the ego-motion's flow alone (what a method blind to movers would output);
* ``movers×<s>``: the true flow with every point's departure from the ego-motion's flow scaled by s
  (``sf_s + s (f − sf_s)``; static points keep the truth, movers move a fraction s of their own motion —
  the form in which the demo preset's net gets movers wrong, docs/learned-flow.md, twenty-second round);
* ``net`` (with a checkpoint): the net's own two passes.

A candidate other than the net has ``f_o = f`` and ``f_d = f − sf_s`` (eq. 12 holds exactly, so its DS
term is 0); the net's ``f_d`` is its dynamic pass. Level points are the net's own sampling when a net is
given, else nested first-N subsets of the (randomly ordered) sampled clouds, as ``sampling="random"``.
A loss whose minimum is the truth gives ``gt`` the lowest weighted value at every level.

Run as ``python -m training.audit --cache <cache> [--checkpoint run/latest.pt]``; prints one row per
(candidate, level) with the weighted level loss and every unweighted term, all in the terms' own units
(depth, DS, Chamfer and Laplacian in m² with the default ``depth_norm="l1"`` making depth metres).

``--pulls`` audits the gradient instead of the value (:func:`truth_pulls`): how hard each term pulls the
true flow of the static points at the finest level, separately where the true target has a frame-2
point nearby and where it has none. A loss can have its lowest value at the truth and still pull single
points off it, towards where their samples happen to fall; a net that sees frame 2 can learn such pulls.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from training.data import FlowBatch, PairDataset, collate, pairs_with_gt_flow, split_pairs
from training.config import LossWeights
from training.losses.total import LevelInputs, multi_level_loss
from training.model.ego_motion import gate_value
from training.model.halflownet_config import HALFlowConfig


@dataclass
class AuditConfig:
    """What the audit evaluates.

    cache: stage-one cache with ground-truth flow.
    checkpoint: optional ``monoflow-train`` checkpoint whose flow is audited too.
    subset: ``train`` or ``val`` pairs (the trainer's split by ``val_fraction``), or ``all``.
    val_fraction: as the trainer's ``data.val_fraction``.
    pairs_max: audit at most this many pairs (evenly spread over the subset).
    n_points: points drawn per cloud (seeded); level_points: points of the 4 output levels, finest first.
    noise_m: σ of the Gaussian perturbations, metres per axis.
    mover_scales: the fractions s of the ``movers×<s>`` candidates.
    rigid_deg / rigid_m: the wrong rigid motion (yaw degrees, forward metres).
    seed: draws of the points and of the noise.
    """

    cache: str = ""
    checkpoint: str = ""
    subset: str = "all"
    val_fraction: float = 0.1
    pairs_max: int = 16
    n_points: int = 2048
    level_points: tuple[int, ...] = (512, 256, 64, 16)  # the demo net's output levels at 2048 points
    noise_m: tuple[float, ...] = (0.05, 0.2)
    mover_scales: tuple[float, ...] = (0.5,)
    rigid_deg: float = 1.0
    rigid_m: float = 0.2
    seed: int = 0
    weights: LossWeights = field(default_factory=LossWeights)


def _yaw_shift(deg: float, metres: float) -> Tensor:
    a = np.radians(deg)
    T = np.eye(4, dtype=np.float32)
    T[0, 0], T[0, 2], T[2, 0], T[2, 2] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)
    T[2, 3] = metres
    return torch.from_numpy(T)


def candidate_flows(batch: FlowBatch, cfg: AuditConfig) -> dict[str, Tensor]:
    """Candidate flows (B, N, 3), metres, at the batch's pc1 points (see the module docstring)."""
    if batch.gt_flow is None:
        raise ValueError("the audit needs pairs with ground-truth flow")
    gen = torch.Generator().manual_seed(cfg.seed)
    gt = batch.gt_flow
    out = {"gt": gt}
    for s in cfg.noise_m:
        out[f"gt+noise{s:g}"] = gt + s * torch.randn(gt.shape, generator=gen)
    T = _yaw_shift(cfg.rigid_deg, cfg.rigid_m)
    moved = (batch.pc1 + gt) @ T[:3, :3].T + T[:3, 3]
    out["gt∘rigid"] = moved - batch.pc1
    out["static"] = batch.static_flow
    for s in cfg.mover_scales:
        out[f"movers×{s:g}"] = batch.static_flow + s * (gt - batch.static_flow)
    return out


def _first_n_levels(n: int, level_points: tuple[int, ...]) -> list[Tensor]:
    return [torch.arange(min(k, n)) for k in level_points]


def _gate(flow: Tensor, static_flow: Tensor) -> Tensor:
    """The gate (B, n) an ego head whose rigid motion is stage one's would give ``flow``, at the head's
    default scale σ (for ``loss.plane_where_held``; :func:`training.model.ego_motion.gate_value`)."""
    sigma = HALFlowConfig().ego_sigma
    return gate_value(((flow - static_flow) ** 2).sum(-1).detach(), sigma * sigma)


def level_losses(batch: FlowBatch, flow_o: list[Tensor], flow_d: list[Tensor], idx1: list[Tensor],
                 idx2: list[Tensor], weights: LossWeights) -> list[dict[str, float]]:
    """Per level (finest first): every enabled unweighted term and ``weighted`` (α_k Σ β L), floats, as
    :func:`training.losses.total.multi_level_loss` computes and logs them."""
    from training.two_pass import gather

    levels = [LevelInputs(pc1=gather(batch.pc1, i1), pc2=gather(batch.pc2, i2), flow_o=fo, flow_d=fd,
                          static_flow=gather(batch.static_flow, i1), K=batch.K, depth2=batch.depth2,
                          gate_o=_gate(fo, gather(batch.static_flow, i1)))
              for fo, fd, i1, i2 in zip(flow_o, flow_d, idx1, idx2)]
    _, logged = multi_level_loss(levels, weights)
    return [{key.split("/", 1)[1]: v for key, v in logged.items() if key.startswith(f"l{k}/")}
            for k in range(len(levels))]


def _audited_pairs(cfg: AuditConfig):
    """The cache's reader and the pairs to audit: ``cfg.subset``'s pairs with ground-truth flow, at most
    ``cfg.pairs_max`` of them, evenly spread."""
    from pipeline.cache import CacheReader

    reader = CacheReader(cfg.cache)
    with_gt = pairs_with_gt_flow(reader)
    train, val = split_pairs(reader, cfg.val_fraction)
    pool = {"train": train, "val": val, "all": list(range(len(reader)))}[cfg.subset]
    pairs = [i for i in pool if i in with_gt]
    if not pairs:
        raise ValueError(f"{cfg.cache}: no {cfg.subset} pair with ground-truth flow")
    if len(pairs) > cfg.pairs_max:
        pairs = [pairs[int(j)] for j in np.linspace(0, len(pairs) - 1, cfg.pairs_max)]
    return reader, pairs


@torch.no_grad()
def audit(cfg: AuditConfig) -> list[dict]:
    """Rows ``{candidate, level, weighted, <terms>}``, each the mean over the audited pairs."""
    from training.two_pass import gather

    reader, pairs = _audited_pairs(cfg)
    net = None
    level_points = tuple(cfg.level_points)
    if cfg.checkpoint:
        from training.selection import load_flow_net

        net = load_flow_net(cfg.checkpoint)
        level_points = net.config.output_points
    data = PairDataset(reader, pairs, cfg.n_points, cfg.seed, colour_features=False, fixed_epoch=-1)
    sums: dict[tuple[str, int], dict[str, float]] = {}
    for j in range(len(pairs)):
        batch = collate([data[j]])
        if net is not None:
            from training.two_pass import forward_two_passes

            out_o, out_d = forward_two_passes(net, batch)
            idx1, idx2 = out_o.indices, out_o.indices2
            cands = {"net": (out_o.flows, out_d.flows)}
        else:
            idx1 = [i[None] for i in _first_n_levels(batch.pc1.shape[1], level_points)]
            idx2 = [i[None] for i in _first_n_levels(batch.pc2.shape[1], level_points)]
            cands = {}
        for name, f in candidate_flows(batch, cfg).items():
            fo = [gather(f, i) for i in idx1]
            fd = [gather(f - batch.static_flow, i) for i in idx1]
            cands[name] = (fo, fd)
        for name, (fo, fd) in cands.items():
            for k, row in enumerate(level_losses(batch, [x.float() for x in fo], [x.float() for x in fd],
                                                 idx1, idx2, cfg.weights)):
                acc = sums.setdefault((name, k), {})
                for key, v in row.items():
                    acc[key] = acc.get(key, 0.0) + v / len(pairs)
    return [{"candidate": name, "level": k, **vals} for (name, k), vals in sums.items()]


PULL_TERMS = ("depth", "chamfer", "laplacian", "smooth")


def truth_pulls(cfg: AuditConfig, far_m: float = 0.5, static_m: float = 0.05) -> dict[str, dict[str, float]]:
    """The pull of each term on the true flow of static points at the finest level.

    For every audited pair, the finest level's points (``cfg.level_points[0]`` of each cloud, as
    :func:`audit` samples them without a net) get the true flow ``f_o = gt`` (``f_d = gt − sf_s``); for each
    term of :data:`PULL_TERMS` the gradient of ``β · n · L`` (the term in the paper's sum form, weighted;
    the smoothness term, where ``weights.flow_smooth`` > 0, with that weight) with respect to ``f_o`` is taken. A point counts as static where its true flow is within ``static_m``
    metres of the camera motion's (``sf_s``), as ``near`` where its true target has a frame-2 point of the
    level within ``far_m`` metres and as ``far`` otherwise. Returns ``{term: {"near": m, "far": m}}``, the
    mean gradient length in metres over those points and pairs, and ``{"share": {"far": fraction}}``, the
    share of static points without a near frame-2 point. Zero pull at the truth is what a loss that points
    at the truth should give; a pull that depends on where the samples fall is a direction the net can
    learn to follow.
    """
    from training.knn import knn
    from training.losses.total import level_terms
    from training.two_pass import gather

    reader, pairs = _audited_pairs(cfg)
    data = PairDataset(reader, pairs, cfg.n_points, cfg.seed, colour_features=False, fixed_epoch=-1)
    beta = dict(zip(("depth", "ds", "chamfer", "laplacian"), cfg.weights.beta), smooth=cfg.weights.flow_smooth)
    sums = {t: {"near": [0.0, 0], "far": [0.0, 0]} for t in PULL_TERMS}
    for j in range(len(pairs)):
        batch = collate([data[j]])
        idx1, idx2 = (torch.arange(min(cfg.level_points[0], c.shape[1]))[None] for c in (batch.pc1, batch.pc2))
        pc1, pc2 = gather(batch.pc1, idx1), gather(batch.pc2, idx2)
        gt, sf = gather(batch.gt_flow, idx1), gather(batch.static_flow, idx1)
        static = ((gt - sf).norm(dim=-1) < static_m)[0]
        d2, _ = knn(pc1 + gt, pc2, 1)
        groups = {"near": static & (d2[0, :, 0] <= far_m ** 2), "far": static & (d2[0, :, 0] > far_m ** 2)}
        flow = gt.clone().requires_grad_(True)
        terms = level_terms(LevelInputs(pc1=pc1, pc2=pc2, flow_o=flow, flow_d=gt - sf, static_flow=sf, K=batch.K,
                                        depth2=batch.depth2, gate_o=_gate(gt, sf)), cfg.weights)
        for term in (t for t in PULL_TERMS if t in terms):
            grad, = torch.autograd.grad(beta[term] * pc1.shape[1] * terms[term], flow, retain_graph=True)
            length = grad[0].norm(dim=-1)
            for name, mask in groups.items():
                sums[term][name][0] += float(length[mask].sum())
                sums[term][name][1] += int(mask.sum())
    out = {t: {g: (v[0] / v[1] if v[1] else float("nan")) for g, v in by.items()} for t, by in sums.items()}
    near, far = sums[PULL_TERMS[0]]["near"][1], sums[PULL_TERMS[0]]["far"][1]
    out["share"] = {"far": far / max(near + far, 1)}
    return out


def format_rows(rows: list[dict]) -> str:
    terms = [t for t in ("weighted", "depth", "ds", "chamfer", "laplacian") if any(t in r for r in rows)]
    lines = ["| candidate | level | " + " | ".join(terms) + " |", "|---|---|" + "---|" * len(terms)]
    for r in sorted(rows, key=lambda r: (r["level"], r["candidate"])):
        values = " | ".join(f"{r.get(t, float('nan')):.4f}" for t in terms)
        lines.append(f"| {r['candidate']} | {r['level']} | {values} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from core.errors import run_cli

    p = argparse.ArgumentParser(prog="python -m training.audit", description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", required=True)
    p.add_argument("--checkpoint", default="")
    p.add_argument("--subset", default="all", choices=("train", "val", "all"))
    p.add_argument("--pairs-max", type=int, default=16)
    p.add_argument("--n-points", type=int, default=2048)
    p.add_argument("--beta", default="", help="loss weights β1..β4 (depth, DS, Chamfer, Laplacian), comma list; "
                                             "default: LossWeights'")
    p.add_argument("--chamfer-truncate", type=float, default=0.0,
                   help="metres; > 0: the Chamfer term truncated there (LossWeights.chamfer_truncate; 0 = the paper)")
    p.add_argument("--chamfer-plane", type=float, default=0.0, help="LossWeights.chamfer_plane (0 = the paper)")
    p.add_argument("--laplacian-plane", type=float, default=0.0, help="LossWeights.laplacian_plane (0 = the paper)")
    p.add_argument("--flow-smooth", type=float, default=0.0, help="LossWeights.flow_smooth (0 = the paper)")
    p.add_argument("--plane-where-held", action="store_true",
                   help="LossWeights.plane_where_held (the gate: what a head fitting stage one's motion would give)")
    p.add_argument("--pulls", action="store_true",
                   help="audit each term's pull on the true flow of static points instead (truth_pulls)")
    args = p.parse_args(argv)

    def run(_):
        beta = {"beta": tuple(float(b) for b in args.beta.split(","))} if args.beta else {}
        weights = LossWeights(chamfer_truncate=args.chamfer_truncate, chamfer_plane=args.chamfer_plane,
                              laplacian_plane=args.laplacian_plane, flow_smooth=args.flow_smooth,
                              plane_where_held=args.plane_where_held, **beta)
        cfg = AuditConfig(cache=args.cache, checkpoint=args.checkpoint, subset=args.subset,
                          pairs_max=args.pairs_max, n_points=args.n_points, weights=weights)
        if args.pulls:
            pulls = truth_pulls(cfg)
            print(f"static points without a frame-2 point within 0.5 m: {pulls['share']['far']:.1%}")
            print("| term | pull, near (m) | pull, far (m) |\n|---|---|---|")
            for term in (t for t in PULL_TERMS if t != "smooth" or args.flow_smooth > 0):
                print(f"| {term} | {pulls[term]['near']:.4f} | {pulls[term]['far']:.4f} |")
            return 0
        print(format_rows(audit(cfg)))
        return 0

    return run_cli(run, None)


if __name__ == "__main__":
    raise SystemExit(main())
