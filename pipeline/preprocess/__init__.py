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

Modules, one responsibility each: :mod:`~pipeline.preprocess.config` (options, validation),
:mod:`~pipeline.preprocess.identity` (what names a cache), :mod:`~pipeline.preprocess.planning` (blocks,
shards), :mod:`~pipeline.preprocess.sequences` (opening the inputs), :mod:`~pipeline.preprocess.block` (one
block's compute), :mod:`~pipeline.preprocess.serial` (blocks in this process),
:mod:`~pipeline.preprocess.parallel` (worker processes), :mod:`~pipeline.preprocess.summary` (what a run
reports), :mod:`~pipeline.preprocess.run` (:func:`run_preprocess`).
"""

from pipeline.preprocess.block import BlockProcessor, BlockResult, DeferBlock
from pipeline.preprocess.config import PreprocessConfig
from pipeline.preprocess.identity import cache_config, dataset_name
from pipeline.preprocess.planning import BlockPlan, plan_blocks, sequence_pairs
from pipeline.preprocess.run import run_preprocess
from pipeline.preprocess.sequences import open_sequences
from pipeline.preprocess.serial import finish_deferred, process_block, process_blocks, sequence_median_factor
from pipeline.preprocess.summary import RUN_INFO_NAME, PreprocessSummary, mean_points, write_run_info

__all__ = [
    "RUN_INFO_NAME",
    "BlockPlan",
    "BlockProcessor",
    "BlockResult",
    "DeferBlock",
    "PreprocessConfig",
    "PreprocessSummary",
    "cache_config",
    "dataset_name",
    "finish_deferred",
    "mean_points",
    "open_sequences",
    "plan_blocks",
    "process_block",
    "process_blocks",
    "run_preprocess",
    "sequence_median_factor",
    "sequence_pairs",
    "write_run_info",
]
