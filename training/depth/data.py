"""Three-frame snippets (t−g, t, t+g) from KITTI-odometry-layout folders (real KITTI or the synthetic world).

Frames are resized to the working size (W, H) and K scaled with them (``pipeline.sources``); the
augmentation (a random zoom by (sx, sy) ∈ [1, max_scale]² and crop back to (W, H), then a horizontal flip
with probability ½) is applied identically to the snippet's three frames, and K follows it. The draw for
snippet i in epoch e depends only on (seed, e, i), so a batch is the same for any number of workers or
ranks (the sampler is the flow trainer's :class:`training.data.StepBatches`).

A snippet's frames must have consecutive frame ids (t − g, t, t + g): a folder holding a subset of a
sequence never pairs frames across a gap.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import Tensor

from core.errors import ConfigError, InputError
from core.geometry import crop_intrinsics, scale_intrinsics
from pipeline.kitti.odometry import OdometrySequence, find_sequences
from pipeline.sources import read_frames, working_K
from training.depth.config import DepthDataConfig

NET_MULTIPLE = 32  # DispResNet needs H and W divisible by this
NET_MIN_SIDE = 64  # and at least 2 cells of its stride-32 feature map (reflection padding)


def check_size(width: int, height: int) -> tuple[int, int]:
    """(H, W) of the working size; ConfigError unless both are multiples of 32 and at least 64."""
    if width < NET_MIN_SIDE or height < NET_MIN_SIDE or width % NET_MULTIPLE or height % NET_MULTIPLE:
        raise ConfigError(f"working size {width}x{height}: width and height must be multiples of "
                          f"{NET_MULTIPLE} and at least {NET_MIN_SIDE} (the depth net's stride)")
    return int(height), int(width)


def expand_ids(root: str, ids: tuple[str, ...] | list[str]) -> list[str]:
    """Sequence ids with ``last`` replaced by the last sequence under ``root``; each checked to exist."""
    found = find_sequences(root)
    if not found:
        raise InputError(root, "no sequence folder with a calib.txt under sequences/")
    out = [found[-1] if str(s) == "last" else str(s) for s in ids]
    for s in out:
        if s not in found:
            raise InputError(f"{root}/sequences/{s}", f"sequence not found (have: {', '.join(found)})")
    return out


def resolve_splits(cfg: DepthDataConfig) -> tuple[list[str], list[str]]:
    """(training ids, validation ids): the configured ones, checked against the folder.

    A validation id ``last`` stands for the last sequence found (the synthetic world's test sequence).
    """
    no_val = [str(s) for s in cfg.val_sequences] == ["none"]
    val = [] if no_val else expand_ids(cfg.root, cfg.val_sequences)
    train = expand_ids(cfg.root, cfg.sequences) if cfg.sequences else [
        s for s in find_sequences(cfg.root) if s not in val]
    if not train:
        raise ConfigError(f"{cfg.root}: no training sequence left (all are validation sequences)")
    if not val and not no_val and len(train) == 1:
        val = list(train)  # one sequence: validate on it (see DepthDataConfig.val_sequences)
    return train, val


def open_sequences(root: str, ids: list[str], camera: str, strict_pose_count: bool = True) -> list[OdometrySequence]:
    return [OdometrySequence(root, s, camera=camera, strict_pose_count=strict_pose_count) for s in ids]


def snippet_centres(seq: OdometrySequence, gap: int) -> list[int]:
    """Positions t whose frames t − gap and t + gap exist with consecutive frame ids."""
    if gap < 1:
        raise ConfigError(f"frame_gap must be >= 1, got {gap}")
    fr = seq.frames
    have = set(fr)
    return [i for i, f in enumerate(fr) if f - gap in have and f + gap in have]


class FrameStore:
    """Frames of several sequences at the working size, with their K; keeps up to ``capacity`` in memory."""

    def __init__(self, sequences: list[OdometrySequence], hw: tuple[int, int], capacity: int = 0) -> None:
        self.sequences = sequences
        self.hw = hw
        self.capacity = capacity
        self.K = [working_K(s, hw).astype(np.float64) for s in sequences]
        self._cache: dict[tuple[int, int], np.ndarray] = {}

    def frame(self, seq: int, pos: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB of position ``pos`` of sequence number ``seq``."""
        key = (seq, pos)
        img = self._cache.get(key)
        if img is None:
            img = read_frames(self.sequences[seq], [pos], self.hw)[0]
            if len(self._cache) < self.capacity:
                self._cache[key] = img
        return img

    def frames(self, seq: int, positions: list[int]) -> np.ndarray:
        return np.stack([self.frame(seq, p) for p in positions])


def scale_crop(frames: np.ndarray, K: np.ndarray, sx: float, sy: float, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
    """Zoom (N, H, W, 3) frames by (sx, sy) ≥ 1 and crop a random (H, W) window; K follows."""
    N, H, W, _ = frames.shape
    Hs, Ws = max(H, int(round(H * sy))), max(W, int(round(W * sx)))
    top = int(rng.integers(0, Hs - H + 1))
    left = int(rng.integers(0, Ws - W + 1))
    out = np.empty_like(frames)
    for k in range(N):
        big = cv2.resize(frames[k], (Ws, Hs), interpolation=cv2.INTER_LINEAR)
        out[k] = big[top:top + H, left:left + W]
    K = crop_intrinsics(scale_intrinsics(K, Ws / W, Hs / H), left, top)
    return out, K


def hflip(frames: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mirror (N, H, W, 3) frames left–right: pixel u ↦ W − 1 − u, so cx ↦ W − 1 − cx."""
    W = frames.shape[2]
    K = K.copy()
    K[0, 2] = (W - 1) - K[0, 2]
    return np.ascontiguousarray(frames[:, :, ::-1]), K


class SnippetDataset(torch.utils.data.Dataset):
    """Snippets of ``sequences``; item = {'images': (3, H, W, 3) uint8 [t−g, t, t+g], 'K': (3, 3), 'index'}.

    Call :meth:`set_epoch` before each epoch (done by :class:`training.data.EpochAware`).
    """

    def __init__(self, sequences: list[OdometrySequence], cfg: DepthDataConfig, seed: int, augment: bool = True
                 ) -> None:
        self.cfg = cfg
        self.hw = check_size(cfg.width, cfg.height)
        self.store = FrameStore(sequences, self.hw, cfg.cache_frames)
        self.items = [(k, t) for k, s in enumerate(sequences) for t in snippet_centres(s, cfg.frame_gap)]
        self.seed = seed
        self.augment = augment
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, pos: int) -> dict[str, np.ndarray]:
        k, t = self.items[pos]
        g = self.cfg.frame_gap
        frames = self.store.frames(k, [t - g, t, t + g])
        K = self.store.K[k].copy()
        if self.augment:
            rng = np.random.default_rng([self.seed, self.epoch, pos])
            if self.cfg.scale_crop and self.cfg.max_scale > 1.0:
                sx, sy = rng.uniform(1.0, self.cfg.max_scale, size=2)
                frames, K = scale_crop(frames, K, float(sx), float(sy), rng)
            if self.cfg.flip and rng.random() < 0.5:
                frames, K = hflip(frames, K)
        return {"images": frames, "K": K.astype(np.float32), "index": np.int64(pos)}


@dataclass
class SnippetBatch:
    """B snippets: images (B, 3 frames, 3, H, W) uint8 RGB, K (B, 3, 3) float32 pixels, index (B,)."""

    images: Tensor
    K: Tensor
    index: Tensor

    def to(self, device) -> "SnippetBatch":
        return SnippetBatch(self.images.to(device, non_blocking=True), self.K.to(device, non_blocking=True),
                            self.index)


def collate(samples: list[dict[str, np.ndarray]]) -> SnippetBatch:
    images = torch.from_numpy(np.stack([s["images"] for s in samples])).permute(0, 1, 4, 2, 3).contiguous()
    return SnippetBatch(images=images, K=torch.from_numpy(np.stack([s["K"] for s in samples])),
                        index=torch.tensor([int(s["index"]) for s in samples]))
