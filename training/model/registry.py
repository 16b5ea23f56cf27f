"""Flow nets by name: ``name -> (config dataclass, builder)``, the one place a net is wired in.

The trainer, ``monoflow-evaluate``, the ablations, the selection and the audit build a net with
:func:`construct_model` from the run's ``model_name`` (``TrainConfig.model_name``, ``--model_name``) and
its ``model`` config; a checkpoint stores the name, and :func:`restore_flow_net` reads it back (a
checkpoint written before the name was stored holds a ``"halflownet"``).

Adding a net: one module with its torch-free config dataclass and its ``torch.nn.Module`` keeping
:mod:`training.model.contract`, plus one line in :data:`_NETS` (or :func:`register_flow_net` from outside
the package, as the tests do). The builder may be given as ``"module:attribute"`` so that this module, and
with it the configs and ``--help``, loads without torch; it is imported when a net is first built.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any, Callable

from core.errors import ConfigError, InputError
from training.model.contract import FlowNet, FlowNetConfig
from training.model.halflownet_config import HALFlowConfig

DEFAULT_NET = "halflownet"


@dataclass(frozen=True)
class FlowNetEntry:
    """A registered net: its config dataclass and the builder ``config -> net`` (or ``"module:attr"``)."""

    config: type
    builder: Callable[[Any], FlowNet] | str

    def build(self, config: FlowNetConfig) -> FlowNet:
        builder = self.builder
        if isinstance(builder, str):
            module, _, attr = builder.partition(":")
            builder = getattr(importlib.import_module(module), attr)
        return builder(config)


_NETS: dict[str, FlowNetEntry] = {
    "halflownet": FlowNetEntry(HALFlowConfig, "training.model.halflownet:HALFlowNet"),
}


def register_flow_net(name: str, config: type, builder: Callable[[Any], FlowNet] | str) -> None:
    """Make a net available by ``name`` (a name already taken by another net is refused)."""
    entry = FlowNetEntry(config, builder)
    if _NETS.get(name, entry) != entry:
        raise ConfigError(f"flow net '{name}' is already registered")
    _NETS[name] = entry


def flow_net_names() -> tuple[str, ...]:
    return tuple(_NETS)


def _entry(name: str) -> FlowNetEntry:
    if name not in _NETS:
        raise ConfigError(f"unknown flow net '{name}' (choose from {', '.join(_NETS)})")
    return _NETS[name]


def config_class(name: str) -> type:
    """The config dataclass of net ``name`` (ConfigError for an unknown name)."""
    return _entry(name).config


def construct_model(name: str, config: FlowNetConfig | None = None) -> FlowNet:
    """A freshly initialised net ``name`` with ``config`` (default: the config class's defaults); draws
    from the torch RNG exactly as the net's own constructor does."""
    entry = _entry(name)
    config = entry.config() if config is None else config
    if not isinstance(config, entry.config):
        raise ConfigError(f"flow net '{name}' takes a {entry.config.__name__}, got {type(config).__name__}")
    return entry.build(config)


def model_name_of(run_config: dict[str, Any]) -> str:
    """The net a saved run config (``asdict(TrainConfig)``) trained: its ``model_name``, else the net of
    every run before names were stored."""
    return run_config.get("model_name") or DEFAULT_NET


def _unknown_fields(cls: type, model: dict[str, Any]) -> list[str]:
    """The keys of a saved ``model`` dict that the config dataclass ``cls`` neither has as a field nor reads as an
    older run's (its ``legacy_fields``), sorted; empty for a config class that is no dataclass (its constructor
    then decides)."""
    if not is_dataclass(cls):
        return []
    known = {f.name for f in fields(cls)} | set(getattr(cls, "legacy_fields", ()))
    return sorted(str(k) for k in model if k not in known)


def restore_flow_net(ckpt: dict[str, Any], path: str | Path) -> tuple[str, FlowNetConfig, FlowNet]:
    """(name, config, net with the saved weights, on the CPU, in train mode) of a loaded ``monoflow-train``
    checkpoint (:func:`training.runtime.checkpoints.load_checkpoint`); every problem is one InputError
    naming ``path``."""
    from training.runtime.checkpoints import nonfinite_entries

    path = Path(path)
    try:
        run = ckpt["config"]
        name = model_name_of(run)
        cls = config_class(name)
        model = run["model"]
        if not isinstance(model, dict):
            raise InputError(path, f"checkpoint's config.model is a {type(model).__name__}, not a mapping of the "
                                   f"{name} net's fields")
        unknown = _unknown_fields(cls, model)
        if unknown:  # fields a newer (or a scratch) version of the code wrote
            raise InputError(path, f"checkpoint's model config has {'a field' if len(unknown) == 1 else 'fields'} this "
                                   f"version of the {name} net does not know: {', '.join(map(repr, unknown))}")
        saved = getattr(cls, "from_saved", None)  # a config may read fields of older runs (HALFlowConfig)
        config = saved(model) if saved is not None else cls(**model)
        state = ckpt["model"]
    except (KeyError, TypeError, AttributeError) as exc:
        raise InputError(path, f"checkpoint lacks the trainer's layout (config.model, model): {exc!r}") from None
    except ConfigError as exc:
        raise InputError(path, f"checkpoint's model config is invalid: {exc}") from None
    bad = nonfinite_entries(state) if isinstance(state, dict) else []
    if bad:
        raise InputError(path, f"non-finite weights (NaN or inf) in {', '.join(bad[:4])}"
                               + (f" and {len(bad) - 4} more" if len(bad) > 4 else ""))
    net = construct_model(name, config)
    try:
        net.load_state_dict(state)
    except RuntimeError as exc:
        raise InputError(path, f"weights do not match the model config ({str(exc).splitlines()[0]})") from None
    return name, config, net
