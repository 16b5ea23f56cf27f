"""benchmarks/learning_curve.py: which settings a curve's ``--set`` list applies to."""

from dataclasses import asdict

import pytest

from benchmarks.learning_curve import demo_train_config
from training.presets import demo_train_config as preset


def test_start_demo_is_the_preset_plus_the_set_list():
    got = demo_train_config("c", "r", seed=3, overrides={"loss.plane_where_held": True}, start="demo")
    want = preset("c", "r", 1, 2048, 0.5, 3, {"data.workers": 0, "progress": False})
    assert got.loss.plane_where_held and not want.loss.plane_where_held
    got.loss.plane_where_held = False
    assert asdict(got) == asdict(want)


def test_start_paper_switches_the_departures_off():
    cfg = demo_train_config("c", "r", start="paper")
    assert not cfg.model.ego_head and cfg.loss.flow_smooth == 0.0 and cfg.data.lidar_rings == 0.0
    assert not cfg.model.eval_anchor and cfg.model.rigid_vote_yaw_deg == 0.0
    assert preset("c", "r").model.ego_head  # the preset has them on, so the two starts differ


def test_an_unknown_start_is_refused():
    with pytest.raises(ValueError, match="'paper' or 'demo'"):
        demo_train_config("c", "r", start="kitti")
