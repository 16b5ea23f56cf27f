"""Data-parallel training through ``torchrun`` (DistributedDataParallel).

A single process (no ``WORLD_SIZE`` in the environment) runs undistributed. Under torchrun the process
group is initialised with NCCL on CUDA and gloo on the CPU (the CPU path is what the tests exercise).
"""

from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class DistInfo:
    """Where this process stands in the job."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def init_distributed(device) -> DistInfo:
    """Initialise the process group when launched by torchrun; otherwise return a single-process info."""
    import torch.distributed as dist

    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo()
    if not dist.is_initialized():
        backend = "nccl" if device.type == "cuda" else "gloo"
        dist.init_process_group(backend=backend)
    return DistInfo(rank=dist.get_rank(), world_size=dist.get_world_size(),
                    local_rank=int(os.environ.get("LOCAL_RANK", "0")))


def wrap_model(model, info: DistInfo, device, sync_bn: bool = False):
    """Wrap ``model`` in DDP when distributed; return it unchanged otherwise.

    ``sync_bn``: first make every batch norm use the statistics of the global batch
    (:func:`training.runtime.sync_bn.convert_batchnorm`), so the run equals a single-process run with the
    same global batch. The layers are replaced inside ``model``: take the module to save, optimise and
    evaluate from :func:`unwrap` of the result.
    """
    if not info.enabled:
        return model
    from torch.nn.parallel import DistributedDataParallel as DDP

    if sync_bn:
        from training.runtime.sync_bn import convert_batchnorm

        model = convert_batchnorm(model, device)
    ids = [device.index] if device.type == "cuda" else None
    return DDP(model, device_ids=ids)


def unwrap(model):
    """The bare module under a DDP wrapper (for checkpoints: keys never carry ``module.``)."""
    return getattr(model, "module", model)


def all_reduce_mean(values: dict[str, float], info: DistInfo) -> dict[str, float]:
    """Average a dict of floats over the ranks (identity when not distributed)."""
    if not info.enabled or not values:
        return values
    import torch
    import torch.distributed as dist

    keys = sorted(values)
    t = torch.tensor([float(values[k]) for k in keys], dtype=torch.float64)
    dist.all_reduce(t)
    t /= info.world_size
    return dict(zip(keys, t.tolist()))


def barrier(info: DistInfo) -> None:
    if info.enabled:
        import torch.distributed as dist

        dist.barrier()


def shutdown(info: DistInfo) -> None:
    if info.enabled:
        import torch.distributed as dist

        if dist.is_initialized():
            dist.destroy_process_group()
