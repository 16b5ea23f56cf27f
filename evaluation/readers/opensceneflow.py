"""OpenSceneFlow / DeFlow preprocessed HDF5 (Argoverse 2, Waymo, ... in one layout).

One ``<scene_id>.h5`` per scene, one group per timestamp (name = the integer timestamp) with ``lidar``
(N, ≥3, sensor/ego frame, LiDAR axes :data:`core.axes.LIDAR`), ``pose`` (4, 4) ego→world,
``ground_mask`` (N,) and, on frames that have ground truth, ``flow`` (N, 3) (``lidar + flow`` is the point
in the *next* frame's coordinates) and ``flow_is_valid`` (N,), optionally ``ego_motion`` (4, 4) =
``T_{t→t+1}``, ``flow_category_indices`` (N,) (passed through as ``classes``; 0 = background, as
Argoverse 2) and ``flow_instance_id`` (N,) (as ``instance``). Consecutive timestamps are paired; pairs
whose first frame has no ``flow`` are skipped. Ground points are removed from both clouds, points with
invalid flow from pc1; ``moving`` = ‖flow − ego flow‖ > ``moving_threshold`` (0.05 m, Argoverse-2's
0.5 m/s at 10 Hz). Points, flow and the pose are converted to camera axes like FlowNet3D's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.readers.base import Entry, SceneFlowFormat
from evaluation.sample import SceneFlowSample
from core.axes import FORMAT_AXES

NAME = "opensceneflow"
_AXES = FORMAT_AXES[NAME]
_H5_SUFFIXES = (".h5", ".hdf5")


@dataclass
class OpenSceneFlowOptions:
    """Options of the OpenSceneFlow HDF5 reader.

    Attributes:
        remove_ground: drop ``ground_mask`` points from both clouds.
        valid_only: drop pc1 points whose ``flow_is_valid`` is false.
        moving_threshold: metres of flow beyond the ego-motion flow that mark a point as moving.
        to_camera: convert LiDAR axes to camera axes (x right, y down, z forward).
    """

    remove_ground: bool = True
    valid_only: bool = True
    moving_threshold: float = 0.05
    to_camera: bool = True


def _timestamps(f: Any) -> list[str]:
    keys = [k for k in f.keys() if k.lstrip("-").isdigit()]
    return sorted(keys, key=int)


def _candidates(root: Path) -> list[Path]:
    return [root] if root.is_file() else sorted(q for q in root.iterdir() if q.suffix in _H5_SUFFIXES)


def _validate(path: Path) -> None:
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"not a readable HDF5 file ({exc})") from None
    with f:
        stamps = _timestamps(f)
        if len(stamps) < 2:
            raise ValueError(f"needs at least two timestamp groups, found {len(stamps)}")
        problems = []
        n_flow = 0
        for i, t in enumerate(stamps):
            g = f[t]
            missing = [k for k in ("lidar", "pose", "ground_mask") if k not in g]
            if missing:
                problems.append(f"group {t}: missing {missing}")
                continue
            shape = g["lidar"].shape
            if len(shape) != 2 or shape[1] < 3:
                problems.append(f"group {t}: 'lidar' must have shape (N, >=3), got {shape}")
                continue
            n = shape[0]
            if g["pose"].shape != (4, 4):
                problems.append(f"group {t}: 'pose' must be (4, 4), got {g['pose'].shape}")
            if g["ground_mask"].shape != (n,):
                problems.append(f"group {t}: 'ground_mask' must be ({n},), got {g['ground_mask'].shape}")
            if "flow" in g and i < len(stamps) - 1:
                n_flow += 1
                if g["flow"].shape != (n, 3):
                    problems.append(f"group {t}: 'flow' must be ({n}, 3), got {g['flow'].shape}")
                if "flow_is_valid" in g and g["flow_is_valid"].shape != (n,):
                    problems.append(
                        f"group {t}: 'flow_is_valid' must be ({n},), got {g['flow_is_valid'].shape}"
                    )
                for key in ("flow_category_indices", "flow_instance_id"):
                    if key in g and g[key].shape != (n,):
                        problems.append(f"group {t}: '{key}' must be ({n},), got {g[key].shape}")
                if "ego_motion" in g and g["ego_motion"].shape != (4, 4):
                    problems.append(f"group {t}: 'ego_motion' must be (4, 4), got {g['ego_motion'].shape}")
        if n_flow == 0 and not problems:
            problems.append("no timestamp group with 'flow' followed by another frame")
        if problems:
            raise ValueError("; ".join(problems[:5]) + (f" (+{len(problems) - 5} more)" if len(problems) > 5 else ""))


def _entries(path: Path, root: Path) -> list[Entry]:
    """Validate one ``.h5`` file; one entry per timestamp with flow, named ``<file stem>/<timestamp>``."""
    import h5py

    _validate(path)
    base = root if root.is_dir() else path
    rel = path.relative_to(base).with_suffix("").as_posix() if path != base else path.stem
    with h5py.File(path, "r") as f:
        stamps = _timestamps(f)
        return [Entry(f"{rel}/{t0}", path, (t0, t1)) for t0, t1 in zip(stamps, stamps[1:]) if "flow" in f[t0]]


def _load(entry: Entry, opts: OpenSceneFlowOptions) -> SceneFlowSample:
    import h5py

    t0, t1 = entry.extra
    with h5py.File(entry.path, "r") as f:
        g0, g1 = f[t0], f[t1]
        pc1 = np.asarray(g0["lidar"][:, :3], dtype=np.float64)
        pc2 = np.asarray(g1["lidar"][:, :3], dtype=np.float64)
        gm1 = np.asarray(g0["ground_mask"][:], dtype=bool)
        gm2 = np.asarray(g1["ground_mask"][:], dtype=bool)
        flow = np.asarray(g0["flow"][:], dtype=np.float64)
        valid = np.asarray(g0["flow_is_valid"][:], dtype=bool) if "flow_is_valid" in g0 else None
        classes = np.asarray(g0["flow_category_indices"][:]) if "flow_category_indices" in g0 else None
        instance = np.asarray(g0["flow_instance_id"][:]) if "flow_instance_id" in g0 else None
        if "ego_motion" in g0:
            pose = np.asarray(g0["ego_motion"][:], dtype=np.float64)
        else:
            pose = np.linalg.inv(np.asarray(g1["pose"][:], np.float64)) @ np.asarray(g0["pose"][:], np.float64)
    ego_flow = pc1 @ pose[:3, :3].T + pose[:3, 3] - pc1
    moving = np.linalg.norm(flow - ego_flow, axis=1) > opts.moving_threshold
    keep1 = np.ones(len(pc1), dtype=bool)
    keep2 = np.ones(len(pc2), dtype=bool)
    if opts.remove_ground:
        keep1 &= ~gm1
        keep2 &= ~gm2
    if opts.valid_only and valid is not None:
        keep1 &= valid
    pc1, flow, moving, pc2 = pc1[keep1], flow[keep1], moving[keep1], pc2[keep2]
    classes = None if classes is None else classes[keep1]
    instance = None if instance is None else instance[keep1]
    if opts.to_camera:
        pc1, pc2, flow = _AXES.to_camera(pc1), _AXES.to_camera(pc2), _AXES.to_camera(flow)
        pose = _AXES.pose_to_camera(pose)
    return SceneFlowSample(
        entry.name,
        pc1.astype(np.float32),
        pc2.astype(np.float32),
        flow.astype(np.float32),
        moving=moving,
        pose=pose,
        classes=classes,
        instance=instance,
    )


FORMAT = SceneFlowFormat(
    name=NAME,
    summary="OpenSceneFlow / DeFlow HDF5: one *.h5 per scene, one group per timestamp (LiDAR axes)",
    options=OpenSceneFlowOptions,
    candidates=_candidates,
    entries=_entries,
    load=_load,
    sniff=lambda folder: any(q.suffix in _H5_SUFFIXES for q in folder.iterdir()),
    looks_for="*.h5",
    file_suffixes=_H5_SUFFIXES,
)
