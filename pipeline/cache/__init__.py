"""Stage one's zarr cache (docs/cache-format.md): records, block writer, manifest, merge/verify, reader.

Importing this package is cheap: zarr is imported only when a block is written or read.

Writer side: build :class:`BlockRecord` s, ``w = CacheWriter(cache_root(out, dataset, config), config, source)``,
skip ``w.has_block(seq, b)``, ``w.write_block(rec)``, then ``w.finalize({seq: n_blocks})``. Array jobs on
several machines write into one tree and run :func:`merge` once at the end; :func:`verify` checks a cache.
Clouds must be built with :func:`points_from_depth` (and depth rounded with :func:`canonical_depth`) so that
the reader's clouds equal stage one's.
"""

from pipeline.cache.layout import SCHEMA_VERSION, cache_root, config_hash
from pipeline.cache.manifest import merge, remove_stale_tmp
from pipeline.cache.points import (
    canonical_depth,
    colours_at,
    dequantize_depth,
    flat_index,
    pixel_uv,
    points_from_depth,
    quantize_depth,
)
from pipeline.cache.reader import CacheReader, PairSample
from pipeline.cache.records import BlockRecord, FrameRecord, PairRecord
from pipeline.cache.verify import VerifyReport, verify
from pipeline.cache.writer import CacheWriter

__all__ = [
    "SCHEMA_VERSION",
    "BlockRecord",
    "CacheReader",
    "CacheWriter",
    "FrameRecord",
    "PairRecord",
    "PairSample",
    "VerifyReport",
    "cache_root",
    "canonical_depth",
    "colours_at",
    "config_hash",
    "dequantize_depth",
    "flat_index",
    "merge",
    "pixel_uv",
    "points_from_depth",
    "quantize_depth",
    "remove_stale_tmp",
    "verify",
]
