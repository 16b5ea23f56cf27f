"""What produced an output: the versions of the packages a result depends on.

Upstream of every stage, so stage one (``preprocess_run.json``), the trainers (``config.json``) and the
evaluation reports record the same list.
"""

from __future__ import annotations

import platform

PACKAGES = ("monoflow", "torch", "numpy", "scipy", "zarr", "numcodecs", "opencv-python-headless", "h5py", "tqdm")


def package_versions() -> dict[str, str]:
    """Python's and each of :data:`PACKAGES`' installed version (packages not installed are left out)."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out
