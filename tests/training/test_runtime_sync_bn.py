"""GlobalBatchNorm: two gloo processes with half a batch each equal one process with the whole batch.

The two-process test cannot hang and tears down cleanly: the process group meets in a file store (no port
to race for), every collective and wait has a timeout, both ranks pass a barrier before the group is
destroyed (a rank tearing down while the other still talks aborted with "terminate called without an
active exception"), and the workers are killed if they outlive the test.
"""

from __future__ import annotations

import datetime
import os
import queue as queue_module

import numpy as np
import pytest
import torch
from torch import nn

from training.runtime.sync_bn import GlobalBatchNorm, convert_batchnorm


WAIT_S = 120  # generous on a loaded 2-core machine; the test takes a few seconds


def _net() -> nn.Module:
    torch.manual_seed(3)
    return nn.Sequential(nn.Linear(4, 6, bias=False), nn.BatchNorm1d(6), nn.ReLU(), nn.Linear(6, 2))


def _data() -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(7)
    x = torch.randn(2, 10, 4, generator=g) * torch.tensor([1.0, 3.0, 0.5, 2.0]) + 1.5
    return x, torch.randn(2, 10, 2, generator=g)


def _loss(net: nn.Module, x: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-element mean, like the flow losses; called twice per step like the trainer's two passes."""
    return ((net(x) - target) ** 2).mean() + (net(0.5 * x) ** 2).mean()


def _worker(rank: int, store_file: str, queue) -> None:
    import torch.distributed as dist
    from torch.nn.parallel import DistributedDataParallel as DDP

    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{store_file}", rank=rank, world_size=2,
                            timeout=datetime.timedelta(seconds=WAIT_S))
    try:
        net = convert_batchnorm(_net(), torch.device("cpu"))
        ddp = DDP(net)
        x, target = _data()
        _loss(ddp, x[rank].reshape(-1, 4), target[rank].reshape(-1, 2)).backward()
        bn = net[1]
        # numpy, not tensors: torch's queue would pass tensors as shared memory this process frees on exit
        queue.put((rank, {k: p.grad.numpy().copy() for k, p in net.named_parameters()},
                   bn.running_mean.numpy().copy(), bn.running_var.numpy().copy(), type(bn).__name__))
        dist.barrier()  # neither rank tears down while the other may still be in a collective
    finally:
        dist.destroy_process_group()
    # The work is done and handed over: flush the queue, then leave without the interpreter's teardown, where
    # gloo's C++ destructors intermittently abort the process ("terminate called without an active
    # exception", exit -6) after everything succeeded. An exception above still exits non-zero.
    queue.close()
    queue.join_thread()
    os._exit(0)


def test_convert_shares_parameters_and_keeps_state_dict_keys():
    net = _net()
    before = {k: v for k, v in net.state_dict().items()}
    weight = net[1].weight
    conv = convert_batchnorm(net, torch.device("cpu"))
    assert isinstance(conv[1], GlobalBatchNorm) and conv[1].weight is weight
    assert conv.state_dict().keys() == before.keys()


def test_single_process_is_plain_batch_norm():
    torch.set_num_threads(1)
    x, target = _data()
    plain, conv = _net(), convert_batchnorm(_net(), torch.device("cpu"))
    for net in (plain, conv):
        _loss(net, x.reshape(-1, 4), target.reshape(-1, 2)).backward()
    for (k, a), (_, b) in zip(plain.named_parameters(), conv.named_parameters()):
        assert torch.equal(a.grad, b.grad), k
    assert torch.equal(plain[1].running_var, conv[1].running_var)


def test_two_processes_match_one_process_with_the_whole_batch(tmp_path):
    torch.set_num_threads(1)
    ctx = torch.multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    procs = [ctx.Process(target=_worker, args=(r, str(tmp_path / "store"), queue), daemon=True) for r in range(2)]
    try:
        for p in procs:
            p.start()
        try:
            results = sorted(queue.get(timeout=WAIT_S) for _ in procs)
        except queue_module.Empty:
            pytest.fail(f"no result within {WAIT_S} s; worker exit codes {[p.exitcode for p in procs]}")
        for p in procs:
            p.join(timeout=WAIT_S)
        assert [p.exitcode for p in procs] == [0, 0]
    finally:
        for p in procs:
            if p.is_alive():
                p.kill()
                p.join(timeout=10)
        queue.close()
    net = _net()
    x, target = _data()
    _loss(net, x.reshape(-1, 4), target.reshape(-1, 2)).backward()
    for rank, grads, mean, var, kind in results:
        assert kind == "GlobalBatchNorm"
        for k, p in net.named_parameters():
            assert np.allclose(grads[k], p.grad.numpy(), rtol=1e-5, atol=1e-6), (rank, k, grads[k], p.grad)
        assert np.allclose(mean, net[1].running_mean.numpy(), atol=1e-6)
        assert np.allclose(var, net[1].running_var.numpy(), atol=1e-6)


def test_rejects_1d_input():
    with pytest.raises(ValueError):
        GlobalBatchNorm(3)(torch.zeros(3))
