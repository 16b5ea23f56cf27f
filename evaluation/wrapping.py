"""The common part of the methods that wrap another method (view pruning, rigid polish): the wrapped method,
the wrapper's config, the row name ``"<method name> + <suffix>"`` and every other attribute (``n_points``,
``n_score``, ``uses_colour``, …) read from the wrapped method."""

from __future__ import annotations

from typing import Any


class MethodWrapper:
    """Base of a wrapper row: subclasses set :attr:`suffix` and :attr:`config_type` and define ``__call__``."""

    suffix = ""
    config_type: Any = None

    def __init__(self, inner, config: Any = None) -> None:
        self.inner = inner
        self.config = config if config is not None else self.config_type()
        self.name = f"{inner.name} + {self.suffix}"

    def __getattr__(self, key):  # n_points, n_score, uses_colour, … of the wrapped method
        if key == "inner":
            raise AttributeError(key)
        return getattr(self.inner, key)
