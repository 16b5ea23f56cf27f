"""``monoflow-predict``'s work: frames → stage one (depth, pose, scale, filters) → the flow net → one HDF5 file.

Per block of consecutive pairs, stage one's :class:`pipeline.preprocess.BlockProcessor` computes every
frame's depth once, every pair's pose, the scale factor (carried over frames without a road plane) and
the filtered pixels; the clouds are rebuilt with the cache's own functions (``points_from_depth``,
``core.geometry.static_flow``), so they equal what ``monoflow-preprocess`` would cache for the same options.

The flow net sees each pair exactly as ``monoflow-evaluate run --protocol full`` shows a scene: both
clouds sampled to ``n_points`` by :func:`evaluation.protocols.prepare_scene` (seeded by ``sample_seed`` and
the pair's name ``<seq>_<t>_<t1>``), the net's level-0 flow spread to the sampled points and then to every
point of pc1 by 3-NN interpolation (:func:`evaluation.protocols.interpolate_flow`). Pairs are batched
(``flow_batch``) on the GPU when there is one.

Resume: each finished pair is written atomically to ``<out>/<name>.parts/<pair>.npz``; a rerun skips them
(and whole blocks whose pairs are all done). The HDF5 file is assembled from the parts at the end.

Frames and units: camera frame of frame t (x right, y down, z forward), metres; ``pc2`` in camera t+1;
``flow`` maps pc1 into camera t+1 (``pc1 + flow``), including the camera's own motion; ``static_flow`` is
the flow the pose alone implies, ``(R p + t) − p`` with ``T_{t→t+1}``; ``dynamic_flow = flow −
static_flow``; ``moving = |dynamic_flow| > moving_threshold``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.predict.config import PredictConfig
from core.errors import ConfigError, InputError

FORMAT_NAME = "monoflow-predict"
FORMAT_VERSION = 1
PART_KEYS = ("pc1", "rgb1", "uv1", "pc2", "rgb2", "uv2", "flow", "static_flow", "T", "scale", "carried")


@dataclass
class PairOutput:
    """One predicted pair (see the module docstring for frames and units)."""

    name: str
    frame_t: int
    frame_t1: int
    pc1: np.ndarray  # (N1, 3) float32, camera t, metres
    rgb1: np.ndarray  # (N1, 3) uint8
    uv1: np.ndarray  # (N1, 2) float32 pixels at the working size
    pc2: np.ndarray  # (N2, 3) float32, camera t+1, metres
    rgb2: np.ndarray
    uv2: np.ndarray
    flow: np.ndarray  # (N1, 3) float32 metres, p1 + flow in camera t+1
    static_flow: np.ndarray  # (N1, 3) float32 metres
    T: np.ndarray  # (4, 4) float64 T_{t→t+1}, metric
    scale: float
    carried: bool
    gt_flow: np.ndarray | None = None


@dataclass
class PredictSummary:
    """What a run did."""

    h5_path: Path
    pairs: int
    pairs_done_before: int
    seconds: float
    blocks_carried: int
    frames_without_scale: int
    mean_points: float
    mean_moving_fraction: float
    pictures: list[Path] = field(default_factory=list)
    ply: list[Path] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def text(self) -> str:
        lines = [f"monoflow-predict: {self.pairs} pairs ({self.pairs_done_before} done before) in "
                 f"{self.seconds:.1f} s → {self.h5_path}",
                 f"  mean points per pc1 {self.mean_points:.0f}, moving fraction {self.mean_moving_fraction:.3f}"]
        if self.blocks_carried or self.frames_without_scale:
            lines.append(f"  scale: {self.frames_without_scale} frames without a factor of their own; "
                         f"{self.blocks_carried} blocks carried the last good factor (or the sequence median)")
        if self.pictures:
            lines.append(f"  pictures: {len(self.pictures)} in {self.pictures[0].parent}")
        if self.ply:
            lines.append(f"  PLY: {len(self.ply)} in {self.ply[0].parent}")
        for w in self.warnings:
            lines.append(f"  WARNING: {w}")
        return "\n".join(lines)


def pair_name(sequence: str, frame_t: int, frame_t1: int) -> str:
    """``<seq>_<t:06d>_<t1:06d>``: the pair's name in the HDF5 file, part files and sampling seed."""
    return f"{sequence}_{frame_t:06d}_{frame_t1:06d}"


def preprocess_config(cfg: PredictConfig, root: Path, sequence: str, camera: str):
    """Stage one's :class:`PreprocessConfig` for the prepared input (same sources, size, scale, filters)."""
    from pipeline.preprocess import PreprocessConfig

    return PreprocessConfig(root=str(root), sequences=(sequence,), camera=camera, depth=cfg.depth, pose=cfg.pose,
                            depth_checkpoint=cfg.depth_checkpoint, pose_checkpoint=cfg.pose_checkpoint,
                            resnet_layers=cfg.resnet_layers, random_init=cfg.random_init,
                            strict_pose_count=cfg.strict_pose_count, size=cfg.size,
                            filters=dataclasses.replace(cfg.filters), scale=dataclasses.replace(cfg.scale),
                            block_size=cfg.block_size, device=cfg.device, batch_size=cfg.batch_size,
                            out=str(Path(cfg.out) / ".unused"), progress=False).validate()


def pairs_of_block(block, sequence: str) -> list[PairOutput]:
    """The clouds of a stage-one :class:`BlockRecord`, rebuilt with the cache's functions (flow not yet set)."""
    from pipeline.cache.points import colours_at, pixel_uv, points_from_depth
    from core.geometry import static_flow

    frames = {f.frame_id: f for f in block.frames}
    out = []
    for p in block.pairs:
        a, b = frames[p.frame_t], frames[p.frame_t1]
        W = a.depth.shape[1]
        pc1 = points_from_depth(a.depth, p.idx1, block.K)
        pc2 = points_from_depth(b.depth, p.idx2, block.K)
        out.append(PairOutput(
            name=pair_name(sequence, p.frame_t, p.frame_t1), frame_t=p.frame_t, frame_t1=p.frame_t1,
            pc1=pc1, rgb1=colours_at(a.rgb, p.idx1), uv1=pixel_uv(p.idx1, W),
            pc2=pc2, rgb2=colours_at(b.rgb, p.idx2), uv2=pixel_uv(p.idx2, W),
            flow=np.zeros_like(pc1), static_flow=static_flow(pc1, p.T, as_float32=True), T=np.asarray(p.T, dtype=np.float64),
            scale=float(p.scale), carried=False, gt_flow=p.gt_flow))
    return out


class FlowPredictor:
    """A monoflow-train checkpoint run on pairs exactly as ``monoflow-evaluate``'s full protocol runs it."""

    def __init__(self, checkpoint: str, device: str = "auto", n_points: int = 0, seed: int = 0,
                 rigid_polish: bool = False) -> None:
        from evaluation.methods import NetMethod
        from evaluation.protocols import ProtocolConfig

        self.method = NetMethod(checkpoint, device=device)
        n = n_points or self.method.n_points
        if n < self.method.n_score:
            raise ConfigError(f"{checkpoint}: the net needs at least {self.method.n_score} points "
                              f"per cloud, --n_points is {n}")
        self.protocol = ProtocolConfig(protocol="full", n_points=n, n_score=1, seeds=(seed,), warmup=False)
        self.seed = seed
        self.rigid_polish = rigid_polish  # monoflow-evaluate's "+ rigid polish" row, on the sampled points

    def scene(self, pair: PairOutput):
        """The :class:`PreparedScene` monoflow-evaluate would build for this pair (colours in [0, 1])."""
        from evaluation.protocols import prepare_scene
        from evaluation.sample import SceneFlowSample

        sample = SceneFlowSample(pair.name, pair.pc1, pair.pc2, np.zeros_like(pair.pc1),
                                 color1=pair.rgb1.astype(np.float32) / 255.0,
                                 color2=pair.rgb2.astype(np.float32) / 255.0)
        return prepare_scene(sample, self.protocol, self.seed)

    def __call__(self, pairs: list[PairOutput]) -> list[np.ndarray]:
        """Flow (N1, 3) float32 metres of every point of each pair's pc1; one batched forward pass."""
        import torch

        from evaluation.protocols import interpolate_flow
        from training.pointops import three_nn_interpolate

        m = self.method
        scenes = [self.scene(p) for p in pairs]

        def t(arrays):
            return torch.tensor(np.stack([np.asarray(a, dtype=np.float32) for a in arrays]), device=m.device)

        use = m.uses_colour
        with torch.no_grad():
            p1 = t([s.pc1 for s in scenes])
            p2 = t([s.pc2 for s in scenes])
            f1, f2 = (t([s.color1 for s in scenes]), t([s.color2 for s in scenes])) if use else (None, None)
            out = m.net(p1, p2, f1, f2)
            sampled = three_nn_interpolate(p1, out.points[0], out.flows[0].float()).cpu().numpy()
        flows = [sampled[b].astype(np.float32) for b in range(len(scenes))]
        if self.rigid_polish:
            from evaluation.rigid_polish import polish_rigid

            flows = [polish_rigid(s.pc1, s.pc2, f)[0] for s, f in zip(scenes, flows)]
        return [interpolate_flow(s.points, s.pc1, f) for s, f in zip(scenes, flows)]


# ----------------------------------------------------------------------------------------------- parts


def _part_path(parts: Path, name: str) -> Path:
    return parts / f"{name}.npz"


def write_part(parts: Path, pair: PairOutput) -> Path:
    """``<parts>/<pair>.npz`` atomically (written under a temporary name, then renamed)."""
    path = _part_path(parts, pair.name)
    tmp = path.with_name(f"{path.stem}.tmp-{os.getpid()}.npz")
    arrays = {k: np.asarray(getattr(pair, k)) for k in PART_KEYS}
    arrays["frames"] = np.array([pair.frame_t, pair.frame_t1], dtype=np.int64)
    if pair.gt_flow is not None:
        arrays["gt_flow"] = pair.gt_flow
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return path


def read_part(path: Path, name: str) -> PairOutput:
    """A part file back (``allow_pickle=False``: nothing in it can run code); InputError when damaged."""
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(path, f"damaged part file ({type(exc).__name__}); delete it to recompute the pair") from None
    missing = [k for k in PART_KEYS + ("frames",) if k not in a]
    if missing:
        raise InputError(path, f"part file lacks {missing}; delete it to recompute the pair")
    return PairOutput(name=name, frame_t=int(a["frames"][0]), frame_t1=int(a["frames"][1]), pc1=a["pc1"],
                      rgb1=a["rgb1"], uv1=a["uv1"], pc2=a["pc2"], rgb2=a["rgb2"], uv2=a["uv2"], flow=a["flow"],
                      static_flow=a["static_flow"], T=a["T"], scale=float(a["scale"]), carried=bool(a["carried"]),
                      gt_flow=a.get("gt_flow"))


# ----------------------------------------------------------------------------------------------- HDF5


def write_h5(path: Path, pairs: list[PairOutput], K: np.ndarray, image_hw: tuple[int, int], attrs: dict[str, Any],
             moving_threshold: float) -> Path:
    """The sequence's HDF5 file (written to a temporary name, then renamed). Layout: ``docs/predict-format.md``."""
    import h5py

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT_NAME
        f.attrs["version"] = FORMAT_VERSION
        f.attrs["units"] = "metres"
        f.attrs["frame"] = "camera: x right, y down, z forward; pc1/flow in camera t, pc2 in camera t+1"
        f.attrs["moving_threshold_m"] = float(moving_threshold)
        f.attrs["image_size_hw"] = np.asarray(image_hw, dtype=np.int64)
        for k, v in attrs.items():
            f.attrs[k] = v
        k_ds = f.create_dataset("intrinsics", data=np.asarray(K, dtype=np.float64))
        k_ds.attrs["units"] = "pixels (working size)"
        poses = f.create_dataset("poses", data=np.stack([p.T for p in pairs]).astype(np.float64))
        poses.attrs["units"] = "metres (translation)"
        poses.attrs["meaning"] = "T_{t->t+1}: p_{t+1} = R p_t + t"
        f.create_dataset("frames", data=np.array([[p.frame_t, p.frame_t1] for p in pairs], dtype=np.int64))
        f.create_dataset("scale", data=np.array([p.scale for p in pairs], dtype=np.float64))
        f.create_dataset("scale_carried", data=np.array([p.carried for p in pairs], dtype=bool))
        f.create_dataset("pair_names", data=np.array([p.name for p in pairs], dtype=h5py.string_dtype()))
        g_all = f.create_group("pairs")
        for p in pairs:
            g = g_all.create_group(p.name)
            g.attrs["frame_t"] = p.frame_t
            g.attrs["frame_t1"] = p.frame_t1
            g.attrs["scale"] = p.scale
            g.attrs["scale_carried"] = p.carried
            g.attrs["T"] = p.T
            dyn = (p.flow - p.static_flow).astype(np.float32)
            moving = np.linalg.norm(dyn, axis=1) > moving_threshold
            for key, data, units in (("pc1", p.pc1, "metres, camera t"), ("pc2", p.pc2, "metres, camera t+1"),
                                     ("rgb1", p.rgb1, "uint8 RGB"), ("rgb2", p.rgb2, "uint8 RGB"),
                                     ("uv1", p.uv1, "pixels (working size), frame t"),
                                     ("uv2", p.uv2, "pixels (working size), frame t+1"),
                                     ("flow", p.flow, "metres; pc1 + flow in camera t+1"),
                                     ("static_flow", p.static_flow, "metres; (R p + t) - p, the pose alone"),
                                     ("dynamic_flow", dyn, "metres; flow - static_flow"),
                                     ("moving", moving, f"bool; |dynamic_flow| > {moving_threshold:g} m")):
                ds = g.create_dataset(key, data=data, compression="gzip", compression_opts=4, shuffle=True)
                ds.attrs["units"] = units
            if p.gt_flow is not None:
                ds = g.create_dataset("gt_flow", data=p.gt_flow, compression="gzip", compression_opts=4)
                ds.attrs["units"] = "metres (dataset ground truth)"
    os.replace(tmp, path)
    return path


def write_ply(path: Path, points: np.ndarray, rgb: np.ndarray, flow: np.ndarray) -> Path:
    """Binary little-endian PLY: x y z (metres, camera t), red green blue, and the flow fx fy fz (metres)."""
    n = len(points)
    header = ("ply\nformat binary_little_endian 1.0\ncomment monoflow-predict: camera frame x right y down "
              f"z forward, metres\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty float fx\n"
              "property float fy\nproperty float fz\nend_header\n")
    rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1"),
                             ("fx", "<f4"), ("fy", "<f4"), ("fz", "<f4")])
    for i, k in enumerate("xyz"):
        rec[k] = points[:, i]
        rec["f" + k] = flow[:, i]
    for i, k in enumerate("rgb"):
        rec[k] = rgb[:, i]
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(rec.tobytes())
    os.replace(tmp, path)
    return path


# ----------------------------------------------------------------------------------------------- the run


def run_predict(cfg: PredictConfig) -> PredictSummary:
    """Run ``monoflow-predict`` as configured (module docstring); MonoflowError on bad input."""
    from evaluation.predict.inputs import default_name, prepare_input
    from pipeline.preprocess import BlockProcessor, DeferBlock, open_sequences, plan_blocks, sequence_median_factor
    from pipeline.scale import announce_scale_problems

    start = time.perf_counter()
    cfg.validate()
    if cfg.pictures:
        from evaluation.pictures import require_matplotlib

        require_matplotlib()  # a missing optional extra is reported before any work
    warnings = announce_scale_problems(cfg.depth, cfg.pose, cfg.scale)
    predictor = FlowPredictor(cfg.checkpoint, cfg.device, cfg.n_points, cfg.sample_seed,
                              cfg.rigid_polish)  # fails early on a bad file
    name = cfg.name or default_name(cfg.input)
    out = Path(cfg.out)
    h5_path = out / f"{name}.h5"
    parts = out / f"{name}.parts"
    if cfg.overwrite:
        shutil.rmtree(parts, ignore_errors=True)
        h5_path.unlink(missing_ok=True)
    elif h5_path.exists():
        raise ConfigError(f"{h5_path} exists (a finished run): pass --overwrite true to predict again")
    parts.mkdir(parents=True, exist_ok=True)
    work = out / f"{name}.work"
    prepared = prepare_input(cfg.input, work, name, cfg.camera, cfg.intrinsics, cfg.poses, cfg.max_frames,
                             cfg.stride)
    pcfg = preprocess_config(cfg, prepared.root, prepared.sequence, prepared.camera)
    sequences = open_sequences(pcfg)
    seq = sequences[prepared.sequence]
    plans = plan_blocks({prepared.sequence: seq.frames}, cfg.block_size)
    if not plans:
        raise InputError(seq.image_dir, "no consecutive frame pairs")
    names = [[pair_name(name, seq.frames[i], seq.frames[j]) for i, j in p.pairs] for p in plans]
    done_before = sum(_part_path(parts, n).is_file() for ns in names for n in ns)
    if predictor.method.uses_colour and prepared.camera in ("image_0", "image_1"):
        warnings.append("the flow net was trained with colour features; these grey frames give it grey colours")
    processor: BlockProcessor | None = None
    bar = None
    if cfg.progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(map(len, names)), initial=done_before, unit="pair", desc=f"predict {name}",
                   file=sys.stderr, dynamic_ncols=True)
    K = hw = None
    carried_blocks = failed_frames = 0
    deferred: list[DeferBlock] = []
    pending_good: list[float] = []  # good factors of blocks finished by an earlier run (resume)

    def handle(block, result) -> None:
        nonlocal K, hw, carried_blocks, failed_frames
        K, hw = block.K, block.frames[0].depth.shape
        carried_blocks += int(result.carried)
        failed_frames += result.frames_without_scale
        for w in result.warnings:
            if w not in warnings and len(warnings) < 5:
                warnings.append(w)
                print(f"WARNING: {w}", file=sys.stderr)
        todo = [p for p in pairs_of_block(block, name) if not _part_path(parts, p.name).is_file()]
        for p in todo:
            p.carried = bool(result.carried)
        for k in range(0, len(todo), cfg.flow_batch):
            chunk = todo[k:k + cfg.flow_batch]
            for p, flow in zip(chunk, predictor(chunk)):
                p.flow = flow
                write_part(parts, p)
                if bar is not None:
                    bar.update(1)

    try:
        for plan, ns in zip(plans, names):
            if all(_part_path(parts, n).is_file() for n in ns):
                part0 = read_part(_part_path(parts, ns[0]), ns[0])
                if processor is not None and not part0.carried:
                    processor.good_factors.setdefault(name, []).append(part0.scale)
                elif processor is None and not part0.carried:
                    pending_good.append(part0.scale)
                continue
            if processor is None:
                processor = BlockProcessor(pcfg, sequences)
                processor.good_factors.setdefault(name, []).extend(pending_good)
            try:
                block, result = processor.build(plan)
            except DeferBlock as d:
                deferred.append(d)
                continue
            handle(block, result)
        for d in deferred:
            s = sequence_median_factor(processor, name)
            block, result = processor.finish(d.inferred, forced_factor=s)
            handle(block, result)
    finally:
        if bar is not None:
            bar.close()

    all_names = [n for ns in names for n in ns]
    pairs = [read_part(_part_path(parts, n), n) for n in all_names]
    if K is None:  # every pair came from parts: K from the prepared input, as stage one scales it
        from pipeline.sources import working_K, working_size

        hw = working_size(seq.image_shape, pcfg.working_size())
        K = working_K(seq, hw)
    attrs = {"sequence": name, "input": str(cfg.input), "input_kind": prepared.kind,
             "depth_source": cfg.depth, "pose_source": cfg.pose, "scale_mode": cfg.scale.mode,
             "flow_checkpoint": str(cfg.checkpoint), "n_points": predictor.protocol.n_points,
             "sample_seed": cfg.sample_seed, "config": json.dumps(dataclasses.asdict(cfg), default=str)}
    write_h5(h5_path, pairs, K, tuple(int(x) for x in hw), attrs, cfg.moving_threshold)

    ply_paths: list[Path] = []
    if cfg.ply:
        for p in pairs:
            ply_paths.append(write_ply(out / f"{name}-ply" / f"{p.name}.ply", p.pc1, p.rgb1, p.flow))
    pictures: list[Path] = []
    if cfg.pictures:
        from evaluation.pictures import pair_picture

        for k, p in enumerate(pairs):
            if k % cfg.picture_every:
                continue
            image = seq.read_image(seq.frames.index(p.frame_t))
            pictures.append(pair_picture(out / f"{name}-pictures" / f"{p.name}.png", p, image, K,
                                         cfg.moving_threshold))
    if not cfg.keep_parts:
        shutil.rmtree(parts, ignore_errors=True)
    moving = [float(np.mean(np.linalg.norm(p.flow - p.static_flow, axis=1) > cfg.moving_threshold))
              for p in pairs if len(p.pc1)]
    return PredictSummary(h5_path=h5_path, pairs=len(pairs), pairs_done_before=done_before,
                          seconds=time.perf_counter() - start, blocks_carried=carried_blocks,
                          frames_without_scale=failed_frames,
                          mean_points=float(np.mean([len(p.pc1) for p in pairs])),
                          mean_moving_fraction=float(np.mean(moving)) if moving else 0.0,
                          pictures=pictures, ply=ply_paths, warnings=warnings)


__all__ = ["FORMAT_NAME", "FlowPredictor", "PairOutput", "PredictSummary", "pair_name", "read_part",
           "run_predict", "write_h5", "write_ply"]
