"""Dataclass configs as command-line flags and TOML files (``--config FILE.toml`` plus flags).

A field ``lr`` becomes ``--lr``; a nested dataclass field ``model.width_scale`` becomes
``--model.width_scale``. Precedence: dataclass defaults < TOML file < flags. Tuples take
comma-separated values (``--alpha 0.16,0.08,0.04,0.02``); booleans take ``true``/``false``.

A nested field whose class depends on another field (the net's config on ``model_name``) says so in its
metadata: ``field(..., metadata={"class_from": ("model_name", resolve)})``, ``resolve(name) -> dataclass``;
its flags and its values then follow the selector's value.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import tomllib
import typing
from pathlib import Path
from typing import Any

from core.errors import ConfigError, InputError


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


_ENTRY = re.compile(r"^(\s*)((?:[A-Za-z_][\w*]*)(?:\s*(?:,|/|and)\s*[A-Za-z_][\w*]*)*)\s*:\s+(\S.*)$")


def field_docs(cls) -> dict[str, str]:
    """Per-field help of dataclass ``cls`` taken from its docstring.

    Recognised entries (the style of this project's configs, Google ``Attributes:`` sections included)::

        name: text, continued on lines indented deeper
        width, height: one text for several fields      (also ``a / b`` and ``use_*`` wildcards)

    A field with ``metadata={"help": ...}`` keeps that text; every other field gets its docstring entry, or
    nothing (a test checks that every command's every option ends up with a text).
    """
    names = [f.name for f in _fields(cls)]
    docs: dict[str, str] = {}
    paragraphs: list[str] = []
    for klass in [c for c in cls.__mro__ if dataclasses.is_dataclass(c)]:  # a subclass's entries win
        paragraphs += _docstring_entries(klass.__dict__.get("__doc__") or "", names, docs)
    for n in names:  # a field only mentioned in another entry's text or a paragraph: that text
        if n not in docs:
            word = re.compile(rf"(?<![\w.]){re.escape(n)}(?!\w)")
            hit = next((t for t in docs.values() if word.search(t)), None) or next(
                (p for p in paragraphs if word.search(p)), None)
            if hit:
                docs[n] = hit
    for f in _fields(cls):
        if f.metadata.get("help"):
            docs[f.name] = f.metadata["help"]
    return docs


def _docstring_entries(doc: str, names: list[str], docs: dict[str, str]) -> list[str]:
    """Add the ``name: text`` entries of one docstring to ``docs`` (first entry wins); return its paragraphs."""
    lines = inspect.cleandoc(doc).splitlines()
    i = 0
    while i < len(lines):
        m = _ENTRY.match(lines[i])
        if not m:
            i += 1
            continue
        indent = len(m.group(1))
        text = [m.group(3).strip()]
        j = i + 1
        while j < len(lines) and lines[j].strip() and len(lines[j]) - len(lines[j].lstrip()) > indent \
                and not (_ENTRY.match(lines[j]) and len(_ENTRY.match(lines[j]).group(1)) == indent):
            text.append(lines[j].strip())
            j += 1
        keys = [k.strip() for k in re.split(r"\s*(?:,|/|\band\b)\s*", m.group(2)) if k.strip()]
        body = " ".join(text)
        for key in keys:
            for n in names:
                if n == key or (key.endswith("*") and n.startswith(key[:-1])):
                    docs.setdefault(n, body)
        i = j
    return [" ".join(x.strip() for x in para.splitlines()) for para in re.split(r"\n\s*\n", "\n".join(lines))]


def add_dataclass_args(parser: argparse.ArgumentParser, cls, prefix: str = "",
                       aliases: dict[str, list[str]] | None = None, values: dict[str, Any] | None = None) -> None:
    """Add one ``--flag`` per (nested) field of dataclass ``cls``; defaults stay unset (None).

    Help texts come from :func:`field_docs` (the field's ``help`` metadata or the class docstring).
    ``--name-with-dashes`` is accepted as an alias of ``--name_with_underscores``; ``aliases`` adds others
    ({"data.n_points": ["--n-points"]}). ``values`` holds dotted selector values ({"model_name": "x"})
    that choose the class of a ``class_from`` field (default: the selector's default).
    """
    hints = _hints(cls)
    docs = field_docs(cls)
    for f in _fields(cls):
        tp = hints[f.name]
        name = f"{prefix}{f.name}"
        nested = _nested_class(cls, f, hints, values or {}, prefix)
        if nested is not None:
            add_dataclass_args(parser, nested, prefix=f"{name}.", aliases=aliases, values=values)
            continue
        help_text = docs.get(f.name, "")
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        flags = [f"--{name}"]
        dashed = f"--{name.replace('_', '-')}"
        if dashed != flags[0]:
            flags.append(dashed)
        flags += [a for a in (aliases or {}).get(name, []) if a not in flags]
        metavar = _metavar(tp)
        parser.add_argument(*flags, dest=name, type=_converter(tp), default=None, metavar=metavar,
                            help=f"{help_text} (default: {_show(default)})".strip().replace("%", "%%"))


def _nested_class(cls, f: dataclasses.Field, hints: dict[str, Any], values: dict[str, Any], prefix: str):
    """The dataclass of nested field ``f`` of ``cls`` (None for a plain field): its annotation, or for a
    ``class_from`` field the class its resolver gives for the selector's value in ``values`` (dotted
    names), else the selector's default."""
    chooser = f.metadata.get("class_from")
    if chooser is None:
        return hints[f.name] if _is_dc(hints[f.name]) else None
    selector, resolve = chooser
    key = f"{prefix}{selector}"
    return resolve(values[key] if values.get(key) is not None else
                   next(g.default for g in _fields(cls) if g.name == selector))


def add_underscore_aliases(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Accept ``--a_b`` for every ``--a-b`` option of ``parser`` and its sub-parsers (and the reverse), so every
    command takes the project's one style (``--section.field_name``) and the older dashed spellings alike."""
    for action in list(parser._actions):
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                add_underscore_aliases(sub)
            continue
        for opt in list(action.option_strings):
            if not opt.startswith("--"):
                continue
            for alt in ("--" + opt[2:].replace("-", "_"), "--" + opt[2:].replace("_", "-")):
                if alt != opt and alt not in parser._option_string_actions:
                    action.option_strings.append(alt)
                    parser._option_string_actions[alt] = action
        # the project's style (underscores) is shown first
        action.option_strings.sort(key=lambda o: (not o.startswith("--"), "-" in o[2:]))
    return parser


def _show(value: Any) -> str:
    if isinstance(value, tuple):
        return ",".join(map(str, value)) if value else "empty"
    return str(value)


def _metavar(tp: Any) -> str | None:
    """``{true,false}`` for booleans, ``A,B,...`` for tuples, else argparse's own (the flag's name)."""
    if tp is bool:
        return "{true,false}"
    if tp in (tuple, list) or typing.get_origin(tp) in (tuple, list):
        return "A,B,..."
    return None


def flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested dict (``asdict`` of a config, a TOML file) as dotted ``{"section.field": value}`` pairs;
    lists become tuples (the configs' sequence type)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = tuple(v) if isinstance(v, list) else v
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
        name = f"{prefix}{f.name}"
        nested = _nested_class(cls, f, hints, values, prefix)
        if nested is not None:
            kwargs[f.name] = _build(nested, values, f"{name}.", source)
        elif name in values:
            v = values[name]
            if isinstance(v, list):
                v = tuple(v)
            kwargs[f.name] = v
    return cls(**kwargs)


def load_toml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        return flatten(tomllib.loads(path.read_text()))
    except FileNotFoundError:
        raise InputError(path, "config file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(path, f"not valid TOML ({exc})") from None


def build_config(cls, args: argparse.Namespace, config_file: str | Path | None = None, base=None):
    """Resolve ``cls`` from defaults (or the ``base`` instance, e.g. a preset) < TOML ``config_file`` < flags
    set in ``args``."""
    values: dict[str, Any] = flatten(dataclasses.asdict(base)) if base is not None else {}
    source = "flags"
    if config_file:
        values.update(load_toml(config_file))
        source = str(config_file)
    for key, v in vars(args).items():
        if v is not None and "." in key or (v is not None and key in {f.name for f in _fields(cls)}):
            values[key] = v
    return _build(cls, values, "", source)


def parse_config(cls, argv: list[str] | None, prog: str, description: str, required: tuple[str, ...] = ()):
    """``cls`` (a flat dataclass config) from command-line ``argv``: one flag per field (its field doc as help) over
    the defaults; a field named in ``required`` left empty is argparse's usage error (``--<name> is required``,
    exit code 2)."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_dataclass_args(parser, cls)
    cfg = build_config(cls, parser.parse_args(argv), base=cls())
    for name in required:
        if not getattr(cfg, name):
            parser.error(f"--{name} is required")
    return cfg


def config_from_dict(cls, data: dict[str, Any], overrides: dict[str, Any] | None = None,
                     source: str = "saved config"):
    """Rebuild a (nested) dataclass config from its ``dataclasses.asdict`` form (or any part of it), with
    ``overrides`` as dotted ``{"section.field": value}`` pairs on top; ``source`` names it in errors."""
    values = flatten(data)
    values.update(overrides or {})
    return _build(cls, values, "", source)
