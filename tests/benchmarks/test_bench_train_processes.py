"""benchmarks/bench_train_processes.py: both settings train and the table has a round's row."""

from __future__ import annotations

import pytest

from _trainer_fixtures import tiny_cache  # noqa: F401


@pytest.mark.slow
def test_one_round_prints_both_settings_and_their_ratio(tiny_cache, tmp_path, capsys):  # noqa: F811
    from benchmarks.bench_train_processes import main

    assert main(["--cache", str(tiny_cache), "--short", "1", "--long", "3", "--workdir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    row = [line for line in out.splitlines() if line.startswith("| 1 |")]
    assert len(row) == 1
    cells = [c.strip() for c in row[0].strip("|").split("|")]
    one, two, ratio = (float(c) for c in cells[1:])  # (noise can make a 2-step difference anything)
    assert ratio == pytest.approx(one / two, rel=0.01, abs=0.01)
    assert (tmp_path / "procs-2" / "latest.pt").exists() and (tmp_path / "procs-1" / "latest.pt").exists()
