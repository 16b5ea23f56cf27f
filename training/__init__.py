"""Stage two of monoflow: the HALFlowNet-style scene-flow net, point ops, the paper's four losses, the trainer.

May import :mod:`pipeline` (the cache reader, geometry); never imports :mod:`evaluation`.
"""
