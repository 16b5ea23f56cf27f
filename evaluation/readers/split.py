"""A scene-flow test split: every entry validated up front, each scene read lazily on access.

:func:`load_split` detects or takes the format (:mod:`evaluation.readers.registry`), lets the format list
and validate its entries, raises one :class:`~core.errors.InputError` listing every malformed file,
and returns a :class:`SceneFlowSplit` sorted by scene name.
"""

from __future__ import annotations

import functools
import os
import zipfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

from evaluation.readers.base import Entry
from evaluation.readers.registry import REGISTRY, detect_format, get_format
from evaluation.sample import SceneFlowSample
from core.errors import InputError


@dataclass
class SceneFlowSplit(Sequence[SceneFlowSample]):
    """A validated, lazily read test split: ``split[i]`` reads scene i (sorted by name) from disk."""

    root: Path
    fmt: str
    entries: list[Entry]
    loader: Callable[[Entry], SceneFlowSample] = field(repr=False)

    @property
    def names(self) -> list[str]:
        """Scene names, sorted."""
        return [e.name for e in self.entries]

    def __len__(self) -> int:
        return len(self.entries)

    @overload
    def __getitem__(self, index: int) -> SceneFlowSample: ...

    @overload
    def __getitem__(self, index: slice) -> list[SceneFlowSample]: ...

    def __getitem__(self, index: int | slice) -> SceneFlowSample | list[SceneFlowSample]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        entry = self.entries[index]
        try:
            return self.loader(entry)
        except InputError:
            raise
        except (ValueError, OSError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            where = entry.path if not entry.extra else f"{entry.path}:{entry.extra[0]}"
            raise InputError(where, f"cannot read scene {entry.name!r}: {exc}") from None

    def __iter__(self) -> Iterator[SceneFlowSample]:
        for i in range(len(self)):
            yield self[i]


def _check_options(options: dict[str, Any]) -> None:
    for name, value in options.items():
        if value is None:
            continue
        if name not in REGISTRY:
            raise TypeError(f"load_split() got options for unknown format {name!r}; formats: {tuple(REGISTRY)}")
        cls = REGISTRY[name].options
        if not isinstance(value, cls):
            raise TypeError(f"load_split({name}=...) takes a {cls.__name__}, got {type(value).__name__}")


def load_split(path: str | os.PathLike[str], fmt: str = "auto", *, names: Sequence[str] | None = None,
               **options: Any) -> SceneFlowSplit:
    """Open a scene-flow test split (a folder, or a single scene file/folder).

    Args:
        path: folder of ``*.npz`` (FlowNet3D), folder of scene folders (HPLFlowNet), folder of ``*.h5``
            (OpenSceneFlow), or one such scene.
        fmt: ``"auto"`` or a registered format name (:data:`evaluation.readers.registry.FORMATS`).
        names: keep only these scene names (e.g. HPLFlowNet's 142 mapped KITTI scenes); an unknown
            name is an error.
        **options: per-format options keyed by format name, e.g. ``flownet3d=FlowNet3DOptions(...)``,
            ``hplflownet=HPLFlowNetOptions(...)``; the read format's are used (defaults as documented
            there), the others ignored.

    Returns:
        A :class:`SceneFlowSplit`, sorted by scene name, reading each sample on access.

    Raises:
        InputError: when the path holds nothing readable, or one or more entries are malformed (one
            error naming every bad file and its problem).
    """
    _check_options(options)
    root = Path(path)
    fmt = detect_format(root) if fmt == "auto" else get_format(fmt, root).name
    if not root.exists():
        raise InputError(root, "no such file or folder")
    spec = REGISTRY[fmt]
    entries: list[Entry] = []
    bad: list[tuple[Path, str]] = []
    for candidate in spec.candidates(root):
        try:
            entries.extend(spec.entries(candidate, root))
        except ValueError as exc:
            bad.append((candidate, str(exc)))
    if bad:
        listing = "; ".join(f"{p}: {problem}" for p, problem in bad)
        raise InputError(root, f"{len(bad)} malformed {fmt} entr{'y' if len(bad) == 1 else 'ies'}: {listing}")
    if not entries:
        raise InputError(root, f"no {fmt} scenes found")
    entries.sort(key=lambda e: e.name)
    if names is not None:
        wanted = set(names)
        unknown = sorted(wanted - {e.name for e in entries})
        if unknown:
            raise InputError(root, f"unknown scene names {unknown[:10]}")
        entries = [e for e in entries if e.name in wanted]
    opts = options.get(fmt) or spec.options()
    return SceneFlowSplit(root=root, fmt=fmt, entries=entries, loader=functools.partial(spec.load, opts=opts))
