"""One scene's answers, shared by the rows of a stack, so that a stack costs one run of each of its parts.

The evaluation's stacked rows wrap the row before them: ``<net>``, ``<net> + view pruning``, ``… + rigid
polish``, ``… + refinement`` (``monoflow-evaluate run --view-prune --rigid-polish --refine``). Each wrapper
first asks its inner row for the flow of the scene's clouds, which the protocol has just run as its own
row. Inside a scene's :class:`AnswerBook` that question is answered from the book: the inner row's flow as it
computed it, and the seconds it took are added to the asking row's time. So each row's time per scene stays
the time of running it from scratch (its parts measured once each, in the same scene), and every row's flow
is the one it would compute alone (the methods are deterministic: the same clouds give the same flow).

Only calls with the very arrays the book was opened on (the scene's own sampled clouds, read-only) are
answered; a call on other clouds (the view pruning's second pass, on the points that stay in view) runs the
method. Wrappers ask through :func:`ask`, which is a plain call when no book is open.

A method may also mark points of frame 1 as it computes its flow: its class defines
``marked(pc1, pc2, color1, color2) -> (flow, marks)``, ``marks`` a dict of (N,) arrays (the rigid polish's
``"static"``: the points its step 4 gave the registered camera motion). The book keeps the marks with the flow,
and :func:`ask_marked` returns both, so a row stacked on such a method reads its marks whichever pass computed
them. Only the class's own ``marked`` counts, not one a wrapper forwards from the method it wraps: a wrapper's
flow is not its inner method's, so neither are the marks.
"""

from __future__ import annotations

import time
from contextvars import ContextVar
from typing import Any

import numpy as np

Marks = dict[str, np.ndarray]  # per-point marks of frame 1 that a method gives with its flow (module docstring)

_OPEN: ContextVar["AnswerBook | None"] = ContextVar("answer_book", default=None)


class AnswerBook:
    """The flows computed on one scene's clouds ``(pc1, pc2, color1, color2)`` (the arrays themselves, by
    identity), each with its marks and the seconds its method took; ``with`` opens it for :func:`ask`.

    :meth:`timed` runs a top-level call and returns its seconds: the wall time plus the seconds of every
    answer it was given from the book (the time those answers took when they were computed)."""

    def __init__(self, pc1: np.ndarray, pc2: np.ndarray, color1: np.ndarray | None = None,
                 color2: np.ndarray | None = None) -> None:
        self.clouds = (pc1, pc2, color1, color2)
        self._answers: dict[int, tuple[Any, np.ndarray, Marks, float]] = {}  # id(method) -> (method, flow, marks, s)
        self._credit = [0.0]  # per open call: seconds of the answers it was given, not in its wall time

    def __enter__(self) -> "AnswerBook":
        self._token = _OPEN.set(self)
        return self

    def __exit__(self, *exc) -> None:
        _OPEN.reset(self._token)

    def holds(self, pc1, pc2, color1, color2) -> bool:
        """Whether these are the book's own clouds (the same array objects)."""
        return all(a is b for a, b in zip((pc1, pc2, color1, color2), self.clouds))

    def timed(self, call, *args, **kwargs) -> tuple[Any, float]:
        """``call(*args, **kwargs)`` and its seconds: wall time + the seconds of the answers given inside it."""
        self._credit.append(0.0)
        t0 = time.perf_counter()
        try:
            out = call(*args, **kwargs)
        finally:
            wall = time.perf_counter() - t0
            credit = self._credit.pop()
            self._credit[-1] += credit  # an enclosing call was given them too
        return out, wall + credit

    def answer(self, method, pc1, pc2, color1, color2, **kwargs) -> tuple[np.ndarray, Marks]:
        """``method``'s flow and marks on the book's clouds: from the book when it has them (their seconds
        credited to the calls open now), else computed, timed and kept. Copies: a caller's change stays its own."""
        kept = self._answers.get(id(method))
        if kept is None or kept[0] is not method:
            (flow, marks), seconds = self.timed(_run, method, pc1, pc2, color1, color2, **kwargs)
            kept = (method, flow, marks, seconds)
            self._answers[id(method)] = kept
        else:
            self._credit[-1] += kept[3]
        return kept[1].copy(), {k: v.copy() for k, v in kept[2].items()}


def _run(method, pc1, pc2, color1, color2, **kwargs) -> tuple[np.ndarray, Marks]:
    """``method``'s flow (float32) and marks, by its class's own ``marked`` when it has one (no marks otherwise)."""
    marked = getattr(type(method), "marked", None)
    if callable(marked):
        flow, marks = marked(method, pc1, pc2, color1, color2, **kwargs)
        marks = {k: np.asarray(v).copy() for k, v in marks.items()}
    else:
        flow, marks = method(pc1, pc2, color1, color2, **kwargs), {}
    return np.asarray(flow, dtype=np.float32), marks


def ask(method, pc1, pc2, color1=None, color2=None, **kwargs) -> np.ndarray:
    """``method(pc1, pc2, color1, color2, **kwargs)``, answered from the open :class:`AnswerBook` when these are
    its clouds (see the module docstring); a plain call otherwise."""
    book = _OPEN.get()
    if book is None or not book.holds(pc1, pc2, color1, color2):
        return method(pc1, pc2, color1, color2, **kwargs)
    return book.answer(method, pc1, pc2, color1, color2, **kwargs)[0]


def ask_marked(method, pc1, pc2, color1=None, color2=None, **kwargs) -> tuple[np.ndarray, Marks]:
    """``method``'s flow (float32) and the marks it gives with it (empty for a method without ``marked``),
    answered from the open :class:`AnswerBook` when these are its clouds; computed otherwise."""
    book = _OPEN.get()
    if book is None or not book.holds(pc1, pc2, color1, color2):
        return _run(method, pc1, pc2, color1, color2, **kwargs)
    return book.answer(method, pc1, pc2, color1, color2, **kwargs)
