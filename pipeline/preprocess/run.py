"""``run_preprocess``: stage one over whole sequences, top to bottom (docs/design.md §3, §4).

Validate the options, open the sequences, plan the blocks and take this shard's, name and open the cache,
skip the blocks already written (a killed run resumes), run the rest in this process
(:mod:`pipeline.preprocess.serial`) or in ``workers`` processes (:mod:`pipeline.preprocess.parallel`),
write the manifest once every block of the plan is present (else ``merge`` writes it later), summarise.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

from core.errors import InputError
from pipeline.preprocess.block import BlockProcessor, BlockResult
from pipeline.preprocess.config import PreprocessConfig
from pipeline.preprocess.identity import cache_config, cache_source
from pipeline.preprocess.parallel import run_parallel
from pipeline.preprocess.planning import BlockPlan, plan_blocks, shard_plans
from pipeline.preprocess.sequences import open_sequences
from pipeline.preprocess.serial import process_blocks
from pipeline.preprocess.summary import PreprocessSummary, RunTimes, summarise, write_run_info
from pipeline.scale import announce_scale_problems


def run_preprocess(
    config: PreprocessConfig, on_block: Callable[[BlockResult], None] | None = None
) -> PreprocessSummary:
    """Run stage one as configured; return the summary. MonoflowError on bad input (nothing half-written)."""
    from pipeline.cache.layout import cache_root
    from pipeline.cache.writer import CacheWriter

    start = time.perf_counter()
    config.validate()
    run_warnings = announce_scale_problems(config.depth, config.pose, config.scale)
    sequences = open_sequences(config)
    plans = plan_blocks({name: seq.frames for name, seq in sequences.items()}, config.block_size)
    if not plans:
        raise InputError(Path(config.root) / "sequences", "no consecutive frame pairs in the selected sequences")
    mine = shard_plans(plans, config.shard_spec())
    cache_cfg = cache_config(config, list(sequences))
    source = cache_source(config, sequences)
    root = cache_root(config.out, source["dataset"], cache_cfg)
    writer = CacheWriter(root, cache_cfg, source)
    write_run_info(root, config)
    todo = [p for p in mine if not writer.has_block(p.sequence, p.index)]

    report = _BlockReport(config, total=len(mine), initial=len(mine) - len(todo), on_block=on_block)
    setup_seconds = time.perf_counter() - start
    t_blocks = time.perf_counter()
    try:
        if todo and config.workers == 1:
            processor = BlockProcessor(config, sequences)  # builds the nets: counted as setup
            setup_seconds += time.perf_counter() - t_blocks
            t_blocks = time.perf_counter()
            process_blocks(processor, writer, todo, report)
        elif todo:
            run_parallel(config, root, cache_cfg, source, todo, report)
    finally:
        report.close()
    times = RunTimes(start, setup_seconds, blocks_seconds=time.perf_counter() - t_blocks)

    manifest_written = _finalize_when_complete(writer, plans)
    return summarise(config, writer, mine, len(mine) - len(todo), report.results,
                     run_warnings + sorted(report.shouted)[:3], times, manifest_written)


def _finalize_when_complete(writer, plans: list[BlockPlan]) -> bool:
    """Write the manifest when every block of the whole plan (all shards) is present; True when written."""
    if all(writer.has_block(p.sequence, p.index) for p in plans):
        writer.finalize([(p.sequence, p.index) for p in plans])
        return True
    return False


class _BlockReport:
    """What happens per finished block: keep its result, shout its first warning (once per run: every block
    of a non-metric run says the same), move the progress bar, call the caller's ``on_block``."""

    def __init__(self, config: PreprocessConfig, total: int, initial: int,
                 on_block: Callable[[BlockResult], None] | None) -> None:
        self.results: list[BlockResult] = []
        self.shouted: set[str] = set()
        self.on_block = on_block
        self.bar = _progress(config, total, initial)

    def __call__(self, res: BlockResult) -> None:
        self.results.append(res)
        for w in res.warnings:
            if not self.shouted:
                _shout(w)
            self.shouted.add(w)
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix_str(f"{res.sequence}/{res.index:05d} {res.pairs} pairs")
        if self.on_block is not None:
            self.on_block(res)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _shout(message: str) -> None:
    """A loud warning on stderr, one line (stage one goes on; ``--scale.refuse_non_metric true`` stops instead)."""
    print(f"WARNING: {message}", file=sys.stderr)


def _progress(config: PreprocessConfig, total: int, initial: int):
    """A tqdm bar over the blocks on stderr, or None with ``progress = false``."""
    if not config.progress:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="block", desc="stage one", file=sys.stderr, dynamic_ncols=True)


__all__ = ["run_preprocess"]
