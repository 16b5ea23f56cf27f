"""Load and save depth/pose net checkpoints in SC-SfMLearner's format.

A checkpoint is ``{'epoch': int, 'state_dict': {...}}`` (the official ``dispnet_model_best.pth.tar`` and
``exp_pose_model_best.pth.tar``) or a bare state dict; a ``module.`` prefix (DataParallel/DDP) is stripped.
Loading is strict: any missing or unexpected key or shape mismatch raises
:class:`core.errors.InputError` with one line naming the file and the first offending keys.
Files are read with ``torch.load(weights_only=True)``: no code inside a checkpoint is ever run.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path

import torch
from torch import Tensor, nn

from core.errors import InputError
from pipeline.nets.depth_net import DispResNet
from pipeline.nets.pose_net import PoseResNet
from pipeline.nets.resnet import RESNET_SPECS

_SHOW = 4  # offending keys listed per kind
_BOTTLENECK_KEY = re.compile(r"^encoder\.encoder\.layer\d\.\d+\.conv3\.weight$")


def read_state_dict(path: str | os.PathLike[str]) -> dict[str, Tensor]:
    """The state dict stored in ``path`` (CPU tensors, ``module.`` prefixes stripped)."""
    from core.safeload import load_weights_only

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such checkpoint file")
    obj = load_weights_only(path)
    if isinstance(obj, Mapping) and "state_dict" in obj:
        obj = obj["state_dict"]
    if not isinstance(obj, Mapping) or not obj:
        raise InputError(path, "checkpoint holds no state dict (expected a dict of tensors or {'state_dict': ...})")
    state: dict[str, Tensor] = {}
    for key, value in obj.items():
        if not isinstance(key, str) or not isinstance(value, Tensor):
            raise InputError(path, f"state dict entry {key!r} is a {type(value).__name__}, not a tensor")
        state[key.removeprefix("module.")] = value
    return state


def detect_resnet_layers(state: Mapping[str, Tensor]) -> int:
    """18 or 50: ResNet-50's Bottleneck blocks have a ``conv3``, ResNet-18's BasicBlocks do not."""
    return 50 if any(_BOTTLENECK_KEY.match(k) for k in state) else 18


def _listing(items: list[str]) -> str:
    shown = ", ".join(items[:_SHOW])
    return shown + (f", … (+{len(items) - _SHOW} more)" if len(items) > _SHOW else "")


def check_state_dict(net: nn.Module, state: Mapping[str, Tensor], path: str | os.PathLike[str], what: str) -> None:
    """Raise a one-line InputError unless ``state`` has exactly ``net``'s keys and shapes.

    BatchNorm ``num_batches_tracked`` buffers may be absent (pre-0.4.1 checkpoints; torch fills them in).
    """
    expected = net.state_dict()
    missing = [k for k in expected if k not in state and not k.endswith("num_batches_tracked")]
    unexpected = [k for k in state if k not in expected]
    shapes = [
        f"{k}: file {tuple(state[k].shape)} vs net {tuple(v.shape)}"
        for k, v in expected.items()
        if k in state and tuple(state[k].shape) != tuple(v.shape)
    ]
    if not (missing or unexpected or shapes):
        return
    parts = []
    if missing:
        parts.append(f"{len(missing)} missing keys ({_listing(missing)})")
    if unexpected:
        parts.append(f"{len(unexpected)} unexpected keys ({_listing(unexpected)})")
    if shapes:
        parts.append(f"{len(shapes)} shape mismatches ({_listing(shapes)})")
    raise InputError(path, f"state dict does not match {what}: " + "; ".join(parts))


def _load(net: nn.Module, state: dict[str, Tensor], path: Path, what: str, device: str | torch.device) -> nn.Module:
    check_state_dict(net, state, path, what)
    net.load_state_dict(state, strict=True)
    return net.to(device).eval()


def _layers(state: Mapping[str, Tensor], resnet_layers: int | None, path: Path) -> int:
    layers = detect_resnet_layers(state) if resnet_layers is None else resnet_layers
    if layers not in RESNET_SPECS:
        raise InputError(path, f"unsupported ResNet depth {layers} (supported: {sorted(RESNET_SPECS)})")
    return layers


def load_depth_net(
    path: str | os.PathLike[str], resnet_layers: int | None = None, map_location: str | torch.device = "cpu"
) -> DispResNet:
    """DispResNet (eval mode, on ``map_location``) from a checkpoint; depth auto-detected when None."""
    path = Path(path)
    state = read_state_dict(path)
    layers = _layers(state, resnet_layers, path)
    return _load(DispResNet(layers), state, path, f"DispResNet-{layers}", map_location)


def load_pose_net(
    path: str | os.PathLike[str], resnet_layers: int | None = None, map_location: str | torch.device = "cpu"
) -> PoseResNet:
    """PoseResNet (eval mode, on ``map_location``) from a checkpoint; depth auto-detected when None."""
    path = Path(path)
    state = read_state_dict(path)
    layers = _layers(state, resnet_layers, path)
    return _load(PoseResNet(layers), state, path, f"PoseResNet-{layers}", map_location)


def _unwrap(net: nn.Module) -> nn.Module:
    while True:  # DataParallel / DDP (.module), torch.compile (._orig_mod)
        for attr in ("module", "_orig_mod"):
            inner = getattr(net, attr, None)
            if isinstance(inner, nn.Module):
                net = inner
                break
        else:
            return net


def save_checkpoint(path: str | os.PathLike[str], net: nn.Module, epoch: int) -> Path:
    """Write ``{'epoch': epoch, 'state_dict': …}`` (CPU tensors, no ``module.`` prefix) atomically.

    The file appears complete or not at all: it is written to ``<path>.tmp-<pid>`` and renamed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to("cpu", copy=True) for k, v in _unwrap(net).state_dict().items()}
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        torch.save({"epoch": int(epoch), "state_dict": state}, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def load_imagenet_encoder(net: DispResNet | PoseResNet, path: str | os.PathLike[str]) -> None:
    """Initialise ``net``'s encoder from a local torchvision ImageNet ResNet state dict (``resnet18-*.pth``).

    For multi-image encoders (the pose net) ``conv1.weight`` is tiled over the stacked images and divided
    by their number, as SC-SfMLearner / Monodepth2 do. Nothing is downloaded.
    """
    path = Path(path)
    state = read_state_dict(path)
    backbone = net.encoder.encoder
    n = backbone.num_input_images
    w = state.get("conv1.weight")
    if n > 1 and w is not None and w.dim() == 4 and w.shape[1] == 3:
        state["conv1.weight"] = torch.cat([w] * n, dim=1) / n
    check_state_dict(backbone, state, path, f"torchvision ResNet-{backbone.num_layers}")
    backbone.load_state_dict(state, strict=True)
