"""Scene-flow metrics, the community's definitions (docs/design.md §6).

Per point, with predicted flow ``f`` and ground truth ``g`` (metres):

* ``EPE3D = ‖f − g‖``
* ``rel = EPE3D / (‖g‖ + 1e-4)``
* ``Acc3DS`` (strict) = ``EPE3D < 0.05 or rel < 0.05``
* ``Acc3DR`` (relaxed) = ``EPE3D < 0.1 or rel < 0.1``
* ``Outliers3D`` = ``EPE3D > 0.3 or rel > 0.1``

Each is averaged over the points of a scene, then the scene values are averaged over scenes (every scene
weighs the same, whatever its point count). Accuracies and outliers are fractions in [0, 1].

When a per-point ``moving`` mask is given, the same metrics are also computed on the static and on the
moving points; a scene contributes to a subset's average only if it has points in that subset.

Metrics that keep the static majority from hiding the movers (Chodosh et al. 2023, Khatri et al. 2024),
computed where the split marks them:

* **three-way EPE** (needs ``moving`` and ``foreground``, i.e. a per-point class with 0 = background):
  the metrics on background-static (``bg_static``), foreground-static (``fg_static``) and
  foreground-dynamic (``fg_dynamic``) points; ``EPE3D_threeway`` is the mean of the three subsets'
  EPE3D (each first averaged over the scenes that have such points, like every subset here — the
  Argoverse-2 API sums points over the whole split instead). Background points marked moving belong to
  none of the three.
* **dynamic normalised EPE** (needs ``moving``): per scene, the mean EPE of the moving points divided by
  their mean true flow length ‖g‖ (``moving["EPE3D_norm"]``, dimensionless) — the share of the motion
  left undescribed (0 = perfect, 1 = as bad as predicting zero flow for them, on average). Flow here
  includes the camera's own motion (KITTI's convention), so the denominator is the total observed
  motion of those points, not the object's motion alone as on ego-compensated Argoverse-2 data.
* **distance bands** (needs ``depth``, camera z of the scored points in metres): the metrics on points
  with z in [0, 20), [20, 35) and [35, ∞) m (``z0-20``, ``z20-35``, ``z35+``; 35 m is the far limit,
  :data:`pipeline.filters.FAR_LIMIT_M`), each present only where a scene has such points; monocular depth
  error grows with range.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from pipeline.filters import FAR_LIMIT_M

METRIC_NAMES: tuple[str, ...] = ("EPE3D", "Acc3DS", "Acc3DR", "Outliers3D")
THREEWAY: tuple[str, ...] = ("bg_static", "fg_static", "fg_dynamic")
#: (name, lower, upper) camera-z bands, metres: near, up to the far limit, and beyond it (only protocols that
#: keep far points have any there); names ``z0-20``, ``z20-35``, ``z35+``.
BANDS: tuple[tuple[str, float, float], ...] = (("z0-20", 0.0, 20.0), (f"z20-{FAR_LIMIT_M:g}", 20.0, FAR_LIMIT_M),
                                               (f"z{FAR_LIMIT_M:g}+", FAR_LIMIT_M, float("inf")))
SUBSETS: tuple[str, ...] = ("static", "moving", *THREEWAY, *(b[0] for b in BANDS))
OPTIONAL_METRICS: tuple[str, ...] = ("EPE3D_norm",)  # aggregated where every member has it
REL_EPS = 1e-4


def _as_flow(name: str, value: Any) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    return arr


def point_errors(pred: np.ndarray, gt: np.ndarray) -> dict[str, np.ndarray]:
    """Per-point ``epe`` and ``rel`` errors and the three boolean classifications (float64 / bool)."""
    pred = _as_flow("pred", pred)
    gt = _as_flow("gt", gt)
    if pred.shape != gt.shape:
        raise ValueError(f"pred {pred.shape} and gt {gt.shape} differ in shape")
    epe = np.linalg.norm(pred - gt, axis=1)
    rel = epe / (np.linalg.norm(gt, axis=1) + REL_EPS)
    return {
        "epe": epe,
        "rel": rel,
        "acc_strict": (epe < 0.05) | (rel < 0.05),
        "acc_relax": (epe < 0.1) | (rel < 0.1),
        "outlier": (epe > 0.3) | (rel > 0.1),
    }


def _summarise(err: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, float | int]:
    return {
        "EPE3D": float(err["epe"][keep].mean()),
        "Acc3DS": float(err["acc_strict"][keep].mean()),
        "Acc3DR": float(err["acc_relax"][keep].mean()),
        "Outliers3D": float(err["outlier"][keep].mean()),
        "n_points": int(keep.sum()),
    }


def _vector(name: str, value: Any, n: int, dtype: type) -> np.ndarray:
    arr = np.asarray(value)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    return arr.astype(dtype)


def scene_metrics(
    pred: np.ndarray,
    gt: np.ndarray,
    mask: np.ndarray | None = None,
    moving: np.ndarray | None = None,
    foreground: np.ndarray | None = None,
    depth: np.ndarray | None = None,
) -> dict[str, Any]:
    """Metrics of one scene.

    Args:
        pred: (N, 3) predicted flow, metres.
        gt: (N, 3) ground-truth flow, metres.
        mask: optional (N,) bool, the points to score (default: all).
        moving: optional (N,) bool, True on independently moving points; adds ``"static"`` and
            ``"moving"`` sub-dicts, each present only when that subset has scored points; the
            ``"moving"`` one also holds ``"EPE3D_norm"`` (dynamic normalised EPE, module docstring).
        foreground: optional (N,) bool, True on foreground-class points (class ≠ 0); with ``moving``
            adds the three-way subsets ``"bg_static"``, ``"fg_static"``, ``"fg_dynamic"``.
        depth: optional (N,) camera z of the scored points, metres; adds the distance-band subsets.

    Returns:
        ``{"EPE3D", "Acc3DS", "Acc3DR", "Outliers3D": float, "n_points": int}`` plus the optional
        subset sub-dicts of the same form (:data:`SUBSETS`).

    Raises:
        ValueError: on mismatched shapes or when no point is scored.
    """
    err = point_errors(pred, gt)
    n = len(err["epe"])
    keep = np.ones(n, dtype=bool)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (n,):
            raise ValueError(f"mask must have shape ({n},), got {mask.shape}")
        keep &= mask.astype(bool)
    if not keep.any():
        raise ValueError("no points to score (empty scene or empty mask)")
    out: dict[str, Any] = _summarise(err, keep)
    if moving is not None:
        moving = _vector("moving", moving, n, bool)
        for subset, sel in (("static", keep & ~moving), ("moving", keep & moving)):
            if sel.any():
                out[subset] = _summarise(err, sel)
        if "moving" in out:
            sel = keep & moving
            speed = float(np.linalg.norm(np.asarray(gt, np.float64)[sel], axis=1).mean())
            out["moving"]["EPE3D_norm"] = out["moving"]["EPE3D"] / max(speed, REL_EPS)
        if foreground is not None:
            fg = _vector("foreground", foreground, n, bool)
            for subset, sel in (("bg_static", ~fg & ~moving), ("fg_static", fg & ~moving),
                                ("fg_dynamic", fg & moving)):
                if (sel & keep).any():
                    out[subset] = _summarise(err, sel & keep)
    if depth is not None:
        z = _vector("depth", depth, n, np.float64)
        for name, lo, hi in BANDS:
            sel = keep & (z >= lo) & (z < hi)
            if sel.any():
                out[name] = _summarise(err, sel)
    return out


def threeway(metrics: Mapping[str, Any]) -> float | None:
    """Mean of the three-way subsets' EPE3D of an :func:`aggregate` output, or None if one is missing."""
    if all(s in metrics for s in THREEWAY):
        return float(np.mean([metrics[s]["EPE3D"] for s in THREEWAY]))
    return None


def _mean_std(values: list[float], with_std: bool, key: str, out: dict[str, Any]) -> None:
    arr = np.asarray(values, dtype=np.float64)
    out[key] = float(arr.mean())
    if with_std:
        out[f"{key}_std"] = float(arr.std(ddof=0))


def _aggregate_flat(scenes: list[Mapping[str, Any]], with_std: bool) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in METRIC_NAMES:
        _mean_std([s[key] for s in scenes], with_std, key, out)
    for key in OPTIONAL_METRICS:
        if all(key in s for s in scenes):
            _mean_std([s[key] for s in scenes], with_std, key, out)
    out["n_scenes"] = len(scenes)
    out["n_points"] = int(sum(int(s.get("n_points", 0)) for s in scenes))
    return out


def aggregate(scenes: Iterable[Mapping[str, Any]], with_std: bool = False) -> dict[str, Any]:
    """Mean over scenes of per-scene metrics (each scene weighs the same).

    Args:
        scenes: dicts as returned by :func:`scene_metrics`.
        with_std: also report ``"<metric>_std"``, the population standard deviation over scenes.

    Returns:
        ``{"EPE3D", "Acc3DS", "Acc3DR", "Outliers3D", "n_scenes", "n_points"}`` (``n_points`` summed)
        plus subset dicts (:data:`SUBSETS`) of the same form over the scenes that have such points, and
        ``"EPE3D_threeway"`` when all three three-way subsets are present.

    Raises:
        ValueError: when ``scenes`` is empty or a scene lacks a metric.
    """
    scenes = list(scenes)
    if not scenes:
        raise ValueError("no scenes to aggregate")
    for i, s in enumerate(scenes):
        missing = [k for k in METRIC_NAMES if k not in s]
        if missing:
            raise ValueError(f"scene {i} lacks metrics {missing}")
    out = _aggregate_flat(scenes, with_std)
    for subset in SUBSETS:
        members = [s[subset] for s in scenes if subset in s]
        if members:
            out[subset] = _aggregate_flat(members, with_std)
    tw = threeway(out)
    if tw is not None:
        out["EPE3D_threeway"] = tw
    return out


def mean_over_runs(runs: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Mean ± std over repeated runs (e.g. sampling seeds) of :func:`aggregate` outputs.

    Returns the same layout with each metric the mean over runs and ``"<metric>_std"`` the population
    standard deviation over runs; ``n_scenes`` / ``n_points`` are taken from the first run.
    """
    runs = list(runs)
    if not runs:
        raise ValueError("no runs to average")

    def merge(items: list[Mapping[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key in METRIC_NAMES:
            _mean_std([r[key] for r in items], True, key, out)
        for key in (*OPTIONAL_METRICS, "EPE3D_threeway"):
            if all(key in r for r in items):
                _mean_std([r[key] for r in items], True, key, out)
        out["n_scenes"] = items[0].get("n_scenes")
        out["n_points"] = items[0].get("n_points")
        out["n_runs"] = len(items)
        return out

    out = merge(runs)
    for subset in SUBSETS:
        members = [r[subset] for r in runs if subset in r]
        if len(members) == len(runs):
            out[subset] = merge(members)
    return out
