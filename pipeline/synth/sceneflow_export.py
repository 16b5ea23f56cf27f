"""The scene-flow test split, in the two layouts the community's KITTI test sets use.

* FlowNet3D ``kitti_rm_ground``: ``flownet3d/XXXXXX.npz`` with ``pos1``, ``pos2``, ``gt`` (N, 3) in
  LiDAR-like axes (:data:`core.axes.LIDAR`: stored (x, y, z) = (cam_z, −cam_x, −cam_y)), ground
  removed, camera z < 35 m; ``pos2`` is the next scan (camera-(t+1) frame), not pos1 moved.
* HPLFlowNet ``KITTI_processed_occ_final``: ``hplflownet/XXXXXX/pc1.npy``, ``pc2.npy`` in axes
  (−cam_x, −cam_y, cam_z) (:data:`core.axes.HPLFLOWNET`), ``pc2 = pc1 + flow`` point to point;
  ground kept (its reader drops stored y < −1.4 and keeps z < 35).

Both come from the LiDAR scan at t, restricted to points that project into image_2 at t; the flow is
the generator's ground truth (camera-(t+1) position minus camera-t position, metres). Each pc1 point
also carries ``moving`` (bool), ``classes`` (int32: 0 background, 1 car — parked or moving, the
three-way EPE's foreground) and ``instance`` (int32: the world object's index, −1 for none).
Each layout's axes are :data:`core.axes.FORMAT_AXES`, the table the evaluation readers use too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.axes import FORMAT_AXES
from pipeline.filters import FAR_LIMIT_M
from pipeline.synth.writer import frame_name, save_npy, save_npz

CLASS_CODES = {"background": 0, "car": 1}
FOREGROUND_CATEGORIES = {"parked_car": CLASS_CODES["car"], "moving_car": CLASS_CODES["car"]}


def object_classes(categories: list[str], obj: np.ndarray) -> np.ndarray:
    """Class code (:data:`CLASS_CODES`) of each point from its object index ``obj`` (−1: background)."""
    codes = np.array([FOREGROUND_CATEGORIES.get(c, 0) for c in categories] + [0], dtype=np.int32)
    return codes[obj]


@dataclass
class ScanGT:
    """A scan's returns inside image_2's field of view at t, camera-t frame (metres).

    ``flow`` (N, 3) is None for a sequence's last frame (no t+1); ``ground``: road, kerb or pavement;
    ``classes`` (N,) int32 (:data:`CLASS_CODES`) and ``instance`` (N,) int32 object index (−1: none).
    """

    points: np.ndarray
    flow: np.ndarray | None
    moving: np.ndarray
    ground: np.ndarray
    classes: np.ndarray | None = None
    instance: np.ndarray | None = None


def write_pair(root: Path, index: int, scan_t: ScanGT, scan_t1: ScanGT) -> tuple[int, int]:
    """Write pair ``index`` (t → t+1) in both layouts; return (FlowNet3D N1, HPLFlowNet N)."""
    name = frame_name(index)
    keep1 = ~scan_t.ground & (scan_t.points[:, 2] < FAR_LIMIT_M)
    keep2 = ~scan_t1.ground & (scan_t1.points[:, 2] < FAR_LIMIT_M)
    labels = {k: getattr(scan_t, k).astype(np.int32) for k in ("classes", "instance") if getattr(scan_t, k) is not None}
    fn3d = FORMAT_AXES["flownet3d"]
    save_npz(
        root / "flownet3d" / f"{name}.npz",
        pos1=fn3d.from_camera(scan_t.points[keep1]).astype(np.float32),
        pos2=fn3d.from_camera(scan_t1.points[keep2]).astype(np.float32),
        gt=fn3d.from_camera(scan_t.flow[keep1]).astype(np.float32),
        moving=scan_t.moving[keep1],
        **{k: v[keep1] for k, v in labels.items()},
    )
    hpl = FORMAT_AXES["hplflownet"]
    pc1 = hpl.from_camera(scan_t.points)
    pc2 = hpl.from_camera(scan_t.points + scan_t.flow)
    d = root / "hplflownet" / name
    save_npy(d / "pc1.npy", pc1.astype(np.float32))
    save_npy(d / "pc2.npy", pc2.astype(np.float32))
    save_npy(d / "moving.npy", scan_t.moving)
    for k, v in labels.items():
        save_npy(d / f"{k}.npy", v)
    return int(keep1.sum()), len(pc1)


README = """Scene-flow test split of the monoflow synthetic world (sequence {seq}, {pairs} pairs t -> t+1).

Source: the simulated HDL-64E scan at frame t (sequences/{seq}/velodyne), restricted to the points
that project inside image_2 at t. Ground truth flow = position of the same surface point at t+1 in
camera-(t+1) coordinates minus its position in camera-t coordinates (metres), i.e. it includes the
ego-motion, as KITTI scene flow does. Camera = image_2 (x right, y down, z forward).

flownet3d/XXXXXX.npz   (as FlowNet3D's kitti_rm_ground)
  pos1 (N1,3) float32, gt (N1,3) float32, pos2 (N2,3) float32, moving (N1,) bool,
  classes (N1,) int32, instance (N1,) int32
  axes: stored (x, y, z) = (cam_z, -cam_x, -cam_y)  <=>  camera (x, y, z) = (-y, -z, x)
  ground (road, kerb, pavement) removed using the generator's labels; camera z < {max_z} m.
  pos2 = the scan at t+1 (camera-(t+1) frame, same filters), NOT pos1 + gt.

hplflownet/XXXXXX/pc1.npy, pc2.npy, moving.npy, classes.npy, instance.npy
  (as HPLFlowNet's KITTI_processed_occ_final, plus the labels)
  pc1 (N,3) float32, pc2 = pc1 + flow (point to point), moving (N,) bool, classes/instance (N,) int32
  axes: stored (x, y, z) = (-cam_x, -cam_y, cam_z)
  ground NOT removed and no depth limit: the reader removes stored y < -1.4 (both clouds) and
  keeps z < {max_z}.

moving = the point lies on an independently moving car.
classes = 0 background, 1 car (parked or moving): the foreground of the three-way EPE.
instance = index of the world object the point lies on (-1: none).
"""


def write_readme(root: Path, seq: str, pairs: int) -> None:
    root.mkdir(parents=True, exist_ok=True)
    (root / "README.txt").write_text(README.format(seq=seq, pairs=pairs, max_z=FAR_LIMIT_M), encoding="utf-8")
