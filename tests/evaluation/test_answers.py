"""A stack's rows share one scene's answers (evaluation/answers.py): the inner row runs once per scene, every
row's flow is the one it computes alone, and a wrapper row's time still counts its inner row's seconds."""

from __future__ import annotations

import time

import numpy as np

from evaluation.answers import AnswerBook, ask, ask_marked
from evaluation.protocols import ProtocolConfig, run_protocol
from evaluation.sample import SceneFlowSample
from evaluation.wrapping import MethodWrapper


class Slow:
    """``0.01 · pc1 + 0.1`` after sleeping ``seconds``; counts its calls."""

    def __init__(self, name: str = "base", seconds: float = 0.0) -> None:
        self.name, self.seconds, self.calls = name, seconds, 0

    def __call__(self, pc1, pc2, color1=None, color2=None):
        self.calls += 1
        time.sleep(self.seconds)
        return (0.01 * np.asarray(pc1) + 0.1).astype(np.float32)


class Doubled(MethodWrapper):
    """Its inner row's flow doubled, after sleeping ``seconds``."""

    suffix = "doubled"
    config_type = dict

    def __init__(self, inner, seconds: float = 0.0) -> None:
        super().__init__(inner)
        self.seconds = seconds

    def __call__(self, pc1, pc2, color1=None, color2=None):
        time.sleep(self.seconds)
        return 2 * np.asarray(ask(self.inner, pc1, pc2, color1, color2))


def _split(n: int = 3) -> list[SceneFlowSample]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        pc1 = rng.uniform(-10, 10, size=(200, 3)).astype(np.float32)
        out.append(SceneFlowSample(f"s{i}", pc1, pc1 + 0.2, np.full_like(pc1, 0.2)))
    return out


def test_a_stack_runs_its_inner_row_once_per_scene_with_the_flow_and_seconds_of_a_run_from_scratch():
    cfg = ProtocolConfig(protocol="fps", n_points=128, n_score=64, warmup=False)
    base = Slow(seconds=0.02)
    once = Doubled(base, seconds=0.01)
    twice = Doubled(once, seconds=0.01)
    results = run_protocol(_split(), [base, once, twice], cfg, progress=False)
    assert base.calls == 3  # one call per scene, not one per row that wraps it
    alone_base = Slow()
    alone = run_protocol(_split(), [Doubled(Doubled(alone_base))], cfg, progress=False)[0]
    assert alone_base.calls == 3
    assert alone.metrics == results[2].metrics  # the same flow as the row run alone
    # each row's time is at least the sleeps of everything it runs from scratch (sleep never returns early)
    for res, least in zip(results, (0.02, 0.03, 0.04)):
        assert res.seconds_per_scene >= least, (res.name, res.seconds_per_scene)


def test_only_the_book_s_own_clouds_are_answered():
    pc1, pc2 = np.zeros((5, 3), np.float32), np.ones((5, 3), np.float32)
    base = Slow()
    with AnswerBook(pc1, pc2) as book:
        first, _ = book.timed(ask, base, pc1, pc2)
        again = ask(base, pc1, pc2)
        assert base.calls == 1 and np.array_equal(first, again)
        again[:] = 7  # a caller's change does not reach the kept answer
        assert np.array_equal(ask(base, pc1, pc2), first)
        ask(base, pc1.copy(), pc2)  # equal values, other arrays (e.g. the view pruning's second pass): a new run
        assert base.calls == 2
    ask(base, pc1, pc2)  # no book open: a plain call
    assert base.calls == 3


def test_an_answer_s_seconds_reach_every_enclosing_call():
    pc1, pc2 = np.zeros((5, 3), np.float32), np.ones((5, 3), np.float32)
    base = Slow(seconds=0.03)
    with AnswerBook(pc1, pc2) as book:
        _, first = book.timed(ask, base, pc1, pc2)
        _, outer = book.timed(ask, Doubled(Doubled(base)), pc1, pc2)
    assert first >= 0.03 and outer >= first  # the outer call's wall time alone is near zero


class Marking(Slow):
    """``Slow`` that also marks the points with positive x (its class defines ``marked``)."""

    def marked(self, pc1, pc2, color1=None, color2=None):
        return self(pc1, pc2, color1, color2), {"right": np.asarray(pc1)[:, 0] > 0}


def test_marks_are_kept_with_the_flow_and_only_a_class_s_own_count():
    rng = np.random.default_rng(1)
    pc1, pc2 = rng.normal(size=(6, 3)).astype(np.float32), rng.normal(size=(6, 3)).astype(np.float32)
    base = Marking()
    flow, marks = ask_marked(base, pc1, pc2)  # no book: computed
    assert base.calls == 1 and np.array_equal(marks["right"], pc1[:, 0] > 0)
    with AnswerBook(pc1, pc2):
        first = ask(base, pc1, pc2)
        again, kept = ask_marked(base, pc1, pc2)  # from the book, marks included
        assert base.calls == 2 and np.array_equal(first, again) and np.array_equal(kept["right"], marks["right"])
        kept["right"][:] = False  # a caller's change does not reach the kept marks
        assert np.array_equal(ask_marked(base, pc1, pc2)[1]["right"], pc1[:, 0] > 0)
        # a wrapper forwards attributes of the method it wraps, but its flow is its own, so are its (no) marks
        wrapped = Doubled(base)
        assert callable(wrapped.marked)
        doubled, none = ask_marked(wrapped, pc1, pc2)
        assert none == {} and np.allclose(doubled, 2 * first)
    assert np.array_equal(flow, first)
