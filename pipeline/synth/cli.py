"""``monoflow-synth``: write the seeded synthetic world (KITTI odometry layout + ground truth)."""

from __future__ import annotations

import argparse
import os
from dataclasses import replace

from core.errors import run_cli
from pipeline.synth.config import SynthConfig


def build_parser() -> argparse.ArgumentParser:
    d = SynthConfig()
    p = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="monoflow-synth",
        description="Render a seeded synthetic driving world as a KITTI-odometry folder with ground-truth depth, "
        "3D flow, LiDAR scans and a scene-flow test split.",
    )
    p.add_argument("--out", required=True, help="output folder (written atomically)")
    p.add_argument("--seed", type=int, default=d.seed, help="world seed: same seed, same world (default %(default)s)")
    p.add_argument("--width", type=int, default=d.width, help="image width in pixels (default %(default)s)")
    p.add_argument("--height", type=int, default=d.height, help="image height in pixels (default %(default)s)")
    p.add_argument("--focal-scale", type=float, default=d.focal_scale, help="multiplies KITTI-scaled fx, fy")
    p.add_argument("--sequences", type=int, default=d.n_sequences, help="training sequences (default %(default)s)")
    p.add_argument("--frames", type=int, default=d.frames, help="frames per training sequence (default %(default)s)")
    p.add_argument("--test-frames", type=int, default=d.test_frames, help="frames of the test sequence, 0 = none")
    p.add_argument("--parked", type=int, default=d.parked_cars, help="parked cars per sequence")
    p.add_argument("--movers", type=int, default=d.moving_cars, help="moving cars per sequence")
    p.add_argument("--crossing", type=int, default=d.crossing_cars,
                   help="cars per sequence crossing the road on a side street ahead, at the movers' speeds "
                        "(default %(default)s)")
    p.add_argument("--mover-speed", type=float, nargs=2, metavar=("MIN", "MAX"),
                   default=(d.mover_speed_min, d.mover_speed_max), help="moving cars' speed range, m/s")
    p.add_argument("--lidar-az-step", type=float, default=d.lidar_azimuth_step_deg,
                   help="LiDAR azimuth step of the training sequences, degrees (default %(default)s)")
    p.add_argument("--test-lidar-az-step", type=float, default=d.test_lidar_azimuth_step_deg,
                   help="LiDAR azimuth step of the test sequence, degrees (default %(default)s)")
    p.add_argument("--lidar-scans", choices=("all", "test"), default=d.lidar_scans,
                   help="sequences with Velodyne scans: all (KITTI's layout) or the test sequence alone (its scans make "
                        "the scene-flow split; nearly half a frame's rendering saved for runs that read only the "
                        "training cameras) (default %(default)s)")
    p.add_argument("--supersample", type=int, default=d.supersample, help="colour samples per pixel side")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="processes rendering frames; the output does not depend on it (default %(default)s)")
    p.add_argument("--force", action="store_true", help="replace an existing different world at --out")
    from core.options import add_underscore_aliases

    return add_underscore_aliases(p)


def _body(argv: list[str] | None) -> int:
    a = build_parser().parse_args(argv)
    from pipeline.synth.generator import generate

    cfg = replace(
        SynthConfig(),
        seed=a.seed, width=a.width, height=a.height, focal_scale=a.focal_scale, n_sequences=a.sequences,
        frames=a.frames, test_frames=a.test_frames, parked_cars=a.parked, moving_cars=a.movers, crossing_cars=a.crossing,
        mover_speed_min=a.mover_speed[0], mover_speed_max=a.mover_speed[1],
        lidar_azimuth_step_deg=a.lidar_az_step, test_lidar_azimuth_step_deg=a.test_lidar_az_step,
        supersample=a.supersample, lidar_scans=a.lidar_scans,
    )
    summary = generate(cfg, a.out, force=a.force, workers=max(1, a.workers))
    print("\n".join(summary.lines()))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(_body, argv)


if __name__ == "__main__":
    raise SystemExit(main())
