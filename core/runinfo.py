"""What produced an output: the versions of the packages a result depends on, and the git revision.

Upstream of every stage, so stage one (``preprocess_run.json``, the cache's ``code_version``), the trainers
(``config.json``) and the evaluation reports record the same list and ask git the same way.
"""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path

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


def git_revision(describe: bool = False) -> str | None:
    """The git revision of the source checkout holding this code; None for an installed copy or without git.

    ``describe=False``: the full ``rev-parse HEAD`` hash (the cache's ``code_version``). ``describe=True``:
    ``git describe --always --dirty`` (short hash, ``-dirty`` with uncommitted changes; run folders, reports).
    Only a checkout whose root (the folder above ``core/``) holds ``.git`` counts, so a copy installed
    into some other repository's virtualenv never reports that repository's revision.
    """
    src = Path(__file__).resolve().parent.parent
    if not (src / ".git").exists():
        return None
    cmd = ["describe", "--always", "--dirty"] if describe else ["rev-parse", "HEAD"]
    try:
        out = subprocess.run(["git", "-C", str(src), *cmd], capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return (out.stdout.strip() or None) if out.returncode == 0 else None
