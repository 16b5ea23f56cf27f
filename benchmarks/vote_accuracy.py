"""How good the camera translation of the translation vote is, on the points the net would see.

For every pair: ``--n-points`` random points of each cloud, then the net's level-0 sample (farthest-point
sampling to ``--level-points``), the vote (:func:`training.model.translation_vote.vote_translation`) on
those, and its error against the true flow of the static points (mean ‖flow − t‖ over the static points of
the random sample, metres; the rotation's share of the static flow stays in it). Pairs whose error is over
``--fail-m`` are counted as failures: the vote locked onto a mover or a wrong mode. Sources are labelled
stage-one caches (``--cache``: camera clouds, stage one's flow from the given poses) and scene-flow splits
(``--split NAME=FOLDER``). ``--candidates 1`` scores the fullest histogram cell alone, for comparison.

Used for docs/learned-flow.md (tenth round), on training caches rather than test splits::

    python -m benchmarks.vote_accuracy --cache w/cache/world/<hash> --pairs 40 --candidates 1,4
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.named_folders import named_folder


def vote_errors(samples, n_points: int, level_points: int, candidates: int, seed: int = 0,
                rigid: str = "") -> np.ndarray:
    """Per pair, the mean static-point error of the voted translation (metres), as the ``tvote`` baseline
    finds it on the pair's random sample; ``samples`` yield :class:`evaluation.sample.SceneFlowSample`.
    ``rigid`` "free" or "planar": of the rigid vote's flow ``R p + t − p`` instead (the ``rvote`` baseline,
    :mod:`training.model.rigid_vote`), fitted on the same level-0 samples; with "-dense" its rounds match the
    whole random sample of frame 2, with "-far" its choice is weighed by range ("free-dense-far")."""
    from evaluation.baselines.rigid_vote import RigidVoteBaseline
    from evaluation.baselines.translation_vote import TranslationVoteBaseline
    from training.model.rigid_vote import RigidVoteConfig
    from training.model.translation_vote import VoteConfig

    cfg = VoteConfig(candidates=candidates)
    if rigid:
        method = RigidVoteBaseline(RigidVoteConfig(vote=cfg, planar=rigid.startswith("planar"),
                                                   range_weighted="far" in rigid),
                                   sample_points=level_points, dense_target="dense" in rigid)
    else:
        method = TranslationVoteBaseline(cfg, sample_points=level_points)
    rng = np.random.default_rng(seed)
    out = []
    for s in samples:
        i1 = rng.choice(len(s.pc1), min(n_points, len(s.pc1)), replace=False)
        i2 = rng.choice(len(s.pc2), min(n_points, len(s.pc2)), replace=False)
        flow = method(s.pc1[i1], s.pc2[i2])  # (n, 3) per point, metres
        static = np.ones(len(i1), bool) if s.moving is None else ~np.asarray(s.moving, bool)[i1]
        if static.any():
            out.append(float(np.linalg.norm(s.flow[i1][static] - flow[static], axis=1).mean()))
    return np.asarray(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="vote_accuracy", description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", action="append", default=[], help="stage-one cache folder (labelled pairs)")
    p.add_argument("--split", action="append", default=[], type=named_folder,
                   help="NAME=FOLDER of a scene-flow test split")
    p.add_argument("--pairs", type=int, default=40, help="cache pairs, evenly spaced (0 = all)")
    p.add_argument("--n-points", type=int, default=2048)
    p.add_argument("--level-points", type=int, default=512)
    p.add_argument("--candidates", default="1,4", help="comma list of VoteConfig.candidates to compare")
    p.add_argument("--fail-m", type=float, default=0.5)
    p.add_argument("--rigid", default="", help="comma list of rigid-vote modes to add (free, planar): the vote "
                   "followed by trimmed rigid matching (training.model.rigid_vote); '-dense' matches the rounds "
                   "against the whole cloud, '-far' weighs the choice by range (e.g. free-dense-far)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)

    import torch

    from benchmarks.sensor_gap import cache_samples
    from core.errors import InputError
    from evaluation.readers.split import load_split
    from pipeline.cache import CacheReader

    torch.set_num_threads(args.threads)
    sources: dict[str, list] = {}
    try:
        for path in args.cache:
            reader = CacheReader(path)
            step = 1 if args.pairs <= 0 else max(1, len(reader) // args.pairs)
            sources[f"cache {path}"] = cache_samples(reader, list(range(0, len(reader), step)), "c")
        for name, folder in args.split:
            sources[name] = list(load_split(folder))
    except InputError as exc:
        print(f"vote_accuracy: {exc}")
        return 2
    if not sources:
        p.error("give at least one --cache or --split")
    print(f"| source | vote | candidates | pairs | mean static error (m) | median | failures (> {args.fail_m} m) |")
    print("|---|---|---|---|---|---|---|")
    modes = [""] + [m for m in args.rigid.split(",") if m]
    for name, samples in sources.items():
        for k in (int(c) for c in args.candidates.split(",")):
            for mode in modes:
                e = vote_errors(samples, args.n_points, args.level_points, k, rigid=mode)
                print(f"| {name} | {mode or 'translation'} | {k} | {len(e)} | {e.mean():.3f} | {np.median(e):.3f} "
                      f"| {int((e > args.fail_m).sum())} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
