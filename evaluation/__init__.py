"""Evaluation of monoflow: scene-flow test-set readers, community metrics, ICP/FGR baselines, reports, ablations."""
