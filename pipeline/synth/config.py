"""Options of the synthetic driving world (:class:`SynthConfig`) and the version of its generator.

Every number that shapes the written world lives here, so that ``synth.json`` (the config, the seed and
:data:`SYNTH_VERSION`) identifies a world completely: the same file means byte-identical output.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from core.errors import ConfigError

#: Bumped whenever a change to the generator changes its output for the same config.
SYNTH_VERSION = "2"  # 2: mottled asphalt (textures.ground)

#: Native KITTI odometry image size (sequences 04-12) and intrinsics that K is scaled from.
KITTI_SIZE = (1226, 370)
KITTI_FX, KITTI_FY, KITTI_CX, KITTI_CY = 707.0912, 707.0912, 601.8873, 183.1104


@dataclass(frozen=True)
class SynthConfig:
    """The synthetic world's options. Lengths in metres, speeds in m/s, angles in degrees.

    The defaults suit a CPU demo: two 40-frame training sequences and one 20-frame test sequence of
    416×128 images. K is KITTI's (1226×370) scaled to ``width × height`` and its focal lengths multiplied
    by ``focal_scale``.
    """

    seed: int = 0
    width: int = 416
    height: int = 128
    focal_scale: float = 1.0
    n_sequences: int = 2  # training sequences 00 .. n-1; the test sequence comes after them
    frames: int = 40  # frames per training sequence
    test_frames: int = 20  # frames of the test sequence (0 = no test sequence)
    fps: float = 10.0
    parked_cars: int = 10
    moving_cars: int = 4
    crossing_cars: int = 0  # cars crossing the street on a side street ahead (pipeline.synth.world); 0 = none
    mover_speed_min: float = 3.0
    mover_speed_max: float = 12.0
    ego_speed_min: float = 8.0  # ≈ 0.8 m per frame at 10 Hz
    ego_speed_max: float = 12.0
    min_turn_radius: float = 250.0  # road curvature |κ| ≤ 1 / min_turn_radius
    camera_height: float = 1.65  # cam0 above the road
    ego_pitch_deg: float = 0.2  # amplitude of a slow pitch oscillation
    lidar_beams: int = 64
    lidar_elev_max_deg: float = 2.0
    lidar_elev_min_deg: float = -24.8
    lidar_azimuth_step_deg: float = 0.5
    test_lidar_azimuth_step_deg: float = 0.2  # denser scans for the test sequence (the scene-flow split)
    lidar_range: float = 120.0
    camera_range: float = 250.0  # surfaces beyond are sky (16-bit depth PNGs hold < 256 m)
    supersample: int = 1  # colour samples per pixel side (anti-aliasing); depth and flow use pixel centres
    variety: float = 0.0  # 0..1: each training sequence draws its own camera, driving and traffic (synth.variety)
    ego_stop: bool = False  # the ego car brakes to a near stop mid-sequence and pulls away again
    # which sequences get Velodyne scans: "all" (KITTI's odometry layout) or "test" (the test sequence alone,
    # whose scans make the scene-flow split: a world for runs that read only the cameras of the training
    # sequences, such as stage one from ground-truth depth; the scans are nearly half of a frame's rendering)
    lidar_scans: str = "all"

    def validate(self) -> "SynthConfig":
        """Raise :class:`ConfigError` for options that make no sense; return self."""
        if not 0 <= self.seed < 2**63:
            raise ConfigError(f"seed must be a non-negative integer below 2**63, got {self.seed}")
        if self.width < 16 or self.height < 16:
            raise ConfigError(f"image size {self.width}x{self.height} is too small (min 16x16)")
        if self.n_sequences < 0 or self.frames < 2 and self.n_sequences > 0:
            raise ConfigError("need n_sequences >= 0 and frames >= 2")
        if self.test_frames == 1 or self.test_frames < 0:
            raise ConfigError("test_frames must be 0 or >= 2")
        if self.n_sequences == 0 and self.test_frames == 0:
            raise ConfigError("nothing to generate: no training sequence and no test sequence")
        if self.n_sequences + (1 if self.test_frames else 0) > 100:
            raise ConfigError("at most 100 sequences (two-digit names)")
        if not (0 < self.mover_speed_min <= self.mover_speed_max):
            raise ConfigError("need 0 < mover_speed_min <= mover_speed_max")
        if not (0 < self.ego_speed_min <= self.ego_speed_max):
            raise ConfigError("need 0 < ego_speed_min <= ego_speed_max")
        if self.parked_cars < 0 or self.moving_cars < 0 or self.crossing_cars < 0:
            raise ConfigError("car counts must be >= 0")
        if self.lidar_azimuth_step_deg <= 0 or self.test_lidar_azimuth_step_deg <= 0 or self.lidar_beams < 1:
            raise ConfigError("LiDAR azimuth steps must be > 0 and lidar_beams >= 1")
        if self.camera_range >= 256.0 or self.camera_range <= 0:
            raise ConfigError("camera_range must lie in (0, 256) m (16-bit depth PNG)")
        if not 0.0 <= self.variety <= 1.0:
            raise ConfigError(f"variety must lie in [0, 1], got {self.variety}")
        if self.lidar_scans not in ("all", "test"):
            raise ConfigError(f"lidar_scans must be 'all' or 'test', got {self.lidar_scans!r}")
        if self.supersample < 1 or self.focal_scale <= 0 or self.fps <= 0 or self.min_turn_radius < 50:
            raise ConfigError("need supersample >= 1, focal_scale > 0, fps > 0, min_turn_radius >= 50")
        return self

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "SynthConfig":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ConfigError(f"unknown synth option(s): {sorted(unknown)}")
        return cls(**d)

    def sequence_names(self) -> list[tuple[str, int, str]]:
        """(name, frames, split) of every sequence: training ones first, then the test sequence."""
        out = [(f"{i:02d}", self.frames, "train") for i in range(self.n_sequences)]
        if self.test_frames:
            out.append((f"{self.n_sequences:02d}", self.test_frames, "test"))
        return out
