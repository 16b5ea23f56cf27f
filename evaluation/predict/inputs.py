"""What ``monoflow-predict`` reads: a KITTI-odometry sequence folder, a plain folder of images, or a video.

Every input is turned into a KITTI-odometry tree (``root/sequences/<name>/image_2/000000.png``,
``calib.txt``, optionally ``root/poses/<name>.txt``) so that stage one's own readers, depth and pose
sources, scale recovery and filters run on it unchanged (:class:`pipeline.preprocess.BlockProcessor`):

* a KITTI sequence folder (``.../sequences/NN`` with ``calib.txt`` and the camera folder) is used in place;
* a plain image folder is linked frame by frame (sorted by name) into ``<work>/kitti``;
* a video is decoded with OpenCV into ``<work>/kitti`` once (a marker file says when decoding finished,
  so an interrupted decode starts again and a finished one is reused).

Intrinsics (native pixels): ``fx,fy,cx,cy``, or a calibration file — a KITTI ``calib.txt`` /
object-benchmark calib (the camera's ``P``, else ``P2``, else ``P0``), or a text file holding a 3×3 K or a
3×4 P. A KITTI sequence folder brings its own ``calib.txt``.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import ConfigError, InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v")
DONE_MARKER = ".decoded"


@dataclass
class PreparedInput:
    """A KITTI-odometry tree stage one can read: ``root``, sequence id ``sequence``, camera folder ``camera``.

    kind: "kitti" | "images" | "video"; sources: original file of each frame id, in order (images/videos:
    the frame id is the position).
    """

    root: Path
    sequence: str
    camera: str
    kind: str
    sources: list[str]


def parse_intrinsics(text: str, camera: str = "image_2") -> np.ndarray:
    """(3, 3) float64 K from ``"fx,fy,cx,cy"`` (native pixels) or from a calibration file (module docstring)."""
    text = text.strip()
    numbers = re.fullmatch(r"\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*", text)
    if numbers:
        try:
            fx, fy, cx, cy = (float(x) for x in numbers.groups())
        except ValueError:
            raise ConfigError(f"intrinsics must be fx,fy,cx,cy in pixels, got {text!r}") from None
        if fx <= 0 or fy <= 0:
            raise ConfigError(f"intrinsics: focal lengths must be positive pixels, got fx={fx}, fy={fy}")
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    path = Path(text)
    if not path.is_file():
        raise InputError(path, "intrinsics file not found (give fx,fy,cx,cy or a calibration file)")
    rows = []
    for line in path.read_text(errors="replace").splitlines():
        line = line.split("#")[0].strip()
        if not line:
            continue
        body = line.split(":", 1)[1] if ":" in line else line
        try:
            rows.append((line.split(":", 1)[0].strip() if ":" in line else None,
                         [float(x) for x in body.replace(",", " ").split()]))
        except ValueError:
            continue
    keyed = {k: v for k, v in rows if k is not None and len(v) == 12}
    want = "P" + camera[-1] if camera.startswith("image_") else "P2"
    for key in (want, "P2", "P_rect_02", "P0"):
        if key in keyed:
            return np.asarray(keyed[key], dtype=np.float64).reshape(3, 4)[:, :3].copy()
    flat = [x for k, v in rows if k is None for x in v]
    if len(flat) in (9, 12):
        M = np.asarray(flat, dtype=np.float64).reshape(3, -1)
        K = M[:, :3].copy()
        if K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], (0, 0, 1), atol=1e-6):
            return K
    raise InputError(path, f"no intrinsics found: expected a '{want}:' / 'P2:' line of 12 numbers, or a 3x3 K "
                           "or 3x4 P matrix")


def _calib_text(K: np.ndarray) -> str:
    P = np.hstack([K, np.zeros((3, 1))])
    line = " ".join(f"{x:.12e}" for x in P.reshape(-1))
    return "".join(f"P{k}: {line}\n" for k in range(4))


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "sequence"


def default_name(source: str) -> str:
    """The sequence name of an input path: the folder's or video's name (KITTI: the sequence id)."""
    p = Path(source.rstrip("/"))
    return _safe_name(p.stem if p.is_file() else p.name)


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.symlink(src.resolve(), dst)
    except OSError:
        shutil.copyfile(src, dst)


def _write_tree_files(seq_dir: Path, K: np.ndarray, poses: str | None, root: Path, name: str) -> None:
    (seq_dir / "calib.txt").write_text(_calib_text(K))
    if poses:
        src = Path(poses)
        if not src.is_file():
            raise InputError(src, "poses file not found")
        (root / "poses").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, root / "poses" / f"{name}.txt")


def prepare_input(source: str, work: Path, name: str, camera: str = "image_2", intrinsics: str = "",
                  poses: str = "", max_frames: int = 0, stride: int = 1) -> PreparedInput:
    """Turn ``source`` into a KITTI-odometry tree (module docstring); ``work`` holds what must be written.

    ``max_frames`` > 0 keeps the first that many frames (after ``stride``, which keeps every stride-th frame of
    an image folder or video). Bad input → :class:`InputError` naming the file.
    """
    src = Path(source)
    if not src.exists():
        raise InputError(src, "input not found (a KITTI sequence folder, a folder of images or a video file)")
    if stride < 1:
        raise ConfigError(f"stride must be >= 1, got {stride}")
    if src.is_dir() and (src / "calib.txt").is_file() and (src / camera).is_dir():
        return _kitti_input(src, work, name, camera, intrinsics, poses, max_frames, stride)
    if src.is_dir():
        return _image_folder(src, work, name, intrinsics, poses, max_frames, stride)
    if src.suffix.lower() in VIDEO_SUFFIXES or src.is_file():
        return _video(src, work, name, intrinsics, poses, max_frames, stride)
    raise InputError(src, "not a folder or a video file")


def _needs_k(intrinsics: str, what: Path) -> np.ndarray:
    if not intrinsics:
        raise ConfigError(f"{what}: give the camera's intrinsics with --intrinsics fx,fy,cx,cy (native pixels) "
                          "or --intrinsics CALIB_FILE")
    return parse_intrinsics(intrinsics)


def _kitti_input(src: Path, work: Path, name: str, camera: str, intrinsics: str, poses: str, max_frames: int,
                 stride: int) -> PreparedInput:
    in_layout = src.parent.name == "sequences" and not intrinsics and not poses and not max_frames and stride == 1
    if in_layout:
        frames = sorted(p for p in (src / camera).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        return PreparedInput(src.parent.parent, src.name, camera, "kitti", [str(p) for p in frames])
    # a sequence folder outside the layout, or a subset: link its frames (same ids) into the work tree
    root = work / "kitti"
    seq_dir = root / "sequences" / name
    img_dir = seq_dir / camera
    if img_dir.exists():
        shutil.rmtree(img_dir)
    img_dir.mkdir(parents=True)
    frames = sorted(p for p in (src / camera).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.stem.isdigit())
    frames = frames[::stride]
    if max_frames:
        frames = frames[:max_frames]
    if stride > 1:  # renumber so that kept frames stay consecutive pairs
        for k, f in enumerate(frames):
            _link_or_copy(f, img_dir / f"{k:06d}{f.suffix.lower()}")
    else:
        for f in frames:
            _link_or_copy(f, img_dir / f.name)
    if stride == 1:  # dataset depth, LiDAR, disparity, ground truth: the same frame ids, linked whole
        for extra in src.iterdir():
            target = seq_dir / extra.name
            if extra.name in (camera, "calib.txt") or target.exists() or target.is_symlink():
                continue
            os.symlink(extra.resolve(), target)
    if intrinsics:
        (seq_dir / "calib.txt").write_text(_calib_text(parse_intrinsics(intrinsics, camera)))
    else:
        shutil.copyfile(src / "calib.txt", seq_dir / "calib.txt")
    layout_poses = src.parent.parent / "poses" / f"{src.name}.txt"
    pose_file = poses or (str(layout_poses) if layout_poses.is_file() and stride == 1 else "")
    if pose_file:
        (root / "poses").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(pose_file, root / "poses" / f"{name}.txt")
    return PreparedInput(root, name, camera, "kitti", [str(p) for p in frames])


def _image_folder(src: Path, work: Path, name: str, intrinsics: str, poses: str, max_frames: int,
                  stride: int) -> PreparedInput:
    frames = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not frames:
        raise InputError(src, f"no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    frames = frames[::stride]
    if max_frames:
        frames = frames[:max_frames]
    if len(frames) < 2:
        raise InputError(src, "needs at least two frames")
    K = _needs_k(intrinsics, src)
    root = work / "kitti"
    seq_dir = root / "sequences" / name
    img_dir = seq_dir / "image_2"
    if img_dir.exists():
        shutil.rmtree(img_dir)
    img_dir.mkdir(parents=True)
    for k, f in enumerate(frames):
        _link_or_copy(f, img_dir / f"{k:06d}{f.suffix.lower()}")
    _write_tree_files(seq_dir, K, poses, root, name)
    return PreparedInput(root, name, "image_2", "images", [str(p) for p in frames])


def _video(src: Path, work: Path, name: str, intrinsics: str, poses: str, max_frames: int,
           stride: int) -> PreparedInput:
    import cv2

    K = _needs_k(intrinsics, src)
    root = work / "kitti"
    seq_dir = root / "sequences" / name
    img_dir = seq_dir / "image_2"
    marker = seq_dir / DONE_MARKER
    wanted = f"{src.resolve()} {src.stat().st_size} stride={stride} max={max_frames}"
    if not (marker.is_file() and marker.read_text() == wanted):
        if img_dir.exists():
            shutil.rmtree(img_dir)
        img_dir.mkdir(parents=True)
        marker.unlink(missing_ok=True)
        cap = cv2.VideoCapture(str(src))
        if not cap.isOpened():
            raise InputError(src, "OpenCV cannot open this file as a video")
        kept = read = 0
        try:
            while True:
                ok, bgr = cap.read()
                if not ok:
                    break
                if read % stride == 0:
                    cv2.imwrite(str(img_dir / f"{kept:06d}.png"), bgr)
                    kept += 1
                read += 1
                if max_frames and kept >= max_frames:
                    break
        finally:
            cap.release()
        if kept < 2:
            raise InputError(src, f"decoded {kept} frames; at least two are needed")
        marker.write_text(wanted)
    _write_tree_files(seq_dir, K, poses, root, name)
    frames = sorted(img_dir.glob("*.png"))
    return PreparedInput(root, name, "image_2", "video", [f"{src}#{k}" for k in range(len(frames))])


__all__ = ["PreparedInput", "default_name", "parse_intrinsics", "prepare_input"]
