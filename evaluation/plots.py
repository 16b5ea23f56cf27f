"""Figures of an evaluation: the methods' EPE3D / Acc3DS as bars, and a top-down view of one scene.

* ``metrics.png``: two bar panels, EPE3D (m, lower is better) and Acc3DS (higher is better), one bar per
  method, with the std over seeds as error bars when there is one.
* ``scene-<name>.png``: one panel per method, the scene seen from above in the camera frame of frame 1
  (x right on the horizontal axis, z forward on the vertical axis, metres): every input point of pc1 in
  light grey, the scored points coloured by their EPE3D on the panel's own colour scale (its own colour bar:
  a method far worse than the others does not wash the rest out), and arrows of the predicted (black) and
  true (green) flow's x–z components on a subsample of the scored points.

Needs matplotlib, the optional extra ``plots`` (``pip install monoflow[plots]``); without it
:func:`write_plots` raises :class:`~core.errors.ConfigError` saying so. Uses the Agg canvas directly,
so no display and no global pyplot state are involved.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from evaluation.pictures import INSTALL_HINT  # one install hint for every picture
from evaluation.predictions import ScenePrediction
from core.errors import ConfigError


def _matplotlib():
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise ConfigError(f"plots need matplotlib, which is not installed: {INSTALL_HINT}") from None
    return Figure, FigureCanvasAgg


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "scene"


def bar_chart(path: Path, rows: Sequence[Mapping[str, Any]], title: str = "") -> Path:
    """``rows`` as from :func:`evaluation.protocols.summary_rows` → a PNG of EPE3D and Acc3DS per method."""
    Figure, Canvas = _matplotlib()
    names = [str(r["method"]) for r in rows]
    x = np.arange(len(rows))
    fig = Figure(figsize=(max(6.0, 1.2 * len(rows) + 2.0), 3.6), dpi=120)
    Canvas(fig)
    for i, (key, label) in enumerate((("EPE3D", "EPE3D (m) ↓"), ("Acc3DS", "Acc3DS ↑"))):
        ax = fig.add_subplot(1, 2, i + 1)
        vals = [float(r[key]) for r in rows]
        err = [float(r.get(f"{key}_std") or 0.0) for r in rows]
        ax.bar(x, vals, yerr=err if any(err) else None, color=f"C{i}", capsize=3)
        ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel(label)
        if key == "Acc3DS":
            ax.set_ylim(0, 1)
        ax.grid(axis="y", alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    return path


def top_down(path: Path, predictions: Sequence[ScenePrediction], background: np.ndarray | None = None) -> Path:
    """One panel per prediction: x (right) vs z (forward) of the scored points coloured by EPE3D (m), each panel
    on its own colour scale, with predicted (black) and true (green) flow arrows on a subsample."""
    Figure, Canvas = _matplotlib()
    if not predictions:
        raise ValueError("no predictions to plot")
    errors = [np.linalg.norm(p.pred_flow - p.gt_flow, axis=1) for p in predictions]
    n = len(predictions)
    fig = Figure(figsize=(4.2 * n + 0.5, 4.6), dpi=120)
    Canvas(fig)
    axes = [fig.add_subplot(1, n, i + 1) for i in range(n)]
    rng = np.random.default_rng(0)
    for ax, pred, err in zip(axes, predictions, errors):
        vmax = max(float(np.percentile(err, 98)), 1e-3)
        if background is not None:
            ax.scatter(background[:, 0], background[:, 2], s=0.5, c="0.85", linewidths=0, rasterized=True)
        sc = ax.scatter(pred.points[:, 0], pred.points[:, 2], s=2.0, c=err, cmap="viridis", vmin=0.0, vmax=vmax,
                        linewidths=0, rasterized=True)
        pick = rng.choice(len(pred.points), size=min(150, len(pred.points)), replace=False)
        for vec, colour in ((pred.gt_flow, "tab:green"), (pred.pred_flow, "black")):
            ax.quiver(pred.points[pick, 0], pred.points[pick, 2], vec[pick, 0], vec[pick, 2], angles="xy",
                      scale_units="xy", scale=1.0, width=0.003, color=colour, alpha=0.7)
        ax.set_title(f"{pred.method}\nEPE3D {err.mean():.3f} m (arrows: black predicted, green true)", fontsize=8)
        ax.set_xlabel("x (m, right)")
        ax.set_aspect("equal", adjustable="datalim")
        fig.colorbar(sc, ax=ax, label="EPE3D (m)", shrink=0.8, pad=0.02)
    axes[0].set_ylabel("z (m, forward)")
    fig.suptitle(f"scene {predictions[0].name}, top-down (camera frame of frame 1); each panel has its own "
                 "colour scale", fontsize=9)
    fig.savefig(path)
    return path


def write_plots(out_dir: str | Path, rows: Sequence[Mapping[str, Any]], scenes: Sequence[Any], methods: Sequence[Any],
                cfg: Any, scene_index: int = 0,
                predictions: Mapping[str, ScenePrediction] | None = None) -> list[Path]:
    """Write ``metrics.png`` and ``scene-<name>.png`` into ``out_dir``; return their paths.

    ``scenes`` / ``methods`` / ``cfg`` are what :func:`evaluation.protocols.run_protocol` was given; the
    scene view shows ``scenes[scene_index]``. ``predictions`` (method name → that scene's first-seed
    prediction, e.g. collected by ``run_protocol``'s ``on_prediction``) avoids running the methods
    again; missing ones are recomputed on exactly the protocol's points for the first seed.
    """
    _matplotlib()  # fail early and clearly, before any work
    from evaluation.protocols import predict, prepare_scene

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [bar_chart(out / "metrics.png", rows)]
    if not len(scenes):
        return paths
    sample = scenes[scene_index]
    have = dict(predictions or {})
    prepared = None
    preds = []
    for m in methods:
        p = have.get(m.name)
        if p is None or p.name != sample.name:
            if prepared is None:
                prepared = prepare_scene(sample, cfg, cfg.seeds[0])
            flow = predict(m, prepared)
            p = ScenePrediction(sample.name, prepared.points, flow, prepared.gt, prepared.moving, method=m.name)
        preds.append(p)
    paths.append(top_down(out / f"scene-{_slug(sample.name)}.png", preds, background=sample.pc1))
    return paths
