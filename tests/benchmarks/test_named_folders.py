"""The benchmark tools' ``NAME=FOLDER`` / ``KEY=VALUE`` items (benchmarks/named_folders.py): a malformed
item or a missing split is refused with one line naming it, never a traceback."""

from __future__ import annotations

import argparse

import pytest

from benchmarks.named_folders import key_value, named_folder


def test_items_split_at_the_first_equals_sign():
    assert named_folder("own=runs/w0/a=b") == ("own", "runs/w0/a=b")
    assert key_value("model.norm=layer") == ("model.norm", "layer")
    assert key_value("data.ego_speed_scale=0.5,2.0") == ("data.ego_speed_scale", "0.5,2.0")


@pytest.mark.parametrize("text", ["runs/w0", "=runs/w0", "own=", " = "])
def test_a_malformed_split_is_refused(text):
    with pytest.raises(argparse.ArgumentTypeError, match="NAME=FOLDER"):
        named_folder(text)


def test_a_setting_without_a_key_is_refused():
    for text in ("model.norm", "=layer"):
        with pytest.raises(argparse.ArgumentTypeError, match="KEY=VALUE"):
            key_value(text)


@pytest.mark.parametrize("tool", ["learning_curve", "sensor_gap", "vote_accuracy"])
def test_each_tool_refuses_a_malformed_split_with_one_usage_line(tool, capsys):
    import importlib

    main = importlib.import_module(f"benchmarks.{tool}").main
    required = {"learning_curve": ["--cache", "c", "--out", "o"], "sensor_gap": ["--checkpoint", "k", "--cache", "c"],
                "vote_accuracy": []}[tool]
    with pytest.raises(SystemExit) as exc:
        main([*required, "--split", "no-equals-sign"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "NAME=FOLDER" in err[-1] and "no-equals-sign" in err[-1] and "Traceback" not in "\n".join(err)


def test_learning_curve_names_a_missing_split_in_one_line(tmp_path, capsys):
    from benchmarks.learning_curve import main

    code = main(["--cache", str(tmp_path), "--out", str(tmp_path / "o"), "--split", f"x={tmp_path / 'nothing'}"])
    assert code == 2
    out = capsys.readouterr().out.strip()
    assert out.startswith("learning_curve: ") and "nothing" in out and "\n" not in out
    assert not (tmp_path / "o").exists()  # nothing written before the inputs are read
