"""Stage one's options (:class:`PreprocessConfig`) and their validation.

The field docs are the ``monoflow-preprocess`` help; :meth:`PreprocessConfig.validate` turns options that make
no sense into one :class:`~core.errors.ConfigError` / :class:`~core.errors.InputError` line before
anything is read or written.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from core.errors import ConfigError, InputError
from pipeline.filters import FilterConfig
from pipeline.scale import ScaleConfig
from pipeline.sources import DEPTH_SOURCES, POSE_SOURCES

@dataclass
class PreprocessConfig:
    """Stage one's options (``monoflow-preprocess`` flags / ``--config`` TOML keys)."""

    root: str = field(default="", metadata={"help": "dataset root in the KITTI odometry layout (root/sequences/NN/)"})
    dataset: str = field(
        default="", metadata={"help": "name of the dataset folder in the cache; empty = the root folder's name"}
    )
    sequences: tuple[str, ...] = field(
        default=(), metadata={"help": "comma-separated sequence ids; empty = every sequence"}
    )
    camera: str = field(default="image_2", metadata={"help": "camera folder (image_2 = left colour)"})
    strict_pose_count: bool = field(
        default=True,
        metadata={"help": "a complete sequence's poses file must have exactly one line per image; false = "
                          "only a line for every frame id (e.g. frames 0..50 beside the full 1,101-line 06.txt)"},
    )
    depth: str = field(default="net", metadata={"help": f"depth source: {' | '.join(DEPTH_SOURCES)}"})
    pose: str = field(default="net", metadata={"help": f"pose source: {' | '.join(POSE_SOURCES)} (gt = dataset poses)"})
    depth_checkpoint: str | None = field(default=None, metadata={"help": "DispResNet checkpoint (.pth.tar)"})
    pose_checkpoint: str | None = field(default=None, metadata={"help": "PoseResNet checkpoint (.pth.tar)"})
    resnet_layers: int = field(default=18, metadata={"help": "ResNet depth of randomly initialised nets"})
    random_init: bool = field(default=False, metadata={"help": "seeded random nets when no checkpoint (tests)"})
    seed: int = field(default=0, metadata={"help": "seed of random_init nets"})
    disparity_dir: str | None = field(
        default=None,
        metadata={"help": "depth=disparity: folder of <frame>.png, {seq} replaced by the sequence; "
                          "none = sequences/NN/disp_2"},
    )
    disparity_focal: float | None = field(
        default=None, metadata={"help": "depth=disparity: focal length, native pixels; none = the camera's fx"}
    )
    disparity_baseline: float = field(default=0.54, metadata={"help": "depth=disparity: stereo baseline, metres"})
    size: str = field(default="832x256", metadata={"help": "working size WxH, or 'native'"})
    filters: FilterConfig = field(default_factory=FilterConfig)
    scale: ScaleConfig = field(default_factory=ScaleConfig)
    block_size: int = field(default=16, metadata={"help": "pairs per block (the unit of work and storage)"})
    device: str = field(default="auto", metadata={"help": "auto | cpu | cuda[:i]"})
    amp: bool = field(default=False, metadata={"help": "mixed-precision inference"})
    batch_size: int = field(default=8, metadata={"help": "frames per net forward pass"})
    workers: int = field(default=1, metadata={"help": "blocks processed in parallel (spawned processes)"})
    shard: str = field(default="0/1", metadata={"help": "'i/n': process the blocks b with b mod n == i"})
    out: str = field(default="cache", metadata={"help": "output root (cache/<dataset>/<config-hash>/)"})
    progress: bool = field(default=True, metadata={"help": "tqdm progress bar per block"})

    # ------------------------------------------------------------------ derived values

    def working_size(self) -> tuple[int, int] | None:
        """(W, H) or None for the native size."""
        text = self.size.strip().lower()
        if text == "native":
            return None
        m = re.fullmatch(r"(\d+)\s*[x×,]\s*(\d+)", text)
        if not m or int(m[1]) < 1 or int(m[2]) < 1:
            raise ConfigError(f"size must be WxH (e.g. 832x256) or 'native', got {self.size!r}")
        return int(m[1]), int(m[2])

    def shard_spec(self) -> tuple[int, int]:
        """(i, n) of ``shard = "i/n"``: this run takes the blocks whose global index b has ``b % n == i``."""
        m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", self.shard)
        if not m or int(m[2]) < 1 or int(m[1]) >= int(m[2]):
            raise ConfigError(f"shard must be 'i/n' with 0 <= i < n, got {self.shard!r}")
        return int(m[1]), int(m[2])

    def validate(self) -> "PreprocessConfig":
        """Raise ConfigError for options that make no sense; return self."""
        if not self.root:
            raise ConfigError("no dataset root given (--root)")
        if self.depth not in DEPTH_SOURCES:
            raise ConfigError(f"depth source must be one of {', '.join(DEPTH_SOURCES)}, got {self.depth!r}")
        if self.pose not in POSE_SOURCES:
            raise ConfigError(f"pose source must be one of {', '.join(POSE_SOURCES)}, got {self.pose!r}")
        if self.block_size < 1 or self.workers < 1 or self.batch_size < 1:
            raise ConfigError("block_size, workers and batch_size must be >= 1")
        self.working_size()
        self.shard_spec()
        self.filters.check()
        for kind in ("depth", "pose"):
            path = getattr(self, f"{kind}_checkpoint")
            if getattr(self, kind) != "net":
                continue
            if path and not Path(path).is_file():
                raise InputError(path, "checkpoint not found")
            if not path and not self.random_init:
                raise ConfigError(f"{kind} source 'net' needs --{kind}_checkpoint (or --random_init true for tests)")
        return self

    def net_spec(self):
        """The :class:`pipeline.sources.NetSpec` of the depth / pose nets these options ask for."""
        from pipeline.sources import NetSpec

        return NetSpec(
            depth_checkpoint=self.depth_checkpoint,
            pose_checkpoint=self.pose_checkpoint,
            need_depth=self.depth == "net",
            need_pose=self.pose == "net",
            random_init=self.random_init,
            seed=self.seed,
            resnet_layers=self.resnet_layers,
            device=self.device,
            amp=self.amp,
            batch_size=self.batch_size,
        )


__all__ = ["PreprocessConfig"]
