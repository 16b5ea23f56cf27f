"""benchmarks/bench_train.py's configuration: ``--model`` overrides replace a size's defaults."""

from __future__ import annotations

from argparse import Namespace

from benchmarks.bench_train import SIZES, _config


def _args(model: list[str]) -> Namespace:
    return Namespace(steps=2, device="cpu", threads=1, amp=False, workers=0, model=model)


def test_demo_size_scales_its_levels_from_its_points(tmp_path):
    cfg = _config(tmp_path / "cache", tmp_path / "run", "demo", _args([]))
    assert cfg.model.n_points == SIZES["demo"]["n_points"] == 2048
    assert cfg.model.level_points == (512, 256, 64, 16, 4)


def test_model_overrides_replace_the_sizes_levels_and_width(tmp_path):
    cfg = _config(tmp_path / "cache", tmp_path / "run", "demo",
                  _args(["level_points=1024,512,128,32,8", "width_scale=0.25", "ego_head=true"]))
    assert tuple(cfg.model.level_points) == (1024, 512, 128, 32, 8)
    assert cfg.model.width_scale == 0.25
    assert cfg.model.ego_head is True
