"""Per-sequence variety of the synthetic world (``SynthConfig.variety``).

A net trained on one street, one camera and one driving style learns that street. With ``variety`` > 0
every *training* sequence draws its own options around the world's config, seeded by (seed, sequence
index), so one world holds several cameras and driving styles:

* camera: focal lengths × U(1 − 0.25v, 1 + 0.25v), image width and height × U(1 − 0.15v, 1 + 0.15v)
  (rounded to even pixels), camera height 1.65 m ± 0.25v m, pitch oscillation up to 0.2 + 0.5v degrees;
* driving: ego speed range from U(2, 8) to U(10, 16) m/s (blended with the config's by v), a stop (the
  ego car brakes to ≈0.3 m/s and pulls away again) with probability 0.3v, turn radius down to 60 m;
* traffic: parked cars U(0.4, 1.8) × the config's, moving cars U(0.25, 2) × the config's (at least 1),
  mover speeds from U(1, 4) to U(8, 16) m/s; crossing cars U(0.25, 2) × the config's, rounded (drawn only when
  the config has some, so a world without them is the one it was before the option).

The test sequence keeps the config unchanged, so a world's scene-flow split does not move with
``variety`` and a net trained on a varied world is still scored on the config's own camera and street.
``variety = 0`` writes exactly the world it wrote before the option existed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.synth.config import SynthConfig


def _blend(base: float, drawn: float, v: float) -> float:
    return (1.0 - v) * base + v * drawn


def sequence_config(cfg: SynthConfig, index: int, split: str) -> SynthConfig:
    """The options sequence ``index`` (split ``"train"`` or ``"test"``) is drawn with."""
    v = float(cfg.variety)
    if v <= 0 or split != "train":
        return cfg
    rng = np.random.default_rng([int(cfg.seed) & 0xFFFFFFFF, int(cfg.seed) >> 32, index, 0x7A41E7])

    def scale(spread: float) -> float:
        return float(rng.uniform(1.0 - spread * v, 1.0 + spread * v))

    width = max(16, int(round(cfg.width * scale(0.15) / 2)) * 2)
    height = max(16, int(round(cfg.height * scale(0.15) / 2)) * 2)
    ego_lo = _blend(cfg.ego_speed_min, rng.uniform(2.0, 8.0), v)
    ego_hi = max(ego_lo, _blend(cfg.ego_speed_max, rng.uniform(10.0, 16.0), v))
    mov_lo = _blend(cfg.mover_speed_min, rng.uniform(1.0, 4.0), v)
    mov_hi = max(mov_lo, _blend(cfg.mover_speed_max, rng.uniform(8.0, 16.0), v))
    radius = max(60.0, _blend(cfg.min_turn_radius, rng.uniform(60.0, 300.0), v))
    drawn = replace(
        cfg,
        width=width,
        height=height,
        focal_scale=cfg.focal_scale * scale(0.25),
        camera_height=cfg.camera_height + float(rng.uniform(-0.25, 0.25)) * v,
        ego_pitch_deg=cfg.ego_pitch_deg + float(rng.uniform(0.0, 0.5)) * v,
        ego_speed_min=ego_lo,
        ego_speed_max=ego_hi,
        ego_stop=bool(rng.random() < 0.3 * v),
        min_turn_radius=radius,
        parked_cars=int(round(cfg.parked_cars * rng.uniform(0.4, 1.8))),
        moving_cars=max(1, int(round(cfg.moving_cars * rng.uniform(0.25, 2.0)))),
        mover_speed_min=mov_lo,
        mover_speed_max=mov_hi,
        variety=0.0,
    )
    if cfg.crossing_cars == 0:
        return drawn
    # drawn last, so a sequence's camera, driving and other traffic are those of the world without crossing cars
    return replace(drawn, crossing_cars=int(round(cfg.crossing_cars * rng.uniform(0.25, 2.0))))


def shifted_test_config(seed: int = 1000, **overrides) -> SynthConfig:
    """A test-only world configured outside the training world's range, for generalisation checks.

    It differs from the default config (and from everything ``variety = 1`` draws) in its camera (focal
    lengths × 0.72, 496×152 images, mounted 1.95 m high), its street (turns down to a 70 m radius), its
    traffic (9 moving cars at 4–18 m/s, 16 parked) and its LiDAR (0.16° azimuth steps, elevations
    +3° … −25°); it has no training sequences, only the 20-frame test sequence and its scene-flow split.
    """
    base = dict(seed=seed, n_sequences=0, test_frames=20, width=496, height=152, focal_scale=0.72,
                camera_height=1.95, min_turn_radius=70.0, moving_cars=9, parked_cars=16, mover_speed_min=4.0,
                mover_speed_max=18.0, ego_speed_min=11.0, ego_speed_max=15.0, test_lidar_azimuth_step_deg=0.16,
                lidar_elev_max_deg=3.0, lidar_elev_min_deg=-25.0)
    base.update(overrides)
    return SynthConfig(**base).validate()
