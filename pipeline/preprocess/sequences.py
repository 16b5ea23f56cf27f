"""Opening the configured sequences, refusing ones stage one cannot process (one line naming the file)."""

from __future__ import annotations

from pathlib import Path

from core.errors import InputError
from pipeline.preprocess.config import PreprocessConfig


def open_sequences(config: PreprocessConfig):
    """{sequence id: OdometrySequence} for the configured (or all) sequences."""
    from pipeline.kitti.odometry import OdometrySequence, find_sequences

    names = list(config.sequences) or find_sequences(config.root)
    if not names:
        raise InputError(Path(config.root) / "sequences", "no sequence folders with a calib.txt")
    need_poses = config.pose == "gt"
    out = {}
    for name in sorted(dict.fromkeys(names)):
        seq = OdometrySequence(config.root, name, config.camera, strict_pose_count=config.strict_pose_count)
        gaps = [f for f in range(seq.frames[0], seq.frames[-1] + 1) if f not in set(seq.frames)]
        if gaps:
            suffix = seq.image_path(0).suffix
            raise InputError(seq.image_dir / f"{gaps[0]:06d}{suffix}",
                             f"missing: the sequence has frames {seq.frames[0]}..{seq.frames[-1]} "
                             f"but {len(gaps)} of them are absent")
        if need_poses and not seq.has_poses:
            raise InputError(seq.poses_path, "poses file not found (pose source 'gt' needs the dataset's poses)")
        if config.sequences and len(seq.frames) < 2:  # asked for by name: refuse rather than drop it silently
            raise InputError(seq.image_dir, f"sequence {name} has {len(seq.frames)} frame(s); a frame pair needs 2")
        out[seq.sequence] = seq
    return out


__all__ = ["open_sequences"]
