"""``generate(config, root)``: write a whole synthetic world, atomically.

Layout (KITTI odometry + ground truth; camera image_2, K = P2[:, :3]; metres)::

    root/synth.json                              config, seed, generator version, per-sequence facts
    root/poses/NN.txt                            cam0 camera-to-world, 3×4 per line, frame 0 = identity
    root/sequences/NN/calib.txt                  P0..P3 (P2 = K [I | (0.06, 0, 0)]), Tr velodyne → cam0
    root/sequences/NN/times.txt                  seconds (10 Hz)
    root/sequences/NN/image_2/XXXXXX.png         RGB
    root/sequences/NN/depth_2/XXXXXX.png         KITTI 16-bit depth (z · 256), 0 = sky
    root/sequences/NN/flow3d_2/XXXXXX.npz        t → t+1 (all frames but the last): flow (H, W, 3) float32
                                                 = p_{t+1} in camera t+1 − p_t in camera t; moving, valid,
                                                 visible_next (H, W) bool
    root/sequences/NN/velodyne/XXXXXX.bin        float32 (x fwd, y left, z up, reflectance)
    root/sceneflow/{README.txt, flownet3d/, hplflownet/}   the test sequence's scene-flow split

Training sequences come first (00, 01, …), the test sequence last. The world is written to
``<root>.tmp-<pid>`` and renamed to ``root`` when complete. An existing ``root`` holding the same world
(same ``synth.json`` config and generator version) is kept as is; a different world, or anything else,
is only replaced with ``force=True``.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.errors import ConfigError, InputError
from pipeline.synth.config import SYNTH_VERSION, SynthConfig
from pipeline.synth.rig import make_rig
from pipeline.synth.sceneflow_export import write_pair, write_readme
from pipeline.synth.variety import sequence_config
from pipeline.synth.sequence import FrameResult, SequenceJob, generate_frame, write_sequence_files
from pipeline.synth.world import build_world
from pipeline.synth.writer import write_json


@dataclass
class GenerateSummary:
    """What :func:`generate` wrote (or found already there, ``reused``)."""

    root: Path
    sequences: dict[str, dict] = field(default_factory=dict)  # name → split, frames, movers, …
    frames: int = 0
    flow_pairs: int = 0
    test_pairs: int = 0
    moving_cars: int = 0
    seconds: float = 0.0
    reused: bool = False

    @property
    def scanned_sequences(self) -> list[str]:
        """The sequences with Velodyne scans (all, or the test sequence alone: ``SynthConfig.lidar_scans``)."""
        return [n for n, s in self.sequences.items() if s.get("points_per_scan", 0.0) > 0]

    @property
    def points_per_scan(self) -> float:
        """Mean LiDAR points per scan over the scanned sequences (0 without scans)."""
        scanned = self.scanned_sequences
        return float(np.mean([self.sequences[n]["points_per_scan"] for n in scanned])) if scanned else 0.0

    def lines(self) -> list[str]:
        state = "already present (same config), kept" if self.reused else f"written in {self.seconds:.1f} s"
        out = [f"synthetic world at {self.root}: {state}"]
        for name, s in self.sequences.items():
            out.append(f"  sequence {name} ({s['split']}): {s['frames']} frames, {s['moving_cars']} moving cars, "
                       f"{s['parked_cars']} parked, road curvature {s['curvature']:+.5f} /m")
        scanned = self.scanned_sequences
        lidar = (f"{self.points_per_scan:.0f} LiDAR points per scan (sequences {', '.join(scanned)})" if scanned
                 else "no LiDAR scans")
        out.append(f"  {self.frames} frames, {self.flow_pairs} flow pairs, {self.test_pairs} scene-flow test pairs, "
                   f"{lidar}, {self.moving_cars} moving cars")
        return out


def _identity(cfg: SynthConfig) -> dict:
    return {"generator": "monoflow-synth", "version": SYNTH_VERSION, "config": cfg.to_dict()}


def identity_of(meta: dict) -> dict | None:
    """The identity a world's ``synth.json`` (``meta``) records, in :func:`_identity`'s form: generator, version and
    config, the config read through :class:`SynthConfig`, so a world written before an option existed counts with
    that option's default (what it was made with); None when the file holds no readable config."""
    if not isinstance(meta, dict):
        return None
    try:
        config = SynthConfig.from_dict(meta.get("config") or {}).to_dict()
    except (ConfigError, TypeError):
        return None
    return {"generator": meta.get("generator"), "version": meta.get("version"), "config": config}


def world_identity(root: str | Path) -> dict | None:
    """:func:`identity_of` the world at ``root``; None where it has no readable ``synth.json`` (not a synthetic
    world, e.g. KITTI)."""
    meta = _existing(Path(root))
    return None if meta is None else identity_of(meta)


def _same_world(meta: dict, ident: dict) -> bool:
    """Whether the world described by ``meta`` (its ``synth.json``) is the one ``ident`` would write
    (:func:`identity_of`)."""
    return identity_of(meta) == ident


def _existing(root: Path) -> dict | None:
    try:
        return json.loads((root / "synth.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _remove_stale_temporaries(root: Path) -> None:
    """Delete ``<root>.tmp-<pid>`` / ``.old-<pid>`` folders left by runs whose process is gone
    (:func:`core.processes.writer_gone`: no such process, or one that only reuses the id)."""
    from core.processes import writer_gone

    if not root.parent.is_dir():
        return
    for p in root.parent.glob(f"{root.name}.*-*"):
        kind, _, pid = p.name[len(root.name) + 1:].partition("-")
        if kind not in ("tmp", "old") or not pid.isdigit() or int(pid) == os.getpid():
            continue
        if writer_gone(int(pid), p):
            shutil.rmtree(p, ignore_errors=True)


_JOBS: dict[str, SequenceJob] = {}  # inherited by forked workers


def _run_frame(task: tuple[str, int]) -> FrameResult:
    name, k = task
    return generate_frame(_JOBS[name], k)


def generate(config: SynthConfig, root: str | os.PathLike, *, force: bool = False, workers: int = 1) -> GenerateSummary:
    """Generate the world of ``config`` under ``root`` (KITTI odometry layout + ground truth).

    ``workers`` > 1 renders frames in that many forked processes; the output does not depend on it.
    """
    cfg = config.validate()
    root = Path(root)
    t0 = time.perf_counter()
    ident = _identity(cfg)
    if root.exists():
        old = _existing(root)
        if old is not None and _same_world(old, ident):
            return _summary_from_json(root, old, reused=True)
        if not force and not (root.is_dir() and not any(root.iterdir())):
            what = "a different synthetic world" if old is not None else "something that is not a synthetic world"
            raise InputError(root, f"exists and holds {what}; pass --force (force=True) to replace it")
    _remove_stale_temporaries(root)
    tmp = root.parent / f"{root.name}.tmp-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        meta = _write_world(cfg, tmp, workers)
        write_json(tmp / "synth.json", {**ident, "seed": cfg.seed, **meta})
        if root.exists():
            trash = root.parent / f"{root.name}.old-{os.getpid()}"
            os.rename(root, trash)
            os.rename(tmp, root)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            root.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.rename(tmp, root)
            except OSError:
                other = _existing(root)  # another run finished the same folder first
                if other is None or not _same_world(other, ident):
                    raise InputError(root, "was created by another run meanwhile, with a different world") from None
                shutil.rmtree(tmp, ignore_errors=True)
                return _summary_from_json(root, other, reused=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    summary = _summary_from_json(root, _existing(root), reused=False)
    summary.seconds = time.perf_counter() - t0
    return summary


def _write_world(cfg: SynthConfig, out: Path, workers: int) -> dict:
    jobs: list[SequenceJob] = []
    for index, (name, n_frames, split) in enumerate(cfg.sequence_names()):
        seq_cfg = sequence_config(cfg, index, split)
        world = build_world(seq_cfg, index, n_frames)
        job = SequenceJob(name, world, make_rig(seq_cfg), seq_cfg, out / "sequences" / name,
                          want_scan_gt=split == "test")
        write_sequence_files(job, out)
        jobs.append(job)
    _JOBS.clear()
    _JOBS.update({j.name: j for j in jobs})
    tasks = [(j.name, k) for j in jobs for k in range(j.world.n_frames)]
    try:
        if workers > 1:
            with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork")) as pool:
                results = list(pool.map(_run_frame, tasks, chunksize=2))
        else:
            results = [_run_frame(t) for t in tasks]
    finally:
        _JOBS.clear()
    by_task = dict(zip(tasks, results))
    sequences: dict[str, dict] = {}
    test_pairs = 0
    for j in jobs:
        split = "test" if j.want_scan_gt else "train"
        res = [by_task[(j.name, k)] for k in range(j.world.n_frames)]
        movers = j.world.movers
        sequences[j.name] = {
            "split": split,
            "frames": j.world.n_frames,
            "curvature": j.world.road.curvature,
            "moving_cars": len(movers),
            "mover_speeds": [round(m.speed, 4) for m in movers],
            "parked_cars": sum(o.category == "parked_car" for o in j.world.objects),
            "points_per_scan": float(np.mean([r.scan_points for r in res])),
        }
        if j.cfg is not cfg:  # a varied sequence (SynthConfig.variety): its own camera and driving
            sequences[j.name].update({"image_size": [j.cfg.width, j.cfg.height], "K": j.rig.K.round(9).tolist(),
                                      "ego_speed": [round(j.cfg.ego_speed_min, 3), round(j.cfg.ego_speed_max, 3)],
                                      "ego_stop": j.cfg.ego_stop})
        if j.want_scan_gt:
            sf = out / "sceneflow"
            counts = [write_pair(sf, k, res[k].scan_gt, res[k + 1].scan_gt) for k in range(len(res) - 1)]
            write_readme(sf, j.name, len(counts))
            test_pairs = len(counts)
            sequences[j.name]["sceneflow_points"] = {"flownet3d_mean": float(np.mean([c[0] for c in counts])),
                                                     "hplflownet_mean": float(np.mean([c[1] for c in counts]))}
    K = make_rig(cfg).K
    return {
        "sequences": sequences,
        "test_sequence": next((n for n, s in sequences.items() if s["split"] == "test"), None),
        "sceneflow_pairs": test_pairs,
        "image_size": [cfg.width, cfg.height],
        "K": K.round(9).tolist(),
    }


def _summary_from_json(root: Path, meta: dict, reused: bool) -> GenerateSummary:
    seqs = meta.get("sequences", {})
    frames = sum(s["frames"] for s in seqs.values())
    return GenerateSummary(
        root=root,
        sequences=seqs,
        frames=frames,
        flow_pairs=sum(s["frames"] - 1 for s in seqs.values()),
        test_pairs=int(meta.get("sceneflow_pairs", 0)),
        moving_cars=sum(s["moving_cars"] for s in seqs.values()),
        reused=reused,
    )
