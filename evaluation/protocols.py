"""Scoring protocols: which points every method sees and which points are scored.

``paper``: sample ``n_points`` from each cloud (seeded by the seed and the scene name; with replacement
only when a cloud has fewer points), run every method on those clouds, and score ``n_score`` points of
the sampled pc1 chosen by farthest-point sampling from its first point — the net's level-0 points
(2048 of 8192 at the paper's settings), where the net's flow is its own output, not an interpolation.
``full``: the same sampled input, but each method's flow is spread to *every* input point of pc1 by
3-NN inverse-distance interpolation (exact at the sampled points) and all of them are scored.

Every method sees exactly the same sampled clouds (as read-only arrays, in the same order) and is
scored on exactly the same points. Metrics are per point → mean per scene → mean over scenes; with
several seeds the table gives the mean over seeds and the population std over seeds. Frames: camera
frame of frame 1 (pc1, flow) and of frame 2 (pc2), metres (see :mod:`evaluation.sample`).
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from evaluation.methods import FlowMethod
from evaluation.metrics import aggregate, mean_over_runs, scene_metrics
from evaluation.predictions import ScenePrediction
from evaluation.sample import SceneFlowSample
from pipeline.errors import ConfigError, InputError

PROTOCOLS = ("paper", "full")


@dataclass
class ProtocolConfig:
    """How a split is scored.

    protocol: ``"paper"`` or ``"full"`` (module docstring).
    n_points: points sampled from each cloud (what every method sees).
    n_score: scored points of the paper protocol (ignored by ``full``).
    seeds: sampling seeds; more than one adds ``<metric>_std`` over seeds.
    warmup: run each method once, untimed, on the first scene before timing (first-call set-up such as
        thread pools and lazy imports is then not counted in the time per scene).
    """

    protocol: str = "paper"
    n_points: int = 8192
    n_score: int = 2048
    seeds: tuple[int, ...] = (0,)
    warmup: bool = True

    def validate(self) -> "ProtocolConfig":
        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"unknown protocol {self.protocol!r}; expected one of {', '.join(PROTOCOLS)}")
        if self.n_points < 1 or self.n_score < 1:
            raise ConfigError(f"n_points and n_score must be >= 1, got {self.n_points} and {self.n_score}")
        if self.protocol == "paper" and self.n_score > self.n_points:
            raise ConfigError(f"n_score ({self.n_score}) cannot exceed n_points ({self.n_points})")
        if not self.seeds:
            raise ConfigError("at least one sampling seed is needed")
        return self


@dataclass
class MethodResult:
    """One method over a split.

    metrics: mean over scenes (mean ± std over seeds when several), as :func:`~evaluation.metrics.aggregate`.
    seconds_per_scene: mean wall time of one call (method + spreading its flow to the scored points), s.
    per_scene: the first seed's scene metrics, each with its ``name``.
    per_seed: one :func:`~evaluation.metrics.aggregate` per seed, each with its ``seed``.
    """

    name: str
    metrics: dict[str, Any]
    seconds_per_scene: float
    per_scene: list[dict[str, Any]] = field(default_factory=list)
    per_seed: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class PreparedScene:
    """One scene as every method sees it for one seed.

    pc1, pc2: (n_points, 3) sampled clouds (camera frames 1 and 2, metres); color1, color2 likewise or None.
    index1, index2: rows of the sample's pc1 / pc2 they were taken from.
    score_index: (n_score,) rows of the sampled pc1 that are scored (paper), or None (full: every input point).
    points, gt, moving: the scored points, their true flow and motion mask.
    """

    name: str
    seed: int
    pc1: np.ndarray
    pc2: np.ndarray
    color1: np.ndarray | None
    color2: np.ndarray | None
    index1: np.ndarray
    index2: np.ndarray
    score_index: np.ndarray | None
    points: np.ndarray
    gt: np.ndarray
    moving: np.ndarray | None
    pose: np.ndarray | None = None


def choose_points(rng: np.random.Generator, n_have: int, n_want: int) -> np.ndarray:
    """``n_want`` row indices of a cloud of ``n_have`` points in random order: distinct when possible,
    else every point once plus random repeats (order matters to nets that take the first N)."""
    if n_have < 1:
        raise ValueError("cannot sample an empty cloud")
    if n_have >= n_want:
        return rng.choice(n_have, size=n_want, replace=False)
    extra = rng.choice(n_have, size=n_want - n_have, replace=True)
    return rng.permutation(np.concatenate([np.arange(n_have), extra]))


def scored_points(pc1_sampled: np.ndarray, n_score: int) -> np.ndarray:
    """Indices of the ``n_score`` farthest-point-sampled points (starting at index 0), like the net's L0."""
    import torch

    from training.pointops import farthest_point_sample

    n = min(n_score, len(pc1_sampled))
    pts = torch.from_numpy(np.ascontiguousarray(pc1_sampled, dtype=np.float32))[None]
    return farthest_point_sample(pts, n)[0].numpy()


def interpolate_flow(query: np.ndarray, ref: np.ndarray, values: np.ndarray) -> np.ndarray:
    """3-NN inverse-distance interpolation of ``values`` (at ``ref``) at ``query``; all (·, 3) metres."""
    import torch

    from training.pointops import three_nn_interpolate

    def t(x: np.ndarray):
        return torch.tensor(np.asarray(x, dtype=np.float32))[None]

    with torch.no_grad():
        return three_nn_interpolate(t(query), t(ref), t(values))[0].numpy()


def _readonly(x: np.ndarray | None) -> np.ndarray | None:
    if x is None:
        return None
    x = np.array(x, copy=True)
    x.setflags(write=False)
    return x


def prepare_scene(sample: SceneFlowSample, cfg: ProtocolConfig, seed: int) -> PreparedScene:
    """Sample ``sample`` for ``seed`` (deterministic in the seed and the scene name) and pick the scored points."""
    if sample.n1 == 0 or sample.n2 == 0:
        raise InputError(f"scene {sample.name}", f"empty cloud after the reader's filters (pc1 {sample.n1} points, "
                                                 f"pc2 {sample.n2})")
    rng = np.random.default_rng([seed, zlib.crc32(sample.name.encode())])
    s1 = choose_points(rng, sample.n1, cfg.n_points)
    s2 = choose_points(rng, sample.n2, cfg.n_points)
    pc1, pc2 = sample.pc1[s1], sample.pc2[s2]
    c1 = sample.color1[s1] if sample.color1 is not None else None
    c2 = sample.color2[s2] if sample.color2 is not None else None
    if cfg.protocol == "paper":
        idx = scored_points(pc1, cfg.n_score)
        points, gt = pc1[idx], sample.flow[s1][idx]
        moving = sample.moving[s1][idx] if sample.moving is not None else None
    else:
        idx = None
        points, gt, moving = sample.pc1, sample.flow, sample.moving
    return PreparedScene(sample.name, seed, *(_readonly(a) for a in (pc1, pc2, c1, c2)), s1, s2, idx,
                         _readonly(points), _readonly(gt), _readonly(moving), sample.pose)


def predict(method: FlowMethod, scene: PreparedScene) -> np.ndarray:
    """The method's flow at the scored points of ``scene``, (n_scored, 3) float32 metres."""
    if getattr(method, "needs_pose", False):
        flow = method(scene.pc1, scene.pc2, scene.color1, scene.color2, pose=scene.pose)
    else:
        flow = method(scene.pc1, scene.pc2, scene.color1, scene.color2)
    flow = np.asarray(flow, dtype=np.float32)
    if flow.shape != scene.pc1.shape:
        raise ValueError(f"method {method.name!r} returned flow of shape {flow.shape}, expected {scene.pc1.shape}")
    if scene.score_index is not None:
        return flow[scene.score_index]
    return interpolate_flow(scene.points, scene.pc1, flow)


def _check_names(methods: Sequence[FlowMethod]) -> None:
    names = [m.name for m in methods]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ConfigError(f"methods need distinct names, repeated: {dupes}")


def run_protocol(split: Sequence[SceneFlowSample], methods: Sequence[FlowMethod], cfg: ProtocolConfig,
                 on_prediction: Callable[[str, ScenePrediction], None] | None = None,
                 progress: bool = True) -> list[MethodResult]:
    """Run every method on every scene for every seed.

    ``on_prediction(method_name, ScenePrediction)`` receives the first seed's predictions (scored points,
    predicted and true flow) as they are made. Returns one :class:`MethodResult` per method, in order.
    """
    from tqdm import tqdm

    cfg.validate()
    _check_names(methods)
    if not methods:
        raise ConfigError("no method to evaluate")
    if len(split) == 0:
        raise ConfigError("the split holds no scene")
    per_seed: dict[str, list[list[dict[str, Any]]]] = {m.name: [] for m in methods}
    seconds: dict[str, float] = {m.name: 0.0 for m in methods}
    calls = 0
    warm = not cfg.warmup
    few: list[str] = []  # scenes with fewer distinct frame-1 points than are scored
    for seed in cfg.seeds:
        scenes: dict[str, list[dict[str, Any]]] = {m.name: [] for m in methods}
        for sample in tqdm(split, desc=f"seed {seed}", disable=not progress, dynamic_ncols=True):
            scene = prepare_scene(sample, cfg, seed)
            if seed == cfg.seeds[0] and cfg.protocol == "paper" and sample.n1 < cfg.n_score:
                few.append(f"{sample.name} ({sample.n1})")
            if not warm:
                for m in methods:
                    predict(m, scene)
                warm = True
            calls += 1
            for m in methods:
                t0 = time.perf_counter()
                pred = predict(m, scene)
                seconds[m.name] += time.perf_counter() - t0
                row = scene_metrics(pred, scene.gt, moving=scene.moving)
                row["name"] = sample.name
                scenes[m.name].append(row)
                if on_prediction is not None and seed == cfg.seeds[0]:
                    on_prediction(m.name, ScenePrediction(name=sample.name, points=scene.points, pred_flow=pred,
                                                          gt_flow=scene.gt, moving=scene.moving, method=m.name))
        if few and seed == cfg.seeds[0]:
            import sys

            shown = ", ".join(few[:5]) + (f" and {len(few) - 5} more" if len(few) > 5 else "")
            print(f"note: {len(few)} scene(s) have fewer frame-1 points than the {cfg.n_score} scored; their "
                  f"scores count repeated points: {shown}", file=sys.stderr)
        for name, rows in scenes.items():
            per_seed[name].append(rows)
    results = []
    for m in methods:
        runs = [aggregate(rows) for rows in per_seed[m.name]]
        metrics = runs[0] if len(runs) == 1 else mean_over_runs(runs)
        seeds = [{"seed": s, **r} for s, r in zip(cfg.seeds, runs)]
        results.append(MethodResult(m.name, metrics, seconds[m.name] / max(calls, 1), per_seed[m.name][0], seeds))
    return results


def summary_rows(results: Iterable[MethodResult]) -> list[dict[str, Any]]:
    """Flat rows (one per method) for tables and CSV: metrics, their std over seeds, EPE3D on static /
    moving points, time per scene, scenes and seeds."""
    rows = []
    for r in results:
        m = r.metrics
        row: dict[str, Any] = {"method": r.name}
        for key in ("EPE3D", "Acc3DS", "Acc3DR", "Outliers3D"):
            row[key] = m[key]
            if f"{key}_std" in m:
                row[f"{key}_std"] = m[f"{key}_std"]
        for subset in ("static", "moving"):
            if subset in m:
                row[f"EPE3D_{subset}"] = m[subset]["EPE3D"]
                if "EPE3D_std" in m[subset]:
                    row[f"EPE3D_{subset}_std"] = m[subset]["EPE3D_std"]
        row["seconds_per_scene"] = r.seconds_per_scene
        row["n_scenes"] = m.get("n_scenes")
        row["n_seeds"] = m.get("n_runs", 1)
        rows.append(row)
    return rows
