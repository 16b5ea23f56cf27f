"""What a scene-flow format is to the readers: one :class:`SceneFlowFormat` record per format module.

A format module (``evaluation/readers/<name>.py``) defines its options dataclass, its validation and its
loader and exposes them as one ``FORMAT = SceneFlowFormat(...)``; :mod:`evaluation.readers.registry`
lists the records. Loaders return :class:`~evaluation.sample.SceneFlowSample` in camera axes (x right,
y down, z forward, metres), converting from the format's axes in :data:`core.axes.FORMAT_AXES`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from evaluation.sample import SceneFlowSample
from core.axes import FORMAT_AXES, Axes


@dataclass(frozen=True)
class Entry:
    """One scene of a split: its name, the file or folder holding it, and format-specific keys
    (OpenSceneFlow: the two timestamp groups)."""

    name: str
    path: Path
    extra: tuple[str, ...] = ()


@dataclass(frozen=True)
class SceneFlowFormat:
    """One scene-flow file format: how to recognise, list, validate and read its scenes.

    Attributes:
        name: the format's name (``--format NAME``; its options are the ``--NAME.<option>`` flags).
        summary: one line saying what the files look like (shown in ``--help``).
        options: the dataclass of the reader's options; its field docs become the flags' help.
        candidates: ``root`` → the files or folders that may hold scenes (``[root]`` for a single scene),
            sorted.
        entries: ``(candidate, root)`` → the scenes of that candidate after validating it without reading
            the data; raises ValueError saying what is wrong when it is malformed.
        load: ``(entry, options)`` → the scene in camera axes.
        sniff: a folder → True when it holds this format (cheap checks).
        looks_for: what ``sniff`` looks for, in words (for the "nothing found" error).
        file_suffixes: suffixes of a single-scene file of this format (none: scenes are folders).
        fallback: sniffed only when no other format matched (its check walks the whole tree).
        frame2_holds_frame1: frame 2 is frame 1's own points moved, by the format's construction (it stores no
            flow: the flow is ``pc2 − pc1`` row by row), so the refinement's point pairs suit it
            (``monoflow-evaluate --pairing auto``); False = frame 2 may be another sampling, and
            :mod:`evaluation.pairing` reads from the files which it is.
    """

    name: str
    summary: str
    options: type
    candidates: Callable[[Path], list[Path]]
    entries: Callable[[Path, Path], list[Entry]]
    load: Callable[[Entry, Any], SceneFlowSample]
    sniff: Callable[[Path], bool]
    looks_for: str
    file_suffixes: tuple[str, ...] = ()
    fallback: bool = False
    frame2_holds_frame1: bool = False

    @property
    def axes(self) -> Axes:
        """The axes this format's files store points and flow in (:data:`core.axes.FORMAT_AXES`)."""
        return FORMAT_AXES[self.name]
