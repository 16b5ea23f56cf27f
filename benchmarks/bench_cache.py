"""Benchmark of stage one's cache: bytes per pair on disk and random-access read time per pair.

    .venv/bin/python benchmarks/bench_cache.py                      # synthetic street, 832x256
    .venv/bin/python benchmarks/bench_cache.py --source kitti       # real KITTI frames + predicted depth
    .venv/bin/python benchmarks/bench_cache.py --blocks 8 --pairs-per-block 16 --reads 400

Writes a cache into a temporary folder (or --out), then reads pairs in a seeded random order through
CacheReader. Read times include zarr decoding and rebuilding the clouds and static flow; files are in
the OS page cache (they were just written), so this measures CPU cost, not a cold disk. Run it as a
DataLoader worker runs, one BLAS thread: OPENBLAS_NUM_THREADS=1 (numpy's BLAS threads otherwise fight the
other workers on a loaded machine).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _block(source: str, seq: str, b: int, pairs: int, height: int, width: int, data: Path):
    if source == "kitti":
        from testkit.kitti_sample import kitti_block

        blk = kitti_block(data / "kitti_sceneflow2015_000139", pairs, height, width)
        blk.sequence, blk.block_index = seq, b
        return blk
    from testkit.demo_scene import street_block

    return street_block(seq, b, pairs, height, width, with_truth=source == "synthetic-gt")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", choices=["synthetic", "synthetic-gt", "kitti"], default="synthetic",
                    help="synthetic street (no GT), with GT flow + moving mask, or real KITTI 000139 frames")
    ap.add_argument("--size", default="832x256", help="working size WxH (default 832x256)")
    ap.add_argument("--blocks", type=int, default=4)
    ap.add_argument("--pairs-per-block", type=int, default=8)
    ap.add_argument("--reads", type=int, default=200, help="random pair reads to time")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--out", type=Path, default=None, help="cache folder to keep (default: a temp folder)")
    args = ap.parse_args(argv)
    width, height = (int(x) for x in args.size.lower().split("x"))

    from pipeline.cache import CacheReader, CacheWriter, verify

    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        config = {"bench": args.source, "size": [width, height], "pairs_per_block": args.pairs_per_block}
        w = CacheWriter(root, config, {"bench": True})
        write_s, make_s = [], []
        for b in range(args.blocks):
            t0 = time.perf_counter()
            blk = _block(args.source, "00", b, args.pairs_per_block, height, width, args.data)
            t1 = time.perf_counter()
            w.write_block(blk)
            write_s.append(time.perf_counter() - t1)
            make_s.append(t1 - t0)
        w.finalize({"00": args.blocks})
        report = verify(root)
        assert report.ok, report.summary()
        n = report.pairs_checked
        per_pair = report.bytes_on_disk / n

        reader = CacheReader(root)
        rng = np.random.default_rng(args.seed)
        order = rng.integers(0, len(reader), args.reads)
        times, points = [], []
        for i in order:
            t0 = time.perf_counter()
            s = reader[int(i)]
            times.append(time.perf_counter() - t0)
            points.append(s.pc1.shape[0] + s.pc2.shape[0])
        times_ms = np.array(times) * 1e3
        # every read in a block not yet open (as with random sampling over many more blocks than are open)
        cold = CacheReader(root, max_open_blocks=1)
        cold_ms = []
        for i in order[: max(1, args.reads // 4)]:
            cold._open.clear()
            t0 = time.perf_counter()
            cold[int(i)]
            cold_ms.append((time.perf_counter() - t0) * 1e3)
        result = {
            "source": args.source,
            "size": f"{width}x{height}",
            "pairs": n,
            "pairs_per_block": args.pairs_per_block,
            "bytes_per_pair": round(per_pair),
            "write_s_per_block": round(float(np.median(write_s)), 3),
            "read_ms_per_pair_median": round(float(np.median(times_ms)), 2),
            "read_ms_per_pair_p90": round(float(np.percentile(times_ms, 90)), 2),
            "read_ms_per_pair_block_not_open": round(float(np.median(cold_ms)), 2),
            "points_per_pair": int(np.mean(points)),
            "cpu_count": os.cpu_count(),
        }
    print(f"{result['source']} {result['size']}: {result['bytes_per_pair'] / 1e3:.0f} kB/pair on disk "
          f"({result['pairs']} pairs, {result['pairs_per_block']}/block); random read "
          f"{result['read_ms_per_pair_median']:.1f} ms/pair median, p90 {result['read_ms_per_pair_p90']:.1f} ms "
          f"({result['points_per_pair']} points/pair), {result['read_ms_per_pair_block_not_open']:.1f} ms when its block "
          f"is not open yet; write {result['write_s_per_block']:.2f} s/block")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
