"""Machinery shared by monoflow's trainers (scene flow and self-supervised depth/pose).

One place for: devices, torchrun/DDP set-up (with batch norm over the global batch, ``sync_bn``), atomic
checkpoints with RNG state, run folders with the resolved config, and CSV/JSONL logs. Both trainers use it; neither copies it.
"""
