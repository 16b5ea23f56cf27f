"""Command-line flags of the readers: ``--format NAME`` and each format's options as ``--NAME.<option>``.

The flags follow the project's dotted style (``--model.ego_head`` in ``monoflow-train``): every field of a
registered format's options dataclass becomes ``--<format>.<field>`` with the field's doc as its help, in
one ``--help`` group per format. Only the read format's flags may be given (others are a config error).
"""

from __future__ import annotations

import argparse
from typing import Any

from evaluation.readers.registry import FORMATS, REGISTRY, detect_format, get_format
from evaluation.readers.split import SceneFlowSplit, load_split
from core.errors import ConfigError
from core.options import add_dataclass_args, config_from_dict


def add_reader_flags(parser: argparse.ArgumentParser) -> None:
    """Add ``--format`` and one group of ``--<format>.<option>`` flags per registered format."""
    parser.add_argument("--format", default="auto",
                        help=f"auto | {' | '.join(FORMATS)}; each format's options are its --<format>.<option> "
                             "flags below")
    for fmt in REGISTRY.values():
        group = parser.add_argument_group(f"{fmt.name} reader options (--format {fmt.name})", fmt.summary)
        add_dataclass_args(group, fmt.options, prefix=f"{fmt.name}.")  # type: ignore[arg-type]
        for action in group._group_actions:  # absent unless given, so that "--NAME.max_depth none" counts
            action.default = argparse.SUPPRESS


def reader_options(args: argparse.Namespace) -> dict[str, Any]:
    """The options of every format whose ``--<format>.<option>`` flags were given, keyed by format name
    (the flags on top of the dataclass defaults; ``none`` sets an optional field to None)."""
    out: dict[str, Any] = {}
    for fmt in REGISTRY.values():
        prefix = f"{fmt.name}."
        given = {k[len(prefix):]: v for k, v in vars(args).items() if k.startswith(prefix)}
        if given:
            try:
                out[fmt.name] = config_from_dict(fmt.options, {}, overrides=given, source=f"--{fmt.name}.* flags")
            except ValueError as exc:  # an options class's own check (__post_init__)
                raise ConfigError(f"--{fmt.name}.* flags: {exc}") from None
    return out


def open_split(args: argparse.Namespace) -> SceneFlowSplit:
    """The split ``--split`` in ``--format`` read with the ``--<format>.<option>`` flags."""
    options = reader_options(args)
    fmt = detect_format(args.split) if args.format == "auto" else get_format(args.format, args.split).name
    other = sorted(set(options) - {fmt})
    if other:
        raise ConfigError(f"--{other[0]}.* options were given but {args.split} is read as {fmt} "
                          f"(its options are --{fmt}.*)")
    return load_split(args.split, fmt, **options)
