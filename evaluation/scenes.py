"""Which scenes of a split are scored: HPLFlowNet's raw-data mapping, ``--scenes`` selections (KITTI_t),
and the guard that refuses to score scenes a checkpoint trained on.

* :func:`mapped_scenes` — HPLFlowNet (``datasets/kitti.py``, ``make_dataset``) keeps a KITTI scene-flow
  training scene only when its line of the devkit's ``train_mapping.txt`` is non-empty (scene ``i`` ↔
  line ``i``, 0-based; 142 of 200 lines are non-empty).
* :func:`select_scenes` — ``all``, ``first:N``, ``last:N`` over the sorted scene names, and ``kitti_t``:
  the last 50 of the 150 KITTI_o scenes (FlowNet3D's ``kitti_rm_ground``), the test set of SCOOP,
  RigidFlow, Self-Point-Flow and the label-free optimisation methods, whose first 100 (``first:100``)
  serve for label-free fine-tuning.
* :func:`trained_scenes` / :func:`check_not_trained_on` — the scenes a checkpoint's run records having
  trained on: a ``train_scenes`` list in the checkpoint's config (top level or under ``data``), a
  ``train_scenes.txt`` (one name per line) or ``train_scenes.json`` (a list) beside the checkpoint, and,
  for the synthetic world, its test sequence when the run's stage-one cache was built on that sequence
  of the same world.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from core.errors import ConfigError, InputError

KITTI_O_SCENES = 150
KITTI_T_SCENES = 50


def read_mapping(path: str | Path) -> list[str]:
    """The lines of a KITTI devkit ``train_mapping.txt``, stripped (an empty string: no raw recording).

    Raises:
        InputError: when the file is missing, unreadable or has no non-empty line.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "mapping file not found (the KITTI devkit's train_mapping.txt)")
    try:
        lines = [line.strip() for line in p.read_text(encoding="utf-8").splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read the mapping file ({exc})") from None
    if not any(lines):
        raise InputError(p, "the mapping file has no non-empty line")
    return lines


def scene_index(name: str) -> int | None:
    """The KITTI scene number of a scene name (its last path component, e.g. ``000012`` → 12), or None."""
    last = name.replace("\\", "/").rstrip("/").split("/")[-1]
    stem = last.split(".")[0]
    return int(stem) if stem.isdigit() else None


def mapped_scenes(names: Sequence[str], mapping: str | Path) -> tuple[list[str], list[str]]:
    """Split ``names`` into (kept, dropped) by HPLFlowNet's rule: a scene is kept when line
    ``scene_index(name)`` of ``mapping`` is non-empty.

    Raises:
        InputError: naming the mapping file, when a scene name is not a number or lies past its end.
    """
    lines = read_mapping(mapping)
    kept, dropped, bad = [], [], []
    for name in names:
        i = scene_index(name)
        if i is None or i >= len(lines):
            bad.append(name)
        elif lines[i]:
            kept.append(name)
        else:
            dropped.append(name)
    if bad:
        raise InputError(Path(mapping), f"{len(bad)} scene name(s) are not scene numbers of its {len(lines)} "
                                        f"lines: {bad[:5]}")
    return kept, dropped


_SPEC = re.compile(r"^(first|last):(\d+)$")


def select_scenes(names: Sequence[str], spec: str) -> list[str]:
    """The scenes of ``names`` (sorted, as a split lists them) that ``spec`` selects.

    spec: ``all``; ``first:N`` / ``last:N`` (N ≥ 1, at most ``len(names)``); ``kitti_t`` (the last 50 of
    exactly 150 scenes).

    Raises:
        ConfigError: on an unknown spec, a count beyond the split, or ``kitti_t`` on a split that is not
            the 150 KITTI_o scenes.
    """
    spec = spec.strip()
    names = list(names)
    if spec in ("", "all"):
        return names
    if spec == "kitti_t":
        if len(names) != KITTI_O_SCENES:
            raise ConfigError(f"--scenes kitti_t is the last {KITTI_T_SCENES} of KITTI_o's {KITTI_O_SCENES} scenes; "
                              f"this split has {len(names)} (use last:N)")
        return names[-KITTI_T_SCENES:]
    m = _SPEC.match(spec)
    if not m:
        raise ConfigError(f"--scenes must be all, first:N, last:N or kitti_t, got {spec!r}")
    n = int(m.group(2))
    if not 1 <= n <= len(names):
        raise ConfigError(f"--scenes {spec}: the split has {len(names)} scenes")
    return names[:n] if m.group(1) == "first" else names[-n:]


def _listed(value: Any, where: Path) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise InputError(where, "train_scenes must be a list of scene names")
    return value


def trained_scenes(checkpoint: str | Path, config: dict[str, Any] | None = None) -> tuple[set[str], str | None]:
    """Scene names the checkpoint's run records having trained on, and where that record is (None: none).

    Looks at ``config["train_scenes"]`` / ``config["data"]["train_scenes"]``, then ``train_scenes.txt`` and
    ``train_scenes.json`` beside the checkpoint.
    """
    path = Path(checkpoint)
    config = config or {}
    for holder, where in ((config, "config.train_scenes"), (config.get("data") or {}, "config.data.train_scenes")):
        if isinstance(holder, dict) and "train_scenes" in holder:
            return set(_listed(holder["train_scenes"], path)), f"{path} ({where})"
    txt, js = path.parent / "train_scenes.txt", path.parent / "train_scenes.json"
    if txt.is_file():
        return {line.strip() for line in txt.read_text(encoding="utf-8").splitlines() if line.strip()}, str(txt)
    if js.is_file():
        try:
            value = json.loads(js.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise InputError(js, f"not valid JSON ({exc})") from None
        return set(_listed(value, js)), str(js)
    return set(), None


def synthetic_overlap(split_root: str | Path, config: dict[str, Any] | None) -> str | None:
    """A reason to refuse, when ``split_root`` is a synthetic world's test split (``<world>/sceneflow/…``)
    and the run's stage-one cache (``config["cache"]``) was built on that world's test sequence; else None."""
    root = Path(split_root).resolve()
    world = next((p.parent for p in (root, *root.parents) if p.name == "sceneflow"), None)
    cache = (config or {}).get("cache")
    if world is None or not cache or not (world / "synth.json").is_file():
        return None
    header = Path(cache) / "cache.json"
    if not header.is_file():
        return None
    try:
        test_seq = json.loads((world / "synth.json").read_text()).get("test_sequence")
        source = json.loads(header.read_text()).get("source") or {}
    except (OSError, json.JSONDecodeError):
        return None
    if not test_seq or Path(str(source.get("root", ""))).resolve() != world.resolve():
        return None
    if test_seq in (source.get("sequences") or {}):
        return f"its cache {cache} holds sequence {test_seq} of {world}, the sequence this test split comes from"
    return None


def check_not_trained_on(checkpoint: str | Path, config: dict[str, Any] | None, split_root: str | Path,
                         names: Sequence[str]) -> None:
    """Refuse (ConfigError) to score scenes the checkpoint's run records having trained on."""
    seen, where = trained_scenes(checkpoint, config)
    overlap = sorted(seen & set(names))
    if overlap:
        raise ConfigError(f"{checkpoint} trained on {len(overlap)} of the scenes to evaluate ({overlap[:5]}, "
                          f"recorded in {where}); choose disjoint scenes, e.g. --scenes last:N")
    reason = synthetic_overlap(split_root, config)
    if reason:
        raise ConfigError(f"{checkpoint} trained on the scenes to evaluate: {reason}")
