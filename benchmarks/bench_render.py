"""Benchmark of the synthetic world's CPU ray caster: frames per second at the demo size and at KITTI's
working size, and the wall time of generating the default demo world.

    .venv/bin/python benchmarks/bench_render.py                    # 416x128 and 832x256, 6 frames each
    .venv/bin/python benchmarks/bench_render.py --sizes 832x256 --frames 10
    .venv/bin/python benchmarks/bench_render.py --demo --workers 2 # + the whole default world (3 sequences)

Per size: ``render`` = the image_2 camera alone (colour + depth), ``frame`` = everything the generator
does for one frame (render, 3D flow with its visibility ray cast, the LiDAR scan, writing the files).
Wall-clock seconds on this machine (numpy, one process), after one warm-up frame.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def bench_size(width: int, height: int, frames: int) -> dict:
    from pipeline.synth.config import SynthConfig
    from pipeline.synth.render import render_camera
    from pipeline.synth.rig import make_rig
    from pipeline.synth.sequence import SequenceJob, generate_frame
    from pipeline.synth.world import build_world

    cfg = SynthConfig(width=width, height=height)
    world = build_world(cfg, 0, frames + 2)
    rig = make_rig(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        job = SequenceJob("00", world, rig, cfg, Path(tmp), want_scan_gt=False)
        generate_frame(job, 0)  # warm-up
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(1, frames + 1):
            render_camera(world, k, rig.K, job.cam2_pose(k), width, height, cfg.camera_range, cfg.supersample)
        t_render, c_render = (time.perf_counter() - t0) / frames, (time.process_time() - c0) / frames
        t0, c0 = time.perf_counter(), time.process_time()
        points = 0
        for k in range(1, frames + 1):
            points += generate_frame(job, k).scan_points
        t_frame, c_frame = (time.perf_counter() - t0) / frames, (time.process_time() - c0) / frames
    return {
        "size": f"{width}x{height}",
        "render_fps": round(1.0 / t_render, 2),
        "render_s": round(t_render, 4),
        "render_cpu_s": round(c_render, 4),
        "frame_fps": round(1.0 / t_frame, 2),
        "frame_s": round(t_frame, 4),
        "frame_cpu_s": round(c_frame, 4),
        "lidar_points": int(points / frames),
    }


def bench_demo(workers: int) -> dict:
    from pipeline.synth import SynthConfig, generate

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        s = generate(SynthConfig(), Path(tmp) / "demo", workers=workers)
        wall = time.perf_counter() - t0
        size = sum(p.stat().st_size for p in (Path(tmp) / "demo").rglob("*") if p.is_file())
    return {"demo_world": "default SynthConfig()", "workers": workers, "frames": s.frames, "seconds": round(wall, 2),
            "frames_per_s": round(s.frames / wall, 2), "megabytes": round(size / 1e6, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="416x128,832x256", help="comma-separated WxH (default %(default)s)")
    ap.add_argument("--frames", type=int, default=6, help="timed frames per size")
    ap.add_argument("--demo", action="store_true", help="also time generating the whole default demo world")
    ap.add_argument("--workers", type=int, default=1, help="processes for --demo")
    args = ap.parse_args(argv)
    import os

    print(f"# bench_render: {os.cpu_count()} CPUs visible")
    for size in args.sizes.split(","):
        w, h = (int(x) for x in size.lower().split("x"))
        r = bench_size(w, h, args.frames)
        print(json.dumps(r))
    if args.demo:
        print(json.dumps(bench_demo(args.workers)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
