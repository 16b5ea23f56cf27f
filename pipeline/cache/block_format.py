"""The on-disk encoding of one block: array names, dtypes, chunk/shard shapes, codecs, attributes.

One zarr v3 group per block (docs/cache-format.md). Big arrays are written once, whole, as a single shard
(one file) of explicit inner chunks; small arrays are one chunk. Every chunk carries a CRC32C so that
``verify`` catches flipped bits. Imports zarr: import this module only where zarr is needed.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Iterator

import numpy as np
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec
from zarr.codecs.numcodecs import Delta

CHUNK_POINTS = 65_536
"""Inner chunk length of the ragged per-point arrays (a pair's slice touches 1–3 chunks)."""
CLEVEL = 5

REQUIRED_ARRAYS = ("K", "T", "scale", "depth", "rgb", "idx1", "offsets1", "idx2", "offsets2")
OPTIONAL_ARRAYS = ("gt_flow", "moving")


@contextlib.contextmanager
def quiet_zarr() -> Iterator[None]:
    """Silence exactly zarr's notices that numcodecs' Delta and consolidated metadata are outside the zarr
    v3 core spec: we know, and docs/cache-format.md says so."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Numcodecs codecs are not in the Zarr version 3 specification")
        warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part in the Zarr format 3")
        yield


def _blosc(shuffle: str, typesize: int | None = None) -> list:
    return [BloscCodec(cname="zstd", clevel=CLEVEL, shuffle=shuffle, typesize=typesize), Crc32cCodec()]


def _small(group: zarr.Group, name: str, data: np.ndarray) -> None:
    """A small array stored as one chunk (Blosc zstd + shuffle)."""
    group.create_array(name, data=data, chunks=data.shape, compressors=_blosc("shuffle"), fill_value=0)


def _sharded(group: zarr.Group, name: str, data: np.ndarray, chunks: tuple[int, ...], filters: list, compressors: list) -> None:
    """A big array written once as one shard (one file) of ``chunks``-shaped inner chunks."""
    if data.shape[0] == 0:  # nothing to store: an empty array (metadata only)
        group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=(1,) + data.shape[1:] if data.ndim > 1 else (1,),
                           filters=filters, compressors=compressors, fill_value=0)
        return
    n = math.ceil(data.shape[0] / chunks[0]) * chunks[0]
    shards = (n,) + tuple(data.shape[1:])
    group.create_array(name, data=data, chunks=chunks, shards=shards, filters=filters, compressors=compressors, fill_value=0)


def write_arrays(group: zarr.Group, arrays: dict[str, np.ndarray]) -> None:
    """Create every array of a block in ``group`` from already validated, typed numpy ``arrays``."""
    with quiet_zarr():
        _write_arrays(group, arrays)


def _write_arrays(group: zarr.Group, arrays: dict[str, np.ndarray]) -> None:
    for name in ("K", "T", "scale", "offsets1", "offsets2"):
        _small(group, name, arrays[name])
    depth, rgb = arrays["depth"], arrays["rgb"]
    _, H, W = depth.shape
    # Row-wise delta turns smooth depth into small steps; bit-shuffle then zstd (measured: 173 KB/frame).
    _sharded(group, "depth", depth, (1, H, W), [Delta(dtype="uint16")], _blosc("bitshuffle"))
    # Planar RGB, delta along each row of each channel (measured: 384 KB vs 489 KB interleaved, real KITTI).
    _sharded(group, "rgb", rgb, (1, 3, H, W), [Delta(dtype="uint8")], _blosc("noshuffle", 1))
    for name in ("idx1", "idx2"):
        n = max(1, min(CHUNK_POINTS, arrays[name].shape[0]))
        # Sorted indices: deltas are mostly 1 and compress to almost nothing.
        _sharded(group, name, arrays[name], (n,), [Delta(dtype="int32")], _blosc("shuffle"))
    if "gt_flow" in arrays:
        n = max(1, min(CHUNK_POINTS, arrays["gt_flow"].shape[0]))
        # int32 ulp offsets from the static flow (encode.gt_flow_to_ulp_offsets): zeros on static points
        _sharded(group, "gt_flow", arrays["gt_flow"], (n, 3), [], _blosc("shuffle"))
    if "moving" in arrays:
        n = max(1, min(CHUNK_POINTS, arrays["moving"].shape[0]))
        _sharded(group, "moving", arrays["moving"], (n,), [], _blosc("noshuffle", 1))


def open_block_group(path) -> zarr.Group:
    """Open a finished block read-only through its consolidated metadata (one small file read)."""
    store = zarr.storage.LocalStore(str(path), read_only=True)
    with quiet_zarr():
        return zarr.open_group(store, mode="r", use_consolidated=True)


def consolidate(path) -> None:
    """Put every array's metadata into the group's zarr.json (a reader then opens a block in one read)."""
    with quiet_zarr():
        zarr.consolidate_metadata(str(path))


def create_group(path) -> zarr.Group:
    return zarr.open_group(str(path), mode="w-", zarr_format=3)
