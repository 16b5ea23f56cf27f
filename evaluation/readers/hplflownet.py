"""HPLFlowNet's ``KITTI_processed_occ_final`` (also the synthetic world's ``sceneflow/hplflownet``).

One folder per scene with ``pc1.npy`` and ``pc2.npy`` (N, 3) of corresponding points in stored axes
``(−x, −y, z)`` of the camera (:data:`core.axes.HPLFLOWNET`); flow = ``pc2 − pc1``; optional
``moving.npy``, ``classes.npy``, ``instance.npy`` (N,). Filtering follows HPLFlowNet's own loader
(``datasets/kitti.py`` + ``transforms.ProcessData.process_inference``), applied to the stored axes: ground
is ``y_s < −1.4`` and a pair is dropped **only when both** its pc1 and pc2 points are ground
(``is_ground = (pc1.y < −1.4) & (pc2.y < −1.4)``) — ``ground_rule="either"`` drops a pair when either
point is ground instead; then pairs are kept where ``z_s < 35`` in **both** pc1 and pc2.

HPLFlowNet additionally keeps only the 142 of 200 scenes that have a KITTI-raw mapping (its
``KITTI_mapping.txt``, the devkit's ``train_mapping.txt``); ``monoflow-evaluate run --protocol hplflownet
--mapping FILE`` applies it (:func:`evaluation.scenes.mapped_scenes`), or pass the kept names as
``names=`` to :func:`evaluation.readers.load_split`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from evaluation.readers.arrays import LABELS, Spec, check_labels, check_mask, check_points, npy_header, raise_problems
from evaluation.readers.base import Entry, SceneFlowFormat
from evaluation.sample import SceneFlowSample
from core.axes import FORMAT_AXES
from pipeline.filters import FAR_LIMIT_M

NAME = "hplflownet"
_AXES = FORMAT_AXES[NAME]


@dataclass
class HPLFlowNetOptions:
    """Options of the HPLFlowNet ``KITTI_processed_occ_final`` reader (HPLFlowNet's defaults).

    Attributes:
        remove_ground: drop ground pairs (stored ``y < −ground_height``).
        ground_height: metres below the camera (stored y is up).
        ground_rule: ``both`` (HPLFlowNet: drop a pair when its pc1 and pc2 points are both ground) or
            ``either`` (drop when either is ground).
        max_depth: keep pairs with stored z < max_depth (metres) in both clouds (HPLFlowNet's
            ``DEPTH_THRESHOLD`` = 35); none keeps everything.
    """

    remove_ground: bool = True
    ground_height: float = 1.4
    ground_rule: Literal["both", "either"] = "both"
    max_depth: float | None = FAR_LIMIT_M

    def __post_init__(self) -> None:
        if self.ground_rule not in ("both", "either"):
            raise ValueError(f"ground_rule must be 'both' or 'either', got {self.ground_rule!r}")


def _scene_dirs(root: Path) -> list[Path]:
    """Leaf folders holding ``.npy`` files (HPLFlowNet takes every leaf folder of its root)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        if not dirnames and any(f.endswith(".npy") for f in filenames):
            out.append(Path(dirpath))
        elif "pc1.npy" in filenames or "pc2.npy" in filenames:
            out.append(Path(dirpath))
    return out


def _candidates(root: Path) -> list[Path]:
    is_scene = (root / "pc1.npy").exists() or (root / "pc2.npy").exists()
    return sorted([root] if is_scene else _scene_dirs(root))


def _entries(folder: Path, root: Path) -> list[Entry]:
    """Validate one scene folder from its headers; one entry named by its path under ``root``."""
    problems: list[str | None] = []
    specs: dict[str, Spec] = {}
    for fname in ("pc1.npy", "pc2.npy", "moving.npy", "classes.npy", "instance.npy"):
        fpath = folder / fname
        if not fpath.is_file():
            if fname in ("pc1.npy", "pc2.npy"):
                problems.append(f"missing {fname}")
            continue
        try:
            specs[fname] = npy_header(fpath)
        except (OSError, ValueError, EOFError) as exc:
            problems.append(f"{fname} is not a readable .npy ({exc})")
    if "pc1.npy" in specs:
        shape1 = specs["pc1.npy"][0]
        problems.append(check_points("pc1.npy", *specs["pc1.npy"]))
        n = shape1[0] if shape1 else -1
        if "pc2.npy" in specs:
            problems.append(check_points("pc2.npy", *specs["pc2.npy"], rows=n))
        if "moving.npy" in specs:
            problems.append(check_mask("moving.npy", *specs["moving.npy"], rows=n))
        for key in LABELS:
            if f"{key}.npy" in specs:
                problems.append(check_labels(f"{key}.npy", *specs[f"{key}.npy"], rows=n))
    raise_problems(problems)
    return [Entry(folder.name if folder == root else folder.relative_to(root).as_posix(), folder)]


def kept_pairs(pc1: np.ndarray, pc2: np.ndarray, opts: HPLFlowNetOptions) -> np.ndarray:
    """(N,) bool: the point pairs (``pc1``, ``pc2``: (N, 3) in the stored axes) that the reader keeps under
    ``opts`` — HPLFlowNet's ground rule, then its depth limit (module docstring)."""
    keep = np.ones(len(pc1), dtype=bool)
    if opts.remove_ground:
        g1 = pc1[:, 1] < -opts.ground_height
        g2 = pc2[:, 1] < -opts.ground_height
        keep &= ~((g1 & g2) if opts.ground_rule == "both" else (g1 | g2))
    if opts.max_depth is not None:
        keep &= (pc1[:, 2] < opts.max_depth) & (pc2[:, 2] < opts.max_depth)
    return keep


def _load(entry: Entry, opts: HPLFlowNetOptions) -> SceneFlowSample:
    pc1 = np.load(entry.path / "pc1.npy").astype(np.float32)
    pc2 = np.load(entry.path / "pc2.npy").astype(np.float32)
    optional = {}
    for key in ("moving", *LABELS):
        path = entry.path / f"{key}.npy"
        optional[key] = np.load(path) if path.is_file() else None
    keep = kept_pairs(pc1, pc2, opts)
    pc1, pc2 = pc1[keep], pc2[keep]
    flow = pc2 - pc1
    moving, classes, instance = (None if optional[k] is None else optional[k][keep] for k in ("moving", *LABELS))
    return SceneFlowSample(
        entry.name, _AXES.to_camera(pc1), _AXES.to_camera(pc2), _AXES.to_camera(flow), moving=moving,
        classes=classes, instance=instance,
    )


FORMAT = SceneFlowFormat(
    name=NAME,
    summary="HPLFlowNet KITTI_processed_occ_final: one folder per scene (pc1.npy, pc2.npy; (−x, −y, z) axes)",
    options=HPLFlowNetOptions,
    candidates=_candidates,
    entries=_entries,
    load=_load,
    sniff=lambda folder: bool(_scene_dirs(folder)),
    looks_for="folders with pc1.npy/pc2.npy",
    fallback=True,
    frame2_holds_frame1=True,
)
