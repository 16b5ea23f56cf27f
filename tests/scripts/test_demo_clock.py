"""The demo's phase headers (scripts/demo.py: PhaseClock)."""

from __future__ import annotations

import re
import time

from scripts.demo import PhaseClock


def test_each_header_shows_the_seconds_since_its_own_clock_started(capsys):
    first = PhaseClock()
    time.sleep(1.1)
    second = PhaseClock()  # a second demo in the same process starts from zero, not from the first one's start
    first.say("phase a")
    second.say("phase b")
    out = capsys.readouterr().out
    a, b = (int(s) for s in re.findall(r"=== phase [ab]  \[(\d+) s\]", out))
    assert a >= 1 and b < a  # 1.1 s apart: the rounded seconds differ by at least one
    assert first.elapsed() > second.elapsed() > 0
