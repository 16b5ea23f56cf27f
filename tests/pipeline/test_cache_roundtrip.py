"""Cache write → read round trip: the reader gives back exactly what stage one computed."""

from __future__ import annotations

import multiprocessing as mp
import pickle

import numpy as np
import pytest

from pipeline.cache import (
    BlockRecord,
    CacheReader,
    CacheWriter,
    FrameRecord,
    PairRecord,
    cache_root,
    canonical_depth,
    colours_at,
    config_hash,
    pixel_uv,
    points_from_depth,
)
from core.errors import ConfigError
from core.geometry import static_flow
from testkit.demo_scene import street_block

H, W = 24, 64
CONFIG = {"size": [W, H], "filters": {"ground_y": 1.15, "max_z": 35.0}}


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.uint8)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """Two sequences (3 + 1 blocks of 3 pairs, with ground truth) written and finalized."""
    root = cache_root(tmp_path_factory.mktemp("cache"), "synth", CONFIG)
    blocks = [street_block("00", b, 3, H, W) for b in range(3)] + [street_block("01", 0, 3, H, W, seed=5)]
    w = CacheWriter(root, CONFIG, {"dataset": "synth"})
    for b in blocks:
        assert w.write_block(b)
    manifest = w.finalize({"00": 3, "01": 1})
    return root, blocks, manifest


def test_config_hash_is_canonical():
    assert config_hash({"a": 1, "b": [1, 2]}) == config_hash({"b": [1, 2], "a": 1})
    assert config_hash({"a": 1}) != config_hash({"a": 2})
    assert len(config_hash(CONFIG)) == 12


def test_round_trip_equals_records(cache):
    root, blocks, manifest = cache
    r = CacheReader(root)
    assert len(r) == 12 == manifest["num_pairs"]
    assert r.image_size == (H, W)
    assert r.pairs_of("00") == range(0, 9) and r.pairs_of("01") == range(9, 12)
    i = 0
    for blk in blocks:
        frames = {f.frame_id: f for f in blk.frames}
        for p in blk.pairs:
            s = r[i]
            f1, f2 = frames[p.frame_t], frames[p.frame_t1]
            assert (s.sequence, s.frame_t, s.frame_t1, s.index) == (blk.sequence, p.frame_t, p.frame_t1, i)
            # clouds bitwise equal to what stage one builds with points_from_depth
            assert np.array_equal(_bits(s.pc1), _bits(points_from_depth(f1.depth, p.idx1, blk.K)))
            assert np.array_equal(_bits(s.pc2), _bits(points_from_depth(f2.depth, p.idx2, blk.K)))
            assert s.pc1.dtype == np.float32 and s.pc1.shape == (p.idx1.size, 3)
            assert np.array_equal(s.rgb1, colours_at(f1.rgb, p.idx1)) and s.rgb1.dtype == np.uint8
            assert np.array_equal(s.rgb2, colours_at(f2.rgb, p.idx2))
            assert np.array_equal(s.uv1, pixel_uv(p.idx1, W)) and np.array_equal(s.uv2, pixel_uv(p.idx2, W))
            sf = static_flow(s.pc1.astype(np.float64), p.T).astype(np.float32)
            assert np.array_equal(_bits(s.static_flow), _bits(sf))
            assert np.array_equal(s.depth2, f2.depth) and s.depth2.dtype == np.float32
            assert np.array_equal(s.T, p.T.astype(np.float32)) and s.T.dtype == np.float32
            assert np.array_equal(s.K, blk.K.astype(np.float32))
            assert np.array_equal(_bits(s.gt_flow), _bits(p.gt_flow)) and np.array_equal(s.moving, p.moving)
            assert s.moving.dtype == np.bool_
            assert s.scale == p.scale and s.stats == p.stats
            i += 1
    assert np.array_equal(r[-1].pc1, r[11].pc1)
    with pytest.raises(IndexError):
        r[12]


def test_ground_truth_flow_moves_the_red_box(cache):
    """Sanity of the fixture itself: moving points' GT flow differs from static flow by the box's motion."""
    r = CacheReader(cache[0])
    s = r[0]
    assert s.moving.sum() >= 5
    d = s.gt_flow[s.moving] - s.static_flow[s.moving]
    assert np.allclose(np.linalg.norm(d, axis=1), 0.6, atol=1e-4)
    assert np.allclose(s.gt_flow[~s.moving], s.static_flow[~s.moving], atol=1e-6)


def _hand_block(depth_raw: np.ndarray) -> BlockRecord:
    """Frames 10, 11, 13; pairs (10, 11), (13, 10) backwards and non-adjacent, and an empty pair."""
    h, w = depth_raw.shape
    rng = np.random.default_rng(3)
    frames = [FrameRecord(fid, depth_raw + k, rng.integers(0, 256, (h, w, 3), dtype=np.uint8)) for k, fid in enumerate([13, 10, 11])]
    K = np.array([[5.0, 0.0, 2.5], [0.0, 5.0, 1.5], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    pairs = [
        PairRecord(10, 11, np.array([0, 4, 7], np.int32), np.array([1, 2], np.int32), T, 2.5, {"kept": 3}),
        PairRecord(13, 10, np.array([2, 11], np.int32), np.array([0], np.int32), T, 2.5, {"kept": 2}),
        PairRecord(11, 13, np.array([], np.int32), np.array([5], np.int32), T, 2.5, {"kept": 0}),
    ]
    return BlockRecord("seq_a", 0, K, frames, pairs)


def test_unsorted_frames_reversed_pairs_empty_pair_and_raw_depth(tmp_path):
    depth_raw = np.linspace(1.0, 9.0, 12, dtype=np.float32).reshape(3, 4) + np.float32(0.0012345)
    blk = _hand_block(depth_raw)
    w = CacheWriter(tmp_path, {"k": 1}, {})
    w.write_block(blk)
    w.finalize({"seq_a": 1})
    r = CacheReader(tmp_path)
    frames = {f.frame_id: f for f in blk.frames}
    for j, p in enumerate(blk.pairs):
        s = r[j]
        assert (s.frame_t, s.frame_t1) == (p.frame_t, p.frame_t1)
        assert np.array_equal(s.pc1, points_from_depth(frames[p.frame_t].depth, p.idx1, blk.K))
        assert np.array_equal(s.depth2, canonical_depth(frames[p.frame_t1].depth))
        assert np.array_equal(s.rgb2, colours_at(frames[p.frame_t1].rgb, p.idx2))
        assert s.gt_flow is None and s.moving is None
    assert r[2].pc1.shape == (0, 3) and r[2].static_flow.shape == (0, 3)
    # the stored depth is the 1/256 m grid: at most half a step from the raw depth
    assert np.abs(r[0].depth2 - frames[11].depth).max() <= 1 / 512


def test_bad_records_are_refused(tmp_path):
    w = CacheWriter(tmp_path, {"k": 1}, {})
    blk = _hand_block(np.ones((3, 4), np.float32))
    blk.pairs[0].idx1 = np.array([4, 0], np.int32)
    with pytest.raises(ValueError, match="ascending"):
        w.write_block(blk)
    blk = _hand_block(np.ones((3, 4), np.float32))
    blk.pairs[0].idx2 = np.array([12], np.int32)
    with pytest.raises(ValueError, match="outside"):
        w.write_block(blk)
    blk = _hand_block(np.ones((3, 4), np.float32))
    blk.pairs[1].frame_t = 99
    with pytest.raises(ValueError, match="frame 99"):
        w.write_block(blk)
    assert not w.has_block("seq_a", 0)


def test_root_of_another_config_is_refused(tmp_path):
    CacheWriter(tmp_path, {"k": 1}, {"x": 1})
    CacheWriter(tmp_path, {"k": 1}, {"x": 2})  # same config: fine (source is informational)
    with pytest.raises(ConfigError, match="another config"):
        CacheWriter(tmp_path, {"k": 2}, {})


def test_existing_block_is_not_rewritten(cache, tmp_path):
    root, blocks, _ = cache
    w = CacheWriter(root, CONFIG, {"dataset": "synth"})
    assert w.has_block("00", 1)
    assert w.write_block(blocks[1]) is False


def _child_reads(reader: CacheReader, q) -> None:
    s = reader[7]
    q.put((reader._pid, s.pc1, s.rgb2))


def test_reader_reopens_after_fork_and_pickles(cache):
    r = CacheReader(cache[0])
    parent = r[7]  # opens stores in the parent
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    proc = ctx.Process(target=_child_reads, args=(r, q))
    proc.start()
    pid, pc1, rgb2 = q.get(timeout=60)
    proc.join(timeout=60)
    assert proc.exitcode == 0
    assert pid == proc.pid  # the child used its own handles
    assert np.array_equal(pc1, parent.pc1) and np.array_equal(rgb2, parent.rgb2)
    clone = pickle.loads(pickle.dumps(r))
    assert not clone._open and np.array_equal(clone[7].pc2, parent.pc2)


def test_kept_pairs_are_read_once_equal_read_only_and_bounded(cache, monkeypatch):
    root = cache[0]
    plain, keeping = CacheReader(root), CacheReader(root, keep_mb=100)
    reads = []
    read = keeping._read
    monkeypatch.setattr(keeping, "_read", lambda blk, k, j, i: reads.append(i) or read(blk, k, j, i))
    for _ in range(2):
        for i in (3, 7, 3):
            a, b = plain[i], keeping[i]
            for name, value in vars(a).items():
                if isinstance(value, np.ndarray):
                    assert np.array_equal(value, getattr(b, name)), name
                    with pytest.raises(ValueError):  # a caller cannot change what the next one gets
                        getattr(b, name)[...] = 0
    assert reads == [3, 7]  # each pair decoded once
    pair = sum(v.nbytes for v in vars(plain[3]).values() if isinstance(v, np.ndarray))
    one = CacheReader(root, keep_mb=1.5 * pair / 2**20)  # room for one pair: the first is kept, no other
    one[3], one[7], one[3]
    assert set(one._kept) == {3} and one._kept_total == pair
    assert plain[3].pc1.flags.writeable and not plain._kept  # keep_mb 0: nothing kept
    assert one[3] is one[3]
    clone = pickle.loads(pickle.dumps(one))  # another process starts with nothing kept
    assert not clone._kept and clone._kept_total == 0 and clone.keep_bytes == one.keep_bytes


def test_gt_flow_ulp_offsets_are_exact_and_zero_on_static_points():
    from pipeline.cache.encode import gt_flow_from_ulp_offsets, gt_flow_to_ulp_offsets

    sf = np.array([[0.5, -0.25, 1e-30], [-3.0, 0.0, 2.0], [1.0, 1.0, 1.0]], np.float32)
    gt = sf.copy()
    gt[1] = [4.0, -0.0, -7.5]  # a moving point, with sign changes and a negative zero
    gt[2] = np.nextafter(sf[2], np.float32(2))  # one ulp away, as a source computing it differently would be
    off = gt_flow_to_ulp_offsets(gt, sf)
    assert off.dtype == np.int32
    assert off[0].tolist() == [0, 0, 0] and off[2].tolist() == [1, 1, 1]
    assert np.array_equal(_bits(gt_flow_from_ulp_offsets(off, sf)), _bits(gt))
