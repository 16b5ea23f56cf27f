"""The scene-flow formats the readers know, registered once, and format detection from a path.

Adding a format is one module defining ``FORMAT = SceneFlowFormat(...)`` (:mod:`evaluation.readers.base`)
and one line in :data:`_REGISTERED`; :func:`~evaluation.readers.load_split`, the detection below and the
``monoflow-evaluate run --format NAME --NAME.<option>`` flags (:mod:`evaluation.readers.flags`) find it here.
"""

from __future__ import annotations

import os
from pathlib import Path

from evaluation.readers import flownet3d, hplflownet, opensceneflow
from evaluation.readers.base import SceneFlowFormat
from core.errors import InputError

_REGISTERED: tuple[SceneFlowFormat, ...] = (
    flownet3d.FORMAT,
    hplflownet.FORMAT,
    opensceneflow.FORMAT,
)

REGISTRY: dict[str, SceneFlowFormat] = {f.name: f for f in _REGISTERED}
#: names of the registered formats, in registration order
FORMATS: tuple[str, ...] = tuple(REGISTRY)


def get_format(name: str, where: str | os.PathLike[str]) -> SceneFlowFormat:
    """The format called ``name``; an :class:`InputError` naming ``where`` when there is none."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise InputError(where, f"unknown format {name!r}; expected one of {FORMATS} or 'auto'") from None


def _sniff_order() -> list[SceneFlowFormat]:
    """Cheap checks first; a fallback format is looked for only when no other matched."""
    return [f for f in _REGISTERED if not f.fallback] + [f for f in _REGISTERED if f.fallback]


def detect_format(path: str | os.PathLike[str]) -> str:
    """The format of a file or folder: ``"flownet3d"``, ``"hplflownet"``, ``"opensceneflow"``, ...

    A file is recognised by its suffix; a folder by each format's ``sniff``.

    Raises:
        InputError: when nothing recognisable is there or several formats are mixed.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "no such file or folder")
    if p.is_file():
        for fmt in _sniff_order():
            if p.suffix in fmt.file_suffixes:
                return fmt.name
        suffixes = [f.file_suffixes[0] for f in _sniff_order() if f.file_suffixes]
        raise InputError(p, f"not a scene-flow file (expected {', '.join(suffixes)} or a folder)")
    found = [f.name for f in _sniff_order() if not f.fallback and f.sniff(p)]
    if not found:
        found = [f.name for f in _sniff_order() if f.fallback and f.sniff(p)][:1]
    if not found:
        wanted = ", ".join(f"no {f.looks_for}" for f in _sniff_order())
        raise InputError(p, f"no scene-flow data found ({wanted})")
    if len(found) > 1:
        raise InputError(p, f"mixes several formats ({', '.join(found)}); pass fmt= explicitly")
    return found[0]
