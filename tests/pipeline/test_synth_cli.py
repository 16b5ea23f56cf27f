"""monoflow-synth: determinism (same seed → byte-identical, any worker count), seeds differ, the CLI's
summary, atomic writing and refusing to overwrite a different world."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.synth import SYNTH_VERSION, SynthConfig, generate
from pipeline.synth.cli import main

TINY = SynthConfig(seed=11, width=64, height=24, n_sequences=1, frames=3, test_frames=2, parked_cars=3,
                   moving_cars=2, lidar_azimuth_step_deg=3.0, test_lidar_azimuth_step_deg=3.0)
FLAGS = ["--width", "64", "--height", "24", "--sequences", "1", "--frames", "3", "--test-frames", "2",
         "--parked", "3", "--movers", "2", "--lidar-az-step", "3.0", "--test-lidar-az-step", "3.0"]


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_is_byte_identical_whatever_the_workers(tmp_path):
    a = _files(generate(TINY, tmp_path / "a").root)
    b = _files(generate(TINY, tmp_path / "b", workers=2).root)
    assert a.keys() == b.keys()
    assert [k for k in a if a[k] != b[k]] == []
    expected = {"synth.json", "poses/00.txt", "poses/01.txt", "sequences/00/calib.txt", "sequences/00/times.txt",
                "sequences/00/image_2/000002.png", "sequences/00/depth_2/000002.png", "sequences/00/velodyne/000002.bin",
                "sequences/00/flow3d_2/000001.npz", "sequences/01/flow3d_2/000000.npz", "sceneflow/README.txt",
                "sceneflow/flownet3d/000000.npz", "sceneflow/hplflownet/000000/pc1.npy",
                "sceneflow/hplflownet/000000/pc2.npy", "sceneflow/hplflownet/000000/moving.npy"}
    assert expected <= a.keys()
    assert "sequences/00/flow3d_2/000002.npz" not in a  # no t+1 for the last frame
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]  # no temporary folders left


def test_a_different_seed_draws_a_different_world(tmp_path):
    from dataclasses import replace

    a = generate(TINY, tmp_path / "a").root
    b = generate(replace(TINY, seed=12), tmp_path / "b").root
    for rel in ("sequences/00/image_2/000000.png", "poses/00.txt", "sequences/00/velodyne/000000.bin"):
        assert (a / rel).read_bytes() != (b / rel).read_bytes(), rel


def test_cli_prints_summary_keeps_same_world_and_refuses_a_different_one(tmp_path, capsys):
    out = tmp_path / "w"
    assert main(["--out", str(out), "--seed", "5", *FLAGS]) == 0
    text = capsys.readouterr().out
    assert "5 frames" in text and "3 flow pairs" in text and "1 scene-flow test pairs" in text
    assert "LiDAR points per scan" in text and "moving cars" in text and "written in" in text
    meta = json.loads((out / "synth.json").read_text())
    assert meta["version"] == SYNTH_VERSION and meta["seed"] == 5 and meta["config"]["width"] == 64
    assert meta["sequences"]["01"]["split"] == "test" and meta["test_sequence"] == "01"
    stamp = (out / "sequences/00/image_2/000000.png").stat().st_mtime_ns

    assert main(["--out", str(out), "--seed", "5", *FLAGS]) == 0  # same world: kept, not rewritten
    assert "already present" in capsys.readouterr().out
    assert (out / "sequences/00/image_2/000000.png").stat().st_mtime_ns == stamp

    assert main(["--out", str(out), "--seed", "6", *FLAGS]) == 2  # a different world: refused
    assert "different synthetic world" in capsys.readouterr().err and json.loads((out / "synth.json").read_text())["seed"] == 5

    assert main(["--out", str(out), "--seed", "6", "--force", *FLAGS]) == 0
    assert json.loads((out / "synth.json").read_text())["seed"] == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w"]


def test_cli_crossing_cars_are_movers_of_the_world(tmp_path):
    assert main(["--out", str(tmp_path / "x"), "--seed", "5", "--crossing", "2", *FLAGS]) == 0
    meta = json.loads((tmp_path / "x" / "synth.json").read_text())
    assert meta["config"]["crossing_cars"] == 2
    # the two lane movers and the two crossing ones, in every sequence
    assert [s["moving_cars"] for s in meta["sequences"].values()] == [4, 4]


def test_cli_refuses_a_folder_that_is_not_a_world_and_bad_options(tmp_path, capsys):
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert main(["--out", str(other), *FLAGS]) == 2
    assert "not a synthetic world" in capsys.readouterr().err and (other / "notes.txt").exists()
    assert main(["--out", str(tmp_path / "x"), "--width", "8"]) == 2
    assert "too small" in capsys.readouterr().err
    assert main(["--out", str(tmp_path / "x"), "--mover-speed", "5", "2"]) == 2
    assert not (tmp_path / "x").exists()


def test_summary_counts_match_the_files(tmp_path):
    s = generate(TINY, tmp_path / "w")
    assert s.frames == 5 and s.flow_pairs == 3 and s.test_pairs == 1 and not s.reused
    assert s.moving_cars == sum(v["moving_cars"] for v in s.sequences.values()) > 0
    n = np.fromfile(tmp_path / "w/sequences/00/velodyne/000000.bin", dtype=np.float32).reshape(-1, 4).shape[0]
    assert n > 0.5 * 64 * 120 and s.points_per_scan > 0.5 * 64 * 120  # 64 beams × 120 azimuths, most return
    with pytest.raises(Exception, match="different synthetic world"):
        generate(SynthConfig(**{**TINY.to_dict(), "seed": 99}), tmp_path / "w")


def test_stale_temporary_of_a_dead_run_is_removed(tmp_path):
    import subprocess

    proc = subprocess.Popen(["true"])  # a process that has exited: its pid is free
    proc.wait()
    stale = tmp_path / f"w.tmp-{proc.pid}"
    (stale / "sequences").mkdir(parents=True)
    generate(TINY, tmp_path / "w")
    assert not stale.exists() and (tmp_path / "w" / "synth.json").is_file()


def test_a_world_scanned_on_its_test_sequence_alone_differs_only_by_the_training_scans(tmp_path):
    """``lidar_scans="test"`` (the demo's world): every other file byte-identical to the full world's, no Velodyne
    scan of a training sequence, the scene-flow split the same; a world written before the option existed is
    the default's and is kept, not refused."""
    from dataclasses import replace

    full = _files(generate(TINY, tmp_path / "full").root)
    s = generate(replace(TINY, lidar_scans="test"), tmp_path / "test")
    part = _files(s.root)
    scans = {k for k in full if k.startswith("sequences/00/velodyne/")}
    assert scans and set(full) - set(part) == scans and set(part) <= set(full)
    assert [k for k in part if k != "synth.json" and part[k] != full[k]] == []
    assert s.sequences["00"]["points_per_scan"] == 0 and s.points_per_scan == s.sequences["01"]["points_per_scan"] > 0
    assert "LiDAR points per scan (sequences 01)," in s.lines()[-1]  # the mean is the scanned sequences' alone
    with pytest.raises(Exception, match="lidar_scans"):
        SynthConfig(lidar_scans="train").validate()
    meta = json.loads((tmp_path / "full/synth.json").read_text())
    del meta["config"]["lidar_scans"]  # as written before the option existed
    (tmp_path / "full/synth.json").write_text(json.dumps(meta))
    assert generate(TINY, tmp_path / "full").reused
