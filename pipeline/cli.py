"""``monoflow-preprocess``: stage one from the command line (also ``python -m pipeline``).

Usage::

    monoflow-preprocess [run] --root DATA --sequences 00,01 --depth net --depth_checkpoint dispnet.pth.tar \\
        --pose net --pose_checkpoint posenet.pth.tar --scale.mode camera-height --out cache [--config run.toml]
    monoflow-preprocess merge CACHE_ROOT     # write manifest.json once every shard's blocks are present
    monoflow-preprocess verify CACHE_ROOT    # decode every block, check it against the manifest
    monoflow-preprocess kitti-sceneflow DATA_SCENE_FLOW OUT   # KITTI 2015 → HPLFlowNet-layout test split

``run`` is the default sub-command. Options come from ``--config FILE.toml`` (top-level keys and
``[filters]`` / ``[scale]`` tables) overridden by flags; every option is listed by ``run --help``.
Bad input ends with one line ``error: <file>: <problem>`` and exit code 2.
"""

from __future__ import annotations

import argparse
import sys

from core.errors import run_cli

COMMANDS = ("run", "merge", "verify", "kitti-sceneflow")


def _run_parser() -> argparse.ArgumentParser:
    from core.options import add_dataclass_args
    from pipeline.preprocess import PreprocessConfig

    p = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="monoflow-preprocess run",
        description="Stage one: depth, pose, scale, filters -> zarr cache (cache/<dataset>/<config-hash>/).",
    )
    p.add_argument("--config", metavar="FILE.toml", default=None, help="options file; flags override it")
    add_dataclass_args(p, PreprocessConfig)
    return p


def _top_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="monoflow-preprocess",
        description="Stage one of monoflow: monocular frames -> filtered coloured point clouds + static flow (cache).",
        epilog="'run' is the default: `monoflow-preprocess --root DATA ...` runs stage one. "
        "See `monoflow-preprocess run --help` for its options.",
    )
    sub = p.add_subparsers(dest="command", metavar="{run,merge,verify,kitti-sceneflow}")
    sub.add_parser("run", allow_abbrev=False, help="run stage one (default)", add_help=False)
    m = sub.add_parser("merge", allow_abbrev=False, help="write a cache's manifest from its finished blocks (after sharded runs)")
    m.add_argument("cache_root", help="the cache folder: <out>/<dataset>/<config-hash>")
    v = sub.add_parser("verify", allow_abbrev=False, help="decode and check every block of a finished cache")
    v.add_argument("cache_root", help="the cache folder: <out>/<dataset>/<config-hash>")
    k = sub.add_parser("kitti-sceneflow", allow_abbrev=False,
                       help="write KITTI Scene Flow 2015's training scenes as point pairs in HPLFlowNet's "
                            "KITTI_processed_occ_final layout (pipeline/kitti/stereo_flow.py)")
    k.add_argument("root", help="the unpacked data_scene_flow folder (holding training/disp_occ_0, disp_occ_1, "
                                "flow_occ and calib_cam_to_cam, the last from data_scene_flow_calib)")
    k.add_argument("out", help="the split folder to write (OUT/000000/pc1.npy, pc2.npy, …); finished scenes "
                               "are kept, so an interrupted run resumes")
    k.add_argument("--scenes", type=int, default=200, help="scenes 0 … N−1 (200: all, as HPLFlowNet writes them; "
                                                          "evaluate with --protocol hplflownet --mapping to keep its 142)")
    return p


def _cmd_run(argv: list[str]) -> int:
    from core.options import build_config
    from pipeline.preprocess import PreprocessConfig, run_preprocess

    args = _run_parser().parse_args(argv)
    config = build_config(PreprocessConfig, args, args.config)
    summary = run_preprocess(config)
    print(summary.text())
    return 0


def _cmd_merge(root: str) -> int:
    from pipeline.cache.manifest import merge

    manifest = merge(root)
    print(f"{root}: manifest written, {manifest['num_pairs']} pairs in {manifest['num_blocks']} blocks")
    return 0


def _cmd_verify(root: str) -> int:
    from pipeline.cache.verify import verify

    report = verify(root)
    print(report.summary())
    return 0 if report.ok else 1


def _cmd_kitti_sceneflow(root: str, out: str, scenes: int) -> int:
    from core.errors import ConfigError
    from pipeline.kitti.stereo_flow import SCENES, build_split

    if not 1 <= scenes <= SCENES:
        raise ConfigError(f"--scenes must be in 1..{SCENES}, got {scenes}")
    written = build_split(root, out, range(scenes))
    print(f"{out}: {len(written)} scenes (HPLFlowNet layout; evaluate with monoflow-evaluate run --split {out} "
          f"--protocol hplflownet --mapping <devkit>/mapping/train_mapping.txt)")
    return 0


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS + ("-h", "--help"):
        argv = ["run"] + argv
    if argv[0] == "run":
        return _cmd_run(argv[1:])
    args = _top_parser().parse_args(argv)
    if args.command == "merge":
        return _cmd_merge(args.cache_root)
    if args.command == "kitti-sceneflow":
        return _cmd_kitti_sceneflow(args.root, args.out, args.scenes)
    return _cmd_verify(args.cache_root)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``monoflow-preprocess``; returns the exit code (2 on bad input)."""
    return run_cli(_main, argv)


if __name__ == "__main__":
    sys.exit(main())
