"""``monoflow-predict``: scene flow for every consecutive pair of a KITTI sequence, an image folder or a video.

Examples::

    monoflow-predict --input /data/kitti/sequences/06 --camera image_2 --depth net --pose net \\
        --depth_checkpoint runs/depth/dispnet_model_best.pth.tar --pose_checkpoint runs/depth/exp_pose_model_best.pth.tar \\
        --scale.mode camera-height --checkpoint runs/kitti/best.pt --out runs/kitti/predict --pictures true
    monoflow-predict --input my_drive.mp4 --intrinsics 721.5,721.5,609.6,172.9 --depth_checkpoint ... \\
        --pose_checkpoint ... --checkpoint runs/kitti/best.pt --ply true

Writes ``<out>/<name>.h5`` (layout: docs/predict-format.md), optional PLY files and pictures. An interrupted
run resumes (finished pairs are kept in ``<out>/<name>.parts/``). Bad input ends with one line
``error: <file>: <problem>`` and exit code 2.
"""

from __future__ import annotations

import argparse
import sys

from core.errors import run_cli


def build_parser() -> argparse.ArgumentParser:
    """One flag per (nested) field of :class:`evaluation.predict.config.PredictConfig`, help from the field docs."""
    from evaluation.predict.config import PredictConfig
    from core.options import add_dataclass_args

    p = argparse.ArgumentParser(prog="monoflow-predict", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--config", metavar="FILE.toml", default=None, help="options file; flags override it")
    add_dataclass_args(p, PredictConfig)
    return p


def _main(argv: list[str] | None) -> int:
    from evaluation.predict.config import PredictConfig
    from evaluation.predict.run import run_predict
    from core.options import build_config

    args = build_parser().parse_args(argv)
    cfg = build_config(PredictConfig, args, args.config, base=PredictConfig())
    summary = run_predict(cfg)
    print(summary.text())
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``monoflow-predict``; returns the exit code (2 on bad input)."""
    return run_cli(_main, argv)


if __name__ == "__main__":
    sys.exit(main())
