"""Per-sequence variety of the synthetic world and the shifted test world (pipeline/synth/variety.py)."""

from __future__ import annotations

import json

from pipeline.synth.config import SynthConfig
from pipeline.synth.variety import sequence_config, shifted_test_config


def test_variety_zero_and_the_test_sequence_keep_the_config():
    cfg = SynthConfig(seed=3)
    assert all(sequence_config(cfg, i, "train") is cfg for i in range(3))
    varied = SynthConfig(seed=3, variety=1.0)
    assert sequence_config(varied, 2, "test") is varied


def test_varied_sequences_differ_stay_in_range_and_are_deterministic():
    cfg = SynthConfig(seed=7, variety=1.0, n_sequences=8)
    seqs = [sequence_config(cfg, i, "train") for i in range(8)]
    assert seqs == [sequence_config(cfg, i, "train") for i in range(8)]
    assert len({(s.width, s.height, s.focal_scale) for s in seqs}) == 8
    for s in seqs:
        s.validate()
        assert 0.75 <= s.focal_scale <= 1.25 and 1.4 <= s.camera_height <= 1.9
        assert 0.85 * 416 - 2 <= s.width <= 1.15 * 416 + 2 and s.moving_cars >= 1 and s.min_turn_radius >= 60
        assert s.variety == 0.0


def test_crossing_cars_are_varied_last_and_change_nothing_else():
    from dataclasses import replace

    plain = SynthConfig(seed=7, variety=1.0, n_sequences=8)
    crossing = replace(plain, crossing_cars=2)
    counts = []
    for i in range(8):
        a, b = sequence_config(plain, i, "train"), sequence_config(crossing, i, "train")
        assert a.crossing_cars == 0 and replace(b, crossing_cars=0) == a  # the rest of the draw is the same
        counts.append(b.crossing_cars)
    assert min(counts) >= 0 and max(counts) <= 4 and len(set(counts)) > 1  # 2 x U(0.25, 2), rounded
    assert sequence_config(crossing, 8, "test").crossing_cars == 2  # the test sequence keeps the config's


def test_shifted_world_lies_outside_the_training_ranges():
    s = shifted_test_config()
    assert s.n_sequences == 0 and s.test_frames == 20
    assert s.focal_scale < 0.75 and s.camera_height > 1.9 and s.width > 1.15 * 416 + 2
    assert s.mover_speed_max > 16 and s.test_lidar_azimuth_step_deg != SynthConfig().test_lidar_azimuth_step_deg


def test_a_varied_world_records_each_sequence_camera(tmp_path):
    from pipeline.kitti.calib import read_odometry_calib
    from pipeline.synth.generator import generate

    cfg = SynthConfig(seed=1, width=96, height=32, n_sequences=2, frames=3, test_frames=0, variety=1.0,
                      moving_cars=1, parked_cars=1)
    generate(cfg, tmp_path / "w")
    meta = json.loads((tmp_path / "w" / "synth.json").read_text())
    ks = [meta["sequences"][n]["K"] for n in ("00", "01")]
    assert ks[0] != ks[1]
    for name, K in zip(("00", "01"), ks):
        calib = read_odometry_calib(tmp_path / "w" / "sequences" / name / "calib.txt")
        assert abs(calib.P["P2"][0, 0] - K[0][0]) < 1e-6
        w, h = meta["sequences"][name]["image_size"]
        assert (w, h) != (96, 32)
