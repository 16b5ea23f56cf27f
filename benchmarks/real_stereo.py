"""A stereo-KITTI-style scene-flow split with movers, from a real KITTI 2015 scene, not from the synthetic generator.

HPLFlowNet's ``KITTI_processed_occ_final`` (the "stereoKITTI" split most scene-flow papers report) turns each
KITTI Scene Flow 2015 training scene's disparities and optical flow into corresponding point pairs
(:mod:`pipeline.kitti.stereo_flow`). The KITTI download cannot be fetched here; what the project has is one
real scene, KITTI 2015 training scene 000139 (two colour frames), with **Self-Mono-SF's predicted**
disparities of both frames and optical flow in KITTI's formats (``../shared/data/kitti_sceneflow2015_000139``,
see its SOURCE.txt). This tool writes that scene through the same code path as the real split, so the clouds
have stereoKITTI's character — dense image-grid points, pc2 the same surface points one frame later, ground
and range cut by the reader — and the scene has real street geometry and real traffic: an oncoming van, cars
ahead, a parked row. It is the only split with movers that the generator did not build.

The truth is a published monocular method's *estimate*, not KITTI's ground truth: its depth noise grows with
range (a disparity of 11 px at 35 m), so the static background's flow is not exactly one rigid motion. Read
its numbers as "agreement with a plausible real scene flow", not as accuracy; ``--rigid_background true`` gives
the points not labelled moving the dominant rigid motion instead, as KITTI's own ground truth gives the static
background the camera's motion (docs/learned-flow.md, thirty-fourth round). Scene 000139 has no line in
KITTI's ``train_mapping.txt``, so its calibration is not known; ``P_rect_02`` is taken from a KITTI raw
calibration file (``--calib``, default the 2011_09_26 one, f = 721.5 px, the date of most KITTI 2015 scenes).

``moving`` (written as ``moving.npy``) marks the points whose true flow departs by more than
``moving_m`` from the scene's dominant rigid motion, fitted to the truth by trimmed Kabsch: a label derived
from the flow, not annotated. One scene makes one split of ``pairs`` scenes: the valid pixels are divided at
random into ``pairs`` disjoint sets, one per scene, so every scene scores different points of the same street;
``mapping.txt`` names each scene's source on its line (a ``train_mapping.txt`` that keeps every scene)::

    python -m benchmarks.real_stereo --out w/real_stereo
    monoflow-evaluate run --split w/real_stereo --protocol hplflownet --mapping w/real_stereo/mapping.txt \\
        --checkpoint … --baselines icp-p2p,fgr,nsfp,rvote

Camera frames (x right, y down, z forward), metres.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from core.errors import InputError, run_cli
from core.axes import FORMAT_AXES
from evaluation.baselines.base import kabsch
from evaluation.readers.hplflownet import HPLFlowNetOptions, kept_pairs
from pipeline.kitti.calib import read_raw_cam_to_cam
from pipeline.kitti.png16 import read_disparity_png, read_flow_png
from pipeline.kitti.stereo_flow import StereoPairs, stereo_pairs, write_hpl_scene

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SCENE = SHARED / "kitti_sceneflow2015_000139"
LAYOUTS = ("hplflownet", "flownet3d")  #: the split's file layout (``--layout``)
MAPPING = "mapping.txt"  #: one non-empty line per scene: ``--protocol hplflownet --mapping`` keeps them all
CALIB = SHARED / "kitti_raw_calib_2011_09_26" / "2011_09_26_calib" / "2011_09_26" / "calib_cam_to_cam.txt"


@dataclass
class RealStereoConfig:
    """Options of the real stereo-style split.

    Attributes:
        scene: folder with ``results/disp_0``, ``results/disp_1``, ``results/flow`` (KITTI 16-bit PNGs of
            scene ``name``, frame 10).
        name: the scene's file stem (``000139_10``).
        calib: a KITTI raw ``calib_cam_to_cam.txt`` whose ``P_rect_02`` projects the scene.
        pairs: scenes to write (disjoint random sets of the valid pixels).
        moving_m: metres from the dominant rigid motion beyond which a point is labelled moving.
        seed: seed of the pixel division.
        rigid_background: give the points not labelled moving the dominant rigid motion as their truth (their
            frame-2 point moved there), as KITTI's own ground truth gives the static background the camera's
            motion; off = the estimate's flow everywhere.
        layout: ``hplflownet`` (HPLFlowNet's stereoKITTI folders, every pair, the reader cuts the ground and
            the range) or ``flownet3d`` (one ``.npz`` per scene, as FlowNet3D's ``kitti_rm_ground`` was written
            from KITTI's correspondences: the pairs within that cut, ``pos2`` = ``pos1 + gt`` in shuffled rows;
            docs/learned-flow.md, thirty-fifth round).
        out: the split folder to create (must not exist).
    """

    scene: str = str(SCENE)
    name: str = "000139_10"
    calib: str = str(CALIB)
    pairs: int = 8
    moving_m: float = 0.3
    seed: int = 0
    rigid_background: bool = False
    layout: str = "hplflownet"
    out: str = ""


def scene_pairs(cfg: RealStereoConfig) -> StereoPairs:
    """The scene's point pairs (camera axes), from its disparity and flow PNGs and ``cfg.calib``."""
    root = Path(cfg.scene)
    d0 = read_disparity_png(root / "results" / "disp_0" / f"{cfg.name}.png")
    d1 = read_disparity_png(root / "results" / "disp_1" / f"{cfg.name}.png")
    flow_file = root / "results" / "flow" / f"{cfg.name}.png"
    flow, valid = read_flow_png(flow_file)
    P = read_raw_cam_to_cam(cfg.calib).P_rect.get("02")
    if P is None:
        raise InputError(Path(cfg.calib), "missing key 'P_rect_02'")
    return stereo_pairs(d0, d1, flow, valid, P, where=flow_file)


def dominant_motion(pc1: np.ndarray, pc2: np.ndarray, rounds: int = 10, keep: float = 0.5,
                    floor_m: float = 0.1) -> np.ndarray:
    """4×4 rigid motion fitted to the pairs by trimmed Kabsch: each round refits to the pairs within
    max(``floor_m``, the ``keep`` quantile of the residuals) of the last fit (metres)."""
    a, b = pc1.astype(np.float64), pc2.astype(np.float64)
    use = np.ones(len(a), dtype=bool)
    T = np.eye(4)
    for _ in range(rounds):
        T = kabsch(a[use], b[use])
        r = np.linalg.norm(a @ T[:3, :3].T + T[:3, 3] - b, axis=1)
        use = r <= max(floor_m, float(np.quantile(r, keep)))
    return T


def in_reader_cut(pairs: StereoPairs) -> np.ndarray:
    """The pairs the ``hplflownet`` reader keeps with its default options (not ground in both clouds, z < 35 m
    in both; :func:`evaluation.readers.hplflownet.kept_pairs` on the stored axes)."""
    axes = FORMAT_AXES["hplflownet"]
    return kept_pairs(axes.from_camera(pairs.pc1), axes.from_camera(pairs.pc2), HPLFlowNetOptions())


def build_split(cfg: RealStereoConfig) -> tuple[int, float]:
    """Write the split to ``cfg.out`` (a fresh folder, renamed into place when complete); returns
    (points kept by the reader per scene, on average; the fraction of them labelled moving)."""
    if cfg.pairs < 1:
        raise ValueError(f"pairs must be ≥ 1, got {cfg.pairs}")
    if cfg.layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {cfg.layout!r}")
    out = Path(cfg.out)
    if out.exists():
        raise InputError(out, "exists; choose a new folder (the split is written whole or not at all)")
    pairs = scene_pairs(cfg)
    cut = in_reader_cut(pairs)
    if cut.sum() < 64 * cfg.pairs:
        raise InputError(Path(cfg.scene), f"only {int(cut.sum())} pairs off the ground within 35 m")
    T = dominant_motion(pairs.pc1[cut], pairs.pc2[cut])
    rigid = pairs.pc1.astype(np.float64) @ T[:3, :3].T + T[:3, 3]  # every pc1 point moved by the dominant motion
    moving = np.linalg.norm(rigid - pairs.pc2, axis=1) > cfg.moving_m
    if cfg.rigid_background:  # and the reader's cut made on the frame-2 points written, as it is made on reading
        pairs = replace(pairs, pc2=np.where(moving[:, None], pairs.pc2, rigid.astype(pairs.pc2.dtype)))
        cut = in_reader_cut(pairs)
    part = out.with_name(out.name + ".partial")
    shutil.rmtree(part, ignore_errors=True)
    order = np.random.default_rng(cfg.seed).permutation(len(pairs.pc1))
    for k, idx in enumerate(np.array_split(order, cfg.pairs)):
        idx = np.sort(idx)
        write_scene(part, k, pairs.subset(idx), moving[idx], cfg.layout, cfg.seed)
    if cfg.layout == "hplflownet":
        write_mapping(part, f"{Path(cfg.scene).name} {cfg.name} (pixels {{}} of {cfg.pairs}, seed {cfg.seed})",
                      cfg.pairs)
    part.rename(out)
    return int(cut.sum()) // cfg.pairs, float(moving[cut].mean())


def write_scene(split: Path, k: int, pairs: StereoPairs, moving: np.ndarray, layout: str, seed: int) -> None:
    """Scene ``k`` of a split folder in ``layout``: every pair as HPLFlowNet's folder (its reader cuts), or the pairs
    within the ``hplflownet`` reader's cut as a FlowNet3D ``.npz`` whose frame-2 rows are shuffled by ``(seed, k)``."""
    if layout == "flownet3d":
        cut = in_reader_cut(pairs)
        write_flownet3d_scene(split / f"{k:06d}.npz", pairs.subset(cut), moving[cut], np.random.default_rng([seed, k]))
    else:
        write_hpl_scene(split / f"{k:06d}", pairs, moving)


def write_mapping(split: Path, source: str, count: int) -> None:
    """``mapping.txt``: one non-empty line per scene (``source`` formatted with the scene's index), so ``--protocol
    hplflownet --mapping`` keeps every scene."""
    (split / MAPPING).write_text("".join(source.format(k) + "\n" for k in range(count)), encoding="utf-8")


def write_flownet3d_scene(path: Path, pairs: StereoPairs, moving: np.ndarray, rng: np.random.Generator) -> None:
    """One FlowNet3D-layout scene (LiDAR-like axes): ``pos1``, its flow ``gt``, ``moving``, and ``pos2`` = the same
    points moved, in an order of their own (the file then says nothing about which row pairs with which)."""
    axes = FORMAT_AXES["flownet3d"]
    pos1 = axes.from_camera(pairs.pc1).astype(np.float32)
    gt = axes.from_camera(pairs.pc2 - pairs.pc1).astype(np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, pos1=pos1, pos2=(pos1 + gt)[rng.permutation(len(pos1))], gt=gt, moving=np.asarray(moving, bool))


def _main(argv: list[str] | None) -> int:
    from core.options import parse_config

    cfg = parse_config(RealStereoConfig, argv, "real_stereo", __doc__.split("\n\n")[0],
                       required=("out",))
    n, moving = build_split(cfg)
    print(f"real_stereo: {cfg.pairs} scenes of about {n} points each (after the reader's cuts) in {cfg.out}; "
          f"{moving:.1%} labelled moving")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; a missing or bad PNG / calibration, or an existing ``--out``, is one ``error:`` line."""
    return run_cli(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
