"""The scene-flow nets: HALFlowNet (:mod:`training.model.halflownet`, plain PyTorch) and the contract and
registry every net keeps (:mod:`training.model.contract`, :mod:`training.model.registry`).

The names below load on first use, so that the torch-free configs (``halflownet_config``, ``contract``,
``registry``) import without torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_HOMES = {"FlowOutput": "contract", "Sampling": "contract", "HALFlowConfig": "halflownet_config",
          "HALFlowNet": "halflownet", "count_parameters": "halflownet"}

__all__ = ["FlowOutput", "HALFlowConfig", "HALFlowNet", "Sampling", "count_parameters"]


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
