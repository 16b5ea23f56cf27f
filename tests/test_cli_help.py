"""One CLI style across the commands: every option of every command has a help text (from the config
dataclasses' field docs where the command is built from them), dashed spellings are aliases of the
underscored ones, ``--n_points`` sets the point count in one flag, and a run folder holding a run is not
overwritten without ``--resume`` / ``--overwrite``."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest


def all_parsers() -> dict[str, argparse.ArgumentParser]:
    from evaluation.cli import build_parser as evaluate
    from evaluation.predict.cli import build_parser as predict
    from pipeline.cli import _run_parser, _top_parser
    from pipeline.synth.cli import build_parser as synth
    from training.cli import build_help_parser, build_parser as train
    from training.depth.cli import build_parser as train_depth

    return {"monoflow-synth": synth(), "monoflow-preprocess": _top_parser(), "monoflow-preprocess run": _run_parser(),
            "monoflow-train": train(), "monoflow-train --help (no torch)": build_help_parser(),
            "monoflow-train-depth": train_depth(), "monoflow-evaluate": evaluate(), "monoflow-predict": predict()}


def undocumented(parser: argparse.ArgumentParser, where: str) -> list[str]:
    missing = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                missing += undocumented(sub, f"{where} {name}")
            continue
        text = (action.help or "").strip()
        if not text or text.startswith("(default"):
            missing.append(f"{where}: {'/'.join(action.option_strings) or action.dest}")
    return missing


def test_every_option_of_every_command_has_help():
    parsers = all_parsers()
    missing = [m for name, p in parsers.items() for m in undocumented(p, name)]
    assert not missing, "options without help:\n" + "\n".join(missing)
    counts = {name: sum(1 for a in p._actions if a.option_strings) for name, p in parsers.items()}
    assert counts["monoflow-train"] > 55 and counts["monoflow-train-depth"] > 55 and counts["monoflow-predict"] > 40


def test_help_texts_come_from_field_docs_with_units():
    from training.cli import build_parser

    text = build_parser().format_help()
    assert "points sampled per cloud per step" in text  # DataConfig's docstring
    assert "(default: 8192)" in text
    assert "metres" in build_parser().format_help() or "degrees" in text


def test_dashed_spellings_are_aliases():
    from evaluation.cli import build_parser as evaluate
    from evaluation.predict.cli import build_parser as predict

    a = evaluate().parse_args(["run", "--split", "x", "--n_points", "512", "--max-scenes", "3"])
    b = evaluate().parse_args(["run", "--split", "x", "--n-points", "512", "--max_scenes", "3"])
    assert a.n_points == b.n_points == 512 and a.max_scenes == b.max_scenes == 3
    p = predict().parse_args(["--max-frames", "7", "--scale.refuse-non-metric", "true"])
    assert getattr(p, "max_frames") == 7 and getattr(p, "scale.refuse_non_metric") is True


def test_one_flag_sets_the_point_count():
    from core.options import build_config
    from training.cli import apply_n_points, build_parser
    from training.config import TrainConfig

    args = build_parser().parse_args(["--n_points", "1024"])
    apply_n_points(args)
    cfg = build_config(TrainConfig, args)
    assert cfg.data.n_points == cfg.model.n_points == 1024 and cfg.model.level_points == (256, 128, 32, 8, 4)
    assert cfg.data.colour_features is False  # the KITTI test splits have no colours


def test_existing_run_folder_is_not_overwritten(tmp_path, capsys):
    from training.cli import main as train_main
    from training.depth.cli import main as depth_main

    run = tmp_path / "run"
    run.mkdir()
    (run / "train.csv").write_text("step,loss\n1,0.5\n")
    assert train_main(["--cache", str(tmp_path / "nocache"), "--run_dir", str(run)]) == 2
    err = capsys.readouterr().err
    assert "already holds a run" in err and "--resume" in err and "--overwrite" in err
    assert depth_main(["--data.root", str(tmp_path), "--run_dir", str(run)]) == 2
    assert "already holds a run" in capsys.readouterr().err
    assert (run / "train.csv").read_text().startswith("step,loss")


def test_python_m_predict_help_runs():
    out = subprocess.run([sys.executable, "-m", "evaluation.predict", "--help"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and "--moving_threshold" in out.stdout and "metres" in out.stdout
