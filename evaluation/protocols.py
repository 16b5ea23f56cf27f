"""Scoring protocols: which points every method sees and which points are scored.

``paper``: sample ``n_points`` from each cloud (seeded by the seed and the scene name), run every method
on those clouds, and score ``n_score`` points of pc1 chosen by farthest-point sampling (the level-0
points of the net, 2048 at the paper's settings).
``full``: the same sampled input, but each method's flow is spread to *every* input point of pc1 by
3-NN inverse-distance interpolation and all of them are scored.

Every method sees exactly the same sampled clouds and is scored on exactly the same points.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field
from typing import Any, Iterable, Sequence

import numpy as np

from evaluation.methods import FlowMethod
from evaluation.metrics import aggregate, mean_over_runs, scene_metrics
from evaluation.predictions import ScenePrediction
from evaluation.sample import SceneFlowSample

PROTOCOLS = ("paper", "full")


@dataclass
class ProtocolConfig:
    protocol: str = "paper"
    n_points: int = 8192
    n_score: int = 2048
    seeds: tuple[int, ...] = (0,)


@dataclass
class MethodResult:
    """One method over a split: metrics (mean over scenes; ± std over seeds) and time per scene (s)."""

    name: str
    metrics: dict[str, Any]
    seconds_per_scene: float
    per_scene: list[dict[str, Any]] = field(default_factory=list)


def _choose(rng: np.random.Generator, n_have: int, n_want: int) -> np.ndarray:
    if n_have >= n_want:
        return np.sort(rng.choice(n_have, size=n_want, replace=False))
    extra = rng.choice(n_have, size=n_want - n_have, replace=True)
    return np.concatenate([np.arange(n_have), extra])


def scored_points(pc1_sampled: np.ndarray, n_score: int) -> np.ndarray:
    """Indices of the ``n_score`` farthest-point-sampled points (starting at index 0), like the net's L0."""
    import torch

    from training.pointops import farthest_point_sample

    n = min(n_score, len(pc1_sampled))
    return farthest_point_sample(torch.from_numpy(pc1_sampled.astype(np.float32))[None], n)[0].numpy()


def _interpolate(query: np.ndarray, ref: np.ndarray, values: np.ndarray) -> np.ndarray:
    import torch

    from training.pointops import three_nn_interpolate

    t = lambda x: torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None]  # noqa: E731
    return three_nn_interpolate(t(query), t(ref), t(values))[0].numpy()


def run_protocol(split: Sequence[SceneFlowSample], methods: Sequence[FlowMethod], cfg: ProtocolConfig,
                 on_prediction=None, progress: bool = True) -> list[MethodResult]:
    """Run every method on every scene for every seed; ``on_prediction(ScenePrediction)`` sees seed 0's."""
    from tqdm import tqdm

    if cfg.protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {cfg.protocol!r}; expected one of {PROTOCOLS}")
    per_seed: dict[str, list[list[dict[str, Any]]]] = {m.name: [] for m in methods}
    seconds: dict[str, float] = {m.name: 0.0 for m in methods}
    calls = 0
    for seed in cfg.seeds:
        scenes: dict[str, list[dict[str, Any]]] = {m.name: [] for m in methods}
        for sample in tqdm(split, desc=f"seed {seed}", disable=not progress, dynamic_ncols=True):
            rng = np.random.default_rng([seed, zlib.crc32(sample.name.encode())])
            s1 = _choose(rng, len(sample.pc1), cfg.n_points)
            s2 = _choose(rng, len(sample.pc2), cfg.n_points)
            pc1, pc2 = sample.pc1[s1], sample.pc2[s2]
            c1 = sample.color1[s1] if sample.color1 is not None else None
            c2 = sample.color2[s2] if sample.color2 is not None else None
            if cfg.protocol == "paper":
                idx = scored_points(pc1, cfg.n_score)
                points, gt = pc1[idx], sample.flow[s1][idx]
                moving = sample.moving[s1][idx] if sample.moving is not None else None
            else:
                points, gt, moving = sample.pc1, sample.flow, sample.moving
            calls += 1
            for m in methods:
                t0 = time.perf_counter()
                flow = m(pc1, pc2, c1, c2)
                pred = flow[idx] if cfg.protocol == "paper" else _interpolate(sample.pc1, pc1, flow)
                seconds[m.name] += time.perf_counter() - t0
                scene = scene_metrics(pred, gt, moving=moving)
                scene["name"] = sample.name
                scenes[m.name].append(scene)
                if on_prediction is not None and seed == cfg.seeds[0]:
                    on_prediction(m.name, ScenePrediction(name=sample.name, points=points, pred_flow=pred,
                                                          gt_flow=gt, moving=moving, method=m.name))
        for name, rows in scenes.items():
            per_seed[name].append(rows)
    results = []
    for m in methods:
        runs = [aggregate(rows) for rows in per_seed[m.name]]
        metrics = runs[0] if len(runs) == 1 else mean_over_runs(runs)
        results.append(MethodResult(m.name, metrics, seconds[m.name] / max(calls, 1), per_seed[m.name][0]))
    return results


def summary_rows(results: Iterable[MethodResult]) -> list[dict[str, Any]]:
    """Flat rows (one per method) for tables and CSV."""
    rows = []
    for r in results:
        m = r.metrics
        row = {"method": r.name}
        for key in ("EPE3D", "Acc3DS", "Acc3DR", "Outliers3D"):
            row[key] = m[key]
            if f"{key}_std" in m:
                row[f"{key}_std"] = m[f"{key}_std"]
        for subset in ("static", "moving"):
            if subset in m:
                row[f"EPE3D_{subset}"] = m[subset]["EPE3D"]
        row["seconds_per_scene"] = r.seconds_per_scene
        row["n_scenes"] = m.get("n_scenes")
        rows.append(row)
    return rows
