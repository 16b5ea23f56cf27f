"""Configuration of a self-supervised depth/pose training run (saved in ``config.json`` of the run folder).

Defaults follow SC-SfMLearner's released training (3-frame snippets, Adam 1e-4, batch 4, photometric
0.15·L1 + 0.85·SSIM with the self-discovered and auto masks, geometry consistency 0.5, smoothness 0.1,
one scale, random flips and scale-crops up to 1.15). :func:`demo_config` and :func:`tiny_config` are the
presets for ``make demo DEPTH=learned`` and for the tests.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

from training.runtime.run_config import RunConfig


@dataclass
class DepthDataConfig:
    """Where snippets come from and at which size the nets see them.

    root: a KITTI-odometry-layout folder (``root/sequences/NN/<camera>``, ``calib.txt``, ``poses/NN.txt``).
    sequences: training sequence ids; empty = every sequence under ``root`` not in ``val_sequences``.
    val_sequences: held-out sequences for validation (depth against ``depth_2`` ground truth or projected
        LiDAR, pose against the poses file, and the photometric loss); ``last`` = the last sequence under
        ``root`` (the synthetic world's test sequence); ``none`` = no validation; empty = the training
        sequence itself when there is only one (e.g. one KITTI sequence: training never sees its poses or
        depth, so pose/depth metrics against them still measure the nets; the photometric loss is then
        in-sample), else no validation.
    strict_pose_count: a complete sequence's poses file must have one line per image; false = a line for
        every frame id is enough (e.g. 51 frames beside the full 1,101-line KITTI 06.txt).
    camera: image folder (``image_2`` colour; ``image_0`` for KITTI's grey left camera).
    width, height: working size in pixels (multiples of 32); K is scaled with the images.
    frame_gap: frames between the snippet's neighbours (t−gap, t, t+gap).
    flip, scale_crop, max_scale: augmentation — horizontal flip with probability 0.5 and a random zoom by
        (sx, sy) ∈ [1, max_scale]² followed by a random crop back to (height, width); K follows.
    workers: DataLoader worker processes (0 = load in the training process).
    cache_frames: keep up to this many resized frames in memory per process (0 = always read from disk).
    """

    root: str = "cache/synth"
    sequences: tuple[str, ...] = ()
    val_sequences: tuple[str, ...] = ()
    strict_pose_count: bool = True
    camera: str = "image_2"
    width: int = 416
    height: int = 128
    frame_gap: int = 1
    flip: bool = True
    scale_crop: bool = True
    max_scale: float = 1.15
    workers: int = 0
    cache_frames: int = 4000


@dataclass
class DepthLossConfig:
    """Weights and switches of SC-SfMLearner's loss (images in [0, 1] for the photometric terms).

    photo_weight, smooth_weight, geometry_weight: the loss is photo_weight · photometric + smooth_weight ·
        smoothness + geometry_weight · geometry consistency.
    with_ssim: include the SSIM term in the photometric error (else plain L1).
    ssim_weight: photometric per pixel = (1 − ssim_weight)·|ΔI| + ssim_weight·(1 − SSIM)/2.
    with_mask: weight the photometric error by the self-discovered mask 1 − D_diff.
    with_auto_mask: keep only pixels whose warped error is below the un-warped (static) error.
    num_scales: disparity scales used (1–4, finest first).
    scale_mode: ``upsample`` — each scale's disparity is upsampled to the full image (the released code);
        ``downsample`` — images and K are downsampled to each scale (SfMLearner's pyramid).
    padding_mode: ``zeros`` or ``border`` for sampling outside the reference image.
    min_valid_fraction: a term is 0 for a batch where fewer than this fraction of pixels is valid (the
        released code's fixed 10 000-pixel threshold, made size-independent).
    smooth_on: ``disparity`` (mean-normalised, Monodepth2 / the issue) or ``depth`` (what the released
        code actually passes to its smoothness function).
    pose_antisymmetric: the photometric and geometry terms see ``(net(a,b) − net(b,a)) / 2`` for a pair and
        its negation for the reverse pair (not in the released recipe). Without it, a pose net that cannot
        yet tell frame order predicts the same motion for (t, t+1) and (t, t−1); the auto-mask hides the half
        warped the wrong way and training settles there, the net reporting backward motion for forward
        driving. Antisymmetry makes that state impossible; stage one still runs the plain net.
    pose_symmetric_weight: weight of ``mean ‖(net(a,b) + net(b,a)) / 2‖₁`` with ``pose_antisymmetric``, which
        drives the raw net (what the checkpoint holds) to the antisymmetric output the losses trained.
    """

    photo_weight: float = 1.0
    smooth_weight: float = 0.1
    geometry_weight: float = 0.5
    ssim_weight: float = 0.85
    with_ssim: bool = True
    with_mask: bool = True
    with_auto_mask: bool = True
    num_scales: int = 1
    scale_mode: Literal["upsample", "downsample"] = "upsample"
    padding_mode: Literal["zeros", "border"] = "zeros"
    min_valid_fraction: float = 0.01
    smooth_on: Literal["disparity", "depth"] = "disparity"
    pose_antisymmetric: bool = False
    pose_symmetric_weight: float = 1.0


@dataclass
class DepthModelConfig:
    """ResNet depth of both nets and an optional local ImageNet initialisation (nothing is downloaded).

    depth_layers, pose_layers: ResNet depth (18 or 50) of the depth (DispResNet) and pose (PoseResNet) encoders.
    imagenet_weights: path of a torchvision ``resnet18-*.pth`` / ``resnet50-*.pth`` state dict, or empty for
        random (Kaiming) initialisation.
    """

    depth_layers: int = 18
    pose_layers: int = 18
    imagenet_weights: str = ""


@dataclass
class DepthOptimConfig:
    """Adam (the released code: lr 1e-4, β = (0.9, 0.999), no weight decay, batch 4).

    lr: learning rate.
    beta1, beta2: Adam's moment decay rates.
    weight_decay: L2 weight decay (0 = none).
    batch_size: snippets per optimiser step (global, over all processes).
    """

    lr: float = 1e-4
    beta1: float = 0.9
    beta2: float = 0.999
    weight_decay: float = 0.0
    batch_size: int = 4


@dataclass
class DepthEvalConfig:
    """Depth and pose evaluation settings.

    min_depth, max_depth: metres; ground truth outside is ignored and predictions are clamped into it.
    depth_frames_max: at most this many frames per validation sequence (evenly spread) are scored for depth.
    garg_crop: score only the Garg/Eigen crop (for projected LiDAR); ``auto`` = on for LiDAR, off for dense GT.
    snippet: frames per ATE snippet (SfMLearner protocol: 5).
    segment_lengths: KITTI devkit segment lengths (metres) of the relative translation/rotation errors.
    """

    min_depth: float = 1e-3
    max_depth: float = 80.0
    depth_frames_max: int = 200
    garg_crop: Literal["auto", "on", "off"] = "auto"
    snippet: int = 5
    segment_lengths: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


@dataclass
class DepthTrainConfig(RunConfig):
    """A whole run. ``steps`` counts optimiser steps (global batches of ``optim.batch_size`` snippets).

    run_dir: run folder (config.json, train.csv / val.csv, official-format checkpoints; ``latest.pt`` to resume).
    select_by: which validation number picks the ``*_model_best`` files (lower is better): ``auto`` = depth
        AbsRel when depth ground truth exists, else pose ATE-5 (m) when the poses file exists, else the
        photometric loss; or ``abs_rel`` | ``ate`` | ``rot_err_deg`` | ``loss``. The best files hold the nets
        only (official format, no optimiser state).
    """

    run_dir: str = "runs/depth"
    val_every: int = 250
    ckpt_every: int = 250
    select_by: Literal["auto", "abs_rel", "ate", "rot_err_deg", "loss"] = "auto"
    data: DepthDataConfig = field(default_factory=DepthDataConfig)
    loss: DepthLossConfig = field(default_factory=DepthLossConfig)
    model: DepthModelConfig = field(default_factory=DepthModelConfig)
    optim: DepthOptimConfig = field(default_factory=DepthOptimConfig)
    eval: DepthEvalConfig = field(default_factory=DepthEvalConfig)


def replace(cfg: DepthTrainConfig, **sections) -> DepthTrainConfig:
    """A copy of ``cfg`` with top-level fields and nested sections updated, e.g.
    ``replace(cfg, steps=10, data={"width": 128})``."""
    out = {}
    for key, value in sections.items():
        current = getattr(cfg, key)
        out[key] = dataclasses.replace(current, **value) if isinstance(value, dict) else value
    return dataclasses.replace(cfg, **out)


def demo_config(root: str, run_dir: str, steps: int = 600) -> DepthTrainConfig:
    """The ``make demo DEPTH=learned`` preset: 128×64 snippets, batch 4, lr 1e-4, a short CPU run.

    Trains on every sequence but the last (the synthetic generator's test sequence) and validates on the
    last. Departures from the released recipe, each measured to matter for short runs (see
    ``training/depth/README.md``): antisymmetric poses (``loss.pose_antisymmetric``) — without them the pose
    net often settles on reporting backward motion; and no flips or scale-crops — with them the depth net
    saturated to a constant map within 100–200 steps in every demo-size run measured (CPU and H100). The
    world should be rendered anti-aliased (``SynthConfig(supersample=2)``): aliased textures flicker from
    frame to frame and the photometric loss then prefers a static (infinitely far) road.
    """
    return DepthTrainConfig(
        run_dir=run_dir, steps=steps, seed=0, device="auto", log_every=10, val_every=max(steps // 6, 1),
        ckpt_every=max(steps // 6, 1),
        data=DepthDataConfig(root=root, val_sequences=("last",), width=128, height=64, workers=0, flip=False,
                             scale_crop=False),
        loss=DepthLossConfig(pose_antisymmetric=True),
        optim=DepthOptimConfig(lr=1e-4, batch_size=4),
        eval=DepthEvalConfig(depth_frames_max=20),
    )


def tiny_config(root: str, run_dir: str, steps: int = 20) -> DepthTrainConfig:
    """Test-sized run: 128×64 images, batch 2, the released lr 1e-4, no augmentation, no progress bar, CPU."""
    return DepthTrainConfig(
        run_dir=run_dir, steps=steps, seed=0, device="cpu", log_every=5, val_every=steps, ckpt_every=steps,
        progress=False,
        data=DepthDataConfig(root=root, width=128, height=64, flip=False, scale_crop=False, workers=0),
        optim=DepthOptimConfig(lr=1e-4, batch_size=2),
        eval=DepthEvalConfig(depth_frames_max=8),
    )
