"""Reading stage one's cache: O(1) random access to pair i, for training's DataLoader.

The cache does not store point coordinates (docs/cache-format.md). Each block stores every frame's
depth map once (uint16, 1/256 m) and RGB image, and each pair the flat indices ``v*W + u`` of its kept
pixels in frames t and t+1 (ragged arrays + offsets). A sample is rebuilt here:

* ``pc1 = points_from_depth(depth_t, idx1, K)``, ``rgb1`` = RGB at idx1, ``uv1`` = (u, v) of idx1;
  pc2 / rgb2 / uv2 likewise from frame t+1 and idx2 (:mod:`pipeline.cache.points`);
* ``static_flow = core.geometry.static_flow(pc1, T, as_float32=True)`` with the stored float64 ``T_{t→t+1}``;
* ground-truth flow, when present, from its stored int32 ulp offsets relative to that static flow;

exactly the calls stage one makes, so the clouds equal stage one's bit for bit. Only blocks listed in
``manifest.json`` are read, so a block being written (a temp directory) is never seen.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.cache.encode import gt_flow_from_ulp_offsets
from pipeline.cache.integrity import check_block_files, read_block_attrs
from pipeline.cache.layout import FORMAT_NAME, MANIFEST_NAME, SCHEMA_VERSION
from pipeline.cache.manifest import read_manifest
from pipeline.cache.points import dequantize_depth, pixel_uv, points_at_pixels
from core.errors import InputError
from core.geometry import static_flow


@dataclass
class PairSample:
    """One cached pair (t, t+1). Points in metres, camera frame (x right, y down, z forward).

    pc1 (N1, 3) float32: kept frame-t points in the camera-t frame; rgb1 (N1, 3) uint8; uv1 (N1, 2) float32
    pixel coordinates (u, v) in frame t. pc2, rgb2, uv2: the same for frame t+1 (camera-(t+1) frame).
    static_flow (N1, 3) float32: ``(R p + t) − p`` for pc1 (camera-t frame). T (4, 4) float32: T_{t→t+1}.
    K (3, 3) float32 intrinsics at the working size. depth2 (H, W) float32: the frame-(t+1) depth map,
    metres, 0 = invalid. gt_flow (N1, 3) float32 and moving (N1,) bool when the source had them, else None.
    scale: factor stage one applied to the net's depth and translation. stats: point counts per filter.
    index: the pair's global index in the cache.
    """

    pc1: np.ndarray
    rgb1: np.ndarray
    uv1: np.ndarray
    pc2: np.ndarray
    rgb2: np.ndarray
    uv2: np.ndarray
    static_flow: np.ndarray
    T: np.ndarray
    K: np.ndarray
    depth2: np.ndarray
    sequence: str
    frame_t: int
    frame_t1: int
    scale: float
    gt_flow: np.ndarray | None = None
    moving: np.ndarray | None = None
    stats: dict[str, int] = field(default_factory=dict)
    index: int = -1


def check_block_attrs(path: Path, attrs: dict[str, Any]) -> None:
    """The block's own format and schema version are this code's, and every chunk file it lists is there
    with its size (a missing chunk would read back as zeros); InputError naming the block otherwise."""
    if attrs.get("format") != FORMAT_NAME or attrs.get("schema_version") != SCHEMA_VERSION:
        raise InputError(path, f"block format/schema {attrs.get('format')!r}/{attrs.get('schema_version')!r}, "
                               f"this code reads {FORMAT_NAME!r}/{SCHEMA_VERSION}; rebuild the cache")
    check_block_files(path, attrs)


class _OpenBlock:
    """A block's zarr arrays plus its small per-pair arrays, loaded once when the block is first used."""

    def __init__(self, path: Path) -> None:
        from pipeline.cache.block_format import open_block_group

        g = open_block_group(path)
        attrs = dict(g.attrs)
        check_block_attrs(path, attrs)
        self.arrays = {name: g[name] for name in g.array_keys()}
        self.K64 = self.arrays["K"][...]
        self.T64 = self.arrays["T"][...]
        self.scale = self.arrays["scale"][...]
        self.offsets1 = self.arrays["offsets1"][...]
        self.offsets2 = self.arrays["offsets2"][...]
        pos = {int(f): k for k, f in enumerate(attrs["frame_ids"])}
        self.pair_frames = [(int(a), int(b)) for a, b in attrs["pair_frames"]]
        self.pair_pos = [(pos[a], pos[b]) for a, b in self.pair_frames]
        self.stats = attrs["stats"]
        self.width = int(attrs["width"])


class CacheReader:
    """Random access to the pairs of a finished cache ``root`` (the folder holding ``manifest.json``).

    Pairs are numbered 0..len−1 in (sequence name, block, pair) order. Zarr stores are opened lazily and
    per process: handles are keyed by pid, so a reader created before DataLoader workers fork (or pickled
    into spawned workers) opens its own stores in each worker. At most ``max_open_blocks`` blocks stay open
    (an open block holds metadata and its small per-pair arrays, a few kB, and no file descriptors).
    ``keep_mb`` > 0 keeps the decoded pairs in memory, per process, the first ones read until that many MiB
    are held (none evicted): a cache that fits is read from disk once per process, which on a small cache is
    most of a CPU training step's loading (zarr's per-array reads, ≈60 ms a pair on the demo's). A kept
    pair's arrays are read-only, so that a caller cannot change what the next one gets.
    Raises InputError (naming the file) for a missing or corrupt manifest, a schema-version mismatch, or a
    block listed in the manifest that is missing, unreadable, of another schema, or lacking a chunk file (or
    holding a short one): all blocks are checked when the reader is made (``check_files``), and each again
    when it is opened.
    """

    def __init__(self, root: str | os.PathLike[str], max_open_blocks: int = 4096, check_files: bool = True,
                 keep_mb: float = 0.0) -> None:
        self.root = Path(root)
        self.keep_bytes = max(0.0, float(keep_mb)) * 2**20
        self._kept: dict[int, PairSample] = {}
        self._kept_total = 0
        self.manifest: dict[str, Any] = read_manifest(self.root)
        m = self.manifest
        try:
            self._height = int(m["image_size"]["height"])
            self._width = int(m["image_size"]["width"])
            blocks = [(s, b) for s in sorted(m["sequences"]) for b in m["sequences"][s]["blocks"]]
            self._paths = [self.root / b["path"] for _, b in blocks]
            self._seq_of_block = [s for s, _ in blocks]
            counts = np.array([int(b["num_pairs"]) for _, b in blocks], dtype=np.int64)
            firsts = np.array([int(b["first_pair"]) for _, b in blocks], dtype=np.int64)
            self._seq_range = {
                s: range(int(v["first_pair"]), int(v["first_pair"]) + int(v["num_pairs"])) for s, v in m["sequences"].items()
            }
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(self.root / MANIFEST_NAME, f"malformed manifest ({type(exc).__name__}: {exc})") from None
        self._n = int(counts.sum())
        if self._n != int(m["num_pairs"]) or not np.array_equal(firsts, np.concatenate([[0], np.cumsum(counts)[:-1]])):
            raise InputError(self.root / MANIFEST_NAME, "pair counts / ranges are inconsistent")
        # O(1) lookup: global pair index -> (block number, pair within block)
        self._block_of = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
        self._local_of = (np.arange(self._n, dtype=np.int64) - np.repeat(firsts, counts)).astype(np.int32)
        self._max_open = max(1, int(max_open_blocks))
        self._pid = -1
        self._open: OrderedDict[int, _OpenBlock] = OrderedDict()
        if check_files:
            self.check_files()

    def check_files(self) -> None:
        """Every listed block is present, of this schema, and has every chunk file it lists, with its size
        (one small metadata read and a few ``stat`` calls per block): a damaged cache is refused before
        training starts instead of reading lost chunks as zeros. InputError naming the first bad block."""
        for path in self._paths:
            check_block_attrs(path, read_block_attrs(path))

    # ------------------------------------------------------------------ container protocol

    def __len__(self) -> int:
        return self._n

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width) of the stored images, pixels."""
        return self._height, self._width

    @property
    def sequences(self) -> list[str]:
        return sorted(self._seq_range)

    def pairs_of(self, sequence: str) -> range:
        """Global indices of ``sequence``'s pairs (contiguous); KeyError for an unknown sequence."""
        if sequence not in self._seq_range:
            raise KeyError(f"sequence {sequence!r} not in the cache (has {self.sequences})")
        return self._seq_range[sequence]

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_open"] = OrderedDict()
        state["_pid"] = -1
        state["_kept"], state["_kept_total"] = {}, 0
        return state

    def _own_process(self) -> None:
        """Drop the handles and kept pairs of another process (first use here, e.g. a freshly forked worker)."""
        if self._pid != os.getpid():
            self._open = OrderedDict()
            self._kept, self._kept_total = {}, 0
            self._pid = os.getpid()

    def _block(self, k: int) -> _OpenBlock:
        self._own_process()
        blk = self._open.get(k)
        if blk is None:
            path = self._paths[k]
            if not (path / "zarr.json").is_file():
                raise InputError(path, "block listed in the manifest is missing")
            try:
                blk = _OpenBlock(path)
            except Exception as exc:
                raise InputError(path, f"unreadable block ({type(exc).__name__}: {exc})") from None
            self._open[k] = blk
            if len(self._open) > self._max_open:
                self._open.popitem(last=False)
        else:
            self._open.move_to_end(k)
        return blk

    def __getitem__(self, i: int) -> PairSample:
        i = int(i)
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"pair {i} out of range for a cache of {self._n} pairs")
        k = int(self._block_of[i])
        j = int(self._local_of[i])
        self._own_process()  # a forked process starts with its own (empty) kept pairs
        kept = self._kept.get(i)
        if kept is not None:
            return kept
        blk = self._block(k)  # opened only for a pair that is read
        try:
            sample = self._read(blk, k, j, i)
        except InputError:
            raise
        except Exception as exc:
            raise InputError(self._paths[k], f"unreadable pair {j} ({type(exc).__name__}: {exc})") from None
        if self.keep_bytes > 0:
            self._keep(i, sample)
        return sample

    def _keep(self, i: int, sample: PairSample) -> None:
        arrays = [v for v in vars(sample).values() if isinstance(v, np.ndarray)]
        size = sum(a.nbytes for a in arrays)
        if self._kept_total + size > self.keep_bytes:
            return
        for a in arrays:
            a.flags.writeable = False
        self._kept[i] = sample
        self._kept_total += size

    def _read(self, blk: _OpenBlock, k: int, j: int, i: int) -> PairSample:
        a = blk.arrays
        p1, p2 = blk.pair_pos[j]
        # both frames in one call per array (adjacent frames: a slice; otherwise an orthogonal selection)
        if p2 == p1 + 1:
            codes, planes = a["depth"][p1 : p1 + 2], a["rgb"][p1 : p1 + 2]
        elif p1 == p2 + 1:
            codes, planes = a["depth"][p2 : p2 + 2][::-1], a["rgb"][p2 : p2 + 2][::-1]
        else:
            codes = a["depth"].get_orthogonal_selection(([p1, p2], slice(None), slice(None)))
            planes = a["rgb"].get_orthogonal_selection(([p1, p2], slice(None), slice(None), slice(None)))
        s1, e1 = int(blk.offsets1[j]), int(blk.offsets1[j + 1])
        s2, e2 = int(blk.offsets2[j]), int(blk.offsets2[j + 1])
        idx1 = a["idx1"][s1:e1].astype(np.int64)
        idx2 = a["idx2"][s2:e2].astype(np.int64)
        depth1, depth2 = dequantize_depth(codes[0]), dequantize_depth(codes[1])
        K64, T64 = blk.K64, blk.T64[j]
        W = blk.width
        uv1, uv2 = pixel_uv(idx1, W), pixel_uv(idx2, W)
        # == points_from_depth(depth, idx, K), with uv computed once
        pc1 = points_at_pixels(depth1.reshape(-1)[idx1], uv1, K64)
        pc2 = points_at_pixels(depth2.reshape(-1)[idx2], uv2, K64)
        sf = static_flow(pc1, T64, as_float32=True)
        return PairSample(
            pc1=pc1,
            rgb1=np.ascontiguousarray(planes[0].reshape(3, -1)[:, idx1].T),
            uv1=uv1,
            pc2=pc2,
            rgb2=np.ascontiguousarray(planes[1].reshape(3, -1)[:, idx2].T),
            uv2=uv2,
            static_flow=sf,
            T=T64.astype(np.float32),
            K=K64.astype(np.float32),
            depth2=depth2,
            sequence=self._seq_of_block[k],
            frame_t=blk.pair_frames[j][0],
            frame_t1=blk.pair_frames[j][1],
            scale=float(blk.scale[j]),
            gt_flow=gt_flow_from_ulp_offsets(a["gt_flow"][s1:e1], sf) if "gt_flow" in a else None,
            moving=a["moving"][s1:e1] if "moving" in a else None,
            stats={str(key): int(v) for key, v in blk.stats[j].items()},
            index=i,
        )
