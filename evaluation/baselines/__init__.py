"""Scene-flow baselines scored on the same points as the nets: zero flow, ICP (point-to-point /
point-to-plane) and FGR (FPFH features + Fast Global Registration). The pose-only static flow is
:class:`evaluation.methods.StaticPoseMethod` (it needs the scene's pose, which a baseline is not given).

Every baseline follows :class:`~evaluation.baselines.base.Baseline`: a ``name`` and
``__call__(pc1, pc2) -> flow`` on (N, 3) / (M, 3) camera-frame clouds in metres.
"""

from evaluation.baselines.base import Baseline, RegistrationResult
from evaluation.baselines.fgr import FGRBaseline, FGRConfig, fast_global_registration
from evaluation.baselines.fpfh import FPFHConfig, compute_fpfh
from evaluation.baselines.icp import ICPBaseline, ICPConfig, icp
from evaluation.baselines.zero import ZeroFlowBaseline

__all__ = [
    "Baseline",
    "RegistrationResult",
    "ZeroFlowBaseline",
    "ICPBaseline",
    "ICPConfig",
    "icp",
    "FPFHConfig",
    "compute_fpfh",
    "FGRBaseline",
    "FGRConfig",
    "fast_global_registration",
]
