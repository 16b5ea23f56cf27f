"""The ``NAME=FOLDER`` (and ``KEY=VALUE``) command-line items of the benchmark tools, parsed in one place.

Used as an argparse ``type``: a malformed item is refused by argparse with one usage line naming it,
never a traceback."""

from __future__ import annotations

import argparse


def named_folder(text: str) -> tuple[str, str]:
    """``"own=runs/w0/world/sceneflow/flownet3d"`` → ``("own", "runs/w0/world/sceneflow/flownet3d")``;
    both sides must be non-empty (the name labels the split in every table)."""
    name, sep, folder = text.partition("=")
    if not sep or not name.strip() or not folder.strip():
        raise argparse.ArgumentTypeError(f"needs NAME=FOLDER, got {text!r}")
    return name.strip(), folder.strip()


def key_value(text: str) -> tuple[str, str]:
    """``"model.norm=layer"`` → ``("model.norm", "layer")``; the key must be non-empty, the value may be."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"needs KEY=VALUE, got {text!r}")
    return key.strip(), value
