"""``monoflow-train-depth``: instant --help, one-line errors, presets, --eval_only, and DDP through torchrun."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from _depth_fixtures import depth_world, one_thread  # noqa: F401  (one_thread: autouse fixture)
from pipeline.nets import load_depth_net, load_pose_net
from training.depth.cli import build_parser, main, resolve_config

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    return depth_world(tmp_path_factory.mktemp("synth") / "world", frames=6, test_frames=4, seed=1, parked_cars=3)


def _env() -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}


def test_help_is_instant_and_imports_no_torch():
    code = ("import sys; from training.depth import cli\n"
            "try:\n    cli.main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print('TORCH' if 'torch' in sys.modules else 'NOTORCH')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), cwd=REPO)
    assert "monoflow-train-depth" in out.stdout and "--data.root" in out.stdout and "--preset" in out.stdout
    assert out.stdout.strip().endswith("NOTORCH")


def test_presets_toml_and_flags_resolve_in_order(tmp_path: Path):
    toml = tmp_path / "d.toml"
    toml.write_text('steps = 7\n[optim]\nlr = 0.002\n[data]\nwidth = 256\n')
    args = build_parser().parse_args(["--preset", "demo", "--config", str(toml), "--data.width", "192",
                                      "--data.root", "R", "--run_dir", "X"])
    cfg = resolve_config(args)
    assert (cfg.steps, cfg.optim.lr, cfg.data.width, cfg.data.height) == (7, 0.002, 192, 64)  # flag > TOML > preset
    assert (cfg.data.root, cfg.run_dir, cfg.loss.pose_antisymmetric, cfg.data.flip, cfg.data.val_sequences) == (
        "R", "X", True, False, ("last",))  # the preset's departures survive TOML and flags
    plain = resolve_config(build_parser().parse_args(["--data.root", "R"]))
    assert (plain.optim.lr, plain.optim.batch_size, plain.loss.num_scales, plain.data.width) == (1e-4, 4, 1, 416)
    assert (plain.loss.pose_antisymmetric, plain.data.flip) == (False, True)  # defaults: the released recipe


def test_bad_input_is_one_line(tmp_path: Path, capsys):
    assert main(["--data.root", str(tmp_path / "nowhere"), "--run_dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "nowhere/sequences" in err and len(err.splitlines()) == 1
    assert main(["--preset", "tiny", "--data.root", str(tmp_path), "--data.width", "100"]) == 2
    assert "multiples of 32" in capsys.readouterr().err


def test_train_then_eval_only(world: Path, tmp_path: Path, capsys):
    run = tmp_path / "run"
    args = ["--preset", "tiny", "--data.root", str(world), "--run_dir", str(run), "--steps", "1",
            "--data.val_sequences", "last", "--eval.depth_frames_max", "2"]
    assert main(args) == 0
    assert "checkpoints:" in capsys.readouterr().out
    out = tmp_path / "eval.json"
    assert main(args + ["--eval_only", "--output", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["disp_checkpoint"].endswith("dispnet_model_best.pth.tar") and report["sequences"] == ["01"]
    assert report["metrics"]["depth_frames"] == 2 and report["metrics"]["pose_pairs"] == 3
    final = json.loads((run / "metrics.json").read_text())["final"]
    assert report["metrics"]["abs_rel"] == pytest.approx(final["val_abs_rel"], rel=1e-5)


def test_ddp_through_torchrun_on_cpu(world: Path, tmp_path: Path):
    run = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", "-m",
           "training.depth", "--preset", "tiny", "--data.root", str(world), "--run_dir", str(run), "--steps", "2",
           "--log_every", "1"]
    out = subprocess.run(cmd, capture_output=True, text=True, env=_env(), cwd=REPO, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.count("done: 2 steps") == 1  # only rank 0 reports
    load_depth_net(run / "dispnet_checkpoint.pth.tar")
    load_pose_net(run / "exp_pose_checkpoint.pth.tar")
    rows = (run / "train.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].startswith("step,")
