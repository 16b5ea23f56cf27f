"""What every stage shares: error types and the one-line CLI error rule (:mod:`core.errors`), dataclass
configs as flags and TOML (:mod:`core.options`), camera geometry (:mod:`core.geometry`), the scene-flow
formats' axis conventions (:mod:`core.axes`), atomic JSON (:mod:`core.jsonio`), code-free checkpoint loading
(:mod:`core.safeload`) and run provenance (:mod:`core.runinfo`).

Stage one (``pipeline``), training and evaluation import from here; ``core`` imports none of them, so the
stages keep their one direction (pipeline → training → evaluation) and none of them doubles as the others'
library (``docs/design.md`` §1).
"""
