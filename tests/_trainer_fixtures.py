"""A tiny stage-one cache and a tiny training config for the trainer's tests.

The cache holds an analytic "panels" world, written block by block with
:class:`pipeline.cache.CacheWriter` from ground-truth depth and pose, so the static flow is exact and the
GT flow of every kept point is known: the camera (x right, y down, z forward, metres) looks at a back
wall 14 m ahead and fronto-parallel rectangular panels 4–10 m ahead, and moves 0.5 m forward and 0.1 m
right per frame (no rotation); one panel moves 0.4 m/frame to the left. Every pixel sees a surface (no
sky, no ground), 48×160 pixels, ≈7 700 points per cloud; two sequences, 16 pairs.

Why not the street of :mod:`testkit.demo_scene`: its depth maps show the road, a ramp of depths
in the image. The paper's depth-consistency loss (eqs. 7–10) is zero for any point moved onto a pixel of
D_{t+1} at its own depth, and at the 128-point levels of the tiny net the Chamfer term is dominated by
its sampling noise (≈1.1 m² at the true flow, the same as for zero flow), so a short training there
slides points down onto the road (measured: mean flow y ≈ +1.2 m after 100 steps) and EPE3D rises. On
fronto-parallel panels the depth loss pins the flow's z component, which a short run does learn.
Building the cache takes about a second; :func:`tiny_cache` (session-scoped) builds one copy for each test
module that imports it.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
HEIGHT, WIDTH = 48, 160
PAIRS_PER_BLOCK = 4
BLOCKS = {"00": 3, "01": 1}  # sequence -> blocks: 12 + 4 pairs; val_fraction 0.25 holds out 3 + 1
EGO_STEP = np.array([0.1, 0.0, 0.5])  # camera displacement per frame (world = camera-0 axes), metres
MOVER_STEP = np.array([-0.4, 0.0, 0.0])  # panel 0's displacement per frame, metres
# panels: (x0, x1, y0, y1, z) in the world, metres; colour (RGB); panel 0 moves
PANELS = [((-1.0, 1.0, -1.2, 0.8, 6.0), (200, 40, 40)), ((-4.5, -1.5, -2.0, 1.0, 8.0), (40, 160, 60)),
          ((1.5, 4.5, -1.5, 1.5, 9.5), (50, 60, 200)), ((-2.5, -0.5, 0.2, 1.4, 4.5), (220, 200, 60)),
          ((2.0, 3.0, -0.5, 0.5, 5.0), (120, 30, 160))]
WALL_Z = 14.0


def panels_intrinsics(height: int = HEIGHT, width: int = WIDTH) -> np.ndarray:
    f = 0.9 * width
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def _camera_position(seq_offset: float, frame: int) -> np.ndarray:
    return np.array([seq_offset, 0.0, 0.0]) + frame * EGO_STEP


def render_panels(frame: int, seq_offset: float, K: np.ndarray, height: int = HEIGHT, width: int = WIDTH):
    """(depth (H, W) float32 metres, rgb (H, W, 3) uint8, moving (H, W) bool) seen from frame ``frame``."""
    c = _camera_position(seq_offset, frame)
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    rx, ry = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]  # ray direction with z = 1
    depth = np.full(u.shape, WALL_Z - c[2])
    wx, wy = c[0] + depth * rx, c[1] + depth * ry
    colour = np.stack([90 + 40 * np.sin(1.3 * wx), 90 + 40 * np.cos(1.1 * wy), 110 + 30 * np.sin(0.7 * (wx + wy))], -1)
    moving = np.zeros(u.shape, bool)
    for k, ((x0, x1, y0, y1, z), base) in enumerate(PANELS):
        shift = MOVER_STEP * frame if k == 0 else np.zeros(3)
        d = z - c[2]
        hx, hy = c[0] + d * rx - shift[0], c[1] + d * ry - shift[1]
        hit = (hx >= x0) & (hx <= x1) & (hy >= y0) & (hy <= y1) & (d < depth)
        depth[hit] = d
        stripes = 1.0 + 0.2 * np.sin(5.0 * hx) * np.cos(4.0 * hy)
        colour[hit] = stripes[hit, None] * np.array(base, float)
        moving[hit] = k == 0
    rgb = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
    return depth.astype(np.float32), rgb, moving


def panels_block(sequence: str, block_index: int, seq_offset: float, pairs: int = PAIRS_PER_BLOCK,
                 height: int = HEIGHT, width: int = WIDTH):
    """Block ``block_index`` of a panels sequence: pairs (t, t+1) for t = block_index·pairs … + pairs − 1."""
    from pipeline.cache import BlockRecord, FrameRecord, PairRecord, canonical_depth, points_from_depth
    from core.geometry import static_flow

    K = panels_intrinsics(height, width)
    ids = list(range(block_index * pairs, block_index * pairs + pairs + 1))
    frames, moving = [], {}
    for fid in ids:
        depth, rgb, mov = render_panels(fid, seq_offset, K, height, width)
        frames.append(FrameRecord(fid, canonical_depth(depth), rgb))
        moving[fid] = mov.reshape(-1)
    every = np.arange(height * width, dtype=np.int32)
    T = np.eye(4)
    T[:3, 3] = -EGO_STEP  # camera-t point -> camera-(t+1) point (pure translation)
    pair_records = []
    for t in ids[:-1]:
        pc1 = points_from_depth(frames[t - ids[0]].depth, every, K)
        mov = moving[t]
        gt = (static_flow(pc1, T, as_float32=True) + mov[:, None] * MOVER_STEP.astype(np.float32)).astype(np.float32)
        pair_records.append(PairRecord(t, t + 1, every, every, T, 1.0, {"kept": int(every.size)}, gt, mov))
    return BlockRecord(sequence=sequence, block_index=block_index, K=K, frames=frames, pairs=pair_records)


def build_tiny_cache(out: Path) -> Path:
    """Write the tiny panels cache under ``out``; returns its root (the folder holding manifest.json)."""
    from pipeline.cache import CacheWriter, cache_root

    config = {"size": [WIDTH, HEIGHT], "fixture": "trainer-tests-panels"}
    root = cache_root(out, "panels", config)
    writer = CacheWriter(root, config, {"dataset": "trainer test panels"})
    for s, (seq, n_blocks) in enumerate(BLOCKS.items()):
        for b in range(n_blocks):
            writer.write_block(panels_block(seq, b, seq_offset=0.7 * s))
    writer.finalize(BLOCKS)
    return root


@pytest.fixture(scope="session")
def tiny_cache(tmp_path_factory) -> Path:
    return build_tiny_cache(tmp_path_factory.mktemp("trainer_cache"))


def tiny_config(cache: Path, run_dir: Path, **top):
    """A :class:`TrainConfig` of the tiny net (256 points, width 0.25) on ``cache``; ``top`` overrides
    top-level fields; pass ``data=``, ``optim=`` … as dicts of field overrides."""
    from training.config import DataConfig, OptimConfig, TrainConfig
    from training.losses.total import LossWeights
    from training.model.halflownet import HALFlowConfig

    nested = {"data": DataConfig(n_points=256, workers=0, val_fraction=0.25),
              "optim": OptimConfig(lr=2e-3, batch_size=2),
              "model": HALFlowConfig(n_points=256, level_points=(128, 64, 32, 16, 8), level_k=(8, 8, 8, 8, 4),
                                     cost_k_pc2=8, width_scale=0.25),
              "loss": LossWeights()}
    for key in list(top):
        if key in nested:
            nested[key] = replace(nested[key], **top.pop(key))
    base = dict(cache=str(cache), run_dir=str(run_dir), steps=10, seed=0, device="cpu", threads=1,
                log_every=1, val_every=1000, ckpt_every=5, progress=False)
    base.update(top)
    return TrainConfig(**base, **nested)


def config_flags(cfg) -> list[str]:
    """The ``monoflow-train`` flags that rebuild ``cfg`` (every field, nested ones dotted)."""
    from dataclasses import asdict

    def flat(d, prefix=""):
        for k, v in d.items():
            if isinstance(v, dict):
                yield from flat(v, f"{prefix}{k}.")
            else:
                text = ",".join(map(str, v)) if isinstance(v, (tuple, list)) else str(v).lower() if isinstance(v, bool) else str(v)
                yield f"--{prefix}{k}"
                yield text

    return list(flat(asdict(cfg)))


def child_env() -> dict[str, str]:
    """Environment of a training subprocess: the repo importable, one thread per process."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    return env
