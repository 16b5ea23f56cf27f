"""Label-free per-scene optimisation, one implementation serving two uses:

* the **NSFP baseline** (:class:`NSFPMethod`, baseline name ``nsfp``): an MLP prior fitted to each scene
  with a truncated Chamfer loss (Li et al., NeurIPS 2021);
* **test-time refinement** (:class:`RefinedMethod`, ``monoflow-evaluate run --refine``): a given flow
  (the net's) refined with the paper's label-free Chamfer + Laplacian terms and a robust rigid prior.

Both share the loop (:mod:`.loop`: Adam, iteration budget, early stopping on the loss), the loss terms
(:mod:`.terms`, built on :mod:`training.losses`) and the settings (:mod:`.config`, units in the field docs).
"""

from evaluation.optimise.config import ChamferConfig, LoopConfig, NSFPConfig, RefineConfig
from evaluation.optimise.loop import FitResult, minimise
from evaluation.optimise.nsfp import NSFPMethod, fit_nsfp
from evaluation.optimise.refine import RefinedMethod, refine_flow
from evaluation.optimise.rigid import robust_rigid_fit

__all__ = ["ChamferConfig", "FitResult", "LoopConfig", "NSFPConfig", "NSFPMethod", "RefineConfig",
           "RefinedMethod", "fit_nsfp", "minimise", "refine_flow", "robust_rigid_fit"]
