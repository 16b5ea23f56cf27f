"""Batch norm over the whole data-parallel batch, so that DDP on P processes equals one process.

Under DistributedDataParallel each rank normalises with the statistics of its own share of the batch, so
a 2-process run with a global batch of B pairs is not the 1-process run with B pairs (the per-rank means
and variances differ, and so do the running statistics). Synchronising the norm layers makes every rank
use the statistics of the global batch. torch's :class:`torch.nn.SyncBatchNorm` does that on CUDA only;
:class:`GlobalBatchNorm` does it on any device (the CPU/gloo path the tests run) with two autograd-aware
all-reduces per layer: the sum (mean), then the sum of squared deviations (variance, two-pass, so no
``E[x²] − E[x]²`` cancellation). Outside an initialised multi-process group, or in eval mode, it is plain
batch norm. Parameter and buffer names are those of ``BatchNorm*d``, so checkpoints are interchangeable.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn.modules.batchnorm import _BatchNorm


class _AllReduceSum(torch.autograd.Function):
    """Sum over the ranks; its gradient is the sum of the ranks' gradients (every rank's loss depends on
    the global statistics)."""

    @staticmethod
    def forward(ctx, x: Tensor) -> Tensor:  # type: ignore[override]
        import torch.distributed as dist

        out = x.clone(memory_format=torch.contiguous_format)
        dist.all_reduce(out)
        return out

    @staticmethod
    def backward(ctx, grad: Tensor) -> Tensor:  # type: ignore[override]
        import torch.distributed as dist

        out = grad.clone(memory_format=torch.contiguous_format)
        dist.all_reduce(out)
        return out


def all_reduce_sum(x: Tensor) -> Tensor:
    """Autograd-aware sum of ``x`` over the ranks of the default process group."""
    return _AllReduceSum.apply(x)


def _distributed_world() -> int:
    import torch.distributed as dist

    return dist.get_world_size() if dist.is_available() and dist.is_initialized() else 1


class GlobalBatchNorm(_BatchNorm):
    """Batch norm whose training statistics are those of the batch of all ranks together.

    Input (N, C) or (N, C, *): statistics over every axis but 1 (like ``BatchNorm1d/2d``). Every rank must
    call it the same number of times (it is a collective).
    """

    def _check_input_dim(self, x: Tensor) -> None:
        if x.dim() < 2:
            raise ValueError(f"expected at least 2-D input (N, C, ...), got {x.dim()}-D")

    def forward(self, x: Tensor) -> Tensor:
        self._check_input_dim(x)
        if not self.training or _distributed_world() == 1:
            return super().forward(x)
        dims = [0, *range(2, x.dim())]
        shape = [1, -1] + [1] * (x.dim() - 2)
        count = x.new_tensor([x.numel() / x.shape[1]], dtype=torch.float64)
        sums = all_reduce_sum(torch.cat([x.sum(dims).double(), count]))  # autograd: backward all-reduces too
        n = sums[-1].detach()
        mean = sums[:-1] / n
        centred = x - mean.to(x.dtype).view(shape)
        var = all_reduce_sum(centred.double().pow(2).sum(dims)) / n  # biased, as batch norm normalises with
        y = centred * torch.rsqrt(var + self.eps).to(x.dtype).view(shape)
        if self.affine:
            y = y * self.weight.view(shape) + self.bias.view(shape)
        if self.track_running_stats:
            with torch.no_grad():
                self.num_batches_tracked.add_(1)
                m = 1.0 / float(self.num_batches_tracked) if self.momentum is None else self.momentum
                unbiased = var * (n / (n - 1)) if n > 1 else var
                self.running_mean.mul_(1 - m).add_(m * mean.to(self.running_mean.dtype))
                self.running_var.mul_(1 - m).add_(m * unbiased.to(self.running_var.dtype))
        return y


def convert_batchnorm(module: nn.Module, device: torch.device) -> nn.Module:
    """Replace every ``BatchNorm*d`` of ``module`` by a synchronised one (returns the converted module).

    CUDA: :class:`torch.nn.SyncBatchNorm`; other devices: :class:`GlobalBatchNorm`. Parameters and buffers
    are shared with the originals (same tensors), so an optimiser built afterwards sees them unchanged.
    """
    if device.type == "cuda":
        return nn.SyncBatchNorm.convert_sync_batchnorm(module)
    out = module
    if isinstance(module, _BatchNorm) and not isinstance(module, (GlobalBatchNorm, nn.SyncBatchNorm)):
        out = GlobalBatchNorm(module.num_features, module.eps, module.momentum, module.affine,
                              module.track_running_stats)
        if module.affine:
            out.weight, out.bias = module.weight, module.bias
        if module.track_running_stats:
            out.running_mean, out.running_var = module.running_mean, module.running_var
            out.num_batches_tracked = module.num_batches_tracked
        out.train(module.training)
    for name, child in module.named_children():
        out.add_module(name, convert_batchnorm(child, device))
    return out


__all__ = ["GlobalBatchNorm", "all_reduce_sum", "convert_batchnorm"]
