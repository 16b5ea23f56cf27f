"""Options of ``monoflow-predict`` (flags ``--field`` / ``--section.field`` and ``--config FILE.toml`` keys)."""

from __future__ import annotations

from dataclasses import dataclass, field

from core.errors import ConfigError
from pipeline.filters import FilterConfig
from pipeline.scale import ScaleConfig
from pipeline.sources import DEPTH_SOURCES, POSE_SOURCES

#: Default moving-point threshold: a point moves when its residual ("dynamic") flow is longer than this,
#: in metres per frame pair (0.3 m between KITTI frames at 10 Hz is 3 m/s ≈ 11 km/h).
MOVING_THRESHOLD_M = 0.3


@dataclass
class PredictConfig:
    """What ``monoflow-predict`` reads, which nets it runs and what it writes."""

    input: str = field(default="", metadata={
        "help": "a KITTI-odometry sequence folder (sequences/NN with calib.txt and the camera folder), a folder of "
                "images (sorted by name) or a video file (decoded with OpenCV)"})
    name: str = field(default="", metadata={"help": "sequence name of the outputs; empty = the input's name"})
    camera: str = field(default="image_2", metadata={"help": "KITTI input: camera folder (image_0 = grey left)"})
    intrinsics: str = field(default="", metadata={
        "help": "camera intrinsics in native pixels: 'fx,fy,cx,cy' or a calibration file (KITTI calib.txt, "
                "object calib, or a 3x3 K / 3x4 P text file); KITTI inputs default to their calib.txt"})
    poses: str = field(default="", metadata={
        "help": "KITTI-format poses file (one 3x4 camera-to-world row per frame, metres) for --pose gt; KITTI "
                "inputs default to root/poses/NN.txt"})
    max_frames: int = field(default=0, metadata={"help": "use only the first N frames (0 = all)"})
    stride: int = field(default=1, metadata={"help": "image folder / video: keep every stride-th frame"})
    depth: str = field(default="net", metadata={"help": f"depth source: {' | '.join(DEPTH_SOURCES)} (as stage one)"})
    pose: str = field(default="net", metadata={"help": f"pose source: {' | '.join(POSE_SOURCES)} (gt = poses file)"})
    depth_checkpoint: str | None = field(default=None, metadata={
        "help": "DispResNet checkpoint (.pth.tar; monoflow-train-depth writes dispnet_model_best.pth.tar)"})
    pose_checkpoint: str | None = field(default=None, metadata={
        "help": "PoseResNet checkpoint (.pth.tar; monoflow-train-depth writes exp_pose_model_best.pth.tar)"})
    random_init: bool = field(default=False, metadata={"help": "seeded random depth/pose nets (tests only)"})
    resnet_layers: int = field(default=18, metadata={"help": "ResNet depth of randomly initialised nets"})
    strict_pose_count: bool = field(default=False, metadata={
        "help": "require exactly one pose line per image of a complete sequence (false: a line per frame id)"})
    size: str = field(default="832x256", metadata={"help": "working size WxH in pixels, or 'native'"})
    filters: FilterConfig = field(default_factory=FilterConfig)
    scale: ScaleConfig = field(default_factory=lambda: ScaleConfig(mode="camera-height"))
    block_size: int = field(default=16, metadata={"help": "pairs whose depth and pose are computed together"})
    checkpoint: str = field(default="", metadata={"help": "scene-flow net checkpoint written by monoflow-train"})
    n_points: int = field(default=0, metadata={
        "help": "points sampled per cloud for the flow net (0 = the net's own n_points); the flow is spread to "
                "every point of the cloud by 3-NN interpolation, as monoflow-evaluate's full protocol"})
    sample_seed: int = field(default=0, metadata={
        "help": "sampling seed (with the pair's name, as monoflow-evaluate's --seeds)"})
    flow_batch: int = field(default=4, metadata={"help": "pairs per flow-net forward pass"})
    rigid_polish: bool = field(default=False, metadata={
        "help": "sharpen the net's flow by the rigid polish: its ego-motion and each mover's motion registered "
                "by robust ICP started from it (evaluation/rigid_polish.py; monoflow-evaluate's '+ rigid polish' "
                "row)"})
    moving_threshold: float = field(default=MOVING_THRESHOLD_M, metadata={
        "help": "metres per frame pair: a point is 'moving' when |flow - static flow| exceeds this"})
    device: str = field(default="auto", metadata={"help": "auto | cpu | cuda[:i] (auto = the GPU when there is one)"})
    batch_size: int = field(default=8, metadata={"help": "frames per depth/pose net forward pass"})
    out: str = field(default="predictions", metadata={
        "help": "output folder: <name>.h5, <name>.parts/ (resume state), <name>-ply/, <name>-pictures/"})
    ply: bool = field(default=False, metadata={"help": "also write <name>-ply/<pair>.ply (pc1 coloured, and its flow)"})
    pictures: bool = field(default=False, metadata={
        "help": "also draw <name>-pictures/<pair>.png (needs the 'plots' extra: pip install 'monoflow[plots]')"})
    picture_every: int = field(default=1, metadata={"help": "draw every N-th pair only"})
    overwrite: bool = field(default=False, metadata={
        "help": "start again, discarding finished pairs (default: resume, skipping pairs already done)"})
    keep_parts: bool = field(default=False, metadata={"help": "keep <name>.parts/ after the HDF5 file is written"})
    progress: bool = field(default=True, metadata={"help": "progress bar over pairs"})

    def validate(self) -> "PredictConfig":
        """ConfigError for options that make no sense; returns self."""
        if not self.input:
            raise ConfigError("no input given (--input: KITTI sequence folder, image folder or video)")
        if not self.checkpoint:
            raise ConfigError("no scene-flow checkpoint given (--checkpoint runs/<run>/best.pt or latest.pt)")
        if self.flow_batch < 1 or self.batch_size < 1 or self.block_size < 1 or self.picture_every < 1:
            raise ConfigError("flow_batch, batch_size, block_size and picture_every must be >= 1")
        if self.moving_threshold <= 0:
            raise ConfigError(f"moving_threshold must be positive metres, got {self.moving_threshold}")
        if self.n_points < 0 or self.max_frames < 0:
            raise ConfigError("n_points and max_frames must be >= 0")
        return self


__all__ = ["MOVING_THRESHOLD_M", "PredictConfig"]
