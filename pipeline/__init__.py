"""Stage one of monoflow: monocular frames -> depth, pose, filtered coloured point clouds, static flow -> zarr cache.

Never imports :mod:`training` or :mod:`evaluation` (data flows pipeline -> training -> evaluation).
"""

__version__ = "0.1.0"
