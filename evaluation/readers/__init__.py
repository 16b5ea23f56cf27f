"""Readers of scene-flow test sets, returning :class:`~evaluation.sample.SceneFlowSample` in camera axes.

One module per format, each registered once in :mod:`evaluation.readers.registry` with its name, its
detection, its options dataclass and its loader:

* ``flownet3d`` (:mod:`evaluation.readers.flownet3d`) — FlowNet3D's ``kitti_rm_ground`` ``*.npz``;
* ``hplflownet`` (:mod:`evaluation.readers.hplflownet`) — HPLFlowNet's ``KITTI_processed_occ_final``;
* ``opensceneflow`` (:mod:`evaluation.readers.opensceneflow`) — OpenSceneFlow / DeFlow HDF5.

The synthetic world writes its test split in the first two (:mod:`pipeline.synth.sceneflow_export`);
each format's axes, and their conversion to the camera frame, are :data:`core.axes.FORMAT_AXES`.

:func:`load_split` auto-detects the format, validates every entry up front (shapes, keys) and raises
one :class:`~core.errors.InputError` listing every malformed file; samples are then read lazily,
sorted by name. ``monoflow-evaluate run`` takes each format's options as ``--<format>.<option>`` flags
(:mod:`evaluation.readers.flags`).
"""

from __future__ import annotations

from evaluation.readers.base import Entry, SceneFlowFormat
from evaluation.readers.flownet3d import FlowNet3DOptions
from evaluation.readers.hplflownet import HPLFlowNetOptions
from evaluation.readers.opensceneflow import OpenSceneFlowOptions
from evaluation.readers.registry import FORMATS, REGISTRY, detect_format, get_format
from evaluation.readers.split import SceneFlowSplit, load_split

__all__ = [
    "FORMATS",
    "REGISTRY",
    "Entry",
    "FlowNet3DOptions",
    "HPLFlowNetOptions",
    "OpenSceneFlowOptions",
    "SceneFlowFormat",
    "SceneFlowSplit",
    "detect_format",
    "get_format",
    "load_split",
]
