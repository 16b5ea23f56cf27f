"""From the stage-one cache to training batches.

Every sample is a pair (t, t+1) with ``n_points`` points drawn from each cloud. The draw is seeded by
``(seed, epoch, pair index)`` and done inside ``__getitem__``, so a batch is the same whatever the number
of DataLoader workers or ranks. All points are in camera-t coordinates (x right, y down, z forward,
metres); ``pc2`` is in camera-(t+1) coordinates, so flow includes the ego-motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch
from torch import Tensor

from core import geometry
from core.errors import ConfigError, InputError
from pipeline.filters import FAR_LIMIT_M
from training.augment import (augment_masks, draw_speed_scale, mirror_pair, speed_scaled_view, synthetic_mover,
                              turn_shift_view)

_VAL_EPOCH = -1  # epoch tag of the fixed validation draw


@dataclass
class FlowBatch:
    """A batch of B pairs, each cloud with N points.

    pc1, pc2: (B, N, 3) float32 metres; feat1, feat2: (B, N, 3) RGB in [0, 1] or zeros;
    static_flow: (B, N, 3) flow the camera motion explains, pc1's points (already jittered when the
        jitter augmentation is on); K: (B, 3, 3) pixels; depth2: (B, H, W) metres, 0 = invalid;
    gt_flow: (B, N, 3) or None; moving: (B, N) bool or None; index: (B,) pair indices in the cache;
    pc2_target: (B, N, 3) or None, a second draw of frame t+1's points for the loss (``loss.pc2_target
        independent``), camera-(t+1) frame, metres.
    view1, view2: (B, N) bool or None: pc1 points whose camera-motion target stays in frame t+1's view, pc2
        points that were in frame t's view (``loss.view_mask``, :func:`in_view`).
    """

    pc1: Tensor
    pc2: Tensor
    feat1: Tensor
    feat2: Tensor
    static_flow: Tensor
    K: Tensor
    depth2: Tensor
    index: Tensor
    gt_flow: Tensor | None = None
    moving: Tensor | None = None
    pc2_target: Tensor | None = None
    view1: Tensor | None = None
    view2: Tensor | None = None

    def __post_init__(self) -> None:
        B, N, _ = self.pc1.shape
        expect = {"pc1": (B, N, 3), "pc2": (B, None, 3), "feat1": (B, N, 3), "feat2": (B, None, 3),
                  "static_flow": (B, N, 3), "K": (B, 3, 3), "depth2": (B, None, None), "index": (B,)}
        if self.gt_flow is not None:
            expect["gt_flow"] = (B, N, 3)
        if self.moving is not None:
            expect["moving"] = (B, N)
        if self.pc2_target is not None:
            expect["pc2_target"] = (B, None, 3)
        if self.view1 is not None:
            expect["view1"] = (B, N)
        if self.view2 is not None:
            expect["view2"] = (B, self.pc2.shape[1])
        for name, shape in expect.items():
            got = tuple(getattr(self, name).shape)
            if len(got) != len(shape) or any(s is not None and s != g for s, g in zip(shape, got)):
                raise ValueError(f"FlowBatch.{name} has shape {got}, expected {shape} (None = any)")

    def to(self, device) -> "FlowBatch":
        moved = {f.name: getattr(self, f.name) for f in fields(self)}
        return FlowBatch(**{k: (v.to(device, non_blocking=True) if isinstance(v, Tensor) else v)
                            for k, v in moved.items()})


def _choose(rng: np.random.Generator, n_have: int, n_want: int) -> np.ndarray:
    """``n_want`` indices into ``n_have`` (> 0) points: without replacement when possible, else all + repeats."""
    if n_have >= n_want:
        return rng.choice(n_have, size=n_want, replace=False)
    extra = rng.choice(n_have, size=n_want - n_have, replace=True)
    return rng.permutation(np.concatenate([np.arange(n_have), extra]))


def loss_draws(loss) -> dict[str, bool]:
    """The :class:`PairDataset` keywords a loss config (:class:`training.config.LossWeights`) needs: a second
    pc2 draw for ``pc2_target="independent"``, view masks for ``view_mask``."""
    return {"target_draw": loss.pc2_target == "independent", "view_masks": loss.view_mask}


def in_view(points: np.ndarray, K: np.ndarray, size: tuple[int, int], far: float = FAR_LIMIT_M) -> np.ndarray:
    """(N,) bool: ``points`` (N, 3, a camera's frame, metres) in front of that camera, nearer than ``far``
    along its axis (stage one's far limit) and projecting (K, pixels) inside an image of ``size`` (H, W)."""
    uv, z = geometry.project(np.asarray(points, np.float64), np.asarray(K, np.float64))
    return (z > 1e-6) & (z < far) & geometry.in_image(uv, *size)


def cache_far_limit(reader) -> float:
    """The far limit (metres along the optical axis) the cache's stage one kept points within: its
    ``filters.far_max_z`` when its far filter was on, ``inf`` when off; :data:`FAR_LIMIT_M` for a reader
    without a stage-one manifest."""
    filters = (getattr(reader, "manifest", None) or {}).get("config", {}).get("filters")
    if not filters:
        return FAR_LIMIT_M
    return float(filters.get("far_max_z", FAR_LIMIT_M)) if filters.get("far", True) else math.inf


def independent_draw(rng: np.random.Generator, n_have: int, taken: np.ndarray, n_want: int) -> np.ndarray:
    """``n_want`` indices into ``n_have`` points, avoiding the ``taken`` ones (the net's input) as far as the
    cloud allows: the untaken points first (without replacement), topped up from the whole cloud."""
    rest = np.setdiff1d(np.arange(n_have), taken)
    if len(rest) >= n_want:
        return rng.choice(rest, size=n_want, replace=False)
    return rng.permutation(np.concatenate([rest, rng.choice(n_have, size=n_want - len(rest), replace=True)]))


def random_rigid(rng: np.random.Generator, max_deg: float, max_m: float) -> np.ndarray:
    """A 4×4 rigid motion with Euler angles in ±max_deg (degrees) and translation in ±max_m (metres)."""
    angles = np.radians(rng.uniform(-max_deg, max_deg, size=3)) if max_deg > 0 else np.zeros(3)
    t = rng.uniform(-max_m, max_m, size=3) if max_m > 0 else np.zeros(3)
    return geometry.pose_vec_to_mat(np.concatenate([t, angles]))


def kept_depth(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``depth`` (H, W) with every pixel not in ``uv`` (N, 2) (pixel coordinates of kept points) set to 0."""
    H, W = depth.shape
    flat = np.rint(uv[:, 1]).astype(np.int64) * W + np.rint(uv[:, 0]).astype(np.int64)
    out = np.zeros(H * W, np.float32)
    out[flat] = depth.reshape(-1)[flat]
    return out.reshape(H, W)


class PairDataset(torch.utils.data.Dataset):
    """Samples of a :class:`pipeline.cache.CacheReader` restricted to ``indices``.

    Call :meth:`set_epoch` before each epoch; the draw for pair ``i`` depends only on
    ``(seed, epoch, i)``.
    """

    def __init__(self, reader, indices: list[int], n_points: int, seed: int, colour_features: bool = True,
                 jitter_deg: float = 0.0, jitter_m: float = 0.0, fixed_epoch: int | None = None,
                 depth2_kept_only: bool = False, augment: dict | None = None,
                 ego_speed_scale: tuple[float, float] = (1.0, 1.0), ego_turn_shift: tuple[float, float] = (0.0, 0.0),
                 mirror: float = 0.0, movers: tuple[float, tuple[float, float]] = (0.0, (0.0, 0.0)),
                 target_draw: bool = False, view_masks: bool = False) -> None:
        self.reader = reader
        self.indices = list(indices)
        self.n_points = n_points
        self.seed = seed
        self.colour_features = colour_features
        self.jitter_deg = jitter_deg
        self.jitter_m = jitter_m
        self.depth2_kept_only = depth2_kept_only
        self.augment = dict(augment or {})  # keyword arguments of training.augment.augment_masks
        self.ego_speed_scale = (float(ego_speed_scale[0]), float(ego_speed_scale[1]))
        self.ego_turn_shift = (float(ego_turn_shift[0]), float(ego_turn_shift[1]))  # (degrees, metres)
        self.mirror = float(mirror)
        self.movers = (float(movers[0]), (float(movers[1][0]), float(movers[1][1])))  # (probability, metres)
        self.target_draw = target_draw  # also draw ``pc2_target`` (loss.pc2_target independent)
        self.view_masks = view_masks  # also give ``view1`` / ``view2`` (loss.view_mask)
        self.far = cache_far_limit(reader)  # "in view" means within the far limit this cache was built with
        self.epoch = 0 if fixed_epoch is None else fixed_epoch
        self._fixed = fixed_epoch is not None

    def set_epoch(self, epoch: int) -> None:
        if not self._fixed:
            self.epoch = epoch

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, pos: int) -> dict[str, np.ndarray]:
        i = self.indices[pos]
        s = self.reader[i]
        if len(s.pc1) == 0 or len(s.pc2) == 0:
            raise InputError(getattr(self.reader, "root", "cache"), f"pair {i} has an empty cloud "
                             f"({len(s.pc1)} frame-t, {len(s.pc2)} frame-t+1 points)")
        rng = np.random.default_rng([self.seed, self.epoch - _VAL_EPOCH, i])  # validation draws use tag 0
        # with every augmentation off the masks keep all points and draw nothing: the same draw as without them
        keep1, keep2 = augment_masks(rng, s.pc1, s.pc2, **self.augment)
        k1, k2 = np.flatnonzero(keep1), np.flatnonzero(keep2)
        c1, c2 = k1[_choose(rng, len(k1), self.n_points)], k2[_choose(rng, len(k2), self.n_points)]
        pc1 = s.pc1[c1].astype(np.float32)
        sf = s.static_flow[c1].astype(np.float32)
        gt = None if s.gt_flow is None else s.gt_flow[c1].astype(np.float32)
        A = np.eye(4)  # frame t's camera as the augmentations leave it
        moves = False
        if self.ego_speed_scale != (1.0, 1.0):  # drawn only when on: the default draws stay as they were
            A, moves = speed_scaled_view(s.T, draw_speed_scale(rng, *self.ego_speed_scale)), True
        if self.ego_turn_shift != (0.0, 0.0):  # drawn only when on
            A, moves = turn_shift_view(rng, *self.ego_turn_shift) @ A, True
        if moves:
            moved = geometry.transform_points(A, pc1.astype(np.float64)).astype(np.float32)
            sf = pc1 + sf - moved  # the targets in frame t+1 stay where they were
            gt = None if gt is None else pc1 + gt - moved
            pc1 = moved
        J = np.eye(4)
        if self.jitter_deg > 0 or self.jitter_m > 0:
            J = random_rigid(rng, self.jitter_deg, self.jitter_m)
            sf = (geometry.transform_points(J, (pc1 + sf).astype(np.float64)) - pc1).astype(np.float32)
        moving = None if s.moving is None else np.asarray(s.moving)[c1].astype(bool)
        if self.movers[0] > 0 and rng.random() < self.movers[0]:  # drawn only when on
            made = synthetic_mover(rng, pc1, self.movers[1])
            if made is not None:  # its targets stay; its static flow is the camera's motion at its new place
                idx, at = made
                camera = J @ np.asarray(s.T, np.float64) @ np.linalg.inv(A)  # frame t (as augmented) -> t+1
                if gt is not None:
                    gt[idx] = pc1[idx] + gt[idx] - at
                sf[idx] = geometry.transform_points(camera, at) - at
                pc1[idx] = at
                moving = np.zeros(len(pc1), bool) if moving is None else moving
                moving[idx] = True
        if self.colour_features:
            f1 = s.rgb1[c1].astype(np.float32) / 255.0
            f2 = s.rgb2[c2].astype(np.float32) / 255.0
        else:
            f1 = np.zeros((self.n_points, 3), np.float32)
            f2 = np.zeros((self.n_points, 3), np.float32)
        depth2 = np.asarray(s.depth2, np.float32)
        if self.depth2_kept_only:
            depth2 = kept_depth(depth2, s.uv2)
        out = {"pc1": pc1, "pc2": s.pc2[c2].astype(np.float32), "feat1": f1, "feat2": f2,
               "static_flow": sf, "K": np.asarray(s.K, np.float32), "depth2": depth2,
               "index": np.int64(i)}
        if gt is not None:
            out["gt_flow"] = gt
        if moving is not None:
            out["moving"] = moving
        if self.view_masks:
            size = depth2.shape
            out["view1"] = in_view(pc1 + sf, s.K, size, self.far)
            back = A @ np.linalg.inv(np.asarray(s.T, np.float64))  # frame t+1 -> (augmented) frame t
            out["view2"] = in_view(geometry.transform_points(back, out["pc2"].astype(np.float64)), s.K, size, self.far)
        if self.target_draw:  # drawn only when on
            out["pc2_target"] = s.pc2[independent_draw(rng, len(s.pc2), c2, self.n_points)].astype(np.float32)
        if self.mirror > 0 and rng.random() < self.mirror:  # drawn only when on
            out = mirror_pair(out)
        return out


@dataclass
class LoadFailure:
    """A sample that could not be read, carried out of a DataLoader worker intact.

    DataLoader re-raises a worker's exception as a RuntimeError holding a traceback (it cannot rebuild an
    :class:`InputError`), which would turn "file: problem" into a wall of text; so the worker returns this
    and the training process raises :meth:`error`.
    """

    path: str
    problem: str

    def error(self) -> InputError:
        return InputError(self.path, self.problem)


def collate(samples: list) -> FlowBatch | LoadFailure:
    """Stack samples into a :class:`FlowBatch` (optional fields only when every sample has them); the first
    :class:`LoadFailure` among them, if any, instead."""
    for s in samples:
        if isinstance(s, LoadFailure):
            return s

    def stack(key: str) -> Tensor | None:
        if not all(key in s for s in samples):
            return None
        return torch.from_numpy(np.stack([s[key] for s in samples]))

    return FlowBatch(pc1=stack("pc1"), pc2=stack("pc2"), feat1=stack("feat1"), feat2=stack("feat2"),
                     static_flow=stack("static_flow"), K=stack("K"), depth2=stack("depth2"),
                     index=stack("index"), gt_flow=stack("gt_flow"), moving=stack("moving"),
                     pc2_target=stack("pc2_target"), view1=stack("view1"), view2=stack("view2"))


def pairs_with_gt_flow(reader) -> set[int]:
    """Global indices of the pairs whose block stores ground-truth flow (from the cache's manifest)."""
    out: set[int] = set()
    for seq in reader.manifest["sequences"].values():
        for b in seq["blocks"]:
            if b.get("has_gt_flow", False):
                out.update(range(int(b["first_pair"]), int(b["first_pair"]) + int(b["num_pairs"])))
    return out


def split_pairs(reader, val_fraction: float) -> tuple[list[int], list[int]]:
    """Hold out the last ``val_fraction`` of each sequence's pairs (contiguous, so less leakage)."""
    train: list[int] = []
    val: list[int] = []
    for seq in reader.sequences:
        idx = list(reader.pairs_of(seq))
        n_val = int(math.floor(len(idx) * val_fraction)) if val_fraction > 0 else 0
        if n_val and len(idx) - n_val >= 1:
            train += idx[: len(idx) - n_val]
            val += idx[len(idx) - n_val:]
        else:
            train += idx
    return train, val


def train_val_split(reader, val_fraction: float, val_pairs_max: int) -> tuple[list[int], list[int]]:
    """Training and validation pairs: the held-out tail of every sequence (:func:`split_pairs`), scored
    without labels and by EPE3D where it has ground-truth flow (labelled pairs are kept first); pairs
    held out beyond ``val_pairs_max`` train."""
    train, held = split_pairs(reader, val_fraction)
    with_gt = pairs_with_gt_flow(reader)
    held = sorted(held, key=lambda i: i not in with_gt)
    return sorted(train + held[val_pairs_max:]), sorted(held[:val_pairs_max])


class StepBatches(torch.utils.data.Sampler):
    """Yields the batch (list of dataset positions) of every global step from ``start_step`` on.

    Epoch ``e`` is a permutation seeded by ``(seed, e)``; global step ``s`` takes ``batch_size``
    consecutive entries of it, and rank ``r`` of ``world`` takes its contiguous share of those.
    """

    def __init__(self, n: int, batch_size: int, seed: int, start_step: int, total_steps: int,
                 rank: int = 0, world: int = 1, on_epoch=None) -> None:
        if batch_size % world:
            raise ConfigError(f"batch size {batch_size} is not divisible by the {world} processes")
        if n < batch_size:
            raise ConfigError(f"only {n} training pairs for a batch of {batch_size}")
        self.n, self.bs, self.seed = n, batch_size, seed
        self.start, self.total, self.rank, self.world = start_step, total_steps, rank, world
        self.per_epoch = n // batch_size
        self.on_epoch = on_epoch

    def epoch_of(self, step: int) -> int:
        return step // self.per_epoch

    def batch(self, step: int) -> list[int]:
        epoch, k = divmod(step, self.per_epoch)
        perm = np.random.default_rng([self.seed, epoch]).permutation(self.n)
        glob = perm[k * self.bs:(k + 1) * self.bs]
        share = self.bs // self.world
        return [int(x) for x in glob[self.rank * share:(self.rank + 1) * share]]

    def __iter__(self):
        for step in range(self.start, self.total):
            yield [(self.epoch_of(step), p) for p in self.batch(step)]

    def __len__(self) -> int:
        return max(0, self.total - self.start)


class EpochAware(torch.utils.data.Dataset):
    """Wraps a dataset with ``set_epoch`` so the sampler's (epoch, position) keys select the draw.

    ``carry_errors``: return an :class:`InputError` as a :class:`LoadFailure` (for :func:`collate` to pass
    on) instead of raising it inside a DataLoader worker.
    """

    def __init__(self, base, carry_errors: bool = False) -> None:
        self.base = base
        self.carry_errors = carry_errors

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, key: tuple[int, int]) -> dict[str, np.ndarray] | LoadFailure:
        epoch, pos = key
        self.base.set_epoch(epoch)
        if not self.carry_errors:
            return self.base[pos]
        try:
            return self.base[pos]
        except InputError as exc:
            return LoadFailure(str(exc.path), exc.problem)
