"""Building blocks of the synthetic world: road coordinates, ray-primitive hits with known answers,
culling that never loses a hit, deterministic noise, the world's layout and the rig's calibration."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core import geometry as g
from core.errors import ConfigError
from pipeline.synth import lidar
from pipeline.synth.config import SynthConfig
from pipeline.synth.noise import fbm2, hash_unit, noise2, noise3
from pipeline.synth.raycast import CameraRays, LidarRays, cast, hit_box, hit_cylinder, hit_sphere
from pipeline.synth.rig import make_rig
from pipeline.synth.road import ROAD_HALF_WIDTH, Road
from pipeline.synth.world import build_world


@pytest.mark.parametrize("curv", [0.0, 1 / 300.0, -1 / 250.0])
def test_road_coordinates_round_trip_and_lateral_surfaces(curv):
    road = Road(curv, -50.0, 200.0)
    s = np.array([-20.0, 0.0, 35.0, 120.0])
    l = np.array([-9.0, 1.6, 0.0, 12.6])
    x, z = road.point(s, l)
    s2, l2 = road.to_road(x, z)
    np.testing.assert_allclose(s2, s, atol=1e-9)
    np.testing.assert_allclose(l2, l, atol=1e-9)
    # the heading is the direction of increasing s; right() is perpendicular to it
    h = 1e-4
    x1, z1 = road.point(s + h, 0.0 * s)
    x0, z0 = road.point(s, 0.0 * s)
    np.testing.assert_allclose(np.arctan2((x1 - x0) / h, (z1 - z0) / h), road.heading(s), atol=1e-6)
    rx, rz = road.right(s)
    np.testing.assert_allclose(rx * (x1 - x0) + rz * (z1 - z0), 0.0, atol=1e-9)
    # a ray from the lane towards the right kerb meets the surface l = ROAD_HALF_WIDTH there
    xo, zo = road.point(10.0, 1.6)
    O = np.array([float(xo), -1.0, float(zo)])
    rx0, rz0 = road.right(10.0)
    D = np.array([[float(rx0), 0.0, float(rz0)]])
    ts = np.stack(road.lateral_hits(O, D.T, ROAD_HALF_WIDTH))
    t = np.nanmin(np.where(ts > 0, ts, np.nan))
    assert 6.9 < t < 7.2
    hit = O + t * D[0]
    np.testing.assert_allclose(road.to_road(hit[0], hit[2])[1], ROAD_HALF_WIDTH, atol=1e-9)


def test_primitive_hits_known_answers():
    O = np.zeros(3)
    D = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]).T  # (3, n)
    t = hit_box(O, D, [-1.0, -1.0, 4.0], [1.0, 1.0, 6.0])
    np.testing.assert_allclose(t, [4.0, 2.0, np.inf, np.inf])  # t scales with |D|
    t = hit_cylinder(O, D, 0.0, 10.0, 2.0, -5.0, 5.0)
    np.testing.assert_allclose(t, [8.0, 4.0, np.inf, np.inf])
    t = hit_cylinder(O, D, 0.0, 10.0, 2.0, -5.0, -1.0)  # below the ray's height: missed
    assert np.all(np.isinf(t))
    t = hit_sphere(O, D, [0.0, 0.0, -7.0], 3.0)
    np.testing.assert_allclose(t, [np.inf, np.inf, np.inf, 4.0])


class _AllRays:
    """A ray set without culling (every object tested on every ray), for comparison."""

    def __init__(self, rays):
        self.rays = rays
        self.origin, self.dirs, self.dirs_T = rays.origin, rays.dirs, rays.dirs_T

    def __len__(self):
        return len(self.rays)

    def candidates(self, corners):
        return None, 0.0


def test_culling_never_changes_a_hit():
    cfg = SynthConfig(width=96, height=32, lidar_azimuth_step_deg=2.0)
    w = build_world(cfg, 1, 6)
    rig = make_rig(cfg)
    for k in (0, 5):
        cam = CameraRays(rig.K, w.cam0_poses[k], grid=(np.arange(96.0), np.arange(32.0)))
        velo = LidarRays(lidar.beam_elevations(cfg), lidar.azimuths(cfg.lidar_azimuth_step_deg), w.cam0_poses[k] @ rig.T_velo_to_cam0)
        for rays, tmax in ((cam, 250.0), (velo, 120.0)):
            a = cast(w.objects, k, rays, w.road, tmax)
            b = cast(w.objects, k, _AllRays(rays), w.road, tmax)
            np.testing.assert_array_equal(a.obj, b.obj)
            np.testing.assert_array_equal(a.t, b.t)
            assert a.valid.mean() > 0.5


def test_noise_is_deterministic_bounded_smooth_and_seeded():
    x = np.linspace(-50, 50, 20001)
    y = 0.37 * x + 3.0
    n = noise2(x, y, 4)
    np.testing.assert_array_equal(n, noise2(x.copy(), y.copy(), 4))
    assert n.min() >= 0.0 and n.max() <= 1.0 and n.std() > 0.1
    assert np.abs(np.diff(n)).max() < 0.02  # continuous: steps of 5 mm change it little
    assert np.abs(noise2(x, y, 5) - n).mean() > 0.1
    assert 0.0 <= noise3(x, y, -x, 1).min() and noise3(x, y, -x, 1).max() <= 1.0
    f = fbm2(x, y, 3, 0.5, 6)
    assert 0.0 <= f.min() and f.max() <= 1.0
    # prefiltered: a footprint much larger than every wavelength leaves the mean
    np.testing.assert_allclose(fbm2(x, y, 3, 0.5, 6, fp=np.full_like(x, 100.0)), 0.5)
    np.testing.assert_allclose(fbm2(x, y, 3, 0.5, 6, fp=np.full_like(x, 1e-4)), f)
    h = hash_unit(7, np.arange(-5, 5))
    assert len(set(h.tolist())) == 10 and np.all((h >= 0) & (h < 1))


def test_world_layout_is_sane():
    cfg = SynthConfig(moving_cars=6, parked_cars=12)
    w = build_world(cfg, 0, 40)
    poses = w.cam0_poses
    assert poses.shape == (40, 4, 4)
    np.testing.assert_allclose(poses[:, 1, 3], -cfg.camera_height)  # camera 1.65 m above the road
    s, l = w.road.to_road(poses[:, 0, 3], poses[:, 2, 3])
    assert np.all((l > 0.5) & (l < 2.8))  # stays in its lane
    step = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert np.all((step > 0.7) & (step < 1.35))
    yaw_rate = np.degrees(np.abs(np.diff(np.arctan2(poses[:, 0, 2], poses[:, 2, 2]))))
    assert yaw_rate.max() < 2.0  # mild turns
    movers = w.movers
    assert len(movers) == 6 and sum(o.category == "parked_car" for o in w.objects) == 12
    for m in movers:  # moving along the road at their speed, wheels on the road
        d = np.linalg.norm(np.diff(m.poses[:, :3, 3], axis=0), axis=1)
        np.testing.assert_allclose(d, m.speed / cfg.fps, rtol=1e-3)
        np.testing.assert_allclose(m.poses[:, 1, 3], 0.0)
        assert cfg.mover_speed_min <= m.speed <= cfg.mover_speed_max
    # no two cars (and not the ego car) ever overlap: centres of cars in the same lane keep apart
    cars = [o for o in w.objects if o.category in ("parked_car", "moving_car")]
    centres = np.stack([np.stack([o.pose(k)[:3, 3] for k in range(40)]) for o in cars])  # (C, F, 3)
    ego = poses[:, :3, 3] + np.array([0.0, cfg.camera_height, 0.0])
    for k in range(40):
        c = np.concatenate([centres[:, k], ego[k:k + 1]])
        d = np.linalg.norm(c[:, None] - c[None], axis=-1) + np.eye(len(c)) * 99
        assert d.min() > 2.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_crossing_cars_drive_across_the_road_through_a_side_street_and_hit_nothing(seed: int):
    from pipeline.synth.world import SIDE_STREET_WIDTH

    cfg = SynthConfig(seed=seed, moving_cars=6, parked_cars=12, crossing_cars=3, min_turn_radius=60)
    w = build_world(cfg, 0, 40)
    crossing = [o for o in w.objects if o.name.startswith("crossing")]
    assert len(crossing) == 3 and all(o.moving and o.category == "moving_car" for o in crossing)
    s_lanes = []
    for m in crossing:  # at their speed, at right angles to the road, wheels on the road
        c = m.poses[:, :3, 3]
        d = np.diff(c, axis=0)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), m.speed / cfg.fps, rtol=2e-2)  # (an arc's chord)
        s, l = w.road.to_road(c[:, 0], c[:, 2])
        assert np.ptp(s) < 0.05 and np.ptp(l) > 0.9 * m.speed * 39 / cfg.fps  # along the side street alone
        heading = float(w.road.heading(s[0]))
        along = np.array([math.sin(heading), math.cos(heading)])  # the road's direction in (x, z)
        assert np.abs(d[:, [0, 2]] @ along).max() < 0.02 * m.speed / cfg.fps
        np.testing.assert_allclose(c[:, 1], 0.0)
        forward = m.poses[:, :3, 2][:, [0, 2]]  # the car's own z axis points where it goes
        assert (np.einsum("fk,fk->f", forward[:-1], d[:, [0, 2]]) > 0).all()
        assert np.abs(l[len(l) // 2]) < ROAD_HALF_WIDTH  # on the road halfway through
        s_lanes.append(s[0])
    s_c = (max(s_lanes) + min(s_lanes)) / 2
    # no building, parked car, pole or tree stands in the side street
    for o in w.objects:
        if o.category in ("building", "parked_car", "pole", "tree") and not o.name.startswith("building_"):
            c = o.corners(0)
            if c is None:
                continue
            sc, _ = w.road.to_road(c[:, 0], c[:, 2])
            assert sc.max() < s_c - SIDE_STREET_WIDTH / 2 + 0.3 or sc.min() > s_c + SIDE_STREET_WIDTH / 2 - 0.3, o.name
    # and no car comes within a metre of another car or of the ego car at any frame
    cars = [o for o in w.objects if o.category in ("parked_car", "moving_car")]
    ego = w.cam0_poses[:, :3, 3] + np.array([0.0, cfg.camera_height, 0.0])
    for k in range(40):
        corners = [o.corners(k) for o in cars]
        for m in crossing:
            mine = m.corners(k)
            lo, hi = mine.min(0), mine.max(0)
            assert not ((ego[k] > lo - 1.0) & (ego[k] < hi + 1.0)).all()
            for o, c in zip(cars, corners):
                if o is not m:  # axis-aligned boxes around each (cars at right angles: their boxes are their own)
                    assert (c.min(0) > hi + 0.2).any() or (c.max(0) < lo - 0.2).any(), (m.name, o.name, k)


def test_no_crossing_cars_keeps_the_world_and_its_random_stream():
    """The crossing cars draw from a stream of their own: without them every object is where it was."""
    a = build_world(SynthConfig(seed=4), 1, 20)
    b = build_world(SynthConfig(seed=4, crossing_cars=2), 1, 20)
    named = {o.name: o for o in b.objects}
    # the objects before the side street's gap are the same; the lanes' movers are drawn by the same stream
    lane_movers = [o for o in a.objects if o.name.startswith("mover")]
    assert lane_movers and all(not o.name.startswith("crossing") for o in a.objects)
    assert sum(o.name.startswith("crossing") for o in b.objects) == 2
    np.testing.assert_array_equal(a.cam0_poses, b.cam0_poses)
    kept = [o for o in a.objects if o.name in named and o.category == "building"]
    assert kept and all(np.array_equal(o.poses, named[o.name].poses) for o in kept[:3])


def test_rig_matches_kitti_conventions():
    cfg = SynthConfig(width=832, height=256)
    rig = make_rig(cfg)
    assert rig.K[0, 0] == pytest.approx(707.0912 * 832 / 1226)
    np.testing.assert_allclose(g.camera_offset_from_projection(rig.P["P2"])[:3, 3], [0.06, 0, 0], atol=1e-12)
    np.testing.assert_allclose(g.camera_offset_from_projection(rig.P["P3"])[:3, 3], [-0.473, 0, 0], atol=1e-12)
    assert rig.P["P3"][0, 3] / rig.P["P3"][0, 0] == pytest.approx(-0.473)
    # the velodyne sits 1.73 m above the road when cam0 is 1.65 m above it, 0.27 m behind cam0
    velo_in_cam0 = rig.T_velo_to_cam0[:3, 3]
    assert cfg.camera_height - velo_in_cam0[1] == pytest.approx(1.73) and velo_in_cam0[2] == pytest.approx(-0.27)
    el = np.degrees(lidar.beam_elevations(cfg))
    assert len(el) == 64 and el[0] == pytest.approx(2.0) and el[-1] == pytest.approx(-24.8)
    assert len(lidar.azimuths(cfg.lidar_azimuth_step_deg)) == round(360 / cfg.lidar_azimuth_step_deg)


def test_config_validation():
    with pytest.raises(ConfigError):
        SynthConfig(test_frames=1).validate()
    with pytest.raises(ConfigError):
        SynthConfig(camera_range=300.0).validate()
    with pytest.raises(ConfigError):
        SynthConfig(n_sequences=0, test_frames=0).validate()
    assert SynthConfig().validate().sequence_names() == [("00", 40, "train"), ("01", 40, "train"), ("02", 20, "test")]
    assert SynthConfig.from_dict(SynthConfig(seed=4).to_dict()) == SynthConfig(seed=4)
    with pytest.raises(ConfigError):
        SynthConfig.from_dict({"seed": 1, "nope": 2})
    assert math.isclose(SynthConfig().fps, 10.0)
