"""Saved predictions: one HDF5 file holding, per scene, the scored points, predicted and true flow.

Layout (h5py)::

    /                     attrs: format = "monoflow-predictions", version = 1, method = <name>
    /scenes               group, insertion order tracked
    /scenes/<key>         attrs: name = <scene name>, method = <name>
        points    (N, 3) float32   the scored pc1 points, camera-1 frame, metres
        pred_flow (N, 3) float32   predicted flow, metres
        gt_flow   (N, 3) float32   ground-truth flow, metres
        moving    (N,)   bool      optional: independently moving points
        mask      (N,)   bool      optional: points to score (default all)

``<key>`` is the scene name with ``/`` replaced by ``|`` (HDF5 paths cannot hold ``/``); the exact
name is kept in the ``name`` attribute. Any metric can be recomputed later from the file alone, and
other toolboxes' outputs written in this layout are scored the same way.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.metrics import aggregate, scene_metrics
from core.errors import InputError

FORMAT_NAME = "monoflow-predictions"
FORMAT_VERSION = 1


@dataclass
class ScenePrediction:
    """One scene's saved prediction (arrays as documented in the module docstring)."""

    name: str
    points: np.ndarray
    pred_flow: np.ndarray
    gt_flow: np.ndarray
    moving: np.ndarray | None = None
    mask: np.ndarray | None = None
    method: str = ""

    def metrics(self) -> dict[str, Any]:
        """:func:`evaluation.metrics.scene_metrics` of this scene (with the distance bands of its points'
        camera z; the three-way subsets need classes, which the file does not hold)."""
        return scene_metrics(self.pred_flow, self.gt_flow, mask=self.mask, moving=self.moving,
                             depth=np.asarray(self.points)[:, 2])


def _key(name: str) -> str:
    if not name:
        raise ValueError("scene name must be non-empty")
    return name.replace("/", "|")


def _check(name: str, points: Any, pred: Any, gt: Any, moving: Any, mask: Any) -> tuple[np.ndarray, ...]:
    pts = np.asarray(points, dtype=np.float32)
    prd = np.asarray(pred, dtype=np.float32)
    gtf = np.asarray(gt, dtype=np.float32)
    for label, arr in (("points", pts), ("pred_flow", prd), ("gt_flow", gtf)):
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise ValueError(f"scene {name!r}: {label} must have shape (N, 3), got {arr.shape}")
    n = len(pts)
    if len(prd) != n or len(gtf) != n:
        raise ValueError(f"scene {name!r}: points {pts.shape}, pred_flow {prd.shape}, gt_flow {gtf.shape} differ")
    out = [pts, prd, gtf]
    for label, arr in (("moving", moving), ("mask", mask)):
        if arr is None:
            out.append(None)
            continue
        a = np.asarray(arr).astype(bool)
        if a.shape != (n,):
            raise ValueError(f"scene {name!r}: {label} must have shape ({n},), got {a.shape}")
        out.append(a)
    return tuple(out)


class PredictionWriter:
    """Writes scenes one by one into a new predictions file (use as a context manager).

    The file is written to ``<path>.tmp-<pid>`` and renamed into place on a clean close, so a crash
    never leaves a truncated file under the final name.
    """

    def __init__(self, path: str | os.PathLike[str], method: str, overwrite: bool = True) -> None:
        import h5py

        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise InputError(self.path, "exists (pass overwrite=True to replace it)")
        self.method = method
        self._tmp = self.path.with_name(f"{self.path.name}.tmp-{os.getpid()}")
        self._file = h5py.File(self._tmp, "w")
        self._file.attrs["format"] = FORMAT_NAME
        self._file.attrs["version"] = FORMAT_VERSION
        self._file.attrs["method"] = method
        self._scenes = self._file.create_group("scenes", track_order=True)

    def add(
        self,
        name: str,
        points: np.ndarray,
        pred_flow: np.ndarray,
        gt_flow: np.ndarray,
        moving: np.ndarray | None = None,
        mask: np.ndarray | None = None,
    ) -> None:
        """Append one scene; a repeated name is an error."""
        key = _key(name)
        if key in self._scenes:
            raise ValueError(f"scene {name!r} already written")
        pts, prd, gtf, mov, msk = _check(name, points, pred_flow, gt_flow, moving, mask)
        g = self._scenes.create_group(key)
        g.attrs["name"] = name
        g.attrs["method"] = self.method
        g.create_dataset("points", data=pts)
        g.create_dataset("pred_flow", data=prd)
        g.create_dataset("gt_flow", data=gtf)
        if mov is not None:
            g.create_dataset("moving", data=mov)
        if msk is not None:
            g.create_dataset("mask", data=msk)

    def close(self) -> None:
        """Finish the file and move it into place."""
        if self._file:
            self._file.close()
            os.replace(self._tmp, self.path)
            self._file = None  # type: ignore[assignment]

    def abort(self) -> None:
        """Discard the partial file."""
        if self._file:
            self._file.close()
            self._file = None  # type: ignore[assignment]
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> "PredictionWriter":
        return self

    def __exit__(self, exc_type: Any, *_: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def save_predictions(path: str | os.PathLike[str], method: str, scenes: Iterable[ScenePrediction]) -> Path:
    """Write ``scenes`` to a new predictions file; returns its path."""
    with PredictionWriter(path, method) as writer:
        for s in scenes:
            writer.add(s.name, s.points, s.pred_flow, s.gt_flow, moving=s.moving, mask=s.mask)
    return Path(path)


def iter_predictions(path: str | os.PathLike[str]) -> Iterator[ScenePrediction]:
    """Read the scenes of a predictions file one at a time, in the order they were written.

    Raises:
        InputError: when the file is missing, not HDF5, or lacks the expected layout.
    """
    import h5py

    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such file")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise InputError(p, f"not a readable HDF5 file ({exc})") from None
    with f:
        if "scenes" not in f:
            raise InputError(p, "not a predictions file (no 'scenes' group)")
        method = str(f.attrs.get("method", ""))
        for key, g in f["scenes"].items():
            missing = [k for k in ("points", "pred_flow", "gt_flow") if k not in g]
            if missing:
                raise InputError(p, f"scene {key!r} lacks {missing}")
            name = str(g.attrs.get("name", key))
            try:
                pts, prd, gtf, mov, msk = _check(
                    name,
                    g["points"][()],
                    g["pred_flow"][()],
                    g["gt_flow"][()],
                    g["moving"][()] if "moving" in g else None,
                    g["mask"][()] if "mask" in g else None,
                )
            except ValueError as exc:
                raise InputError(p, str(exc)) from None
            yield ScenePrediction(name, pts, prd, gtf, mov, msk, str(g.attrs.get("method", method)))


def read_predictions(path: str | os.PathLike[str]) -> list[ScenePrediction]:
    """All scenes of a predictions file (see :func:`iter_predictions`)."""
    return list(iter_predictions(path))


def predictions_method(path: str | os.PathLike[str]) -> str:
    """The method name stored in a predictions file's root attributes."""
    import h5py

    with h5py.File(path, "r") as f:
        return str(f.attrs.get("method", ""))


def score_predictions(path: str | os.PathLike[str], with_std: bool = False) -> dict[str, Any]:
    """Metrics of a predictions file: :func:`evaluation.metrics.aggregate` over its scenes, plus
    ``"method"`` and ``"per_scene"`` (scene name → scene metrics).

    Raises:
        InputError: on a malformed file, or a scene with nothing to score.
    """
    per_scene: dict[str, dict[str, Any]] = {}
    method = ""
    for s in iter_predictions(path):
        method = method or s.method
        try:
            per_scene[s.name] = s.metrics()
        except ValueError as exc:
            raise InputError(path, f"scene {s.name!r}: {exc}") from None
    if not per_scene:
        raise InputError(path, "holds no scenes")
    out = aggregate(per_scene.values(), with_std=with_std)
    out["method"] = method
    out["per_scene"] = per_scene
    return out
