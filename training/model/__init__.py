"""The scene-flow network (HALFlowNet design) in plain PyTorch; see :mod:`training.model.halflownet`."""

from training.model.halflownet import FlowOutput, HALFlowConfig, HALFlowNet, Sampling, count_parameters

__all__ = ["FlowOutput", "HALFlowConfig", "HALFlowNet", "Sampling", "count_parameters"]
