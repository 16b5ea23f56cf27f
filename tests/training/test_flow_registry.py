"""The flow-net and method registries: a second net (tests/tiny_flownet.py, one module) registered with one
line trains with the real trainer (``monoflow-train --model_name tiny``), is scored by ``monoflow-evaluate``
from its checkpoint and runs through the ablations; the checkpoint stores the net's name; the default net
is built exactly as before (same RNG draws); a method registered by name is a ``--baselines`` entry."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch
from _trainer_fixtures import REPO, child_env
from tiny_flownet import TinyFlowConfig, TinyFlowNet

from evaluation.cli import main as evaluate
from core.errors import ConfigError, InputError
from training.model import registry

torch.set_num_threads(1)


@pytest.fixture
def tiny_net():
    """The tiny net registered as ``"tiny"`` for the test (and removed again)."""
    registry.register_flow_net("tiny", TinyFlowConfig, TinyFlowNet)
    yield "tiny"
    registry._NETS.pop("tiny")


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    from pipeline.synth.config import SynthConfig
    from pipeline.synth.generator import generate

    root = tmp_path_factory.mktemp("registry") / "world"
    generate(SynthConfig(width=160, height=48, frames=3, test_frames=3, n_sequences=1), root)
    return root


def test_tiny_net_trains_evaluates_and_runs_the_ablations(tiny_net, world: Path, tmp_path: Path, capsys) -> None:
    from training.cli import main as train

    # the ablations entry: stage one, then every Table II variant trained and scored with the tiny net
    out = tmp_path / "abl"
    assert evaluate(["ablations", "--world", str(world), "--out", str(out), "--tables", "II", "--steps", "2",
                     "--size", "160x48", "--n-points", "256", "--batch-size", "2", "--device", "cpu",
                     "--model-name", "tiny"]) == 0
    table = json.loads((out / "table-ii" / "results.json").read_text())
    assert len(table["rows"]) == 5 and all(np.isfinite(r["EPE3D"]) for r in table["rows"])
    run = Path(table["variants"][-1]["run"])
    ckpt = torch.load(run / "latest.pt", weights_only=True)
    assert ckpt["config"]["model_name"] == "tiny"
    assert tuple(ckpt["config"]["model"]["level_points"]) == (128, 64, 32, 16)
    assert set(ckpt["model"]) == {"mlp.0.weight", "mlp.0.bias", "mlp.2.weight", "mlp.2.bias"}
    capsys.readouterr()

    # monoflow-train with the net's own --model.* flags, on the ablation's cache
    cache = json.loads((run / "config.json").read_text())["config"]["train"]["cache"]
    flow_run = tmp_path / "flow_run"
    assert train(["--cache", cache, "--run_dir", str(flow_run), "--steps", "3", "--model_name", "tiny",
                  "--n_points", "256", "--model.width_scale", "0.5", "--optim.batch_size", "2", "--data.workers", "0",
                  "--device", "cpu", "--threads", "1", "--progress", "false"]) == 0
    saved = torch.load(flow_run / "latest.pt", weights_only=True)
    assert saved["step"] == 3 and saved["config"]["model_name"] == "tiny"
    assert TinyFlowConfig(**saved["config"]["model"]) == TinyFlowConfig(width_scale=0.5)
    assert saved["model"]["mlp.0.weight"].shape == (16, 6)

    # monoflow-evaluate reads the name from the checkpoint and scores the net beside a baseline
    capsys.readouterr()
    split = world / "sceneflow" / "flownet3d"
    assert evaluate(["run", "--split", str(split), "--checkpoint", str(flow_run / "latest.pt"), "--baselines",
                     "zero", "--out", str(tmp_path / "eval"), "--no-progress", "--device", "cpu"]) == 0
    report = json.loads((tmp_path / "eval" / "results.json").read_text())
    assert [r["method"] for r in report["rows"]] == ["ours (flow_run, step 3)", "zero"]
    assert report["protocol"]["n_points"] == 256 and report["protocol"]["n_score"] == 128


def test_a_checkpoint_of_an_unregistered_net_is_one_clear_error(tiny_net, tmp_path: Path) -> None:
    from evaluation.methods import NetMethod
    from training.runtime.checkpoints import save_checkpoint

    cfg = TinyFlowConfig(n_points=64, level_points=(32, 16, 8, 4), feature_dim=0)
    path = save_checkpoint(tmp_path / "tiny.pt", {"kind": "flow", "model": TinyFlowNet(cfg).state_dict(),
                                                  "config": {"model_name": "tiny", "model": asdict(cfg)}})
    net = NetMethod(path, device="cpu")
    assert net.model_name == "tiny" and net.n_score == 32 and not net.uses_colour
    pc = np.random.default_rng(0).normal(size=(64, 3)).astype(np.float32)
    assert net(pc, pc + 1.0).shape == (64, 3)
    registry._NETS.pop("tiny")
    with pytest.raises(InputError, match=r"tiny.pt: checkpoint's model config is invalid: unknown flow net 'tiny'"):
        NetMethod(path, device="cpu")
    registry.register_flow_net("tiny", TinyFlowConfig, TinyFlowNet)


def test_old_checkpoints_without_a_name_hold_a_halflownet(tmp_path: Path) -> None:
    from evaluation.methods import NetMethod
    from testkit.flow_checkpoint import tiny_flow_checkpoint
    from training.model.halflownet import HALFlowNet
    from training.runtime.checkpoints import load_checkpoint, save_checkpoint

    path = tiny_flow_checkpoint(tmp_path / "new.pt")
    ckpt = load_checkpoint(path, kind="flow")
    assert ckpt["config"]["model_name"] == "halflownet"
    del ckpt["config"]["model_name"]
    ckpt.pop("checkpoint_version")
    old = save_checkpoint(tmp_path / "old.pt", ckpt)
    net = NetMethod(old, device="cpu")
    assert net.model_name == "halflownet" and isinstance(net.net, HALFlowNet)


@pytest.mark.parametrize("flag, norm", [(True, "batch"), (False, "none")])
def test_runs_saved_with_the_boolean_batch_norm_field_read_as_they_trained(tmp_path: Path, flag, norm) -> None:
    from training.model.halflownet_config import HALFlowConfig
    from training.model.registry import restore_flow_net
    from testkit.flow_checkpoint import tiny_flow_checkpoint
    from training.runtime.checkpoints import load_checkpoint

    ckpt = load_checkpoint(tiny_flow_checkpoint(tmp_path / "new.pt"), kind="flow")
    fields = dict(ckpt["config"]["model"])
    assert fields.pop("norm") == "batch"
    assert HALFlowConfig.from_saved({**fields, "batch_norm": flag}).norm == norm
    ckpt["config"]["model"] = {**fields, "batch_norm": True}
    _, config, _ = restore_flow_net(ckpt, tmp_path / "old.pt")
    assert config.norm == "batch"


def test_the_registry_builds_the_default_net_exactly_as_its_class() -> None:
    from training.model.halflownet import HALFlowNet
    from training.model.halflownet_config import HALFlowConfig

    cfg = HALFlowConfig(n_points=256, level_points=(64, 32, 16, 8, 4), width_scale=0.25)
    torch.manual_seed(3)
    direct, after_direct = HALFlowNet(cfg).state_dict(), torch.rand(3)
    torch.manual_seed(3)
    built, after_built = registry.construct_model("halflownet", cfg).state_dict(), torch.rand(3)
    assert direct.keys() == built.keys() and all(torch.equal(direct[k], built[k]) for k in direct)
    assert torch.equal(after_direct, after_built)  # the same number of draws from the RNG
    assert registry.flow_net_names()[0] == registry.DEFAULT_NET == "halflownet"
    with pytest.raises(ConfigError, match="unknown flow net 'nope' \\(choose from halflownet"):
        registry.construct_model("nope", cfg)
    with pytest.raises(ConfigError, match="takes a HALFlowConfig, got TinyFlowConfig"):
        registry.construct_model("halflownet", TinyFlowConfig())
    with pytest.raises(ConfigError, match="already registered"):
        registry.register_flow_net("halflownet", TinyFlowConfig, TinyFlowNet)


def test_train_flags_and_toml_follow_the_model_name(tiny_net, tmp_path: Path) -> None:
    from core.options import build_config
    from training.cli import apply_n_points, build_parser
    from training.config import TrainConfig

    argv = ["--model_name", "tiny", "--n_points", "512", "--model.width_scale", "2"]
    args = build_parser(argv).parse_args(argv)
    apply_n_points(args, "tiny")
    cfg = build_config(TrainConfig, args)
    assert cfg.model == TinyFlowConfig(n_points=512, level_points=(256, 128, 64, 32), width_scale=2.0)
    assert "--model.level_k" not in build_parser(argv).format_help()
    toml = tmp_path / "run.toml"
    toml.write_text('model_name = "tiny"\n[model]\nfeature_dim = 0\n')
    argv = ["--config", str(toml), "--model.width_scale", "0.5"]
    cfg = build_config(TrainConfig, build_parser(argv).parse_args(argv), toml)
    assert cfg.model == TinyFlowConfig(feature_dim=0, width_scale=0.5) and cfg.model_name == "tiny"
    with pytest.raises(SystemExit):  # a HALFlowNet flag is not one of the tiny net's
        build_parser(["--model_name", "tiny"]).parse_args(["--model_name", "tiny", "--model.level_k", "1,1,1,1,1"])


def test_building_the_train_parser_and_config_imports_no_torch() -> None:
    code = ("import sys\nfrom training.cli import build_parser\nfrom training.config import TrainConfig\n"
            "p = build_parser()\ncfg = TrainConfig()\nassert cfg.model.output_points == (2048, 1024, 256, 64)\n"
            "print('TORCH_LOADED', 'torch' in sys.modules, len(p._actions))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=child_env(), capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert "TORCH_LOADED False" in out.stdout


class _Constant:
    """A method that predicts one fixed flow everywhere (metres)."""

    name = "constant"

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        return np.tile(np.float32([0.0, 0.0, -0.5]), (len(pc1), 1))


def test_a_registered_method_is_a_baseline(world: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    from evaluation import methods

    monkeypatch.setitem(methods._METHODS, "constant", methods.MethodEntry(_Constant))
    assert "constant" in methods.method_names() and "refine" in methods.method_names(wrappers=True)
    assert evaluate(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--baselines", "zero,constant",
                     "--out", str(tmp_path / "eval"), "--no-progress", "--n-points", "256", "--n-score", "64"]) == 0
    rows = json.loads((tmp_path / "eval" / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["zero", "constant"] and rows[0]["EPE3D"] != rows[1]["EPE3D"]
    assert evaluate(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--baselines", "refine"]) == 2
    assert "unknown baseline 'refine' (choose from zero, static, icp-p2p, icp-p2l, fgr, tvote, rvote, nsfp, nsfp-full, constant)" in \
        capsys.readouterr().err
    with pytest.raises(ConfigError, match="unknown wrapper 'zero'"):
        methods.make_method("zero", _Constant())


def test_a_model_config_field_this_code_does_not_know_is_named(tmp_path: Path) -> None:
    """A checkpoint whose ``config.model`` holds a field this version does not have (written by a newer version,
    or a scratch edit): one InputError naming the file and the field, not "lacks the layout"."""
    from testkit.flow_checkpoint import tiny_flow_checkpoint
    from training.model.registry import restore_flow_net
    from training.runtime.checkpoints import load_checkpoint

    ckpt = load_checkpoint(tiny_flow_checkpoint(tmp_path / "new.pt"), kind="flow")
    ckpt["config"]["model"]["eval_departure_from"] = "vote"
    with pytest.raises(InputError, match=r"future.pt: checkpoint's model config has a field this version of the "
                                         r"halflownet net does not know: 'eval_departure_from'"):
        restore_flow_net(ckpt, tmp_path / "future.pt")
    ckpt["config"]["model"]["eval_rounds"] = 3  # every unknown field is named, in order
    with pytest.raises(InputError, match=r"has fields this version of the halflownet net does not know: "
                                         r"'eval_departure_from', 'eval_rounds'"):
        restore_flow_net(ckpt, tmp_path / "future.pt")


def test_a_model_config_that_is_no_mapping_is_named_as_such(tmp_path: Path) -> None:
    """A checkpoint whose ``config.model`` is a list (a scratch edit, another tool's file): one InputError naming the
    file and what the entry is, not the generic "lacks the trainer's layout" that a missing key gets."""
    from testkit.flow_checkpoint import tiny_flow_checkpoint
    from training.model.registry import restore_flow_net
    from training.runtime.checkpoints import load_checkpoint

    ckpt = load_checkpoint(tiny_flow_checkpoint(tmp_path / "net.pt"), kind="flow")
    ckpt["config"]["model"] = [2048, 512]
    with pytest.raises(InputError, match=r"odd.pt: checkpoint's config.model is a list, not a mapping of the "
                                         r"halflownet net's fields"):
        restore_flow_net(ckpt, tmp_path / "odd.pt")
    del ckpt["config"]["model"]
    with pytest.raises(InputError, match=r"odd.pt: checkpoint lacks the trainer's layout"):
        restore_flow_net(ckpt, tmp_path / "odd.pt")


def test_an_older_run_s_field_is_read_not_refused(tmp_path: Path) -> None:
    """``batch_norm`` (before ``norm`` replaced it) is no field of the config any more, yet a checkpoint holding it
    is an older run's, not a newer one's: it restores, as it trained."""
    from testkit.flow_checkpoint import tiny_flow_checkpoint
    from training.model.registry import restore_flow_net
    from training.runtime.checkpoints import load_checkpoint

    ckpt = load_checkpoint(tiny_flow_checkpoint(tmp_path / "old.pt"), kind="flow")
    model = ckpt["config"]["model"]
    norm = model.pop("norm")
    model["batch_norm"] = norm == "batch"
    _, config, _ = restore_flow_net(ckpt, tmp_path / "old.pt")
    assert config.norm == ("batch" if norm == "batch" else "none")
