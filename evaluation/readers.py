"""Readers of scene-flow test sets, returning :class:`~evaluation.sample.SceneFlowSample` in camera axes.

Formats (``fmt``):

* ``"flownet3d"`` — FlowNet3D's ``kitti_rm_ground``: one ``*.npz`` per scene with ``pos1`` (N, 3),
  ``pos2`` (M, 3), ``gt`` (N, 3) in LiDAR-like axes (x fwd, y left, z up); camera = ``(−y, −z, x)``
  (see :mod:`evaluation.axes`). Optional arrays read when present: ``moving`` (N,) (our synthetic
  generator writes it), ``classes`` / ``instance`` (N,) integers (class 0 = background; our generator
  writes them), ``color1`` (N, 3) and ``color2`` (M, 3) in [0, 1]. Optional depth limit
  (FLOT's protocol keeps camera z < 35 m in each cloud separately); off by default.
* ``"hplflownet"`` — HPLFlowNet's ``KITTI_processed_occ_final``: one folder per scene with ``pc1.npy``
  and ``pc2.npy`` (N, 3) of corresponding points in stored axes ``(−x, −y, z)`` of the camera;
  flow = ``pc2 − pc1``; optional ``moving.npy``, ``classes.npy``, ``instance.npy`` (N,). Filtering
  follows HPLFlowNet's own loader
  (``datasets/kitti.py`` + ``transforms.ProcessData.process_inference``), applied to the stored axes:
  ground is ``y_s < −1.4`` and a pair is dropped **only when both** its pc1 and pc2 points are ground
  (``is_ground = (pc1.y < −1.4) & (pc2.y < −1.4)``) — ``ground_rule="either"`` drops a pair when either
  point is ground instead; then pairs are kept where ``z_s < 35`` in **both** pc1 and pc2.
  HPLFlowNet additionally keeps only the 142 of 200 scenes that have a KITTI-raw mapping (its
  ``KITTI_mapping.txt``, the devkit's ``train_mapping.txt``); ``monoflow-evaluate run --protocol
  hplflownet --mapping FILE`` applies it (:func:`evaluation.scenes.mapped_scenes`), or pass the kept
  names as ``names=``.
* ``"opensceneflow"`` — OpenSceneFlow / DeFlow preprocessed HDF5: one ``<scene_id>.h5`` per scene, one
  group per timestamp (name = the integer timestamp) with ``lidar`` (N, ≥3, sensor/ego frame,
  LiDAR axes), ``pose`` (4, 4) ego→world, ``ground_mask`` (N,) and, on frames that have ground truth,
  ``flow`` (N, 3) (``lidar + flow`` is the point in the *next* frame's coordinates) and
  ``flow_is_valid`` (N,), optionally ``ego_motion`` (4, 4) = ``T_{t→t+1}``,
  ``flow_category_indices`` (N,) (passed through as ``classes``; 0 = background, as Argoverse 2) and
  ``flow_instance_id`` (N,) (as ``instance``). Consecutive timestamps are
  paired; pairs whose first frame has no ``flow`` are skipped. Ground points are removed from both
  clouds, points with invalid flow from pc1; ``moving`` = ‖flow − ego flow‖ > ``moving_threshold``
  (0.05 m, Argoverse-2's 0.5 m/s at 10 Hz). Converted to camera axes like FlowNet3D's.

:func:`load_split` auto-detects the format, validates every entry up front (shapes, keys) and raises
one :class:`~pipeline.errors.InputError` listing every malformed file; samples are then read lazily,
sorted by name.
"""

from __future__ import annotations

import functools
import os
import zipfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import numpy as np

from evaluation.axes import LIDAR_TO_CAMERA, conjugate_pose, hpl_to_camera, lidar_to_camera
from evaluation.sample import SceneFlowSample
from pipeline.errors import InputError

FORMATS = ("flownet3d", "hplflownet", "opensceneflow")
_H5_SUFFIXES = (".h5", ".hdf5")


@dataclass
class FlowNet3DOptions:
    """Options of the FlowNet3D ``kitti_rm_ground`` reader.

    Attributes:
        max_depth: keep points with camera z < max_depth (metres) in pc1 (with their flow) and in pc2,
            each cloud separately (FLOT's protocol uses 35); None keeps everything.
    """

    max_depth: float | None = None


@dataclass
class HPLFlowNetOptions:
    """Options of the HPLFlowNet ``KITTI_processed_occ_final`` reader (HPLFlowNet's defaults).

    Attributes:
        remove_ground: drop ground pairs (stored ``y < −ground_height``).
        ground_height: metres below the camera (stored y is up).
        ground_rule: ``"both"`` (HPLFlowNet: drop a pair when pc1 and pc2 points are both ground) or
            ``"either"`` (drop when either is ground).
        max_depth: keep pairs with stored z < max_depth in both clouds (HPLFlowNet's
            ``DEPTH_THRESHOLD`` = 35); None keeps everything.
    """

    remove_ground: bool = True
    ground_height: float = 1.4
    ground_rule: str = "both"
    max_depth: float | None = 35.0

    def __post_init__(self) -> None:
        if self.ground_rule not in ("both", "either"):
            raise ValueError(f"ground_rule must be 'both' or 'either', got {self.ground_rule!r}")


@dataclass
class OpenSceneFlowOptions:
    """Options of the OpenSceneFlow HDF5 reader.

    Attributes:
        remove_ground: drop ``ground_mask`` points from both clouds.
        valid_only: drop pc1 points whose ``flow_is_valid`` is False.
        moving_threshold: metres of flow beyond the ego-motion flow that mark a point as moving.
        to_camera: convert LiDAR axes to camera axes (x right, y down, z forward).
    """

    remove_ground: bool = True
    valid_only: bool = True
    moving_threshold: float = 0.05
    to_camera: bool = True


@dataclass(frozen=True)
class _Entry:
    name: str
    path: Path
    extra: tuple[str, ...] = ()


# ----------------------------------------------------------------------------------------------------
# array headers (validation without reading the data)


def _npy_header(fp: Any) -> tuple[tuple[int, ...], np.dtype]:
    version = np.lib.format.read_magic(fp)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(fp)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(fp)
    else:  # pragma: no cover - version 3 headers are rare
        shape, _, dtype = np.lib.format._read_array_header(fp, version)  # type: ignore[attr-defined]
    return tuple(shape), np.dtype(dtype)


def _npz_headers(path: Path) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Shape and dtype of every array in an ``.npz`` without loading the data."""
    out: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with zf.open(info) as fp:
                out[info.filename[: -len(".npy")]] = _npy_header(fp)
    return out


def _npy_spec(path: Path) -> tuple[tuple[int, ...], np.dtype]:
    with open(path, "rb") as fp:
        return _npy_header(fp)


def _check_points(name: str, shape: tuple[int, ...], dtype: np.dtype, rows: int | None = None) -> str | None:
    if len(shape) != 2 or shape[1] != 3:
        return f"'{name}' must have shape (N, 3), got {shape}"
    if dtype.kind not in "fiu":
        return f"'{name}' must be numeric, got dtype {dtype}"
    if rows is not None and shape[0] != rows:
        return f"'{name}' has {shape[0]} rows, expected {rows}"
    return None


def _check_mask(name: str, shape: tuple[int, ...], dtype: np.dtype, rows: int) -> str | None:
    if shape != (rows,):
        return f"'{name}' must have shape ({rows},), got {shape}"
    if dtype.kind not in "biu":
        return f"'{name}' must be boolean, got dtype {dtype}"
    return None


def _check_labels(name: str, shape: tuple[int, ...], dtype: np.dtype, rows: int) -> str | None:
    if shape != (rows,):
        return f"'{name}' must have shape ({rows},), got {shape}"
    if dtype.kind not in "biu":
        return f"'{name}' must be integer, got dtype {dtype}"
    return None


LABELS = ("classes", "instance")


# ----------------------------------------------------------------------------------------------------
# FlowNet3D kitti_rm_ground


def _validate_flownet3d(entry: _Entry) -> None:
    try:
        specs = _npz_headers(entry.path)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise ValueError(f"not a readable .npz ({exc})") from None
    missing = [k for k in ("pos1", "pos2", "gt") if k not in specs]
    if missing:
        raise ValueError(f"missing arrays {missing} (has {sorted(specs)})")
    n = specs["pos1"][0][0] if specs["pos1"][0] else -1
    checks = [
        _check_points("pos1", *specs["pos1"]),
        _check_points("pos2", *specs["pos2"]),
        _check_points("gt", *specs["gt"], rows=n),
    ]
    if "moving" in specs:
        checks.append(_check_mask("moving", *specs["moving"], rows=n))
    for key in LABELS:
        if key in specs:
            checks.append(_check_labels(key, *specs[key], rows=n))
    if "color1" in specs:
        checks.append(_check_points("color1", *specs["color1"], rows=n))
    if "color2" in specs:
        m = specs["pos2"][0][0] if specs["pos2"][0] else -1
        checks.append(_check_points("color2", *specs["color2"], rows=m))
    problems = [c for c in checks if c]
    if problems:
        raise ValueError("; ".join(problems))


def _load_flownet3d(entry: _Entry, opts: FlowNet3DOptions) -> SceneFlowSample:
    with np.load(entry.path) as data:
        arrays = {k: data[k] for k in ("pos1", "pos2", "gt", "moving", "color1", "color2", *LABELS) if k in data}
    pc1 = lidar_to_camera(arrays["pos1"].astype(np.float32))
    pc2 = lidar_to_camera(arrays["pos2"].astype(np.float32))
    flow = lidar_to_camera(arrays["gt"].astype(np.float32))
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


# ----------------------------------------------------------------------------------------------------
# HPLFlowNet KITTI_processed_occ_final


def _validate_hplflownet(entry: _Entry) -> None:
    problems: list[str] = []
    specs: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
    for fname in ("pc1.npy", "pc2.npy", "moving.npy", "classes.npy", "instance.npy"):
        fpath = entry.path / fname
        if not fpath.is_file():
            if fname in ("pc1.npy", "pc2.npy"):
                problems.append(f"missing {fname}")
            continue
        try:
            specs[fname] = _npy_spec(fpath)
        except (OSError, ValueError, EOFError) as exc:
            problems.append(f"{fname} is not a readable .npy ({exc})")
    if "pc1.npy" in specs:
        shape1 = specs["pc1.npy"][0]
        problems.append(_check_points("pc1.npy", *specs["pc1.npy"]) or "")
        n = shape1[0] if shape1 else -1
        if "pc2.npy" in specs:
            problems.append(_check_points("pc2.npy", *specs["pc2.npy"], rows=n) or "")
        if "moving.npy" in specs:
            problems.append(_check_mask("moving.npy", *specs["moving.npy"], rows=n) or "")
        for key in LABELS:
            if f"{key}.npy" in specs:
                problems.append(_check_labels(f"{key}.npy", *specs[f"{key}.npy"], rows=n) or "")
    problems = [p for p in problems if p]
    if problems:
        raise ValueError("; ".join(problems))


def _load_hplflownet(entry: _Entry, opts: HPLFlowNetOptions) -> SceneFlowSample:
    pc1 = np.load(entry.path / "pc1.npy").astype(np.float32)
    pc2 = np.load(entry.path / "pc2.npy").astype(np.float32)
    optional = {}
    for key in ("moving", *LABELS):
        path = entry.path / f"{key}.npy"
        optional[key] = np.load(path) if path.is_file() else None
    keep = np.ones(len(pc1), dtype=bool)
    if opts.remove_ground:
        g1 = pc1[:, 1] < -opts.ground_height
        g2 = pc2[:, 1] < -opts.ground_height
        keep &= ~((g1 & g2) if opts.ground_rule == "both" else (g1 | g2))
    if opts.max_depth is not None:
        keep &= (pc1[:, 2] < opts.max_depth) & (pc2[:, 2] < opts.max_depth)
    pc1, pc2 = pc1[keep], pc2[keep]
    flow = pc2 - pc1
    moving, classes, instance = (None if optional[k] is None else optional[k][keep] for k in ("moving", *LABELS))
    return SceneFlowSample(
        entry.name, hpl_to_camera(pc1), hpl_to_camera(pc2), hpl_to_camera(flow), moving=moving,
        classes=classes, instance=instance,
    )


# ----------------------------------------------------------------------------------------------------
# OpenSceneFlow HDF5


def _osf_timestamps(f: Any) -> list[str]:
    keys = [k for k in f.keys() if k.lstrip("-").isdigit()]
    return sorted(keys, key=int)


def _osf_entries(path: Path, root: Path) -> list[_Entry]:
    import h5py

    rel = path.relative_to(root).with_suffix("").as_posix() if path != root else path.stem
    with h5py.File(path, "r") as f:
        stamps = _osf_timestamps(f)
        return [
            _Entry(f"{rel}/{t0}", path, (t0, t1))
            for t0, t1 in zip(stamps, stamps[1:])
            if "flow" in f[t0]
        ]


def _validate_osf_file(path: Path) -> None:
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"not a readable HDF5 file ({exc})") from None
    with f:
        stamps = _osf_timestamps(f)
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


def _load_opensceneflow(entry: _Entry, opts: OpenSceneFlowOptions) -> SceneFlowSample:
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
        pc1, pc2, flow = lidar_to_camera(pc1), lidar_to_camera(pc2), lidar_to_camera(flow)
        pose = conjugate_pose(LIDAR_TO_CAMERA, pose)
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


# ----------------------------------------------------------------------------------------------------
# discovery


def _hpl_scene_dirs(root: Path) -> list[Path]:
    """Leaf folders holding ``.npy`` files (HPLFlowNet takes every leaf folder of its root)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        if not dirnames and any(f.endswith(".npy") for f in filenames):
            out.append(Path(dirpath))
        elif "pc1.npy" in filenames or "pc2.npy" in filenames:
            out.append(Path(dirpath))
    return out


def detect_format(path: str | os.PathLike[str]) -> str:
    """The format of a file or folder: ``"flownet3d"``, ``"hplflownet"`` or ``"opensceneflow"``.

    Raises:
        InputError: when nothing recognisable is there or several formats are mixed.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "no such file or folder")
    if p.is_file():
        if p.suffix == ".npz":
            return "flownet3d"
        if p.suffix in _H5_SUFFIXES:
            return "opensceneflow"
        raise InputError(p, "not a scene-flow file (expected .npz, .h5 or a folder)")
    found = []
    if any(p.glob("*.npz")):
        found.append("flownet3d")
    if any(q.suffix in _H5_SUFFIXES for q in p.iterdir()):
        found.append("opensceneflow")
    if not found and _hpl_scene_dirs(p):
        found.append("hplflownet")
    if not found:
        raise InputError(p, "no scene-flow data found (no *.npz, no *.h5, no folders with pc1.npy/pc2.npy)")
    if len(found) > 1:
        raise InputError(p, f"mixes several formats ({', '.join(found)}); pass fmt= explicitly")
    return found[0]


def _entries(root: Path, fmt: str) -> tuple[list[_Entry], list[tuple[Path, str]]]:
    """All entries of ``root`` in ``fmt`` and the (path, problem) pairs of malformed ones."""
    bad: list[tuple[Path, str]] = []
    entries: list[_Entry] = []
    if fmt == "flownet3d":
        files = [root] if root.is_file() else sorted(root.glob("*.npz"))
        for fpath in files:
            entry = _Entry(fpath.stem, fpath)
            try:
                _validate_flownet3d(entry)
            except ValueError as exc:
                bad.append((fpath, str(exc)))
                continue
            entries.append(entry)
    elif fmt == "hplflownet":
        dirs = [root] if (root / "pc1.npy").exists() or (root / "pc2.npy").exists() else _hpl_scene_dirs(root)
        for d in sorted(dirs):
            name = d.name if d == root else d.relative_to(root).as_posix()
            entry = _Entry(name, d)
            try:
                _validate_hplflownet(entry)
            except ValueError as exc:
                bad.append((d, str(exc)))
                continue
            entries.append(entry)
    elif fmt == "opensceneflow":
        files = [root] if root.is_file() else sorted(q for q in root.iterdir() if q.suffix in _H5_SUFFIXES)
        for fpath in files:
            try:
                _validate_osf_file(fpath)
                entries.extend(_osf_entries(fpath, root if root.is_dir() else fpath))
            except ValueError as exc:
                bad.append((fpath, str(exc)))
    else:
        raise InputError(root, f"unknown format {fmt!r}; expected one of {FORMATS} or 'auto'")
    return entries, bad


# ----------------------------------------------------------------------------------------------------
# the split


@dataclass
class SceneFlowSplit(Sequence[SceneFlowSample]):
    """A validated, lazily read test split: ``split[i]`` reads scene i (sorted by name) from disk."""

    root: Path
    fmt: str
    entries: list[_Entry]
    loader: Callable[[_Entry], SceneFlowSample] = field(repr=False)

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


def load_split(
    path: str | os.PathLike[str],
    fmt: str = "auto",
    *,
    names: Sequence[str] | None = None,
    flownet3d: FlowNet3DOptions | None = None,
    hplflownet: HPLFlowNetOptions | None = None,
    opensceneflow: OpenSceneFlowOptions | None = None,
) -> SceneFlowSplit:
    """Open a scene-flow test split (a folder, or a single scene file/folder).

    Args:
        path: folder of ``*.npz`` (FlowNet3D), folder of scene folders (HPLFlowNet), folder of ``*.h5``
            (OpenSceneFlow), or one such scene.
        fmt: ``"auto"``, ``"flownet3d"``, ``"hplflownet"`` or ``"opensceneflow"``.
        names: keep only these scene names (e.g. HPLFlowNet's 142 mapped KITTI scenes); an unknown
            name is an error.
        flownet3d, hplflownet, opensceneflow: per-format options (defaults as documented there).

    Returns:
        A :class:`SceneFlowSplit`, sorted by scene name, reading each sample on access.

    Raises:
        InputError: when the path holds nothing readable, or one or more entries are malformed (one
            error naming every bad file and its problem).
    """
    root = Path(path)
    if fmt == "auto":
        fmt = detect_format(root)
    elif fmt not in FORMATS:
        raise InputError(root, f"unknown format {fmt!r}; expected one of {FORMATS} or 'auto'")
    if not root.exists():
        raise InputError(root, "no such file or folder")
    entries, bad = _entries(root, fmt)
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
    loader: Callable[[_Entry], SceneFlowSample]
    if fmt == "flownet3d":
        loader = functools.partial(_load_flownet3d, opts=flownet3d or FlowNet3DOptions())
    elif fmt == "hplflownet":
        loader = functools.partial(_load_hplflownet, opts=hplflownet or HPLFlowNetOptions())
    else:
        loader = functools.partial(_load_opensceneflow, opts=opensceneflow or OpenSceneFlowOptions())
    return SceneFlowSplit(root=root, fmt=fmt, entries=entries, loader=loader)
