"""Stage one over whole sequences: blocks of consecutive pairs → the zarr cache (docs/design.md §3, §4).

Every sequence's pairs (t, t+1) are split into blocks of ``block_size`` consecutive pairs; a block is the
unit of work and of storage. Per block: read and resize its frames, compute each frame's depth **once**
(one batched net pass, or one file read) and reuse it for both pairs containing the frame, get every pair's
pose, find the block's scale factor, apply the filters, write the block with :class:`CacheWriter`.

Finished blocks are skipped (a killed run resumes), ``workers`` blocks run in parallel processes (spawned;
each builds its own nets), ``shard = "i/n"`` takes the blocks whose global index b has ``b % n == i``. When
every block of the plan is present the manifest is written; otherwise ``merge`` writes it later.
Determinism: a block's bytes depend only on its inputs and the config (the same device and batch size are
assumed: batched float arithmetic may differ in the last bits between them).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import ConfigError, InputError, MonoflowError
from pipeline.filters import FILTER_NAMES, FilterConfig
from pipeline.scale import (ScaleConfig, ScaleError, combine_factors, frame_factor, implausible_depth,
                            scale_consistency_problems)
from pipeline.sources import DEPTH_SOURCES, POSE_SOURCES

RUN_INFO_NAME = "preprocess_run.json"


@dataclass
class PreprocessConfig:
    """Stage one's options (``monoflow-preprocess`` flags / ``--config`` TOML keys)."""

    root: str = field(default="", metadata={"help": "dataset root in the KITTI odometry layout (root/sequences/NN/)"})
    dataset: str = field(
        default="", metadata={"help": "name of the dataset folder in the cache; empty = the root folder's name"}
    )
    sequences: tuple[str, ...] = field(
        default=(), metadata={"help": "comma-separated sequence ids; empty = every sequence"}
    )
    camera: str = field(default="image_2", metadata={"help": "camera folder (image_2 = left colour)"})
    strict_pose_count: bool = field(
        default=True,
        metadata={"help": "a complete sequence's poses file must have exactly one line per image; false = "
                          "only a line for every frame id (e.g. frames 0..50 beside the full 1,101-line 06.txt)"},
    )
    depth: str = field(default="net", metadata={"help": f"depth source: {' | '.join(DEPTH_SOURCES)}"})
    pose: str = field(default="net", metadata={"help": f"pose source: {' | '.join(POSE_SOURCES)} (gt = dataset poses)"})
    depth_checkpoint: str | None = field(default=None, metadata={"help": "DispResNet checkpoint (.pth.tar)"})
    pose_checkpoint: str | None = field(default=None, metadata={"help": "PoseResNet checkpoint (.pth.tar)"})
    resnet_layers: int = field(default=18, metadata={"help": "ResNet depth of randomly initialised nets"})
    random_init: bool = field(default=False, metadata={"help": "seeded random nets when no checkpoint (tests)"})
    seed: int = field(default=0, metadata={"help": "seed of random_init nets"})
    disparity_dir: str | None = field(
        default=None,
        metadata={"help": "depth=disparity: folder of <frame>.png, {seq} replaced by the sequence; "
                          "none = sequences/NN/disp_2"},
    )
    disparity_focal: float | None = field(
        default=None, metadata={"help": "depth=disparity: focal length, native pixels; none = the camera's fx"}
    )
    disparity_baseline: float = field(default=0.54, metadata={"help": "depth=disparity: stereo baseline, metres"})
    size: str = field(default="832x256", metadata={"help": "working size WxH, or 'native'"})
    filters: FilterConfig = field(default_factory=FilterConfig)
    scale: ScaleConfig = field(default_factory=ScaleConfig)
    block_size: int = field(default=16, metadata={"help": "pairs per block (the unit of work and storage)"})
    device: str = field(default="auto", metadata={"help": "auto | cpu | cuda[:i]"})
    amp: bool = field(default=False, metadata={"help": "mixed-precision inference"})
    batch_size: int = field(default=8, metadata={"help": "frames per net forward pass"})
    workers: int = field(default=1, metadata={"help": "blocks processed in parallel (spawned processes)"})
    shard: str = field(default="0/1", metadata={"help": "'i/n': process the blocks b with b mod n == i"})
    out: str = field(default="cache", metadata={"help": "output root (cache/<dataset>/<config-hash>/)"})
    progress: bool = field(default=True, metadata={"help": "tqdm progress bar per block"})

    # ------------------------------------------------------------------ derived values

    def working_size(self) -> tuple[int, int] | None:
        """(W, H) or None for the native size."""
        text = self.size.strip().lower()
        if text == "native":
            return None
        m = re.fullmatch(r"(\d+)\s*[x×,]\s*(\d+)", text)
        if not m or int(m[1]) < 1 or int(m[2]) < 1:
            raise ConfigError(f"size must be WxH (e.g. 832x256) or 'native', got {self.size!r}")
        return int(m[1]), int(m[2])

    def shard_spec(self) -> tuple[int, int]:
        m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", self.shard)
        if not m or int(m[2]) < 1 or int(m[1]) >= int(m[2]):
            raise ConfigError(f"shard must be 'i/n' with 0 <= i < n, got {self.shard!r}")
        return int(m[1]), int(m[2])

    def validate(self) -> "PreprocessConfig":
        """Raise ConfigError for options that make no sense; return self."""
        if not self.root:
            raise ConfigError("no dataset root given (--root)")
        if self.depth not in DEPTH_SOURCES:
            raise ConfigError(f"depth source must be one of {', '.join(DEPTH_SOURCES)}, got {self.depth!r}")
        if self.pose not in POSE_SOURCES:
            raise ConfigError(f"pose source must be one of {', '.join(POSE_SOURCES)}, got {self.pose!r}")
        if self.block_size < 1 or self.workers < 1 or self.batch_size < 1:
            raise ConfigError("block_size, workers and batch_size must be >= 1")
        self.working_size()
        self.shard_spec()
        self.filters.check()
        for kind in ("depth", "pose"):
            path = getattr(self, f"{kind}_checkpoint")
            if getattr(self, kind) != "net":
                continue
            if path and not Path(path).is_file():
                raise InputError(path, "checkpoint not found")
            if not path and not self.random_init:
                raise ConfigError(f"{kind} source 'net' needs --{kind}_checkpoint (or --random_init true for tests)")
        return self

    def net_spec(self):
        from pipeline.sources import NetSpec

        return NetSpec(
            depth_checkpoint=self.depth_checkpoint,
            pose_checkpoint=self.pose_checkpoint,
            need_depth=self.depth == "net",
            need_pose=self.pose == "net",
            random_init=self.random_init,
            seed=self.seed,
            resnet_layers=self.resnet_layers,
            device=self.device,
            amp=self.amp,
            batch_size=self.batch_size,
        )


# Options that change how, where or how fast the cache is written, or where inputs live, not what it holds.
_NOT_CONTENT = ("root", "dataset", "device", "batch_size", "workers", "shard", "out", "progress", "disparity_dir",
                "strict_pose_count")
#: Scale options that decide whether a run stops or warns, not what a finished block holds.
_SCALE_NOT_CONTENT = ("fallback", "refuse_non_metric")
_NET_ONLY = ("resnet_layers", "random_init", "seed", "amp")
_DISPARITY_ONLY = ("disparity_focal", "disparity_baseline")


def _sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def cache_config(config: PreprocessConfig, sequences: list[str]) -> dict[str, Any]:
    """The part of the config that determines the cache's content; it names the cache (config hash).

    Paths are left out (checkpoints enter by their sha256), and so are options the chosen sources ignore,
    so the same inputs give the same cache name on any machine.
    """
    d = dataclasses.asdict(config)
    for key in _NOT_CONTENT:
        d.pop(key)
    for key in _SCALE_NOT_CONTENT:
        d["scale"].pop(key, None)
    d["sequences"] = list(sequences)
    d["stage"] = "preprocess"
    for kind in ("depth", "pose"):
        path = d.pop(f"{kind}_checkpoint")
        d[f"{kind}_checkpoint_sha256"] = _sha256(path) if path and getattr(config, kind) == "net" else None
    if "net" not in (config.depth, config.pose):
        for key in _NET_ONLY:
            d.pop(key)
    if config.depth != "disparity":
        for key in _DISPARITY_ONLY:
            d.pop(key)
    return d


def dataset_name(config: PreprocessConfig) -> str:
    name = config.dataset or Path(config.root).resolve().name or "dataset"
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name).lstrip(".") or "dataset"


# --------------------------------------------------------------------------- plan


@dataclass(frozen=True)
class BlockPlan:
    """One block: sequence, its index there, its global index over all sequences, its pairs as positions."""

    sequence: str
    index: int
    global_index: int
    pairs: tuple[tuple[int, int], ...]


def sequence_pairs(frames: list[int]) -> list[tuple[int, int]]:
    """Positions (k, k+1) whose frame ids are consecutive (a gap in the numbering makes no pair)."""
    return [(k, k + 1) for k in range(len(frames) - 1) if frames[k + 1] == frames[k] + 1]


def plan_blocks(sequence_frames: dict[str, list[int]], block_size: int) -> list[BlockPlan]:
    """Split every sequence's pairs into blocks of ``block_size`` consecutive pairs (sequences sorted)."""
    plans: list[BlockPlan] = []
    for seq in sorted(sequence_frames):
        pairs = sequence_pairs(sequence_frames[seq])
        for b in range(math.ceil(len(pairs) / block_size)):
            chunk = tuple(pairs[b * block_size : (b + 1) * block_size])
            plans.append(BlockPlan(seq, b, len(plans), chunk))
    return plans


def open_sequences(config: PreprocessConfig):
    """{sequence id: OdometrySequence} for the configured (or all) sequences."""
    from pipeline.kitti.odometry import OdometrySequence, find_sequences

    names = list(config.sequences) or find_sequences(config.root)
    if not names:
        raise InputError(Path(config.root) / "sequences", "no sequence folders with a calib.txt")
    need_poses = config.pose == "gt"
    out = {}
    for name in sorted(dict.fromkeys(names)):
        seq = OdometrySequence(config.root, name, config.camera, strict_pose_count=config.strict_pose_count)
        gaps = [f for f in range(seq.frames[0], seq.frames[-1] + 1) if f not in set(seq.frames)]
        if gaps:
            suffix = seq.image_path(0).suffix
            raise InputError(seq.image_dir / f"{gaps[0]:06d}{suffix}",
                             f"missing: the sequence has frames {seq.frames[0]}..{seq.frames[-1]} "
                             f"but {len(gaps)} of them are absent")
        if need_poses and not seq.has_poses:
            raise InputError(seq.poses_path, "poses file not found (pose source 'gt' needs the dataset's poses)")
        if config.sequences and len(seq.frames) < 2:  # asked for by name: refuse rather than drop it silently
            raise InputError(seq.image_dir, f"sequence {name} has {len(seq.frames)} frame(s); a frame pair needs 2")
        out[seq.sequence] = seq
    return out


# --------------------------------------------------------------------------- one block


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

    def __init__(self, inferred: "_Inferred") -> None:
        super().__init__(f"sequence {inferred.plan.sequence} block {inferred.plan.index}: no scale factor yet")
        self.inferred = inferred


@dataclass
class _Inferred:
    """A block after reading and the nets (what :meth:`BlockProcessor.finish` needs)."""

    plan: BlockPlan
    hw: tuple[int, int]
    K: np.ndarray
    positions: list[int]
    where: dict[int, int]
    images: np.ndarray
    depths: np.ndarray
    Ts: np.ndarray
    depth_images: int
    pose_pairs: int
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

    def infer(self, plan: BlockPlan) -> "_Inferred":
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
        return _Inferred(plan, hw, K, positions, where, images, depths, Ts, n1[0] - n0[0], n1[1] - n0[1], clock.laps)

    def finish(self, inf: "_Inferred", forced_factor: float | None = None):
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
    def __init__(self) -> None:
        self.t = time.perf_counter()
        self.laps: dict[str, float] = {}

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self.t
        self.t = now


def _finish_and_write(processor: BlockProcessor, writer, inferred: _Inferred,
                      forced_factor: float | None = None) -> BlockResult | DeferBlock:
    try:
        block, result = processor.finish(inferred, forced_factor)
    except DeferBlock as deferred:
        return deferred
    t = time.perf_counter()
    result.written = writer.write_block(block)
    result.seconds["write"] = time.perf_counter() - t
    return result


def process_block(processor: BlockProcessor, writer, plan: BlockPlan) -> BlockResult | DeferBlock:
    """Build one block and write it (atomically: a block is on disk complete or not at all); a
    :class:`DeferBlock` is returned for a block that has to wait for its sequence's median factor."""
    return _finish_and_write(processor, writer, processor.infer(plan))


def sequence_median_factor(processor: BlockProcessor, sequence: str, root: Path | None = None) -> float:
    """Median of the good block factors of ``sequence`` seen by ``processor`` (else of the blocks already in the
    cache at ``root``); :class:`ScaleError` when the whole sequence gave none."""
    good = list(processor.good_factors.get(sequence, []))
    if not good and root is not None:
        from pipeline.cache.block_format import open_block_group

        for d in sorted((Path(root) / "blocks" / sequence).glob("[0-9][0-9][0-9][0-9][0-9]")):
            if (d / "zarr.json").is_file():
                good.extend(float(x) for x in np.asarray(open_block_group(d)["scale"][...]).ravel())
    if not good:
        raise ScaleError(f"sequence {sequence}: no frame of any block gave a scale factor (no road plane found "
                         f"with --scale.mode {processor.config.scale.mode}); try --scale.mode fixed --scale.factor F")
    return float(np.median(good))


def finish_deferred(processor: BlockProcessor, writer, deferred: list[DeferBlock],
                    done: Callable[[BlockResult], None], root: Path | None = None) -> None:
    """Finish blocks that had no factor before any good one of their sequence, with the sequence median."""
    for item in deferred:
        s = sequence_median_factor(processor, item.inferred.plan.sequence, root)
        res = _finish_and_write(processor, writer, item.inferred, forced_factor=s)
        assert not isinstance(res, DeferBlock)
        done(res)


def process_blocks(processor: BlockProcessor, writer, plans: list[BlockPlan],
                   done: Callable[[BlockResult], None]) -> None:
    """Process ``plans`` in order, overlapping block b's scale/filters/write (a helper thread) with block
    b+1's reading and nets. On an error the block in the helper thread is still finished (or its
    temp directory removed) before the error is raised — the earliest block's error first."""
    from concurrent.futures import ThreadPoolExecutor

    deferred: list[DeferBlock] = []

    def take(res) -> None:
        if isinstance(res, DeferBlock):
            deferred.append(res)
        else:
            done(res)

    with ThreadPoolExecutor(1, thread_name_prefix="stage1-finish") as pool:
        pending = None
        try:
            for plan in plans:
                inferred = processor.infer(plan)
                if pending is not None:
                    take(pending.result())
                    pending = None
                pending = pool.submit(_finish_and_write, processor, writer, inferred)
            if pending is not None:
                take(pending.result())
                pending = None
        except BaseException:
            if pending is not None:
                earlier = pending.exception()  # waits: the block in flight ends complete or not at all
                if earlier is not None:
                    raise earlier from None
            raise
    finish_deferred(processor, writer, deferred, done, getattr(writer, "root", None))


# --------------------------------------------------------------------------- worker processes

_WORKER: dict[str, Any] = {}


def _worker_init(config_dict: dict[str, Any], root: str, cache_cfg: dict, source: dict, threads: int,
                 parent_pid: int) -> None:
    from pipeline.cache.writer import CacheWriter
    from pipeline.lifeline import die_with_parent
    from pipeline.options import config_from_dict

    die_with_parent(parent_pid)  # a killed stage one leaves no worker behind
    try:
        config = config_from_dict(PreprocessConfig, config_dict)
        if config.depth == "net" or config.pose == "net":
            import torch

            torch.set_num_threads(max(1, threads))
        _WORKER["processor"] = BlockProcessor(config)
        _WORKER["writer"] = CacheWriter(root, cache_cfg, source)
    except MonoflowError as exc:
        _WORKER["error"] = _pack_error(exc)


def _pack_error(exc: MonoflowError) -> tuple:
    """A picklable form of a MonoflowError (InputError's constructor takes two arguments)."""
    if isinstance(exc, InputError):
        return ("InputError", str(exc.path), exc.problem)
    return (type(exc).__name__, str(exc), None)


def _unpack_error(packed: tuple) -> MonoflowError:
    kind, a, b = packed
    if kind == "InputError":
        return InputError(a, b)
    if kind == "ConfigError":
        return ConfigError(a)
    if kind == "ScaleError":
        return ScaleError(a)
    return MonoflowError(a)


def _worker_block(plan: BlockPlan):
    if "error" in _WORKER:
        return ("error", _WORKER["error"])
    try:
        res = process_block(_WORKER["processor"], _WORKER["writer"], plan)
        if isinstance(res, DeferBlock):
            return ("deferred", plan)
        return ("ok", res)
    except MonoflowError as exc:
        return ("error", _pack_error(exc))


# --------------------------------------------------------------------------- the run


@dataclass
class PreprocessSummary:
    """The closing summary of a run (over every block of this shard's plan present on disk)."""

    cache_root: Path
    depth_source: str
    pose_source: str
    scale_mode: str
    blocks_planned: int
    blocks_written: int
    blocks_skipped: int
    pairs: int
    pairs_written: int
    mean_points: dict[str, float]
    bytes_per_pair: float
    seconds: float
    setup_seconds: float  # opening sequences and cache, building the nets (one process)
    blocks_seconds: float  # wall clock of the block loop (parts overlap, see process_blocks)
    frames_processed: int
    depth_net_images: int
    pose_net_pairs: int
    mean_scale: float
    stage_seconds: dict[str, float]
    manifest_written: bool
    frames_without_scale: int = 0
    blocks_carried: int = 0
    warnings: list[str] = field(default_factory=list)

    def text(self) -> str:
        pts = ", ".join(f"{k} {v:.0f}" for k, v in self.mean_points.items())
        lines = [
            f"stage one: {self.pairs} pairs in {self.blocks_planned} blocks "
            f"({self.blocks_written} written, {self.blocks_skipped} already done) in {self.seconds:.1f} s"
            + (f" ({self.pairs_written / self.blocks_seconds:.2f} pairs/s over the blocks)"
               if self.pairs_written and self.blocks_seconds > 0 else ""),
            f"  sources: depth {self.depth_source}, pose {self.pose_source}, scale {self.scale_mode}"
            + (f" (mean factor {self.mean_scale:.4g})" if self.blocks_written else ""),
            f"  mean points per cloud after each filter: {pts}",
        ]
        if self.frames_without_scale or self.blocks_carried:
            lines.append(f"  scale: {self.frames_without_scale} frames gave no factor of their own (no road plane / "
                         f"no LiDAR overlap); {self.blocks_carried} blocks had none at all and carried the last "
                         "good factor (or the sequence median)")
        lines += [
            f"  bytes per pair: {self.bytes_per_pair / 1024:.0f} KiB",
        ]
        if self.depth_net_images or self.pose_net_pairs:
            lines.append(
                f"  net calls: depth {self.depth_net_images} images for {self.frames_processed} block frames, "
                f"pose {self.pose_net_pairs} for {self.pairs_written} pairs"
            )
        for w in self.warnings:
            lines.append(f"  WARNING: {w}")
        lines.append(f"  cache: {self.cache_root}" + ("" if self.manifest_written else
                                                     " (manifest not written yet: other shards pending; run `merge`)"))
        return "\n".join(lines)


def write_run_info(root: Path, config: PreprocessConfig) -> Path:
    """``preprocess_run.json`` beside the manifest: resolved config, package versions, git revision."""
    from pipeline.cache.layout import code_version, write_json_atomic
    from pipeline.runinfo import package_versions

    path = Path(root) / RUN_INFO_NAME
    write_json_atomic(path, {"config": dataclasses.asdict(config), "versions": package_versions(),
                             "code_version": code_version()})
    return path


def _block_stats(root: Path, plan: BlockPlan) -> list[dict[str, int]]:
    from pipeline.cache.block_format import open_block_group
    from pipeline.cache.layout import block_dir

    return list(open_block_group(block_dir(root, plan.sequence, plan.index)).attrs["stats"])


def _dir_bytes(path: Path) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)


def run_preprocess(
    config: PreprocessConfig, on_block: Callable[[BlockResult], None] | None = None
) -> PreprocessSummary:
    """Run stage one as configured; return the summary. MonoflowError on bad input (nothing half-written)."""
    from pipeline.cache.layout import block_dir, cache_root
    from pipeline.cache.writer import CacheWriter

    start = time.perf_counter()
    config.validate()
    run_warnings = scale_consistency_problems(config.depth, config.pose, config.scale)
    if run_warnings and config.scale.refuse_non_metric:
        raise ConfigError(run_warnings[0] + " (--scale.refuse_non_metric true)")
    for w in run_warnings:
        _shout(w)
    sequences = open_sequences(config)
    plans = plan_blocks({name: seq.frames for name, seq in sequences.items()}, config.block_size)
    if not plans:
        raise InputError(Path(config.root) / "sequences", "no consecutive frame pairs in the selected sequences")
    shard_i, shard_n = config.shard_spec()
    mine = [p for p in plans if p.global_index % shard_n == shard_i]
    cache_cfg = cache_config(config, list(sequences))
    source = {
        "dataset": dataset_name(config),
        "root": str(Path(config.root).resolve()),
        "camera": config.camera,
        "sequences": {n: {"frames": [s.frames[0], s.frames[-1]], "num_frames": len(s)} for n, s in sequences.items()},
        "depth": config.depth,
        "pose": config.pose,
        "depth_checkpoint": config.depth_checkpoint if config.depth == "net" else None,
        "pose_checkpoint": config.pose_checkpoint if config.pose == "net" else None,
        "disparity_dir": config.disparity_dir if config.depth == "disparity" else None,
    }
    root = cache_root(config.out, source["dataset"], cache_cfg)
    writer = CacheWriter(root, cache_cfg, source)
    write_run_info(root, config)
    todo = [p for p in mine if not writer.has_block(p.sequence, p.index)]

    results: list[BlockResult] = []
    bar = _progress(config, len(mine), len(mine) - len(todo))
    shouted: set[str] = set()

    def done(res: BlockResult) -> None:
        results.append(res)
        for w in res.warnings:
            if not shouted:  # once per run: every block of a non-metric run says the same
                _shout(w)
            shouted.add(w)
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(f"{res.sequence}/{res.index:05d} {res.pairs} pairs")
        if on_block is not None:
            on_block(res)

    setup_seconds = time.perf_counter() - start
    t_blocks = time.perf_counter()
    try:
        if todo and config.workers == 1:
            processor = BlockProcessor(config, sequences)  # builds the nets: counted as setup
            setup_seconds += time.perf_counter() - t_blocks
            t_blocks = time.perf_counter()
            process_blocks(processor, writer, todo, done)
        elif todo:
            _run_parallel(config, root, cache_cfg, source, todo, done)
    finally:
        if bar is not None:
            bar.close()
    blocks_seconds = time.perf_counter() - t_blocks

    manifest_written = False
    if all(writer.has_block(p.sequence, p.index) for p in plans):
        writer.finalize([(p.sequence, p.index) for p in plans])
        manifest_written = True

    present = [p for p in mine if writer.has_block(p.sequence, p.index)]
    all_stats = [st for p in present for st in _block_stats(root, p)]
    n_bytes = sum(_dir_bytes(block_dir(root, p.sequence, p.index)) for p in present)
    stage_seconds: dict[str, float] = {}
    for r in results:
        for k, v in r.seconds.items():
            stage_seconds[k] = stage_seconds.get(k, 0.0) + v
    return PreprocessSummary(
        cache_root=root,
        depth_source=config.depth,
        pose_source=config.pose,
        scale_mode=config.scale.mode if config.scale.mode != "fixed" else f"fixed {config.scale.factor:g}",
        blocks_planned=len(mine),
        blocks_written=sum(r.written for r in results),
        blocks_skipped=len(mine) - len(todo),
        pairs=sum(len(p.pairs) for p in mine),
        pairs_written=sum(r.pairs for r in results if r.written),
        mean_points=mean_points(all_stats, config.filters),
        bytes_per_pair=n_bytes / max(1, len(all_stats)),
        seconds=time.perf_counter() - start,
        setup_seconds=setup_seconds,
        blocks_seconds=blocks_seconds,
        frames_processed=sum(r.frames for r in results),
        depth_net_images=sum(r.depth_images for r in results),
        pose_net_pairs=sum(r.pose_pairs for r in results),
        mean_scale=float(np.mean([r.scale for r in results])) if results else float("nan"),
        stage_seconds=stage_seconds,
        manifest_written=manifest_written,
        frames_without_scale=sum(r.frames_without_scale for r in results),
        blocks_carried=sum(r.carried for r in results),
        warnings=run_warnings + sorted(shouted)[:3],
    )


def _shout(message: str) -> None:
    """A loud warning on stderr, one line (stage one goes on; ``--scale.refuse_non_metric true`` stops instead)."""
    print(f"WARNING: {message}", file=sys.stderr)


def mean_points(stats: list[dict[str, int]], filters: FilterConfig) -> dict[str, float]:
    """Mean points per cloud (frame-t and frame-t+1 clouds alike) after each stage: valid, then each filter."""
    out: dict[str, float] = {}
    for name in ("valid",) + tuple(n for n in FILTER_NAMES if getattr(filters, n)):
        values = [st[f"{side}_{name}"] for st in stats for side in ("pc1", "pc2") if f"{side}_{name}" in st]
        if values:
            out[name] = float(np.mean(values))
    return out


def _progress(config: PreprocessConfig, total: int, initial: int):
    if not config.progress:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="block", desc="stage one", file=sys.stderr, dynamic_ncols=True)


def _run_parallel(config, root, cache_cfg, source, todo, done) -> None:
    """Process ``todo`` in ``config.workers`` spawned processes; on the first error let running blocks
    finish (so no block is left half-written), cancel the rest and raise that error."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    threads = max(1, (os.cpu_count() or 1) // config.workers)
    deferred_plans: list[BlockPlan] = []
    results: list[BlockResult] = []
    done_outer = done

    def done(res: BlockResult) -> None:  # noqa: F811  (keeps the good factors for deferred blocks)
        results.append(res)
        done_outer(res)

    args = (dataclasses.asdict(config), str(root), cache_cfg, source, threads, os.getpid())
    error: MonoflowError | None = None
    with ProcessPoolExecutor(config.workers, mp_context=mp.get_context("spawn"), initializer=_worker_init,
                             initargs=args) as pool:
        pending = {pool.submit(_worker_block, plan) for plan in todo}
        try:
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    if fut.cancelled():
                        continue
                    status, payload = fut.result()
                    if status == "ok":
                        done(payload)
                    elif status == "deferred":
                        deferred_plans.append(payload)
                    elif error is None:
                        error = _unpack_error(payload)
                        for other in pending:
                            other.cancel()
        except BaseException:
            for other in pending:
                other.cancel()
            raise
    if error is not None:
        raise error
    if deferred_plans:  # blocks that met no good factor in their worker: the sequence median, here
        from pipeline.cache.writer import CacheWriter

        processor = BlockProcessor(config)
        for res in sorted(results, key=lambda r: r.index):
            if not res.carried:
                processor.good_factors.setdefault(res.sequence, []).append(res.scale)
        writer = CacheWriter(root, cache_cfg, source)
        items = [DeferBlock(processor.infer(plan)) for plan in sorted(deferred_plans, key=lambda p: p.global_index)]
        finish_deferred(processor, writer, items, done_outer, Path(root))


__all__ = [
    "BlockPlan",
    "BlockProcessor",
    "BlockResult",
    "PreprocessConfig",
    "PreprocessSummary",
    "cache_config",
    "mean_points",
    "plan_blocks",
    "process_block",
    "process_blocks",
    "run_preprocess",
    "sequence_pairs",
    "write_run_info",
]
