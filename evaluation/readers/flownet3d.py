"""FlowNet3D's ``kitti_rm_ground`` (also the synthetic world's ``sceneflow/flownet3d``).

One ``*.npz`` per scene with ``pos1`` (N, 3), ``pos2`` (M, 3), ``gt`` (N, 3) in LiDAR-like axes
(:data:`core.axes.LIDAR`: x forward, y left, z up; camera = ``(−y, −z, x)``). Optional arrays read
when present: ``moving`` (N,) (our synthetic generator writes it), ``classes`` / ``instance`` (N,)
integers (class 0 = background; our generator writes them), ``color1`` (N, 3) and ``color2`` (M, 3) in
[0, 1]. ``pos2`` need not be ``pos1 + gt``: the synthetic world writes the next scan (a re-scan), while
FlowNet3D's KITTI files come from KITTI's correspondences (the first rows of a file quoted in the FlowNet3D
repository's issue 21 satisfy ``pos2 = pos1 + gt`` to every printed digit, its last rows do not);
:mod:`evaluation.pairing` tells the two kinds apart. Optional depth limit (FLOT's protocol keeps camera z < 35 m
in each cloud separately); off by default.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evaluation.readers.arrays import LABELS, check_labels, check_mask, check_points, npz_headers, raise_problems
from evaluation.readers.base import Entry, SceneFlowFormat
from evaluation.sample import SceneFlowSample
from core.axes import FORMAT_AXES

NAME = "flownet3d"
_AXES = FORMAT_AXES[NAME]


@dataclass
class FlowNet3DOptions:
    """Options of the FlowNet3D ``kitti_rm_ground`` reader.

    Attributes:
        max_depth: keep points with camera z < max_depth (metres) in pc1 (with their flow) and in pc2,
            each cloud separately (FLOT's protocol uses 35); none keeps everything.
    """

    max_depth: float | None = None


def _candidates(root: Path) -> list[Path]:
    return [root] if root.is_file() else sorted(root.glob("*.npz"))


def _entries(path: Path, root: Path) -> list[Entry]:
    """Validate one ``.npz`` from its headers; one entry named by the file's stem."""
    try:
        specs = npz_headers(path)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise ValueError(f"not a readable .npz ({exc})") from None
    missing = [k for k in ("pos1", "pos2", "gt") if k not in specs]
    if missing:
        raise ValueError(f"missing arrays {missing} (has {sorted(specs)})")
    n = specs["pos1"][0][0] if specs["pos1"][0] else -1
    checks = [
        check_points("pos1", *specs["pos1"]),
        check_points("pos2", *specs["pos2"]),
        check_points("gt", *specs["gt"], rows=n),
    ]
    if "moving" in specs:
        checks.append(check_mask("moving", *specs["moving"], rows=n))
    for key in LABELS:
        if key in specs:
            checks.append(check_labels(key, *specs[key], rows=n))
    if "color1" in specs:
        checks.append(check_points("color1", *specs["color1"], rows=n))
    if "color2" in specs:
        m = specs["pos2"][0][0] if specs["pos2"][0] else -1
        checks.append(check_points("color2", *specs["color2"], rows=m))
    raise_problems(checks)
    return [Entry(path.stem, path)]


def _load(entry: Entry, opts: FlowNet3DOptions) -> SceneFlowSample:
    with np.load(entry.path) as data:
        arrays = {k: data[k] for k in ("pos1", "pos2", "gt", "moving", "color1", "color2", *LABELS) if k in data}
    pc1 = _AXES.to_camera(arrays["pos1"].astype(np.float32))
    pc2 = _AXES.to_camera(arrays["pos2"].astype(np.float32))
    flow = _AXES.to_camera(arrays["gt"].astype(np.float32))
    moving = arrays.get("moving")
    color1, color2 = arrays.get("color1"), arrays.get("color2")
    classes, instance = arrays.get("classes"), arrays.get("instance")
    if opts.max_depth is not None:
        keep1 = pc1[:, 2] < opts.max_depth
        keep2 = pc2[:, 2] < opts.max_depth
        pc1, flow, pc2 = pc1[keep1], flow[keep1], pc2[keep2]
        moving, color1, classes, instance = (None if a is None else a[keep1]
                                             for a in (moving, color1, classes, instance))
        color2 = None if color2 is None else color2[keep2]
    return SceneFlowSample(entry.name, pc1, pc2, flow, color1=color1, color2=color2, moving=moving,
                           classes=classes, instance=instance)


FORMAT = SceneFlowFormat(
    name=NAME,
    summary="FlowNet3D kitti_rm_ground: one *.npz per scene (pos1, pos2, gt; LiDAR axes)",
    options=FlowNet3DOptions,
    candidates=_candidates,
    entries=_entries,
    load=_load,
    sniff=lambda folder: any(folder.glob("*.npz")),
    looks_for="*.npz",
    file_suffixes=(".npz",),
)
