"""KITTI Scene Flow 2015 → 3D point pairs: the stereo protocol of HPLFlowNet's ``KITTI_processed_occ_final``.

Each valid pixel ``p = (u, v)`` of frame t (index ``_10``) gives one point pair (camera axes: x right, y down,
z forward, metres; the rectified camera-0 frame, as :data:`P_rect_02` places it):

* ``pc1`` — pixel ``p`` back-projected at depth ``f · B / (d0(p) + 1e-5)``, ``d0`` = ``disp_occ_0``;
* ``pc2`` — pixel ``p + flow(p)`` back-projected at depth ``f · B / (d1(p) + 1e-5)``, ``d1`` = ``disp_occ_1``
  (KITTI stores frame t+1's disparity *at frame t's pixel*, so ``pc2[i]`` is the same surface point as
  ``pc1[i]`` one frame later); the scene flow is ``pc2 − pc1`` and includes the camera's motion.

A pixel is used where ``d0 > 0``, ``d1 > 0`` and the flow PNG's valid bit is set. Back-projection follows
``P_rect_02`` = ``[[f, 0, cx, P03], [0, f, cy, P13], [0, 0, 1, P23]]``: ``x = (u (z + P23) − cx z − P03) / f``
and the same for y. ``B`` is KITTI's stereo baseline, 0.54 m. These are the choices of HPLFlowNet's
``data_preprocess/process_kitti.py`` (github.com/laoreja/HPLFlowNet), so a split written here reads like
the published one: :func:`write_hpl_scene` stores axes ``(−x, −y, z)`` (:data:`core.axes.HPLFLOWNET`) and
drops nothing — the reader removes the ground and the points beyond 35 m, and ``--mapping`` keeps the 142
scenes with a raw recording, as in HPLFlowNet's loader.

:func:`kitti_scene` reads one scene of the KITTI download (``training/disp_occ_0``, ``disp_occ_1``,
``flow_occ``, ``calib_cam_to_cam``); :func:`stereo_pairs` works on arrays, so any KITTI-format disparity and
flow (a scene-flow method's predictions, for example) can be turned into a split the same way.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.axes import FORMAT_AXES
from core.errors import InputError
from pipeline.kitti._text import PathLike
from pipeline.kitti.calib import read_raw_cam_to_cam
from pipeline.kitti.png16 import read_disparity_png, read_flow_png

BASELINE_M = 0.54  #: KITTI's stereo baseline, metres (HPLFlowNet's constant)
DISPARITY_EPS = 1e-5  #: added to the disparity before dividing (HPLFlowNet's constant)
SCENES = 200  #: training scenes of KITTI Scene Flow 2015


@dataclass(frozen=True)
class StereoPairs:
    """Corresponding points of one scene, camera axes, metres.

    Attributes:
        pc1: (N, 3) float32, frame t.
        pc2: (N, 3) float32, the same surface points at t+1 (in camera t's frame: the flow includes the
            camera's own motion).
        pixels: (N, 2) int32 (u, v) of each pair's pixel in frame t.
    """

    pc1: np.ndarray
    pc2: np.ndarray
    pixels: np.ndarray

    def subset(self, index: np.ndarray) -> "StereoPairs":
        """The pairs at ``index`` (an integer or boolean index into the N pairs)."""
        return StereoPairs(self.pc1[index], self.pc2[index], self.pixels[index])

    @property
    def flow(self) -> np.ndarray:
        """(N, 3) float32 scene flow ``pc2 − pc1`` (metres)."""
        return self.pc2 - self.pc1


def _check_projection(P: np.ndarray, where: PathLike) -> None:
    P = np.asarray(P, dtype=np.float64)
    if P.shape != (3, 4):
        raise InputError(where, f"P_rect_02 must be 3x4, got shape {P.shape}")
    if P[0, 1] != 0 or P[1, 0] != 0 or P[2, 0] != 0 or P[2, 1] != 0 or P[2, 2] != 1:
        raise InputError(where, "P_rect_02 is not a rectified projection [[f,0,cx,.],[0,f,cy,.],[0,0,1,.]]")
    if not P[0, 0] > 0 or abs(P[0, 0] - P[1, 1]) > 1e-6 * P[0, 0]:
        raise InputError(where, f"P_rect_02 needs one positive focal length, got fx={P[0, 0]}, fy={P[1, 1]}")


def back_project(u: np.ndarray, v: np.ndarray, depth: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(N, 3) float64 camera points (x right, y down, z = ``depth``, metres) of pixels (u, v) under ``P``."""
    f, cx, cy = P[0, 0], P[0, 2], P[1, 2]
    zc = depth + P[2, 3]
    x = (u * zc - (cx * depth + P[0, 3])) / f
    y = (v * zc - (cy * depth + P[1, 3])) / f
    return np.stack([x, y, depth], axis=-1)


def stereo_pairs(disp0: np.ndarray, disp1: np.ndarray, flow: np.ndarray, flow_valid: np.ndarray,
                 P: np.ndarray, baseline_m: float = BASELINE_M, where: PathLike = "<arrays>") -> StereoPairs:
    """Point pairs from frame t's disparity, frame t+1's disparity at frame t's pixels, and the optical flow.

    Args:
        disp0, disp1: (H, W) disparity in pixels; ≤ 0 = invalid.
        flow: (H, W, 2) optical flow in pixels (u right, v down); ``flow_valid`` (H, W) bool.
        P: (3, 4) ``P_rect_02`` at the maps' resolution.
        baseline_m: stereo baseline, metres.
        where: the file named in errors.
    """
    d0 = np.asarray(disp0, dtype=np.float32)
    d1 = np.asarray(disp1, dtype=np.float32)
    fl = np.asarray(flow, dtype=np.float32)
    ok = np.asarray(flow_valid, dtype=bool)
    if d0.ndim != 2 or d1.shape != d0.shape or fl.shape != d0.shape + (2,) or ok.shape != d0.shape:
        raise InputError(where, f"disparities, flow and valid mask must share one (H, W): got {d0.shape}, "
                                f"{d1.shape}, {fl.shape[:2]}, {ok.shape}")
    P = np.asarray(P, dtype=np.float64)
    _check_projection(P, where)
    use = ok & (d0 > 0) & (d1 > 0) & np.isfinite(d0) & np.isfinite(d1)
    v, u = np.nonzero(use)
    fb = P[0, 0] * baseline_m
    z1 = fb / (d0[v, u].astype(np.float64) + DISPARITY_EPS)
    z2 = fb / (d1[v, u].astype(np.float64) + DISPARITY_EPS)
    pc1 = back_project(u.astype(np.float64), v.astype(np.float64), z1, P)
    pc2 = back_project(u + fl[v, u, 0].astype(np.float64), v + fl[v, u, 1].astype(np.float64), z2, P)
    return StereoPairs(pc1.astype(np.float32), pc2.astype(np.float32), np.stack([u, v], axis=1).astype(np.int32))


def kitti_scene(root: PathLike, index: int, baseline_m: float = BASELINE_M) -> StereoPairs:
    """Scene ``index`` of the KITTI Scene Flow 2015 download's ``training/`` folder (``root`` holds it)."""
    root = Path(root)
    train = root / "training" if (root / "training").is_dir() else root
    name = f"{index:06d}_10.png"
    calib = read_raw_cam_to_cam(train / "calib_cam_to_cam" / f"{index:06d}.txt")
    if "02" not in calib.P_rect:
        raise InputError(calib.path or train, "missing key 'P_rect_02' (the left colour camera)")
    d0 = read_disparity_png(train / "disp_occ_0" / name)
    d1 = read_disparity_png(train / "disp_occ_1" / name)
    flow, valid = read_flow_png(train / "flow_occ" / name)
    for path, arr in ((train / "disp_occ_1" / name, d1), (train / "flow_occ" / name, valid)):
        if arr.shape != d0.shape:
            raise InputError(path, f"size {arr.shape[::-1]} differs from disp_occ_0's {d0.shape[::-1]} (W, H)")
    return stereo_pairs(d0, d1, flow, valid, calib.P_rect["02"], baseline_m, where=train / "flow_occ" / name)


def write_hpl_scene(out: PathLike, pairs: StereoPairs, moving: np.ndarray | None = None) -> Path:
    """Write ``pc1.npy`` / ``pc2.npy`` (HPLFlowNet axes) into folder ``out``, atomically; returns it.

    ``moving`` (N,) bool, when given, is written as ``moving.npy`` (the reader's optional label).

    The arrays go to a temporary folder beside the split (``out``'s parent), not inside it, that is renamed
    when both are written: an interrupted run leaves no half-written scene where a reader looks for scenes (a
    left-over temporary folder is replaced next time).
    """
    out = Path(out)
    tmp = temporary_folder(out)
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    axes = FORMAT_AXES["hplflownet"]
    for fname, pts in (("pc1.npy", pairs.pc1), ("pc2.npy", pairs.pc2)):
        np.save(tmp / fname, np.ascontiguousarray(axes.from_camera(pts).astype(np.float32)), allow_pickle=False)
    if moving is not None:
        m = np.asarray(moving, dtype=bool)
        if m.shape != (len(pairs.pc1),):
            raise ValueError(f"moving must be ({len(pairs.pc1)},), got shape {m.shape}")
        np.save(tmp / "moving.npy", m, allow_pickle=False)
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    os.replace(tmp, out)
    return out


def temporary_folder(out: Path) -> Path:
    """Where :func:`write_hpl_scene` writes scene folder ``out`` before renaming it: beside the split folder
    (``out``'s parent), so that no reader of the split sees it."""
    split = out.absolute().parent
    return split.with_name(f".{split.name}.{out.name}.tmp")


def is_written(folder: Path) -> bool:
    """True when ``folder`` holds both arrays (a finished scene)."""
    return (folder / "pc1.npy").is_file() and (folder / "pc2.npy").is_file()


def build_split(root: PathLike, out: PathLike, scenes: range | list[int] = range(SCENES),
                baseline_m: float = BASELINE_M, log=print) -> list[Path]:
    """Write ``out/XXXXXX/pc1.npy, pc2.npy`` for every scene of ``scenes``; finished scenes are skipped.

    All 200 scenes by default, as HPLFlowNet writes them; evaluate with ``--protocol hplflownet
    --mapping …/train_mapping.txt`` to keep its 142.
    """
    out = Path(out)
    written = []
    for i in scenes:
        folder = out / f"{i:06d}"
        if is_written(folder):
            written.append(folder)
            continue
        pairs = kitti_scene(root, i, baseline_m)
        written.append(write_hpl_scene(folder, pairs))
        log(f"{folder}: {len(pairs.pc1)} point pairs")
    return written


__all__ = ["BASELINE_M", "SCENES", "StereoPairs", "back_project", "build_split", "is_written", "kitti_scene",
           "stereo_pairs", "temporary_folder", "write_hpl_scene"]
