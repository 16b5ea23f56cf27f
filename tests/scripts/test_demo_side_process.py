"""The demo's second evaluation, run beside the first in a child process (scripts/demo.py)."""

from __future__ import annotations

import sys
import time

from scripts.demo import SideProcess


def test_side_evaluation_prints_the_child_s_output_and_passes_on_its_exit_code(tmp_path, capsys):
    missing = tmp_path / "no-split"
    log = tmp_path / "side.log"
    command = [sys.executable, "-m", "evaluation", "run", "--split", str(missing), "--baselines", "zero"]
    with SideProcess(command, log, timeout_s=120) as side:
        rc = side.finish()
    out = capsys.readouterr().out
    assert rc == 2  # monoflow-evaluate's exit code for bad input
    assert out == log.read_text()
    assert out.startswith("error: ") and str(missing) in out and "Traceback" not in out


def test_side_process_is_stopped_when_the_block_is_left_early(tmp_path):
    t = time.monotonic()
    with SideProcess([sys.executable, "-c", "import time; time.sleep(120)"], tmp_path / "side.log") as side:
        pass  # left without finish(): an error or an interrupt in the first split
    assert side.proc.returncode is not None and side.proc.returncode != 0  # killed, not finished
    assert time.monotonic() - t < 60


def test_side_process_past_its_timeout_is_reported_in_one_line(tmp_path, capsys):
    with SideProcess([sys.executable, "-c", "import time; time.sleep(120)"], tmp_path / "side.log",
                     timeout_s=0.5) as side:
        rc = side.finish()
    assert rc == 1
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "side.log" in out and "past" in out
