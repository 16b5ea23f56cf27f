"""Scoring protocols: which points every method sees and which points are scored.

Every protocol samples each cloud with a generator seeded by (seed, CRC-32 of the scene name), runs every
method on the same sampled clouds and scores the same points. The named protocols and the reference code
each reproduces (file and line in ``docs/evaluation-protocols.md``):

``released`` — 3DUnMonoFlow's released evaluation (``datasets/kitti_data.py`` + ``train.py:testOnce``):
    ``n_points`` (8192) drawn at random without replacement from each cloud, pc2 independently of pc1;
    a cloud with fewer points gives ``arange(n)`` followed by random repeats, *not shuffled*; the scored
    points are the **first** ``n_score`` (2048) rows of the sampled pc1 (its level 0 takes the first
    2048 with ``torch.split``, and the metric compares them with ``flow[:, :2048]``).
``fps`` — the first ``n_score`` points by farthest-point sampling (from row 0) of ``n_points`` random
    points, shuffled padding (monoflow's earlier ``paper`` protocol, kept bit for bit): the level-0
    points of a net trained with ``sampling="fps"``, whose flow there is its own output. Farthest-point
    sampling favours far, sparse points, so these are not the released code's points. ``paper`` is
    accepted as the old name of ``fps``.
``hplflownet`` — HPLFlowNet's KITTI protocol (``datasets/kitti.py`` + ``transforms.ProcessData``):
    only the scenes whose line of the KITTI devkit ``train_mapping.txt`` is non-empty (142 of 200;
    :func:`mapped_scenes`), ``n_points`` (8192) drawn without replacement from pc1 and, independently,
    from pc2; a cloud with fewer points is used whole, in file order, without padding; **every** sampled
    pc1 point is scored.
``flownet3d`` — FlowNet3D's KITTI evaluation (``kitti_dataset.py`` + ``evaluate.py``): ``n_points``
    (16384) with the released padding rule, every sampled row scored (repeats included).
``full`` — the ``fps`` protocol's input, but each method's flow is spread to *every* input point of pc1
    by 3-NN inverse-distance interpolation (exact at the sampled points) and all of them are scored.

Metrics are per point → mean per scene → mean over scenes; with several seeds the table gives the mean
over seeds and the population std over seeds. Frames: camera frame of frame 1 (pc1, flow) and of frame 2
(pc2), metres (see :mod:`evaluation.sample`).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from evaluation.answers import AnswerBook, ask
from evaluation.methods import FlowMethod
from evaluation.metrics import SUBSETS, aggregate, mean_over_runs, scene_metrics
from evaluation.predictions import ScenePrediction
from evaluation.sample import SceneFlowSample
from core.errors import ConfigError, InputError

PROTOCOLS = ("released", "fps", "hplflownet", "flownet3d", "full")
ALIASES = {"paper": "fps"}  # monoflow's earlier name of the fps protocol
# protocols that score a fixed-size prefix of the sample (n_score) / every sampled point / every input point
PREFIX_SCORED = ("released", "fps")
DEFAULT_POINTS = {"released": 8192, "fps": 8192, "hplflownet": 8192, "flownet3d": 16384, "full": 8192}


@dataclass
class ProtocolConfig:
    """How a split is scored.

    protocol: one of :data:`PROTOCOLS` (module docstring); ``"paper"`` is read as ``"fps"``.
    n_points: points sampled from each cloud (what every method sees).
    n_score: scored points of ``released`` (the first rows) and ``fps`` (farthest-point samples);
        ignored by the protocols that score every sampled or input point.
    seeds: sampling seeds; more than one adds ``<metric>_std`` over seeds.
    warmup: run each method once, untimed, on the first scene before timing (first-call set-up such as
        thread pools and lazy imports is then not counted in the time per scene).
    """

    protocol: str = "fps"
    n_points: int = 8192
    n_score: int = 2048
    seeds: tuple[int, ...] = (0,)
    warmup: bool = True

    def validate(self) -> "ProtocolConfig":
        """Check the settings and replace an alias (``paper``) by its protocol's name; returns self."""
        self.protocol = ALIASES.get(self.protocol, self.protocol)
        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"unknown protocol {self.protocol!r}; expected one of {', '.join(PROTOCOLS)} "
                              f"(or {', '.join(ALIASES)})")
        if self.n_points < 1 or self.n_score < 1:
            raise ConfigError(f"n_points and n_score must be >= 1, got {self.n_points} and {self.n_score}")
        if self.protocol in PREFIX_SCORED and self.n_score > self.n_points:
            raise ConfigError(f"n_score ({self.n_score}) cannot exceed n_points ({self.n_points})")
        if not self.seeds:
            raise ConfigError("at least one sampling seed is needed")
        return self

    def scored_rule(self) -> str:
        """One line saying which points are scored (report headers)."""
        p, n, k = self.protocol, self.n_points, self.n_score
        if p == "released":
            return (f"the first {k} of {n} random points per cloud (released loader: fewer points are "
                    "padded with arange(n) + random repeats, unshuffled)")
        if p == "fps":
            return f"{k} farthest-point samples (from row 0) of {n} random points per cloud"
        if p == "hplflownet":
            return (f"all {n} random points of pc1 (pc2 drawn independently; a smaller cloud is used whole), "
                    "scenes with a raw-data mapping only")
        if p == "flownet3d":
            return f"all {n} sampled points of pc1, repeats included (released padding)"
        return f"every input point of pc1 (methods run on {n} random points, flow spread by 3-NN)"


@dataclass
class MethodResult:
    """One method over a split.

    metrics: mean over scenes (mean ± std over seeds when several), as :func:`~evaluation.metrics.aggregate`.
    seconds_per_scene: mean wall time of one call (method + spreading its flow to the scored points), s; a
        wrapper row's includes the seconds its inner row took on the scene (its flow is taken from that row's
        run, :mod:`evaluation.answers`), so it is the time of running the row from scratch.
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
    score_index: rows of the sampled pc1 that are scored, or None (``full``: every input point).
    points, gt, moving: the scored points (camera-1 frame, metres), their true flow and motion mask.
    foreground: the scored points' foreground flags (class ≠ 0), or None when the split has no classes.
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
    foreground: np.ndarray | None = None


def choose_points(rng: np.random.Generator, n_have: int, n_want: int) -> np.ndarray:
    """``n_want`` row indices of a cloud of ``n_have`` points in random order: distinct when possible,
    else every point once plus random repeats (order matters to nets that take the first N)."""
    if n_have < 1:
        raise ValueError("cannot sample an empty cloud")
    if n_have >= n_want:
        return rng.choice(n_have, size=n_want, replace=False)
    extra = rng.choice(n_have, size=n_want - n_have, replace=True)
    return rng.permutation(np.concatenate([np.arange(n_have), extra]))


def released_points(rng: np.random.Generator, n_have: int, n_want: int) -> np.ndarray:
    """The released loaders' rule (3DUnMonoFlow / FlowNet3D ``SceneflowDataset``): ``n_want`` distinct
    random rows when the cloud has enough, else ``arange(n_have)`` followed by ``n_want − n_have``
    random repeats, in that order (so the first ``n_have`` rows are the file's points in file order)."""
    if n_have < 1:
        raise ValueError("cannot sample an empty cloud")
    if n_have >= n_want:
        return rng.choice(n_have, size=n_want, replace=False)
    return np.concatenate([np.arange(n_have), rng.choice(n_have, size=n_want - n_have, replace=True)])


def hplflownet_points(rng: np.random.Generator, n_have: int, n_want: int) -> np.ndarray:
    """HPLFlowNet's rule (``ProcessData``, ``allow_less_points``): ``n_want`` distinct random rows, or
    every row in file order when the cloud has fewer (no padding)."""
    if n_have < 1:
        raise ValueError("cannot sample an empty cloud")
    if n_have >= n_want:
        return rng.choice(n_have, size=n_want, replace=False)
    return np.arange(n_have)


def scored_points(pc1_sampled: np.ndarray, n_score: int) -> np.ndarray:
    """Indices of the ``n_score`` farthest-point-sampled points (starting at index 0), like the net's L0."""
    import torch

    from training.pointops import farthest_point_sample

    n = min(n_score, len(pc1_sampled))
    pts = torch.from_numpy(np.array(pc1_sampled, dtype=np.float32))[None]  # a writable copy
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
    protocol = ALIASES.get(cfg.protocol, cfg.protocol)
    rng = np.random.default_rng([seed, zlib.crc32(sample.name.encode())])
    draw = {"released": released_points, "flownet3d": released_points,
            "hplflownet": hplflownet_points}.get(protocol, choose_points)
    s1 = draw(rng, sample.n1, cfg.n_points)
    s2 = draw(rng, sample.n2, cfg.n_points)  # drawn after, and independently of, pc1's sample
    pc1, pc2 = sample.pc1[s1], sample.pc2[s2]
    c1 = sample.color1[s1] if sample.color1 is not None else None
    c2 = sample.color2[s2] if sample.color2 is not None else None
    fg_all = sample.foreground
    if protocol == "full":
        idx = None
        points, gt, moving, fg = sample.pc1, sample.flow, sample.moving, fg_all
    else:
        if protocol == "fps":
            idx = scored_points(pc1, cfg.n_score)
        elif protocol == "released":
            idx = np.arange(min(cfg.n_score, len(s1)))
        else:  # hplflownet, flownet3d: every sampled row
            idx = np.arange(len(s1))
        rows = s1[idx]
        points, gt = sample.pc1[rows], sample.flow[rows]
        moving = sample.moving[rows] if sample.moving is not None else None
        fg = fg_all[rows] if fg_all is not None else None
    return PreparedScene(sample.name, seed, *(_readonly(a) for a in (pc1, pc2, c1, c2)), s1, s2, idx,
                         _readonly(points), _readonly(gt), _readonly(moving), sample.pose, _readonly(fg))


def predict(method: FlowMethod, scene: PreparedScene) -> np.ndarray:
    """The method's flow at the scored points of ``scene``, (n_scored, 3) float32 metres."""
    extra = {"pose": scene.pose} if getattr(method, "needs_pose", False) else {}
    flow = ask(method, scene.pc1, scene.pc2, scene.color1, scene.color2, **extra)  # from the scene's book if open
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
            if seed == cfg.seeds[0] and cfg.protocol in ("fps", "released", "paper") and sample.n1 < cfg.n_score:
                few.append(f"{sample.name} ({sample.n1})")
            if not warm:  # every part of every row runs once (a stack's rows share their parts' answers)
                with AnswerBook(scene.pc1, scene.pc2, scene.color1, scene.color2):
                    for m in methods:
                        predict(m, scene)
                warm = True
            calls += 1
            # a wrapper row is given its inner row's flow on this scene, and that row's seconds (evaluation/answers.py)
            with AnswerBook(scene.pc1, scene.pc2, scene.color1, scene.color2) as book:
                for m in methods:
                    pred, dt = book.timed(predict, m, scene)
                    seconds[m.name] += dt
                    row = scene_metrics(pred, scene.gt, moving=scene.moving, foreground=scene.foreground,
                                        depth=scene.points[:, 2])
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
    """Flat rows (one per method) for tables and CSV: metrics, their std over seeds, EPE3D on every subset
    the split allows (static / moving, the three-way subsets and their mean, distance bands), the dynamic
    normalised EPE, time per scene, scenes and seeds."""
    rows = []
    for r in results:
        m = r.metrics
        row: dict[str, Any] = {"method": r.name}
        for key in ("EPE3D", "Acc3DS", "Acc3DR", "Outliers3D", "EPE3D_threeway"):
            if key not in m:
                continue
            row[key] = m[key]
            if f"{key}_std" in m:
                row[f"{key}_std"] = m[f"{key}_std"]
        for subset in SUBSETS:
            if subset in m:
                row[f"EPE3D_{subset}"] = m[subset]["EPE3D"]
                if "EPE3D_std" in m[subset]:
                    row[f"EPE3D_{subset}_std"] = m[subset]["EPE3D_std"]
        if "moving" in m and "EPE3D_norm" in m["moving"]:
            row["EPE3D_norm_dynamic"] = m["moving"]["EPE3D_norm"]
            if "EPE3D_norm_std" in m["moving"]:
                row["EPE3D_norm_dynamic_std"] = m["moving"]["EPE3D_norm_std"]
        row["seconds_per_scene"] = r.seconds_per_scene
        row["n_scenes"] = m.get("n_scenes")
        row["n_seeds"] = m.get("n_runs", 1)
        rows.append(row)
    return rows
