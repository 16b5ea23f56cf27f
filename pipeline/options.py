"""Dataclass configs as command-line flags and TOML files (``--config FILE.toml`` plus flags).

A field ``lr`` becomes ``--lr``; a nested dataclass field ``model.width_scale`` becomes
``--model.width_scale``. Precedence: dataclass defaults < TOML file < flags. Tuples take
comma-separated values (``--alpha 0.16,0.08,0.04,0.02``); booleans take ``true``/``false``.
"""

from __future__ import annotations

import argparse
import dataclasses
import tomllib
import typing
from pathlib import Path
from typing import Any

from pipeline.errors import ConfigError, InputError


def _fields(cls) -> list[dataclasses.Field]:
    return list(dataclasses.fields(cls))


def _hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_dc(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _parse_bool(text: str) -> bool:
    low = text.strip().lower()
    if low in ("1", "true", "yes", "on"):
        return True
    if low in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true/false, got '{text}'")


def _converter(tp: Any):
    """A function turning a flag's text into a value of type ``tp``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        inner = [a for a in args if a is not type(None)]
        conv = _converter(inner[0]) if len(inner) == 1 else str
        return lambda s: None if s.lower() in ("none", "null", "") else conv(s)
    if origin is typing.Literal:
        choices = args

        def lit(s: str):
            for c in choices:
                if str(c) == s:
                    return c
            raise argparse.ArgumentTypeError(f"expected one of {', '.join(map(str, choices))}, got '{s}'")

        return lit
    if origin in (tuple, list):
        elem = args[0] if args else str
        conv = _converter(elem)
        return lambda s: tuple(conv(x) for x in s.split(",") if x != "")
    if tp is bool:
        return _parse_bool
    if tp in (int, float, str):
        return tp
    return str


def add_dataclass_args(parser: argparse.ArgumentParser, cls, prefix: str = "") -> None:
    """Add one ``--flag`` per (nested) field of dataclass ``cls``; defaults stay unset (None)."""
    hints = _hints(cls)
    for f in _fields(cls):
        tp = hints[f.name]
        name = f"{prefix}{f.name}"
        if _is_dc(tp):
            add_dataclass_args(parser, tp, prefix=f"{name}.")
            continue
        help_text = f.metadata.get("help", "")
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        parser.add_argument(f"--{name}", dest=name, type=_converter(tp), default=None,
                            help=f"{help_text} (default: {default})".strip())


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _build(cls, values: dict[str, Any], prefix: str, source: str):
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    known = {f.name for f in _fields(cls)}
    for key in values:
        head = key[len(prefix):].split(".")[0] if key.startswith(prefix) else None
        if head is not None and head not in known:
            raise ConfigError(f"{source}: unknown option '{key}' for {cls.__name__}")
    for f in _fields(cls):
        tp = hints[f.name]
        name = f"{prefix}{f.name}"
        if _is_dc(tp):
            kwargs[f.name] = _build(tp, values, f"{name}.", source)
        elif name in values:
            v = values[name]
            if isinstance(v, list):
                v = tuple(v)
            kwargs[f.name] = v
    return cls(**kwargs)


def load_toml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        return _flatten(tomllib.loads(path.read_text()))
    except FileNotFoundError:
        raise InputError(path, "config file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(path, f"not valid TOML ({exc})") from None


def build_config(cls, args: argparse.Namespace, config_file: str | Path | None = None, base=None):
    """Resolve ``cls`` from defaults (or the ``base`` instance, e.g. a preset) < TOML ``config_file`` < flags
    set in ``args``."""
    values: dict[str, Any] = _flatten(dataclasses.asdict(base)) if base is not None else {}
    source = "flags"
    if config_file:
        values.update(load_toml(config_file))
        source = str(config_file)
    for key, v in vars(args).items():
        if v is not None and "." in key or (v is not None and key in {f.name for f in _fields(cls)}):
            values[key] = v
    return _build(cls, values, "", source)


def config_from_dict(cls, data: dict[str, Any]):
    """Rebuild a (nested) dataclass config from its ``dataclasses.asdict`` form."""
    return _build(cls, _flatten(data), "", "saved config")
