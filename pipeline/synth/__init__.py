"""The seeded synthetic driving world with ground truth (``monoflow-synth``).

A CPU ray caster renders a procedural street (textured road with lane markings, kerbs and pavements,
façades, trees, poles, parked and moving cars) from a camera driving along it, and writes a
KITTI-odometry-format folder plus ground truth: depth, 3D flow t→t+1 with moving/valid/visibility
masks, HDL-64E-like scans and a scene-flow test split (FlowNet3D and HPLFlowNet layouts).

Public API: :class:`SynthConfig`, :func:`generate` (→ :class:`GenerateSummary`); the CLI is
``monoflow-synth`` (:func:`pipeline.synth.cli.main`). ``generate`` is imported lazily so that
``monoflow-synth --help`` stays instant.
"""

from pipeline.synth.config import SYNTH_VERSION, SynthConfig

__all__ = ["SYNTH_VERSION", "GenerateSummary", "SynthConfig", "generate"]


def __getattr__(name: str):
    if name in ("generate", "GenerateSummary"):
        import importlib

        _g = importlib.import_module("pipeline.synth.generator")

        return getattr(_g, name)
    raise AttributeError(name)
