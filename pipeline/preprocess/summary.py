"""What a stage-one run reports: the closing summary (over every block of this shard present on disk) and
``preprocess_run.json`` (resolved config, package versions, git revision) beside the manifest."""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.filters import FILTER_NAMES, FilterConfig
from pipeline.preprocess.block import BlockResult
from pipeline.preprocess.config import PreprocessConfig
from pipeline.preprocess.planning import BlockPlan

RUN_INFO_NAME = "preprocess_run.json"


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
    from core.runinfo import package_versions

    path = Path(root) / RUN_INFO_NAME
    write_json_atomic(path, {"config": dataclasses.asdict(config), "versions": package_versions(),
                             "code_version": code_version()})
    return path


def _block_stats(root: Path, plan: BlockPlan) -> list[dict[str, int]]:
    """The per-pair filter counts a written block holds."""
    from pipeline.cache.block_format import open_block_group
    from pipeline.cache.layout import block_dir

    return list(open_block_group(block_dir(root, plan.sequence, plan.index)).attrs["stats"])


def _dir_bytes(path: Path) -> int:
    """Bytes of every file below ``path``."""
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)


def mean_points(stats: list[dict[str, int]], filters: FilterConfig) -> dict[str, float]:
    """Mean points per cloud (frame-t and frame-t+1 clouds alike) after each stage: valid, then each filter."""
    out: dict[str, float] = {}
    for name in ("valid",) + tuple(n for n in FILTER_NAMES if getattr(filters, n)):
        values = [st[f"{side}_{name}"] for st in stats for side in ("pc1", "pc2") if f"{side}_{name}" in st]
        if values:
            out[name] = float(np.mean(values))
    return out



@dataclass
class RunTimes:
    """Wall-clock marks of a run (``time.perf_counter`` seconds)."""

    start: float  # the run began
    setup_seconds: float  # opening sequences and cache, building the nets (one process)
    blocks_seconds: float  # the block loop


def summarise(config: PreprocessConfig, writer, mine: list[BlockPlan], skipped: int, results: list[BlockResult],
              warnings: list[str], times: RunTimes, manifest_written: bool) -> PreprocessSummary:
    """The summary of a run over this shard's blocks ``mine`` (``skipped`` of them were already done);
    ``results``: the blocks this run processed; ``warnings``: the run's warnings, in order."""
    from pipeline.cache.layout import block_dir

    root = writer.root
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
        blocks_skipped=skipped,
        pairs=sum(len(p.pairs) for p in mine),
        pairs_written=sum(r.pairs for r in results if r.written),
        mean_points=mean_points(all_stats, config.filters),
        bytes_per_pair=n_bytes / max(1, len(all_stats)),
        seconds=time.perf_counter() - times.start,
        setup_seconds=times.setup_seconds,
        blocks_seconds=times.blocks_seconds,
        frames_processed=sum(r.frames for r in results),
        depth_net_images=sum(r.depth_images for r in results),
        pose_net_pairs=sum(r.pose_pairs for r in results),
        mean_scale=float(np.mean([r.scale for r in results])) if results else float("nan"),
        stage_seconds=stage_seconds,
        manifest_written=manifest_written,
        frames_without_scale=sum(r.frames_without_scale for r in results),
        blocks_carried=sum(r.carried for r in results),
        warnings=warnings,
    )


__all__ = ["RUN_INFO_NAME", "PreprocessSummary", "mean_points", "summarise", "write_run_info"]
