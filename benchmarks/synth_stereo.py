"""Stereo-KITTI-style point-pair splits from a synthetic world's per-pixel truth: image-grid clouds like the real one.

The community's KITTI test sets are not LiDAR re-scans: HPLFlowNet's ``KITTI_processed_occ_final`` and FlowNet3D's
``kitti_rm_ground`` turn each KITTI Scene Flow 2015 scene's per-pixel disparity and flow into point pairs — dense
image-grid clouds whose frame 2 is frame 1's own points moved, and whose static background moves exactly with the
camera. The synthetic world's scene-flow splits (``sceneflow/``) are scans of its simulated LiDAR; the only
image-grid split with movers the project has is one real scene (:mod:`benchmarks.real_stereo`), whose truth is a
published method's estimate. This tool writes a world's own image-grid pairs instead: each pixel of frame t with a
depth (``depth_2``, metres) and a true 3D flow (``flow3d_2``) gives ``pc1`` (the pixel back-projected through the
camera's intrinsics) and ``pc2 = pc1 + flow`` — exact truth, a rigid background, the generator's ``moving`` label —
in HPLFlowNet's layout (the reader cuts the ground and the range) or FlowNet3D's (the pairs within that cut, frame 2's
rows shuffled, as :mod:`benchmarks.real_stereo` writes). Any world the generator builds makes one, so development
and held-out worlds both get an image-grid split (docs/learned-flow.md, forty-fourth round)::

    python -m benchmarks.synth_stereo --world w/x61 --out w/x61_stereo
    monoflow-evaluate run --split w/x61_stereo --protocol fps --n_points 2048 --n_score 512 --checkpoint … \\
        --baselines icp-p2p,nsfp --rigid_polish --refine

Camera frames (x right, y down, z forward), metres.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.real_stereo import LAYOUTS, in_reader_cut, write_mapping, write_scene
from core.errors import InputError, run_cli
from core.geometry import backproject
from pipeline.kitti.odometry import OdometrySequence
from pipeline.kitti.png16 import read_depth_png
from pipeline.kitti.stereo_flow import StereoPairs
from pipeline.sources import GT_DEPTH_DIR, read_gt_flow


@dataclass
class SynthStereoConfig:
    """Options of the synthetic image-grid split.

    Attributes:
        world: a world folder written by ``python -m pipeline.synth`` (with ``sequences/<sequence>/depth_2`` and
            ``flow3d_2``).
        sequence: the sequence to read.
        pairs: scenes to write, the pairs t → t+1 from the sequence's first frame on (fewer when the sequence is
            shorter).
        layout: ``hplflownet`` (every pair; the reader cuts the ground and the range) or ``flownet3d`` (the pairs
            within that cut, frame 2's rows shuffled).
        seed: seed of the FlowNet3D layout's row shuffle.
        out: the split folder to create (must not exist).
    """

    world: str = ""
    sequence: str = "00"
    pairs: int = 19
    layout: str = "hplflownet"
    seed: int = 0
    out: str = ""


def pixel_pairs(seq: OdometrySequence, index: int) -> tuple[StereoPairs, np.ndarray]:
    """The point pairs of pair ``index`` → ``index + 1`` (camera-t frame, metres) and their ``moving`` label: every
    pixel with a depth and a valid true flow."""
    path = seq.seq_dir / GT_DEPTH_DIR / (seq.image_path(index).stem + ".png")
    if not path.is_file():
        raise InputError(path, "file not found (ground-truth depth)")
    depth = read_depth_png(path)
    if depth.shape != seq.image_shape:
        raise InputError(path, f"size {depth.shape[1]}x{depth.shape[0]} differs from the images' "
                               f"{seq.image_shape[1]}x{seq.image_shape[0]}")
    gt = read_gt_flow(seq, index, seq.image_shape, visible_next=False)
    use = gt.valid & (depth > 0) & np.isfinite(depth) & np.isfinite(gt.flow).all(-1)
    v, u = np.nonzero(use)
    points = backproject(depth.astype(np.float64), seq.K.astype(np.float64))[v, u]
    pc1 = points.astype(np.float32)
    pc2 = (points + gt.flow[v, u].astype(np.float64)).astype(np.float32)
    return StereoPairs(pc1, pc2, np.stack([u, v], axis=1).astype(np.int32)), gt.moving[v, u]


def build_split(cfg: SynthStereoConfig) -> tuple[int, int, float]:
    """Write the split to ``cfg.out`` (a ``.partial`` folder renamed into place when complete); returns (scenes,
    points kept by the reader per scene on average, the fraction of them labelled moving)."""
    if cfg.pairs < 1:
        raise ValueError(f"pairs must be ≥ 1, got {cfg.pairs}")
    if cfg.layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {cfg.layout!r}")
    out = Path(cfg.out)
    if out.exists():
        raise InputError(out, "exists; choose a new folder (the split is written whole or not at all)")
    seq = OdometrySequence(cfg.world, cfg.sequence)
    count = min(cfg.pairs, len(seq.frames) - 1)
    if count < 1:
        raise InputError(seq.seq_dir, "fewer than two frames: no pair to write")
    part = out.with_name(out.name + ".partial")
    shutil.rmtree(part, ignore_errors=True)
    kept, moved = 0, 0
    for k in range(count):
        pairs, moving = pixel_pairs(seq, k)
        cut = in_reader_cut(pairs)
        kept, moved = kept + int(cut.sum()), moved + int((moving & cut).sum())
        write_scene(part, k, pairs, moving, cfg.layout, cfg.seed)
    if cfg.layout == "hplflownet":
        write_mapping(part, f"{Path(cfg.world).name} sequence {cfg.sequence} pair {{}}", count)
    part.rename(out)
    return count, kept // count, moved / max(kept, 1)


def _main(argv: list[str] | None) -> int:
    from core.options import parse_config

    cfg = parse_config(SynthStereoConfig, argv, "synth_stereo", __doc__.split("\n\n")[0],
                       required=("world", "out"))
    n, kept, moving = build_split(cfg)
    print(f"synth_stereo: {n} scenes of about {kept} points each (after the reader's cuts) in {cfg.out}; "
          f"{moving:.1%} labelled moving")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; a missing or bad depth / flow file, or an existing ``--out``, is one ``error:`` line."""
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
