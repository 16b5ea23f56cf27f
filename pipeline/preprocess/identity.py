"""What names a cache: the content-determining part of the config (its hash is the cache folder's name),
the dataset's folder name, and the ``source`` record of where the inputs came from.

The inputs of :func:`cache_config` decide whether an existing cache is recognised as the same one (resume,
``merge``): change them only together with a cache format version.
"""

from __future__ import annotations

import dataclasses
import hashlib
import re
from pathlib import Path
from typing import Any

from pipeline.preprocess.config import PreprocessConfig

# Options that change how, where or how fast the cache is written, or where inputs live, not what it holds.
_NOT_CONTENT = ("root", "dataset", "device", "batch_size", "workers", "shard", "out", "progress", "disparity_dir",
                "strict_pose_count")
#: Scale options that decide whether a run stops or warns, not what a finished block holds.
_SCALE_NOT_CONTENT = ("fallback", "refuse_non_metric")
_NET_ONLY = ("resnet_layers", "random_init", "seed", "amp")
_DISPARITY_ONLY = ("disparity_focal", "disparity_baseline")


def _sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def cache_config(config: PreprocessConfig, sequences: list[str]) -> dict[str, Any]:
    """The part of the config that determines the cache's content; it names the cache (config hash).

    Paths are left out (checkpoints enter by their sha256), and so are options the chosen sources ignore,
    so the same inputs give the same cache name on any machine.
    """
    d = dataclasses.asdict(config)
    for key in _NOT_CONTENT:
        d.pop(key)
    for key in _SCALE_NOT_CONTENT:
        d["scale"].pop(key, None)
    d["sequences"] = list(sequences)
    d["stage"] = "preprocess"
    for kind in ("depth", "pose"):
        path = d.pop(f"{kind}_checkpoint")
        d[f"{kind}_checkpoint_sha256"] = _sha256(path) if path and getattr(config, kind) == "net" else None
    if "net" not in (config.depth, config.pose):
        for key in _NET_ONLY:
            d.pop(key)
    if config.depth != "disparity":
        for key in _DISPARITY_ONLY:
            d.pop(key)
    return d


def dataset_name(config: PreprocessConfig) -> str:
    """The dataset's folder name in the cache: ``config.dataset``, else the root folder's name (made safe)."""
    name = config.dataset or Path(config.root).resolve().name or "dataset"
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name).lstrip(".") or "dataset"


def _world_identity(root: Path) -> bytes:
    """What names a synthetic world at ``root`` (:func:`pipeline.synth.generator.world_identity`: generator version
    and config from its ``synth.json``); the file's bytes where that is unreadable, ``b"-"`` for a dataset without
    one (KITTI)."""
    from pipeline.cache.layout import canonical_json
    from pipeline.synth.generator import world_identity

    ident = world_identity(root)
    if ident is not None:
        return canonical_json(ident).encode()
    path = root / "synth.json"
    return path.read_bytes() if path.is_file() else b"-"


def input_fingerprint(sequence) -> str:
    """A short digest of what one sequence's inputs are (an :class:`~pipeline.kitti.odometry.OdometrySequence`): the
    bytes of its calibration, poses and timestamps, and for a synthetic world the world's identity (its generator
    version and config). It changes when the dataset at the same path is replaced by another (a world drawn again with
    another seed or by another generator version, another recording), so a cache written from the former is not
    resumed from the latter (:class:`pipeline.cache.writer.CacheWriter`); the frames themselves are not read, so a
    repaired frame file (a truncated PNG written again) does not stop a resume."""
    h = hashlib.sha256()
    for path in (sequence.calib_path, sequence.poses_path, sequence.times_path):
        h.update(path.name.encode())
        h.update(path.read_bytes() if path.is_file() else b"-")
    h.update(_world_identity(sequence.root))
    return h.hexdigest()[:16]


def cache_source(config: PreprocessConfig, sequences: dict) -> dict[str, Any]:
    """The manifest's ``source`` record: where the inputs came from (not part of the cache's name), and what they held
    (``inputs``: :func:`input_fingerprint` per sequence).

    ``sequences``: {sequence id: OdometrySequence} as opened by :func:`pipeline.preprocess.sequences.open_sequences`.
    """
    return {
        "inputs": {n: input_fingerprint(s) for n, s in sequences.items()},
        "dataset": dataset_name(config),
        "root": str(Path(config.root).resolve()),
        "camera": config.camera,
        "sequences": {n: {"frames": [s.frames[0], s.frames[-1]], "num_frames": len(s)} for n, s in sequences.items()},
        "depth": config.depth,
        "pose": config.pose,
        "depth_checkpoint": config.depth_checkpoint if config.depth == "net" else None,
        "pose_checkpoint": config.pose_checkpoint if config.pose == "net" else None,
        "disparity_dir": config.disparity_dir if config.depth == "disparity" else None,
    }


__all__ = ["cache_config", "cache_source", "dataset_name", "input_fingerprint"]
