"""Pictures of scene flow and of training runs (matplotlib, the optional ``plots`` extra).

* :func:`pair_picture` — one PNG per predicted pair: (1) frame t with every point's scene flow projected into
  the image (colour = direction of the image motion, brightness = its length; wheel in the corner), (2) the
  moving-point mask (red: ``|flow − static flow| >`` threshold; blue: static; brightness = residual length),
  (3) a top-down view (x right, z forward, metres, camera-t frame) of both clouds — pc1 blue, pc2 moved into
  camera t orange — with arrows of each point's own motion (flow with the camera's motion removed).
* :func:`training_curves` — ``curves.png`` of a run folder's ``train.csv`` / ``val.csv`` (loss terms per step,
  log scale; each validation metric in its own panel).

All drawing goes through the Agg canvas: no display and no global pyplot state.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import ConfigError, InputError

INSTALL_HINT = "pip install matplotlib (in a monoflow checkout: pip install -e '.[plots]')"


def require_matplotlib():
    """(Figure, FigureCanvasAgg); ConfigError with the install command when matplotlib is missing."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise ConfigError(f"pictures need matplotlib, which is not installed: {INSTALL_HINT}") from None
    return Figure, FigureCanvasAgg


def _save(fig, canvas_cls, path: Path, dpi: int = 110) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas_cls(fig)
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=dpi)
    tmp.replace(path)
    return path


def direction_colours(vectors: np.ndarray, max_length: float) -> np.ndarray:
    """(N, 3) RGB in [0, 1] of 2D vectors (N, 2): hue = direction (right = red, down = yellow-green, left = cyan,
    up = violet, as image axes), value = length / max_length (clipped), full saturation."""
    from matplotlib.colors import hsv_to_rgb

    ang = np.arctan2(vectors[:, 1], vectors[:, 0])
    hue = (ang / (2 * np.pi)) % 1.0
    val = np.clip(np.linalg.norm(vectors, axis=1) / max(max_length, 1e-9), 0.0, 1.0)
    return hsv_to_rgb(np.stack([hue, np.ones_like(hue), 0.15 + 0.85 * val], axis=1))


def _wheel(size: int = 64) -> np.ndarray:
    y, x = np.mgrid[-1:1:size * 1j, -1:1:size * 1j]
    vec = np.stack([x.ravel(), y.ravel()], axis=1)
    rgb = direction_colours(vec, 1.0).reshape(size, size, 3)
    rgba = np.concatenate([rgb, (np.hypot(x, y) <= 1.0)[..., None].astype(float)], axis=2)
    return rgba


def projected_flow(pc1: np.ndarray, flow: np.ndarray, uv1: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image motion (N, 2) pixels of points pc1 (camera t) moved by their scene flow into camera t+1 and
    projected with K; ``ok`` (N,) where the moved point is in front of the camera."""
    p2 = pc1.astype(np.float64) + flow.astype(np.float64)
    z = p2[:, 2]
    ok = z > 1e-3
    zs = np.where(ok, z, 1.0)
    u = K[0, 0] * p2[:, 0] / zs + K[0, 1] * p2[:, 1] / zs + K[0, 2]
    v = K[1, 1] * p2[:, 1] / zs + K[1, 2]
    return np.stack([u, v], axis=1) - uv1.astype(np.float64), ok


def _overlay(base_grey: np.ndarray, uv: np.ndarray, colours: np.ndarray) -> np.ndarray:
    img = np.repeat(base_grey[..., None], 3, axis=2).astype(np.float64)
    u = uv[:, 0].astype(np.int64)
    v = uv[:, 1].astype(np.int64)
    img[v, u] = colours
    return np.clip(img, 0, 1)


def pair_picture(path: str | Path, pair: Any, image: np.ndarray, K: np.ndarray, moving_threshold: float,
                 max_arrows: int = 400) -> Path:
    """The three-panel PNG of one predicted pair (module docstring). ``pair`` has pc1, pc2, uv1, flow,
    static_flow, T, rgb1 (see :class:`evaluation.predict.run.PairOutput`); ``image``: frame t (any size, RGB
    uint8; resized to the working size of K's pixels)."""
    Figure, Canvas = require_matplotlib()
    from core.geometry import se3_inverse
    from pipeline.sources import resize_image

    uv1 = np.asarray(pair.uv1)
    H = int(round(max(2 * K[1, 2], uv1[:, 1].max() + 1 if len(uv1) else 1)))
    W = int(round(max(2 * K[0, 2], uv1[:, 0].max() + 1 if len(uv1) else 1)))
    if image.shape[:2] != (H, W):
        image = resize_image(image, (H, W))
    grey = image.astype(np.float64).mean(axis=2) / 255.0 * 0.45
    motion, ok = projected_flow(pair.pc1, pair.flow, uv1, K)
    mag = np.linalg.norm(motion[ok], axis=1)
    scale_px = float(np.percentile(mag, 98)) if mag.size else 1.0
    flow_img = _overlay(grey, uv1[ok], direction_colours(motion[ok], scale_px))

    dyn = np.linalg.norm(pair.flow - pair.static_flow, axis=1)
    moving = dyn > moving_threshold
    level = np.clip(dyn / (2 * moving_threshold), 0, 1)[:, None]
    col = np.where(moving[:, None], np.array([1.0, 0.15, 0.1]) * (0.5 + 0.5 * level),
                   np.array([0.25, 0.55, 1.0]) * (0.35 + 0.65 * level))
    mask_img = _overlay(grey, uv1, col)

    aspect = W / H
    fig = Figure(figsize=(12, 2 * 12 / aspect + 5.2))
    gs = fig.add_gridspec(3, 2, height_ratios=[1, 1, 5.2 * aspect / 12], width_ratios=[4, 1])
    ax1 = fig.add_subplot(gs[0, :])
    ax1.imshow(flow_img, interpolation="nearest")
    ax1.set_title(f"{pair.name}: scene flow projected into the image (colour = direction, brightness = length; "
                  f"full brightness ≥ {scale_px:.1f} px)", fontsize=9)
    ax1.axis("off")
    wheel = ax1.inset_axes([0.0, 0.0, 0.08 * H / W * 3.2, 0.3])
    wheel.imshow(_wheel(), interpolation="bilinear")
    wheel.axis("off")
    ax2 = fig.add_subplot(gs[1, :])
    ax2.imshow(mask_img, interpolation="nearest")
    ax2.set_title(f"moving points (red, |flow − static flow| > {moving_threshold:g} m): {int(moving.sum())} of "
                  f"{len(moving)} ({100 * moving.mean() if len(moving) else 0:.1f} %); blue = static, brighter = "
                  "larger residual", fontsize=9)
    ax2.axis("off")

    ax3 = fig.add_subplot(gs[2, 0])
    Tinv = se3_inverse(np.asarray(pair.T, dtype=np.float64))
    pc2_t = pair.pc2.astype(np.float64) @ Tinv[:3, :3].T + Tinv[:3, 3]
    end_t = (pair.pc1.astype(np.float64) + pair.flow) @ Tinv[:3, :3].T + Tinv[:3, 3]
    own = end_t - pair.pc1
    rng = np.random.default_rng(0)
    ax3.scatter(pc2_t[:, 0], pc2_t[:, 2], s=1.5, c="tab:orange", alpha=0.5, linewidths=0, label="pc2 (in camera t)",
                rasterized=True)
    ax3.scatter(pair.pc1[:, 0], pair.pc1[:, 2], s=1.5, c="tab:blue", alpha=0.5, linewidths=0, label="pc1",
                rasterized=True)
    mv = np.flatnonzero(moving)
    st = np.flatnonzero(~moving)
    pick = np.concatenate([rng.choice(mv, min(len(mv), max_arrows // 2), replace=False) if len(mv) else mv,
                           rng.choice(st, min(len(st), max_arrows // 2), replace=False) if len(st) else st])
    if len(pick):
        ax3.quiver(pair.pc1[pick, 0], pair.pc1[pick, 2], own[pick, 0], own[pick, 2], angles="xy",
                   scale_units="xy", scale=1.0, width=0.0025,
                   color=np.where(moving[pick, None], [[0.85, 0.1, 0.1]], [[0.2, 0.2, 0.2]]))
    ax3.set_xlabel("x (m, right)")
    ax3.set_ylabel("z (m, forward)")
    ax3.set_aspect("equal", adjustable="datalim")
    ax3.set_title("top-down, camera-t frame: arrows = each point's own motion (camera motion removed; red = "
                  "moving)", fontsize=9)
    ax3.legend(loc="upper right", fontsize=8, markerscale=6)
    ax4 = fig.add_subplot(gs[2, 1])
    ax4.axis("off")
    t = np.asarray(pair.T)[:3, 3]
    ang = math.degrees(math.acos(np.clip((np.trace(np.asarray(pair.T)[:3, :3]) - 1) / 2, -1, 1)))
    ax4.text(0, 0.95, f"T(t→t+1)\n|t| = {np.linalg.norm(t):.3f} m\nrotation {ang:.2f}°\n"
                      f"scale factor {pair.scale:.4g}{' (carried)' if getattr(pair, 'carried', False) else ''}\n"
                      f"pc1 {len(pair.pc1)} points\npc2 {len(pair.pc2)} points\n"
                      f"median |flow| {np.median(np.linalg.norm(pair.flow, axis=1)) if len(pair.flow) else 0:.3f} m",
             va="top", fontsize=9, family="monospace")
    fig.tight_layout()
    return _save(fig, Canvas, Path(path))


# ----------------------------------------------------------------------------------------------- training curves

_SKIP = ("step", "epoch", "time", "seconds", "lr", "grad", "samples", "wall")


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        return {}
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    cols: dict[str, list[float]] = {}
    for r in rows:
        for k, v in r.items():
            try:
                cols.setdefault(k, []).append(float(v))
            except (TypeError, ValueError):
                cols.setdefault(k, []).append(float("nan"))
    return {k: np.asarray(v) for k, v in cols.items()}


def training_curves(run_dir: str | Path, path: str | Path | None = None) -> Path:
    """``<run_dir>/curves.png`` (or ``path``) from ``train.csv`` and ``val.csv`` of a monoflow-train or
    monoflow-train-depth run: the training loss and its terms (log scale; of per-level terms ``l{k}/…`` the
    finest level's) and one panel per validation metric, all against the step."""
    Figure, Canvas = require_matplotlib()
    run = Path(run_dir)
    train = _read_csv(run / "train.csv")
    val = _read_csv(run / "val.csv")
    if not train and not val:
        raise InputError(run, "no train.csv or val.csv in this folder (not a monoflow run folder?)")
    tcols = [k for k in train if "step" != k and "/" not in k and not any(s in k for s in _SKIP)]
    if "loss" in tcols and "total" in tcols:
        tcols.remove("total")
    # per-level terms (monoflow-train: l0/<term> … l3/<term>): the finest level's terms
    tcols += [k for k in train if k.startswith("l0/") and k.split("/", 1)[1] not in ("weighted", "depth1", "depth2")]
    vcols = [k for k in val if k != "step" and not any(s in k for s in _SKIP)][:6]
    n = 1 + len(vcols)
    ncol = min(n, 3)
    nrow = math.ceil(n / ncol)
    fig = Figure(figsize=(5 * ncol, 3.6 * nrow))
    ax = fig.add_subplot(nrow, ncol, 1)
    steps = train.get("step", np.arange(len(next(iter(train.values()))) if train else 0))
    for k in tcols:
        y = train[k]
        if np.all(~np.isfinite(y)):
            continue
        ok = np.isfinite(y) & (y > 0)
        ax.plot(steps[ok], y[ok], lw=1.2 if k == "loss" else 0.9, label=k, color="black" if k == "loss" else None)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_title(f"{run.name}: training loss (black) and its terms", fontsize=10)
    if tcols:
        ax.legend(fontsize=7)
    vsteps = val.get("step", np.arange(len(next(iter(val.values()))) if val else 0))
    for i, k in enumerate(vcols, start=2):
        a = fig.add_subplot(nrow, ncol, i)
        y = val[k]
        a.plot(vsteps, y, marker="o", ms=3, lw=1.2)
        a.set_xlabel("step")
        unit = " (m)" if ("epe" in k.lower() or "ate" in k.lower()) else (" (°)" if "deg" in k else "")
        a.set_title(f"validation: {k}{unit}", fontsize=10)
        a.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, Canvas, Path(path) if path else run / "curves.png")


__all__ = ["INSTALL_HINT", "direction_colours", "pair_picture", "projected_flow", "require_matplotlib",
           "training_curves"]
