"""Batched depth and pose inference on uint8 RGB frames, on CPU or CUDA, optionally with autocast.

The runner counts every image and every forward pass through each net, so that a benchmark can assert
that each frame's depth is computed once (``depth_images == number of distinct frames``) and each pair's
pose once (``pose_pairs == number of pairs``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
import torch
from torch import Tensor

from core.errors import ConfigError
from core.geometry import pose_vec_to_mat
from pipeline.nets.depth_net import DispResNet, disp_to_depth
from pipeline.nets.normalize import normalize_image
from pipeline.nets.pose_net import PoseResNet


def resolve_device(device: str | torch.device = "auto") -> torch.device:
    """``'auto'`` → CUDA when available, else CPU; ``'cuda'`` without a GPU is a :class:`ConfigError`."""
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ConfigError(f"unknown device {device!r} ({exc})") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {device!r} requested but CUDA is not available")
    if dev.type not in ("cpu", "cuda"):
        raise ConfigError(f"unsupported device {device!r} (use auto, cpu or cuda)")
    return dev


def _check_frames(images: np.ndarray | Tensor, name: str) -> Tensor:
    t = torch.as_tensor(images)
    if t.dim() != 4 or t.shape[-1] != 3 or t.dtype != torch.uint8:
        raise ValueError(f"{name}: expected uint8 RGB frames (N, H, W, 3), got {t.dtype} {tuple(t.shape)}")
    return t


class DepthPoseRunner:
    """Runs a :class:`DispResNet` and/or a :class:`PoseResNet` in eval mode over batches of frames.

    The nets are moved to ``device`` and switched to eval mode (in place). ``amp`` enables autocast
    (float16 on CUDA, bfloat16 on CPU); outputs are always returned in full precision.
    Counters: ``depth_images``/``depth_forwards`` and ``pose_pairs``/``pose_forwards``.
    """

    def __init__(
        self,
        depth_net: DispResNet | None,
        pose_net: PoseResNet | None,
        device: str | torch.device = "auto",
        amp: bool = False,
        batch_size: int = 8,
    ) -> None:
        if batch_size < 1:
            raise ConfigError(f"batch_size must be >= 1, got {batch_size}")
        self.device = resolve_device(device)
        self.amp = bool(amp)
        self.batch_size = int(batch_size)
        self.depth_net = None if depth_net is None else depth_net.to(self.device).eval()
        self.pose_net = None if pose_net is None else pose_net.to(self.device).eval()
        self.reset_counters()

    def reset_counters(self) -> None:
        """Zero the image/pair and forward-pass counters."""
        self.depth_images = 0
        self.depth_forwards = 0
        self.pose_pairs = 0
        self.pose_forwards = 0

    def _autocast(self) -> contextlib.AbstractContextManager:
        if not self.amp:
            return contextlib.nullcontext()
        dtype = torch.float16 if self.device.type == "cuda" else torch.bfloat16
        return torch.autocast(device_type=self.device.type, dtype=dtype)

    def _batches(self, frames: Tensor) -> Iterator[Tensor]:
        """Normalised (B, 3, H, W) float32 batches on the device (uint8 is what crosses the bus)."""
        for start in range(0, frames.shape[0], self.batch_size):
            chunk = frames[start : start + self.batch_size]
            if self.device.type == "cuda":
                chunk = chunk.contiguous().pin_memory().to(self.device, non_blocking=True)
            yield normalize_image(chunk.permute(0, 3, 1, 2))

    @torch.inference_mode()
    def depth(self, images: np.ndarray | Tensor) -> np.ndarray:
        """Depth ``1/disp`` (N, H, W) float32 (metres up to an unknown scale) of uint8 frames (N, H, W, 3).

        H and W must be multiples of 32 (the working size; see docs/design.md §3).
        """
        if self.depth_net is None:
            raise ConfigError("this runner has no depth net")
        frames = _check_frames(images, "depth images")
        H, W = frames.shape[1:3]
        if H % 32 or W % 32:
            raise ConfigError(f"the depth net needs a working size whose sides are multiples of 32, got {W}×{H}")
        out = np.empty((frames.shape[0], H, W), dtype=np.float32)
        done = 0
        for batch in self._batches(frames):
            with self._autocast():
                disp = self.depth_net(batch)
            self.depth_forwards += 1
            self.depth_images += batch.shape[0]
            depth = disp_to_depth(disp.float())[:, 0]
            out[done : done + batch.shape[0]] = depth.cpu().numpy()
            done += batch.shape[0]
        return out

    @torch.inference_mode()
    def pose_vectors(self, img_t: np.ndarray | Tensor, img_t1: np.ndarray | Tensor) -> np.ndarray:
        """Raw 6-vectors ``[tx, ty, tz, rx, ry, rz]`` (N, 6) float32 of ``T_{t→t+1}``.

        That is ``pose_net(img_t, img_t1)`` on uint8 frames (N, H, W, 3).
        """
        if self.pose_net is None:
            raise ConfigError("this runner has no pose net")
        a = _check_frames(img_t, "img_t")
        b = _check_frames(img_t1, "img_t1")
        if a.shape != b.shape:
            raise ValueError(f"img_t {tuple(a.shape)} and img_t1 {tuple(b.shape)} differ in shape")
        out = np.empty((a.shape[0], 6), dtype=np.float32)
        done = 0
        for batch_a, batch_b in zip(self._batches(a), self._batches(b)):
            with self._autocast():
                vec = self.pose_net(batch_a, batch_b)
            self.pose_forwards += 1
            self.pose_pairs += batch_a.shape[0]
            out[done : done + batch_a.shape[0]] = vec.float().cpu().numpy()
            done += batch_a.shape[0]
        return out

    def pose(self, img_t: np.ndarray | Tensor, img_t1: np.ndarray | Tensor) -> np.ndarray:
        """``T_{t→t+1}`` (N, 4, 4) float64: maps frame-t camera coordinates to frame-t+1's, ``p1 = R p0 + t``.

        Translation is in the depth net's unknown scale; R = Rx·Ry·Rz from the predicted Euler angles.
        """
        return pose_vec_to_mat(self.pose_vectors(img_t, img_t1).astype(np.float64))
