"""The Table II / III runner: variant switches reach stage one and the trainer, tables are written, and a
rerun reuses the caches and the trained runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from evaluation.ablations import (
    FILTER_VARIANTS,
    LOSS_VARIANTS,
    AblationConfig,
    level_points_for,
    run_folder,
    training_sequences,
)
from evaluation.cli import main

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    from pipeline.synth.config import SynthConfig
    from pipeline.synth.generator import generate

    root = tmp_path_factory.mktemp("ablations") / "world"
    generate(SynthConfig(width=160, height=48, frames=3, test_frames=3, n_sequences=1), root)
    return root


def test_level_points() -> None:
    assert level_points_for(8192) == (2048, 1024, 256, 64, 16)  # the paper's
    assert level_points_for(2048) == (512, 256, 64, 16, 4)
    assert level_points_for(256) == (64, 32, 16, 8, 4)  # strictly decreasing even when n/128 < 4
    from training.model.halflownet import HALFlowConfig

    for n in (128, 200, 256, 640, 1000, 4096):
        HALFlowConfig(n_points=n, level_points=level_points_for(n))  # valid (raises otherwise)


def test_variants_are_the_papers() -> None:
    switches = {"use_depth", "use_ds", "use_chamfer", "use_laplacian"}
    off = [set(k for k, v in s.items() if not v) for s in LOSS_VARIANTS.values()]
    assert off == [{"use_depth"}, {"use_ds"}, {"use_chamfer"}, {"use_laplacian"}, set()]
    assert all(set(s) <= switches for s in LOSS_VARIANTS.values())
    assert list(LOSS_VARIANTS)[-1].startswith("Depth + DSC + Cha + LR")
    from pipeline.filters import FilterConfig

    assert FILTER_VARIANTS == {"with ground": {"ground": False}, "with sky": {"far": False},
                               "without ground or sky": {}}
    for filters in FILTER_VARIANTS.values():
        f = FilterConfig(**filters)
        assert f.lidar and f.occlusion  # only ground / sky change between the rows


def test_training_sequences_leave_out_the_test_sequence(world: Path, tmp_path: Path) -> None:
    info = json.loads((world / "synth.json").read_text())
    assert info["test_sequence"] == "01"
    assert training_sequences(AblationConfig(world=str(world))) == ("00",)
    assert training_sequences(AblationConfig(world=str(world), sequences=("01",))) == ("01",)
    assert training_sequences(AblationConfig(world=str(tmp_path))) == ()  # not a synthetic world: all


def test_run_folder_identity(tmp_path: Path) -> None:
    cfg = AblationConfig(steps=5, n_points=256)
    a = run_folder(cfg, tmp_path / "c1", {}, tmp_path)
    assert a == run_folder(AblationConfig(steps=5, n_points=256), tmp_path / "c1", {}, tmp_path)
    assert a.name.startswith("full-")
    others = [run_folder(cfg, tmp_path / "c2", {}, tmp_path),
              run_folder(AblationConfig(steps=6, n_points=256), tmp_path / "c1", {}, tmp_path),
              run_folder(cfg, tmp_path / "c1", {"use_ds": False}, tmp_path)]
    assert len({a, *others}) == 4
    assert others[2].name.startswith("no-ds-")
    assert run_folder(cfg, tmp_path / "c2", {}, tmp_path, {"far": False}).name.startswith("full-keep-sky-")


def test_bad_tables_and_world(tmp_path: Path, capsys) -> None:
    assert main(["ablations", "--world", str(tmp_path), "--tables", "IV"]) == 2
    assert "--tables takes II and/or III" in capsys.readouterr().err
    assert main(["ablations", "--world", str(tmp_path / "nope"), "--n-points", "256"]) == 2
    assert "no such dataset folder" in capsys.readouterr().err


def test_tables_on_a_tiny_budget_and_reuse(world: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "abl"
    argv = ["ablations", "--world", str(world), "--out", str(out), "--steps", "2", "--size", "160x48",
            "--n-points", "256", "--batch-size", "2", "--device", "cpu"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "### Table II — losses (2 steps each" in printed and "### Table III — ground / sky" in printed
    ii = json.loads((out / "table-ii" / "results.json").read_text())
    iii = json.loads((out / "table-iii" / "results.json").read_text())
    assert [r["method"] for r in ii["rows"]] == list(LOSS_VARIANTS)
    assert [r["method"] for r in iii["rows"]] == list(FILTER_VARIANTS)
    assert (out / "ablations.md").read_text().count("| Method |") == 2
    assert len((out / "table-ii" / "results.csv").read_text().splitlines()) == 6
    assert ii["training_sequences"] == ["00"]
    # Table II's full model and Table III's last row are one run, scored once
    assert ii["rows"][-1]["EPE3D"] == iii["rows"][-1]["EPE3D"]
    assert ii["variants"][-1]["run"] == iii["variants"][-1]["run"]
    runs = sorted(p for p in (out / "runs").iterdir())
    assert len(runs) == 7  # 5 loss variants + 2 filter variants
    # the switches reached the trainer and stage one
    for v in ii["variants"] + iii["variants"]:
        saved = json.loads((Path(v["run"]) / "config.json").read_text())["config"]["train"]
        for key in ("use_depth", "use_ds", "use_chamfer", "use_laplacian"):
            assert saved["loss"][key] == v["loss"].get(key, True), (v["name"], key)
        assert saved["model"]["level_points"] == [64, 32, 16, 8, 4] and saved["steps"] == 2
        manifest = json.loads((Path(saved["cache"]) / "manifest.json").read_text())["config"]
        for key in ("ground", "far", "lidar", "occlusion"):
            assert manifest["filters"][key] == v["filters"].get(key, True), (v["name"], key)
        assert manifest["sequences"] == ["00"]
        assert torch.load(Path(v["run"]) / "latest.pt", weights_only=True)["step"] == 2
    assert len({v["cache"] for v in iii["variants"]}) == 3
    assert not any(v["reused_checkpoint"] for v in ii["variants"])

    # rerun: caches and runs reused, nothing retrained, the same numbers
    stamps = {p: (p / "latest.pt").stat().st_mtime_ns for p in runs}
    assert main(argv) == 0
    assert "reused" in capsys.readouterr().out
    again = json.loads((out / "table-ii" / "results.json").read_text())
    assert all(v["reused_checkpoint"] for v in again["variants"])
    assert [r["EPE3D"] for r in again["rows"]] == [r["EPE3D"] for r in ii["rows"]]
    assert {p: (p / "latest.pt").stat().st_mtime_ns for p in runs} == stamps
    assert sorted((out / "runs").iterdir()) == runs
