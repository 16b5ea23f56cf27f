"""One block's compute: read and resize its frames, each frame's depth **once** (one batched net pass, or one
file read) reused by both pairs holding the frame, every pair's pose, the block's scale factor, the filters,
and the :class:`~pipeline.cache.records.BlockRecord` to write (docs/design.md §3).

:class:`BlockProcessor` does it in two halves, :meth:`~BlockProcessor.infer` (reading and the nets) and
:meth:`~BlockProcessor.finish` (scale, filters, records), so that a runner can overlap one block's finish with
the next block's nets. Nothing here writes to the cache.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from core.errors import MonoflowError
from pipeline.preprocess.config import PreprocessConfig
from pipeline.preprocess.planning import BlockPlan
from pipeline.preprocess.sequences import open_sequences
from pipeline.scale import ScaleError, combine_factors, frame_factor, implausible_depth


@dataclass
class BlockResult:
    """What processing one block produced (for the summary and the benchmark)."""

    sequence: str
    index: int
    pairs: int
    frames: int
    written: bool
    scale: float
    depth_images: int = 0
    pose_pairs: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    stats: list[dict[str, int]] = field(default_factory=list)
    frames_without_scale: int = 0  # frames whose own scale factor failed (no road plane, no LiDAR overlap)
    carried: bool = False  # no frame gave a factor: the block took the last good one (or the sequence median)
    warnings: list[str] = field(default_factory=list)


class DeferBlock(MonoflowError):
    """A block without any scale factor met before any good factor of its sequence: finish it at the end with
    the sequence median (carries the block's inferred data)."""

    def __init__(self, inferred: "InferredBlock") -> None:
        super().__init__(f"sequence {inferred.plan.sequence} block {inferred.plan.index}: no scale factor yet")
        self.inferred = inferred


@dataclass
class InferredBlock:
    """A block after reading and the nets (what :meth:`BlockProcessor.finish` needs)."""

    plan: BlockPlan
    hw: tuple[int, int]  # working size (H, W), pixels
    K: np.ndarray  # (3, 3) intrinsics at the working size
    positions: list[int]  # the block's frames, as positions in the sequence, ascending
    where: dict[int, int]  # position -> row of images / depths
    images: np.ndarray  # (F, H, W, 3) uint8 RGB
    depths: np.ndarray  # (F, H, W) depth as the source gave it (before the scale factor), 0 = invalid
    Ts: np.ndarray  # (P, 4, 4) float64 T_{t→t+1} per pair, as the source gave it
    depth_images: int  # depth-net images run for this block
    pose_pairs: int  # pose-net pairs run for this block
    seconds: dict[str, float]


class BlockProcessor:
    """Builds the sources once (the nets, in this process) and turns block plans into :class:`BlockRecord` s."""

    def __init__(self, config: PreprocessConfig, sequences: dict | None = None, runner: Any = None) -> None:
        from pipeline.sources import build_runner, make_depth_source, make_pose_source

        self.config = config
        self.hw_size = config.working_size()
        self.sequences = sequences if sequences is not None else open_sequences(config)
        self.runner = runner if runner is not None else build_runner(config.net_spec())
        self.depth_source = make_depth_source(
            config.depth, self.runner, disparity_dir=config.disparity_dir,
            disparity_focal=config.disparity_focal, disparity_baseline=config.disparity_baseline,
        )
        self.pose_source = make_pose_source(config.pose, self.runner)
        st = config.scale.scale_translation
        self.scales_translation = config.pose == "net" if st is None else bool(st)
        self.good_factors: dict[str, list[float]] = {}  # per sequence, blocks whose frames gave a factor, in order

    def build(self, plan: BlockPlan):
        """(BlockRecord, BlockResult) of one planned block; nothing is written."""
        return self.finish(self.infer(plan))

    def infer(self, plan: BlockPlan) -> "InferredBlock":
        """First half of a block: read and resize its frames, each frame's depth once, every pair's pose."""
        from pipeline.sources import read_frames, working_K, working_size

        seq = self.sequences[plan.sequence]
        clock = _Clock()
        hw = working_size(seq.image_shape, self.hw_size)
        K = working_K(seq, hw)
        positions = sorted({p for pair in plan.pairs for p in pair})
        where = {p: k for k, p in enumerate(positions)}
        images = read_frames(seq, positions, hw)
        clock.lap("read")
        n0 = self._counters()
        depths = self.depth_source.depths(seq, positions, images, K)  # each frame once
        clock.lap("depth")
        imgs_t = images[[where[i] for i, _ in plan.pairs]]
        imgs_t1 = images[[where[j] for _, j in plan.pairs]]
        Ts = np.array(self.pose_source.poses(seq, list(plan.pairs), imgs_t, imgs_t1), dtype=np.float64)
        clock.lap("pose")
        n1 = self._counters()
        return InferredBlock(plan, hw, K, positions, where, images, depths, Ts, n1[0] - n0[0], n1[1] - n0[1], clock.laps)

    def finish(self, inf: "InferredBlock", forced_factor: float | None = None):
        """Second half of a block: scale, filters (frame-only ones once per frame), ground truth, records.

        A block where no frame gives a factor takes, with ``scale.fallback = carry``, the sequence's last good
        factor, or raises :class:`DeferBlock` when there is none yet (the caller finishes it later with
        ``forced_factor`` = the sequence median); with ``abort`` it raises :class:`ScaleError`.
        """
        from pipeline.cache.points import canonical_depth
        from pipeline.cache.records import BlockRecord, FrameRecord
        from pipeline.pairs import build_pair, frame_points
        from pipeline.sources import LidarDepth, has_gt_flow, read_gt_flow

        cfg = self.config
        plan, K, positions, where = inf.plan, inf.K, inf.positions, inf.where
        seq = self.sequences[plan.sequence]
        clock = _Clock()
        lidar = None
        if cfg.scale.mode == "lidar":
            lidar = inf.depths if cfg.depth == "lidar" else LidarDepth().depths(seq, positions, inf.images, K)
        factors, last_error = [], None
        for k in range(len(positions)):
            try:
                factors.append(frame_factor(cfg.scale, inf.depths[k], K, None if lidar is None else lidar[k]))
            except ScaleError as exc:
                factors.append(float("nan"))
                last_error = exc
        failed = int(sum(1 for f in factors if not np.isfinite(f)))
        carried = False
        try:
            s = combine_factors(factors)
            self.good_factors.setdefault(plan.sequence, []).append(s)
        except ScaleError:
            ids = [seq.frames[p] for p in positions]
            good = self.good_factors.get(plan.sequence)
            if forced_factor is not None:
                s, carried = float(forced_factor), True
            elif cfg.scale.fallback == "carry" and good:
                s, carried = good[-1], True
            elif cfg.scale.fallback == "carry":
                raise DeferBlock(inf) from None
            else:
                raise ScaleError(f"sequence {plan.sequence} block {plan.index} (frames {ids[0]}..{ids[-1]}): "
                                 f"no frame gave a scale factor ({last_error}); --scale.fallback carry takes "
                                 "the last good factor instead") from None
        depths = canonical_depth(inf.depths * np.float32(s))
        warnings = []
        odd = implausible_depth(depths)
        if odd is not None:
            ids = [seq.frames[p] for p in positions]
            warnings.append(f"sequence {plan.sequence} frames {ids[0]}..{ids[-1]}: {odd}")
            if cfg.scale.refuse_non_metric:
                raise ScaleError(f"{warnings[-1]} (--scale.refuse_non_metric true)")
        Ts = inf.Ts.copy()
        if self.scales_translation:
            Ts[:, :3, 3] *= s
        clock.lap("scale")

        T_velo = seq.T_velo_to_cam if cfg.filters.lidar else None
        fps = [frame_points(depths[k], K, cfg.filters, T_velo) for k in range(len(positions))]
        gt_on = has_gt_flow(seq)
        records = []
        for (i, j), T in zip(plan.pairs, Ts):
            gt = read_gt_flow(seq, i, inf.hw, visible_next=False) if gt_on else None
            a, b = where[i], where[j]
            records.append(build_pair(seq.frames[i], seq.frames[j], depths[a], depths[b], T, K, cfg.filters,
                                      scale=s, T_velo_to_cam=T_velo, gt=gt, points_t=fps[a], points_t1=fps[b]))
        clock.lap("filters")
        frames = [FrameRecord(frame_id=seq.frames[p], depth=depths[k], rgb=inf.images[k])
                  for k, p in enumerate(positions)]
        block = BlockRecord(sequence=plan.sequence, block_index=plan.index, K=K, frames=frames, pairs=records)
        result = BlockResult(
            sequence=plan.sequence, index=plan.index, pairs=len(records), frames=len(positions), written=False,
            scale=s, depth_images=inf.depth_images, pose_pairs=inf.pose_pairs,
            seconds={**inf.seconds, **clock.laps}, stats=[dict(r.stats) for r in records],
            frames_without_scale=failed, carried=carried, warnings=warnings,
        )
        return block, result

    def _counters(self) -> tuple[int, int]:
        r = self.runner
        return (0, 0) if r is None else (int(r.depth_images), int(r.pose_pairs))


class _Clock:
    """Seconds per named step, summed over laps (a block's ``seconds`` breakdown)."""

    def __init__(self) -> None:
        self.t = time.perf_counter()
        self.laps: dict[str, float] = {}

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self.t
        self.t = now


__all__ = ["BlockProcessor", "BlockResult", "DeferBlock"]
