"""Training batches from the cache: seeded draws independent of workers and ranks, GT-flow split, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from _trainer_fixtures import tiny_cache, tiny_config  # noqa: F401  (tiny_cache: fixture)
from pipeline.cache import CacheReader
from core.errors import ConfigError, InputError
from training.data import LoadFailure, PairDataset, StepBatches, collate, pairs_with_gt_flow, split_pairs
from training.trainer import Trainer

torch.set_num_threads(1)


def _batches(cache, tmp_path, workers: int, steps: int = 8, start: int = 0) -> list:
    cfg = tiny_config(cache, tmp_path / f"w{workers}-{start}", steps=steps, data={"workers": workers})
    trainer = Trainer(cfg)
    trainer.step = start
    return list(trainer._loader())


def test_batches_do_not_depend_on_worker_count(tiny_cache, tmp_path):  # noqa: F811
    # 12 training pairs, batch 2: 6 steps per epoch, so 8 steps cross into epoch 1
    b0 = _batches(tiny_cache, tmp_path, 0)
    b2 = _batches(tiny_cache, tmp_path, 2)
    assert len(b0) == len(b2) == 8
    for x, y in zip(b0, b2):
        for name in ("pc1", "pc2", "feat1", "feat2", "static_flow", "K", "depth2", "index", "gt_flow", "moving"):
            assert torch.equal(getattr(x, name), getattr(y, name)), name
    # epoch 1 draws other points of the same pairs: same pair, other sample
    first_epoch = {int(i): b.pc1[k] for b in b0[:6] for k, i in enumerate(b.index)}
    again = [(int(i), b.pc1[k]) for b in b0[6:] for k, i in enumerate(b.index)]
    assert all(not torch.equal(first_epoch[i], pc) for i, pc in again)
    # a loader started at step 5 (a resumed run) yields exactly the tail of the uninterrupted sequence
    tail = _batches(tiny_cache, tmp_path, 0, start=5)
    assert len(tail) == 3 and all(torch.equal(x.pc1, y.pc1) for x, y in zip(tail, b0[5:]))


def test_draw_depends_only_on_seed_epoch_and_pair(tiny_cache):  # noqa: F811
    r = CacheReader(tiny_cache)
    a = PairDataset(r, [3, 7, 9], 256, seed=0)
    b = PairDataset(r, [9, 3], 256, seed=0)  # another position for the same pairs
    assert np.array_equal(a[2]["pc1"], b[0]["pc1"]) and np.array_equal(a[0]["pc2"], b[1]["pc2"])
    a.set_epoch(1)
    assert not np.array_equal(a[2]["pc1"], b[0]["pc1"])
    c = PairDataset(r, [9], 256, seed=1)
    assert not np.array_equal(c[0]["pc1"], b[0]["pc1"])
    # the sampled points are points of the cloud, with their own static and GT flow
    s = r[9]
    row = np.flatnonzero((s.pc1 == b[0]["pc1"][0]).all(1))[0]
    assert np.array_equal(s.static_flow[row], b[0]["static_flow"][0])
    assert np.array_equal(s.gt_flow[row], b[0]["gt_flow"][0])
    # the validation draw (fixed epoch) differs from every training epoch's and never changes
    v = PairDataset(r, [9], 256, seed=0, fixed_epoch=-1)
    v.set_epoch(5)
    assert np.array_equal(v[0]["pc1"], PairDataset(r, [9], 256, seed=0, fixed_epoch=-1)[0]["pc1"])
    assert not np.array_equal(v[0]["pc1"], b[0]["pc1"])


def test_ranks_split_the_global_batch():
    full = StepBatches(12, 4, seed=0, start_step=0, total_steps=9)
    r0 = StepBatches(12, 4, seed=0, start_step=0, total_steps=9, rank=0, world=2)
    r1 = StepBatches(12, 4, seed=0, start_step=0, total_steps=9, rank=1, world=2)
    for step in range(9):
        assert r0.batch(step) + r1.batch(step) == full.batch(step)
    epoch0 = sorted(p for s in range(3) for p in full.batch(s))
    assert epoch0 == list(range(12))  # an epoch visits every pair once
    assert list(full)[4] == [(1, p) for p in full.batch(4)]
    with pytest.raises(ConfigError, match="not divisible"):
        StepBatches(12, 5, 0, 0, 1, rank=0, world=2)


def test_split_holds_out_sequence_tails_with_gt_flow(tiny_cache):  # noqa: F811
    r = CacheReader(tiny_cache)
    assert r.sequences == ["00", "01"] and len(r) == 16
    assert pairs_with_gt_flow(r) == set(range(16))
    train, val = split_pairs(r, 0.25)
    assert val == [9, 10, 11, 15] and train == [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 13, 14]
    assert split_pairs(r, 0.0) == (list(range(16)), [])


def test_held_out_pairs_without_gt_flow_are_validated_without_labels(tiny_cache, tmp_path):  # noqa: F811
    import json
    import shutil

    cache = tmp_path / "cache"
    shutil.copytree(tiny_cache, cache)
    m = json.loads((cache / "manifest.json").read_text())
    for b in m["sequences"]["01"]["blocks"]:
        b["has_gt_flow"] = False
    (cache / "manifest.json").write_text(json.dumps(m))
    trainer = Trainer(tiny_config(cache, tmp_path / "run", steps=1))
    assert trainer.val_idx == [9, 10, 11, 15] and 15 not in trainer.train_idx and len(trainer.train_idx) == 12
    val = trainer.validate()
    assert {"val_loss", "val_l0", "val_cycle"} <= set(val) and all(v > 0 for v in val.values())


def test_unreadable_block_is_one_input_error_through_workers(tiny_cache, tmp_path):  # noqa: F811
    """A block whose depth array is corrupt fails inside a DataLoader worker; the trainer re-raises it as the
    reader's one-line InputError instead of DataLoader's RuntimeError with a remote traceback."""
    import shutil

    cache = tmp_path / "cache"
    shutil.copytree(tiny_cache, cache)
    chunks = [c for c in (cache / "blocks" / "00").glob("*/depth/c/**/*") if c.is_file()]
    assert chunks
    for chunk in chunks:  # same length: the reader's file-size check at start passes, the CRC check in the worker fails
        chunk.write_bytes(b"Z" * chunk.stat().st_size)
    trainer = Trainer(tiny_config(cache, tmp_path / "run", steps=2, data={"workers": 2, "val_fraction": 0.0}))
    with pytest.raises(InputError) as err:
        trainer.fit()
    assert "blocks/00/0000" in str(err.value) and "\n" not in str(err.value)


def test_collate_passes_a_load_failure_on():
    fail = LoadFailure("x/y", "broken")
    assert collate([{"pc1": np.zeros((4, 3), np.float32)}, fail]) is fail
    assert str(fail.error()) == "x/y: broken"


def test_epoch_aware_raises_unless_told_to_carry_errors():
    from training.data import EpochAware

    class Broken:
        def set_epoch(self, epoch):
            self.epoch = epoch

        def __len__(self):
            return 1

        def __getitem__(self, pos):
            raise InputError("cache/blocks/00/00000", "unreadable block")

    with pytest.raises(InputError):
        EpochAware(Broken())[(0, 0)]  # the depth trainer's use: errors propagate as before
    got = EpochAware(Broken(), carry_errors=True)[(3, 0)]
    assert isinstance(got, LoadFailure) and str(got.error()) == "cache/blocks/00/00000: unreadable block"


def test_fixture_gt_flow_lands_on_frame_two_surfaces(tiny_cache):  # noqa: F811
    """The panels fixture's GT flow (ego-motion + the moving panel) is right: warped points project onto
    frame t+1's depth map at their own depth, except the few occluded/disoccluded at panel edges."""
    r = CacheReader(tiny_cache)
    for i in (0, 13):
        s = r[i]
        warped = (s.pc1 + s.gt_flow).astype(np.float64)
        uv = warped[:, :2] / warped[:, 2:] * np.diag(s.K)[:2] + s.K[:2, 2]
        u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        inside = (u >= 0) & (u < s.depth2.shape[1]) & (v >= 0) & (v < s.depth2.shape[0])
        err = np.abs(s.depth2[v[inside], u[inside]] - warped[inside, 2])
        assert inside.mean() > 0.85 and np.mean(err < 0.01) > 0.85 and np.median(err) < 0.003
        zero = np.abs(s.depth2[np.rint(s.uv1[:, 1]).astype(int), np.rint(s.uv1[:, 0]).astype(int)] - s.pc1[:, 2])
        assert np.mean(zero < 0.01) < 0.05  # a wrong (zero) flow does not land on the surfaces
        assert 0.1 < s.moving.mean() < 0.4  # the moving panel is in view
        static = ~s.moving
        assert np.array_equal(s.gt_flow[static], s.static_flow[static])


def test_ego_speed_scale_moves_frame_t_only(tiny_cache):  # noqa: F811
    """The speed augmentation moves frame t's points (A = T'^-1 T) and leaves frame t+1 and every target
    there as it was: pc1 + static_flow and pc1 + gt_flow are unchanged, pc2 too; off, nothing changes."""
    r = CacheReader(tiny_cache)
    plain = PairDataset(r, [3, 9], 256, seed=0)[1]
    fast = PairDataset(r, [3, 9], 256, seed=0, ego_speed_scale=(1.5, 1.5))[1]
    assert np.array_equal(plain["pc2"], fast["pc2"])
    assert not np.allclose(plain["pc1"], fast["pc1"], atol=1e-3)
    for key in ("static_flow", "gt_flow"):
        assert np.allclose(plain["pc1"] + plain[key], fast["pc1"] + fast[key], atol=1e-4), key
    # the static flow is now 1.5x the camera's translation (to first order in the small rotation)
    T = r[9].T.astype(np.float64)
    far = np.linalg.norm(fast["static_flow"].mean(0)) / np.linalg.norm(plain["static_flow"].mean(0))
    assert abs(far - 1.5) < 0.1, (far, T[:3, 3])
    same = PairDataset(r, [3, 9], 256, seed=0, ego_speed_scale=(1.0, 1.0))[1]
    assert all(np.array_equal(plain[k], same[k]) for k in plain)


def test_ego_turn_shift_moves_frame_t_by_a_ground_plane_motion(tiny_cache):  # noqa: F811
    """``ego_turn_shift``: frame t's points move by a turn about y and an (x, z) shift within the bounds;
    frame t+1 and every target there stay; (0, 0) draws nothing."""
    r = CacheReader(tiny_cache)
    plain = PairDataset(r, [3, 9], 256, seed=0)[1]
    moved = PairDataset(r, [3, 9], 256, seed=0, ego_turn_shift=(2.0, 0.3))[1]
    assert np.array_equal(plain["pc2"], moved["pc2"])
    for key in ("static_flow", "gt_flow"):
        assert np.allclose(plain["pc1"] + plain[key], moved["pc1"] + moved[key], atol=1e-4), key
    # the motion of frame t: rigid, height kept, a turn about y within 2 degrees and a shift within 0.3 m
    a, b = plain["pc1"].astype(np.float64), moved["pc1"].astype(np.float64)
    assert np.allclose(a[:, 1], b[:, 1], atol=1e-4)
    ca, cb = a - a.mean(0), b - b.mean(0)
    u, _, vt = np.linalg.svd(cb.T @ ca)
    R = u @ vt  # b ≈ R a + t
    yaw = np.degrees(np.arctan2(R[0, 2], R[0, 0]))
    assert 0 < abs(yaw) <= 2.0 and abs(R[1, 1] - 1) < 1e-6
    t = b.mean(0) - a.mean(0) @ R.T
    assert np.all(np.abs(t[[0, 2]]) <= 0.3 + 1e-4) and abs(t[1]) < 1e-4 and np.abs(t).max() > 0
    same = PairDataset(r, [3, 9], 256, seed=0, ego_turn_shift=(0.0, 0.0))[1]
    assert all(np.array_equal(plain[k], same[k]) for k in plain)


def test_ego_turn_shift_is_checked(tiny_cache, tmp_path):  # noqa: F811
    with pytest.raises(ConfigError, match="ego_turn_deg"):
        Trainer(tiny_config(tiny_cache, tmp_path / "bad", data={"ego_turn_deg": -1.0}))


def test_ego_speed_scale_is_checked(tiny_cache, tmp_path):  # noqa: F811
    cfg = tiny_config(tiny_cache, tmp_path / "bad", data={"ego_speed_scale": (2.0, 0.5)})
    with pytest.raises(ConfigError, match="ego_speed_scale"):
        Trainer(cfg)


def test_mirror_reflects_points_depth_map_and_intrinsics_together(tiny_cache):  # noqa: F811
    """A mirrored pair is the same pair with x negated, and it is still consistent: frame t's points moved
    by the true flow project, through the mirrored intrinsics, onto the mirrored depth map at their own
    depth, as they do in the original pair; off, nothing is drawn."""
    r = CacheReader(tiny_cache)
    plain = PairDataset(r, [3, 9], 256, seed=0)[1]
    mirrored = PairDataset(r, [3, 9], 256, seed=0, mirror=1.0)[1]
    for key in ("pc1", "pc2", "static_flow", "gt_flow"):
        assert np.allclose(mirrored[key][:, 0], -plain[key][:, 0]) and np.allclose(mirrored[key][:, 1:], plain[key][:, 1:])
    assert not np.allclose(mirrored["depth2"], plain["depth2"])

    def landed(d):  # share of warped points whose depth-map sample matches their depth within 1 cm
        warped = d["pc1"] + d["gt_flow"]
        uv = warped[:, :2] / warped[:, 2:] * np.diag(d["K"])[:2] + d["K"][:2, 2]
        u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        inside = (u >= 0) & (u < d["depth2"].shape[1]) & (v >= 0) & (v < d["depth2"].shape[0])
        return np.mean(np.abs(d["depth2"][v[inside], u[inside]] - warped[inside, 2]) < 0.01)

    assert landed(plain) > 0.85 and landed(mirrored) > 0.85
    width = plain["depth2"].shape[1]
    assert np.isclose(mirrored["K"][0, 2], width - 1 - plain["K"][0, 2])
    assert np.array_equal(mirrored["depth2"][:, ::-1], plain["depth2"])
    off = PairDataset(r, [3, 9], 256, seed=0, mirror=0.0)[1]
    assert all(np.array_equal(plain[k], off[k]) for k in plain)


def test_mirror_is_checked(tiny_cache, tmp_path):  # noqa: F811
    cfg = tiny_config(tiny_cache, tmp_path / "bad", data={"mirror": 1.5})
    with pytest.raises(ConfigError, match="mirror"):
        Trainer(cfg)


def test_synthetic_mover_keeps_targets_and_gives_the_camera_motion_at_its_new_place(tiny_cache, monkeypatch):  # noqa: F811
    """With a synthetic mover (here a fixed cluster and shift, under the speed and turn augmentations): frame
    t+1, its depth map and every point's flow target stay; the cluster's points are where the mover put them
    and flagged moving; their static flow is the camera's motion at that place (the rigid motion that the
    other points' static flow follows); off, nothing is drawn."""
    import training.data as data
    from evaluation.baselines.base import apply_transform, kabsch

    r = CacheReader(tiny_cache)
    kw = dict(ego_speed_scale=(1.5, 1.5), ego_turn_shift=(2.0, 0.3))
    plain = PairDataset(r, [3, 9], 256, seed=0, **kw)[1]
    picked = np.arange(10, 40)

    def fixed(rng, pc1, motion_m):
        assert motion_m == (0.5, 1.5)
        return picked, pc1[picked].astype(np.float64) + [0.7, 0.0, -0.4]

    monkeypatch.setattr(data, "synthetic_mover", fixed)
    moved = PairDataset(r, [3, 9], 256, seed=0, movers=(1.0, (0.5, 1.5)), **kw)[1]
    for key in ("pc2", "depth2", "K"):
        assert np.array_equal(plain[key], moved[key]), key
    assert np.allclose(plain["pc1"] + plain["gt_flow"], moved["pc1"] + moved["gt_flow"], atol=1e-4)
    assert np.allclose(moved["pc1"][picked], plain["pc1"][picked] + [0.7, 0.0, -0.4], atol=1e-5)
    rest = np.setdiff1d(np.arange(256), picked)
    assert np.array_equal(moved["pc1"][rest], plain["pc1"][rest])
    assert moved["moving"][picked].all() and np.array_equal(moved["moving"][rest], plain["moving"][rest])
    # the camera's motion, fitted to the untouched points' static flow, carries the moved points to their static target
    camera = kabsch(moved["pc1"][rest].astype(np.float64), (moved["pc1"] + moved["static_flow"])[rest].astype(np.float64))
    want = apply_transform(camera, moved["pc1"][picked].astype(np.float64))
    assert np.allclose(moved["pc1"][picked] + moved["static_flow"][picked], want, atol=1e-4)
    assert not np.allclose(moved["static_flow"][picked], plain["static_flow"][picked], atol=1e-3)  # the turn shows
    off = PairDataset(r, [3, 9], 256, seed=0, movers=(0.0, (0.5, 1.5)), **kw)[1]
    assert all(np.array_equal(plain[k], off[k]) for k in plain)


def test_synthetic_movers_are_checked(tiny_cache, tmp_path):  # noqa: F811
    with pytest.raises(ConfigError, match="synthetic_movers"):
        Trainer(tiny_config(tiny_cache, tmp_path / "bad", data={"synthetic_movers": 1.5}))
    with pytest.raises(ConfigError, match="synthetic_mover_m"):
        Trainer(tiny_config(tiny_cache, tmp_path / "bad2", data={"synthetic_movers": 0.5, "synthetic_mover_m": (2.0, 1.0)}))
