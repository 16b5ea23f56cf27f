"""The weight average (``optim.ema_decay``): its arithmetic, what checkpoints hold, and resume."""

from __future__ import annotations

import pytest
import torch

from _trainer_fixtures import tiny_cache, tiny_config  # noqa: F401
from core.errors import ConfigError
from training.model.registry import restore_flow_net
from training.runtime.checkpoints import load_checkpoint
from training.runtime.ema import WeightAverage
from training.trainer import Trainer

torch.set_num_threads(1)


def test_average_follows_the_formula_with_warm_up():
    net = torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.BatchNorm1d(2))
    avg = WeightAverage(net, decay=0.9)
    w0 = net[0].weight.detach().clone()
    with torch.no_grad():
        net[0].weight.add_(1.0)
        net[1].num_batches_tracked.fill_(7)
    d = avg.factor()
    assert d == pytest.approx(0.1)  # warm-up: (1 + 0) / (10 + 0)
    avg.update(net)
    assert torch.allclose(avg.module[0].weight, d * w0 + (1 - d) * (w0 + 1.0))
    assert int(avg.module[1].num_batches_tracked) == 7  # integer buffers are copied
    for _ in range(200):
        avg.update(net)
    assert avg.factor() == 0.9  # the warm-up has ended
    assert torch.allclose(avg.module[0].weight, w0 + 1.0, atol=1e-6)  # a constant net is its own average
    assert not avg.module[0].weight.requires_grad
    with pytest.raises(ValueError):
        WeightAverage(net, decay=1.0)


def test_checkpoint_model_is_the_average_and_resume_is_exact(tiny_cache, tmp_path):  # noqa: F811
    """``model`` in a checkpoint is the average (what evaluation restores); the trained weights travel
    under ``trained_model``; a run stopped at step 6 and resumed reaches the uninterrupted run's weights."""
    kw = dict(steps=12, ckpt_every=6, log_every=1, val_every=6, optim={"ema_decay": 0.8, "batch_size": 2})
    full = Trainer(tiny_config(tiny_cache, tmp_path / "full", **kw))
    full.fit()
    full.close()
    ck = load_checkpoint(tmp_path / "full" / "latest.pt", kind="flow")
    assert ck["average_updates"] == 12
    trained, averaged = ck["trained_model"], ck["model"]
    assert any(not torch.equal(trained[k], averaged[k]) for k in trained if trained[k].is_floating_point())
    _, _, net = restore_flow_net(ck, tmp_path / "full" / "latest.pt")
    assert all(torch.equal(net.state_dict()[k], averaged[k]) for k in averaged)

    half = Trainer(tiny_config(tiny_cache, tmp_path / "half", **{**kw, "steps": 6}))
    half.fit()
    half.close()
    rest = Trainer(tiny_config(tiny_cache, tmp_path / "half", **kw), resume=True)
    assert rest.step == 6 and rest.average.updates == 6
    rest.fit()
    rest.close()
    ck2 = load_checkpoint(tmp_path / "half" / "latest.pt", kind="flow")
    for key in ("model", "trained_model"):
        assert all(torch.allclose(ck[key][k].float(), ck2[key][k].float(), atol=1e-6) for k in ck[key]), key


def test_ema_decay_is_checked(tiny_cache, tmp_path):  # noqa: F811
    with pytest.raises(ConfigError, match="ema_decay"):
        Trainer(tiny_config(tiny_cache, tmp_path / "bad", optim={"ema_decay": 1.5}))


@pytest.mark.parametrize("loss", [{"view_mask": True}, {"pc2_target": "independent"}])
def test_loss_switches_train_and_validate(tiny_cache, tmp_path, loss):  # noqa: F811
    """The loss switches that need extra batch fields (view masks, a second pc2 draw) train and validate
    end to end, with finite losses."""
    import math

    trainer = Trainer(tiny_config(tiny_cache, tmp_path / "run", steps=2, val_every=2, loss=loss,
                                  data={"mirror": 0.5, "ego_speed_scale": (0.5, 2.0)}))
    last = trainer.fit()
    trainer.close()
    chamfer = [v for k, v in last.items() if "chamfer" in k]
    assert math.isfinite(last["loss"]) and math.isfinite(last["val_l0"]) and chamfer and min(chamfer) >= 0
