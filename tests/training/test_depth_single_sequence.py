"""monoflow-train-depth on one real KITTI sequence with nothing but its frames and the official poses file:
no --data.sequences / --data.val_sequences needed, the full 1,101-line 06.txt beside 6 frames is accepted with
--data.strict_pose_count false, the best files are picked by the pose error (no depth ground truth) and hold
the nets only (no optimiser state)."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import torch

from _depth_fixtures import one_thread  # noqa: F401  (autouse fixture)
from training.depth.cli import main as depth_main

GRAY = "kitti_odometry_06_gray"


def test_single_sequence_defaults_validate_select_by_pose_and_keep_best_files_small(shared_data: Path,
                                                                                    tmp_path: Path, capsys):
    root = tmp_path / "kitti"
    seq = root / "sequences" / "06"
    (seq / "image_0").mkdir(parents=True)
    for i in range(6):
        (seq / "image_0" / f"{i:06d}.png").symlink_to(shared_data / GRAY / "image_l" / f"{i:06d}.png")
    (seq / "calib.txt").symlink_to(shared_data / GRAY / "calib.txt")
    (root / "poses").mkdir()
    shutil.copy(shared_data / "kitti_odometry_06_color" / "videos_kitti06" / "06.txt", root / "poses" / "06.txt")
    run = tmp_path / "run"
    args = ["--preset", "tiny", "--data.root", str(root), "--data.camera", "image_0", "--data.width", "128",
            "--data.height", "64", "--steps", "4", "--val_every", "2", "--ckpt_every", "2", "--run_dir", str(run)]
    assert depth_main(args) == 2  # the full poses file beside 6 frames: refused by default, naming the flag
    assert "strict_pose_count" in capsys.readouterr().err
    assert depth_main(args + ["--data.strict_pose_count", "false"]) == 0
    rows = list(csv.DictReader((run / "val.csv").open()))
    assert [int(float(r["step"])) for r in rows] == [0, 2, 4]  # validation ran without being asked for
    assert all(float(r["val_ate"]) > 0 for r in rows) and "val_abs_rel" not in rows[0]
    best = torch.load(run / "dispnet_model_best.pth.tar", map_location="cpu", weights_only=True)
    assert set(best) == {"epoch", "state_dict"}  # nets only: no optimiser state in the "best" files
    latest = (run / "latest.pt").stat().st_size
    assert (run / "dispnet_model_best.pth.tar").stat().st_size < 0.5 * latest
    # the best step is the one with the lowest ATE-5 among the validations after step 0
    ates = {int(float(r["step"])): float(r["val_ate"]) for r in rows if float(r["step"]) > 0}
    ck = torch.load(run / "latest.pt", map_location="cpu", weights_only=True)
    assert abs(ck["best_val"] - min(ates.values())) < 1e-9
    # a second run into the same folder is refused without --resume / --overwrite
    assert depth_main(args + ["--data.strict_pose_count", "false"]) == 2
    assert "already holds a run" in capsys.readouterr().err
