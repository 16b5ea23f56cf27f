"""Label-free checkpoint selection: scores of a net on held-out pairs that need no ground-truth flow.

A real user (KITTI video, no scene-flow labels) must still pick a checkpoint. Candidates, each a mean
over the held-out pairs of a fixed draw (lower is better):

* ``val_loss``: the whole multi-level training loss (eq. 17). Its coarse levels are dominated by
  sampling noise (at 64 points the Chamfer distance between two samplings of the same surfaces is
  metres²; see the objective audit, ``training/audit.py``), so it can fall while the flow worsens.
* ``val_l0``: the finest level's weighted terms alone, α₀(β₁ L_Depth + β₂ L_DS + β₃ L_Cha + β₄ L_LR),
  on the points that are scored — the default criterion (``TrainConfig.select_by``);
* ``val_cycle``: forward–backward consistency, metres: the flow f of pc1 towards pc2, then the net's
  flow b from pc1 + f back towards pc1; mean ‖f + b‖ over the backward pass's finest points. A net that
  outputs zero flow is perfectly consistent, so this is a diagnostic, not a criterion on its own.

How well each tracks EPE3D on the synthetic world is measured in ``docs/learned-flow.md``.
"""

from __future__ import annotations

import torch
from torch import Tensor

CRITERIA = ("val_epe3d", "val_l0", "val_loss")


@torch.no_grad()
def cycle_error(net, pc1: Tensor, feat1: Tensor, out) -> Tensor:
    """(B,) mean forward–backward error in metres (see the module docstring) for a forward ``out``."""
    from training.pointops import three_nn_interpolate

    flow = three_nn_interpolate(pc1, out.points[0], out.flows[0].float())  # (B, N, 3) at every pc1 point
    back = net(pc1 + flow, pc1, feat1, feat1)
    idx = back.indices[0]
    fwd = flow.gather(1, idx[..., None].expand(-1, -1, 3))
    return (fwd + back.flows[0].float()).norm(dim=-1).mean(1)


@torch.no_grad()
def validation_sums(model, batches, loss_weights, device) -> "np.ndarray":
    """Sums over held-out batches (lists of samples): EPE3D sum and points (where labelled), then the
    pair-weighted sums of the total loss, the finest level's weighted loss and the cycle error, and the
    pairs. :func:`scores_from_sums` turns them into means; under DDP the sums of the ranks are reduced
    first."""
    import numpy as np

    from training.data import collate
    from training.losses.total import multi_level_loss
    from training.two_pass import epe3d, forward_two_passes, level_inputs

    sums = np.zeros(6)
    for samples in batches:
        batch = collate(samples).to(device)
        out_o, out_d = forward_two_passes(model, batch)
        levels = level_inputs(batch, out_o, out_d, loss_weights.pc2_target, loss_weights.view_mask)
        total, terms = multi_level_loss(levels, loss_weights)
        e, n = epe3d(out_o, batch) if batch.gt_flow is not None else (0.0, 0)
        cyc = float(cycle_error(model, batch.pc1, batch.feat1, out_o).sum())
        k = len(samples)
        sums += (e, n, float(total) * k, terms["l0/weighted"] * k, cyc, k)
    return sums


def scores_from_sums(sums) -> dict[str, float]:
    """``val_loss``, ``val_l0``, ``val_cycle`` and, where labelled points were scored, ``val_epe3d``."""
    pairs = max(float(sums[5]), 1e-12)
    out = {"val_loss": float(sums[2] / pairs), "val_l0": float(sums[3] / pairs), "val_cycle": float(sums[4] / pairs)}
    if sums[1] > 0:
        out = {"val_epe3d": float(sums[0] / sums[1]), **out}
    return out


def load_flow_net(checkpoint, device: str = "cpu"):
    """The net of a ``monoflow-train`` checkpoint (the registered net its ``config.model_name`` names, with
    the architecture of its ``config.model``), in eval mode."""
    from training.model.registry import restore_flow_net
    from training.runtime.checkpoints import load_checkpoint

    _, _, net = restore_flow_net(load_checkpoint(checkpoint, kind="flow"), checkpoint)
    return net.to(device).eval()


def score_checkpoint(train_config, checkpoint, device: str = "cpu") -> dict[str, float]:
    """The validation scores of a saved net on the held-out pairs of ``train_config`` (its cache, split and
    loss), exactly as the trainer computes them, without a run folder."""
    from pipeline.cache import CacheReader
    from training.data import PairDataset, loss_draws, train_val_split

    cfg, d = train_config, train_config.data
    model = load_flow_net(checkpoint, device)
    reader = CacheReader(cfg.cache)
    _, val_idx = train_val_split(reader, d.val_fraction, d.val_pairs_max)
    val_set = PairDataset(reader, val_idx, d.n_points, cfg.seed, d.colour_features, fixed_epoch=-1,
                          depth2_kept_only=d.depth2_kept_only, **loss_draws(cfg.loss))
    bs = cfg.optim.batch_size
    batches = ([val_set[p] for p in range(s, min(s + bs, len(val_idx)))] for s in range(0, len(val_idx), bs))
    return scores_from_sums(validation_sums(model, batches, cfg.loss, torch.device(device)))
