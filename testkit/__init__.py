"""Scenes for the tests and benchmarks, kept out of the installable library.

Importable from the repository root (``python -m pytest``, ``python benchmarks/x.py``), never shipped in the
wheel (``pyproject.toml`` packages only ``pipeline``, ``training`` and ``evaluation``).

* :mod:`testkit.demo_scene` — an analytic, ray-cast street as cache blocks (any size, optional GT flow).
* :mod:`testkit.kitti_sample` — a cache block from the real KITTI 2015 scene 000139 (``shared/data``).
"""
