"""Running blocks in this process: build, write, and finish deferred blocks with their sequence's median factor.

:func:`process_blocks` overlaps block b's scale/filters/write (one helper thread) with block b+1's reading and
nets. A block is written atomically (on disk complete or not at all). A block where no frame gives a scale
factor before any good factor of its sequence is *deferred* (:class:`~pipeline.preprocess.block.DeferBlock`)
and finished at the end with the sequence median (:func:`finish_deferred`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pipeline.preprocess.block import BlockProcessor, BlockResult, DeferBlock, InferredBlock
from pipeline.preprocess.planning import BlockPlan
from pipeline.scale import ScaleError


def _finish_and_write(processor: BlockProcessor, writer, inferred: InferredBlock,
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


__all__ = ["finish_deferred", "process_block", "process_blocks", "sequence_median_factor"]
