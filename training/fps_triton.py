"""Farthest point sampling as one Triton kernel (CUDA only, optional; the pure-PyTorch loop is the default).

The PyTorch loop in :func:`training.pointops.farthest_point_sample` launches ~8 small kernels per sampled
point, so on a GPU it is bound by launch latency (2048 samples ≈ 16 k launches). Here one program per batch
element keeps the whole cloud and its running minimum distances in registers and runs the ``n`` steps
inside the kernel. Same rule as the loop: start at index 0, take the point farthest from those taken,
ties to the lowest index, a taken point is never taken again. Distances are the same float32 sums, but the
compiler may fuse multiply-adds, so a near-tie can resolve differently from the loop (the sample is then
another valid farthest-point sample; ``tests/training/test_pointops.py`` checks the property on a GPU).

Available when ``triton`` imports and the tensor is on a CUDA device with at most :data:`MAX_POINTS` points.
"""

from __future__ import annotations

import torch
from torch import Tensor

try:  # Triton ships with CUDA builds of torch only
    import triton
    import triton.language as tl
except ImportError:  # pragma: no cover - the CPU build has no triton
    triton = None

MAX_POINTS = 16384
"""Largest cloud the register-resident kernel takes; larger clouds use the PyTorch loop."""


def available(xyz: Tensor) -> bool:
    """Whether :func:`farthest_point_sample_triton` can run on ``xyz`` (B, N, 3)."""
    return triton is not None and xyz.is_cuda and xyz.shape[-1] == 3 and 0 < xyz.shape[1] <= MAX_POINTS


if triton is not None:

    @triton.jit
    def _fps_kernel(xyz_ptr, out_ptr, N, n, BLOCK: tl.constexpr):
        b = tl.program_id(0)
        base = xyz_ptr + b * 3 * N  # planar (B, 3, N)
        offs = tl.arange(0, BLOCK)
        inside = offs < N
        x = tl.load(base + offs, mask=inside, other=0.0)
        y = tl.load(base + N + offs, mask=inside, other=0.0)
        z = tl.load(base + 2 * N + offs, mask=inside, other=0.0)
        min_d = tl.where(inside, float("inf"), -2.0)  # padding lanes never win
        far = tl.argmin(offs, axis=0)  # index 0, as an int32 tensor (loop-carried type)
        for i in range(n):
            tl.store(out_ptr + b * n + i, far.to(tl.int64))
            px = tl.load(base + far)
            py = tl.load(base + N + far)
            pz = tl.load(base + 2 * N + far)
            dx = x - px
            dy = y - py
            dz = z - pz
            min_d = tl.minimum(min_d, dx * dx + dy * dy + dz * dz)
            min_d = tl.where(offs == far, -1.0, min_d)  # never pick a taken point again
            far = tl.argmax(min_d, axis=0, tie_break_left=True)


def farthest_point_sample_triton(xyz: Tensor, n: int) -> Tensor:
    """Farthest point sampling of (B, N, 3) CUDA points → (B, n) int64 indices (see the module docstring)."""
    if not available(xyz):
        raise RuntimeError("the Triton FPS kernel needs triton, a CUDA tensor (B, N, 3) and N <= "
                           f"{MAX_POINTS}; got {tuple(xyz.shape)} on {xyz.device}")
    B, N, _ = xyz.shape
    planar = xyz.detach().float().transpose(1, 2).contiguous()
    out = torch.empty(B, n, dtype=torch.int64, device=xyz.device)
    block = max(triton.next_power_of_2(N), 128)
    _fps_kernel[(B,)](planar, out, N, n, BLOCK=block, num_warps=16 if block >= 8192 else 8)
    return out
