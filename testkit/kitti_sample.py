"""Real KITTI 2015 scene 000139 for tests and benchmarks: a cache block (to measure sizes honestly) and a
KITTI-odometry-layout folder that stage one reads with ``depth="disparity"``.

Uses ``shared/data/kitti_sceneflow2015_000139``: the two colour frames of KITTI 2015 scene 000139 and
Self-Mono-SF's *predicted* disparities for them (a real monocular net's depth, with its real texture),
resized to the working size. Depth = fx · 0.54 m / disparity (KITTI's stereo baseline).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from pipeline.cache.points import canonical_depth
from pipeline.cache.records import BlockRecord, FrameRecord, PairRecord
from core.errors import InputError
from testkit.demo_scene import keep_mask

KITTI_FX, KITTI_CX, KITTI_CY, KITTI_W, KITTI_H = 721.5377, 609.5593, 172.854, 1242, 375
BASELINE_M = 0.54


def load_frames(folder: Path, height: int = 256, width: int = 832) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """(K at the working size, [(depth (H, W) float32 m, rgb (H, W, 3) uint8) for frames 10 and 11])."""
    import cv2

    folder = Path(folder)
    K = np.array([[KITTI_FX * width / KITTI_W, 0, KITTI_CX * width / KITTI_W],
                  [0, KITTI_FX * height / KITTI_H, KITTI_CY * height / KITTI_H], [0, 0, 1.0]])
    out = []
    for img_name, disp_name in (("kitti_img/image_2/000139_10.png", "results/disp_0/000139_10.png"),
                                ("kitti_img/image_2/000139_11.png", "results/disp_1/000139_10.png")):
        bgr = cv2.imread(str(folder / img_name), cv2.IMREAD_COLOR)
        disp = cv2.imread(str(folder / disp_name), cv2.IMREAD_UNCHANGED)
        if bgr is None or disp is None:
            raise InputError(folder, f"cannot read {img_name} / {disp_name}")
        rgb = cv2.resize(bgr[:, :, ::-1], (width, height), interpolation=cv2.INTER_AREA)
        d = cv2.resize(disp.astype(np.float32) / 256.0, (width, height), interpolation=cv2.INTER_LINEAR) * width / KITTI_W
        depth = np.where(d > 0, K[0, 0] * BASELINE_M / np.maximum(d, 1e-3), 0.0).astype(np.float32)
        out.append((canonical_depth(depth), np.ascontiguousarray(rgb)))
    return K, out


def kitti_block(folder: Path, pairs_per_block: int = 8, height: int = 256, width: int = 832) -> BlockRecord:
    """A block of ``pairs_per_block`` pairs whose frames alternate between the two real frames.

    Each frame is compressed on its own (one chunk per frame), so the repetition does not flatter sizes.
    The pose is a 1 m forward step (a stand-in; sizes do not depend on it).
    """
    K, pair = load_frames(folder, height, width)
    frames = [FrameRecord(k, *pair[k % 2]) for k in range(pairs_per_block + 1)]
    T = np.eye(4)
    T[2, 3] = -1.0
    masks = [keep_mask(f.depth, K) for f in frames[:2]]
    pairs = [
        PairRecord(k, k + 1, np.flatnonzero(masks[k % 2]).astype(np.int32),
                   np.flatnonzero(masks[(k + 1) % 2]).astype(np.int32), T, 1.0, {"kept": int(masks[k % 2].sum())})
        for k in range(pairs_per_block)
    ]
    return BlockRecord("kitti_000139", 0, K, frames, pairs)


def scene139_odometry_tree(shared_data: Path, root: Path) -> Path:
    """``root/sequences/139``: the scene's two colour frames as ``image_2/00000{0,1}.png``, its published
    disparities as ``disp_2/`` (frame 1 gets ``disp_1``, the t+1 disparity of frame 0's pixels — a stand-in,
    not a true frame-11 map) and ``calib.txt`` (P0, P2 of the 2011_09_26 raw calibration). Returns ``root``;
    an existing sequence folder is left as it is."""
    from pipeline.kitti.calib import read_raw_cam_to_cam, write_odometry_calib

    sf = Path(shared_data) / "kitti_sceneflow2015_000139"
    seq = Path(root) / "sequences" / "139"
    if seq.exists():
        return Path(root)
    raw = read_raw_cam_to_cam(Path(shared_data) / "kitti_raw_calib_2011_09_26/2011_09_26_calib/2011_09_26/"
                              "calib_cam_to_cam.txt")
    (seq / "image_2").mkdir(parents=True)
    (seq / "disp_2").mkdir()
    for k, frame in enumerate(("10", "11")):
        shutil.copy(sf / f"kitti_img/image_2/000139_{frame}.png", seq / f"image_2/{k:06d}.png")
    shutil.copy(sf / "results/disp_0/000139_10.png", seq / "disp_2/000000.png")
    shutil.copy(sf / "results/disp_1/000139_10.png", seq / "disp_2/000001.png")
    write_odometry_calib(seq / "calib.txt", {"P0": raw.P_rect["00"], "P2": raw.P_rect["02"]})
    return Path(root)
