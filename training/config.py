"""Configuration of a scene-flow training run (saved as ``config.json`` in the run folder).

Torch-free, so that ``monoflow-train --help`` and the evaluator's config handling load without torch. The
net's own config is the registered net's (:mod:`training.model.registry`, ``model_name``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from core.errors import ConfigError
from training.choices import (ALPHA_ORDERS, DEPTH_VARIANTS, PC2_TARGETS, SCHEDULES, AlphaOrder, DepthVariant, KnnBackend,
                              LrSchedule, Pc2Target)
from training.model.contract import FlowNetConfig
from training.model.halflownet_config import HALFlowConfig, level_points_for  # noqa: F401  (re-exported)
from training.model.registry import DEFAULT_NET, config_class
from training.runtime.run_config import RunConfig


@dataclass
class DataConfig:
    """What the trainer reads from a stage-one cache.

    n_points: points sampled per cloud per step (seeded by (seed, epoch, pair index), so results do not
        depend on the number of loader workers).
    val_fraction: the last fraction of each sequence's pairs held out for validation (label-free scores,
        and EPE3D where the cache holds ground-truth flow); 0 disables validation.
    val_pairs_max: at most this many held-out pairs are scored at each validation.
    colour_features: use RGB in [0, 1] as the per-point features (else zeros). Off by default: the KITTI
        scene-flow test splits (FlowNet3D, HPLFlowNet) carry no colours, so a net trained with them meets zeros
        there (monoflow-evaluate warns).
    jitter_deg / jitter_m: the second pass's static flow is moved by a random rigid motion of at most
        these angles (degrees, per axis) and translations (metres, per axis) — the released code's
        augmentation; 0 disables it.
    workers: DataLoader worker processes (0 = load in the training process).
    keep_mb: MiB of decoded pairs each loading process keeps in memory, the first ones read until full (a
        cache that fits is read from disk once per process; most of a CPU step's loading on a small cache);
        0 = read every pair from disk (pipeline.cache.reader.CacheReader).
    depth2_kept_only: the depth-consistency loss samples D_{t+1} only at frame-(t+1) pixels that survived
        stage one's filters (ground, sky, LiDAR range, occlusion), i.e. the surfaces pc2 holds; other pixels
        count as invalid and the points landing there are masked. False = the whole depth map (the
        released code). Without it, a point can satisfy depth consistency by sliding onto the road, which
        the ground filter removed from pc2 (see the note in BENCHMARKS.md / the trainer tests).
    lidar_rings: probability per training pair of keeping only points near LiDAR-like scan rings
        (:mod:`training.augment`); 0 = off.
    ring_band: share of a ring spacing (0.3–0.5°) that a ring keeps (0.5 keeps about half the points).
    density_drop: frame t+1 loses a random share of up to this fraction of its points; 0 = off.
    ground_jitter_m: metres; both frames lose points below a cut drawn up to this far above the lowest
        points, as a test split's height-threshold ground removal would; 0 = off.
    ego_speed_scale: (low, high); each training pair's camera motion is rescaled by a factor drawn
        log-uniformly in this range (rotation angle and translation alike; frame t's cloud is moved, frame
        t+1 and its depth map stay, :func:`training.augment.speed_scaled_view`), so the net learns camera
        speeds beyond the ones its sequences drove at (KITTI: 0–2.5 m per frame); (1, 1) = off.
    ego_turn_deg / ego_shift_m: each training pair's frame-t camera is also turned about its vertical (y)
        axis by an angle drawn uniformly within ± ego_turn_deg (degrees) and shifted in the ground plane
        (x and z) by up to ± ego_shift_m (metres, each axis uniform); frame t's cloud is moved, frame t+1 and
        every target in it stay (:func:`training.augment.turn_shift_view`). The pair's ego-motion then no
        longer follows the training sequences' driving, so the net has to match rather than recall a
        typical motion; 0 = off.
    mirror: probability per training pair of reflecting it left–right (points, flows, the frame-(t+1)
        depth map and the intrinsics' principal point, :func:`training.augment.mirror_pair`): streets
        the training sequences never drove; 0 = off.
    synthetic_movers: probability per training pair of one synthetic mover: an object-sized cluster of
        frame t's sampled points (single-linkage gaps < 0.8 m, ≥ 8 points, ≤ 6 m on every axis; label-free) is
        put back where it would have stood at time t had it driven on its own — a turn of up to ±5° about
        its vertical axis and a horizontal shift along a heading drawn over the whole circle — while frame
        t+1 and its depth map stay (:func:`training.augment.synthetic_mover`). The cluster's flow targets stay
        where they were, its static flow is the camera's motion at its new place, so the Chamfer and depth
        terms see a mover the static flow does not explain. The training world's movers all drive along its
        roads at its speeds; these come at every heading and at speeds of ``synthetic_mover_m``; 0 = off.
    synthetic_mover_m: (low, high), metres per frame: the synthetic mover's own displacement, drawn uniformly.
    """

    n_points: int = 8192
    val_fraction: float = 0.1
    val_pairs_max: int = 64
    colour_features: bool = False
    jitter_deg: float = 0.0
    jitter_m: float = 0.0
    workers: int = 2
    keep_mb: float = 512.0
    depth2_kept_only: bool = False
    lidar_rings: float = 0.0
    ring_band: float = 0.5
    density_drop: float = 0.0
    ground_jitter_m: float = 0.0
    ego_speed_scale: tuple[float, float] = (1.0, 1.0)
    ego_turn_deg: float = 0.0
    ego_shift_m: float = 0.0
    mirror: float = 0.0
    synthetic_movers: float = 0.0
    synthetic_mover_m: tuple[float, float] = (0.2, 2.0)

    def augment(self) -> dict:
        """The keyword arguments of :func:`training.augment.augment_masks` for training pairs."""
        return {"lidar_rings": self.lidar_rings, "ring_band": self.ring_band, "density_drop": self.density_drop,
                "ground_jitter_m": self.ground_jitter_m}


@dataclass
class OptimConfig:
    """Adam with the paper's step decay: lr · decay^(samples // decay_every), floored at lr_min.

    schedule: ``step`` (the paper's step decay above) or ``cosine``: from ``lr`` at step 0 down to
        ``lr_min`` at the run's last step along half a cosine (``decay`` and ``decay_every_samples`` unused).
        Its lr depends on the run's length, so a run continued to more steps follows a new curve from
        where it stands.
    lr: initial learning rate.
    decay: factor applied every ``decay_every_samples`` training samples.
    decay_every_samples: training pairs seen between two decays.
    decay_every_epochs: > 0: the decays' period in passes over the training pairs instead, i.e.
        ``decay_every_samples`` = this × the number of training pairs. The paper's 200k samples are about
        10 epochs of FlyingThings3D's 19.6k training pairs; on a cache of a few hundred pairs the same
        count would never decay (docs/learned-flow.md, thirteenth round). 0 = ``decay_every_samples``.
    lr_min: the learning rate never goes below this.
    batch_size: pairs per optimiser step (global, over all processes).
    grad_clip: clip the gradient norm to this (0 = no clipping).
    ema_decay: 0 = off; else validation, every checkpoint's inference weights and so every evaluation use
        an exponential moving average of the trained weights with this decay per step (Polyak averaging,
        :mod:`training.runtime.ema`; 0.99 averages over roughly the last 100 steps).
    """

    schedule: LrSchedule = "step"
    lr: float = 1e-3
    decay: float = 0.7
    decay_every_samples: int = 200_000
    decay_every_epochs: float = 0.0
    lr_min: float = 1e-4
    batch_size: int = 5
    grad_clip: float = 0.0
    ema_decay: float = 0.0



FINEST_ONLY_TERMS = {"ego": "ego_motion", "pull": "gate_pull", "smooth": "flow_smooth"}
"""The departure terms :attr:`LossWeights.finest_only` can keep to the finest level, and their weights."""


@dataclass
class LossWeights:
    """Weights and switches of the unsupervised loss.

    beta: (depth, dynamic-static, Chamfer, Laplacian) = (β1, β2, β3, β4), paper §IV-B.
    alpha: (α1, α2, α3, α4) as the paper lists them. The paper does not say which end of the pyramid
        α1 belongs to. ``alpha_order="released"`` (default) follows the released code, which gives the
        largest factor to the finest level: finest-first weights are ``reversed(alpha)`` = (0.16, 0.08,
        0.04, 0.02). ``"paper"`` reads α_k as level k counted from the finest: (0.02, 0.04, 0.08, 0.16).
    use_*: switch a term off for the loss ablations (it is then neither computed nor logged).
    depth_variant: ``"paper"`` | ``"released"`` (see :func:`depth_consistency`).
    laplacian_k, interp_k: neighbours of the Laplacian (10) and of its interpolation (5).
    eps: depth (metres) at or below which a warped point counts as behind the camera.
    depth_edge_tolerance: depth consistency ignores points whose bilinear depth sample straddles a depth
        edge (2×2 pixels spanning more than this fraction); 0 = plain bilinear sampling (the paper).
    depth_norm: ``l1`` (the residual's length, default) or ``l2`` (its square, the paper's form).
    knn_backend: "auto" | "kdtree" | "torch" neighbour search of the Laplacian terms (see training.knn).
    pc2_target: which frame-(t+1) points every level's Chamfer and Laplacian terms compare with: ``level``
        (the paper: pc2 sampled at the same level) or ``finest`` (the finest level's pc2 points at every
        level). At the coarse levels a 16- or 64-point pc2 sample is so sparse that the Chamfer distance is
        mostly sampling noise (the objective audit: the same ≈8 m² at the true flow and at the ego-motion
        alone), so the paper's coarse terms reward moving points onto other random points; against the
        finest level's points they measure the distance to the surfaces again (docs/learned-flow.md).
        ``independent``: a second draw of frame t+1's points, disjoint from the net's input where the cloud
        has enough points and taken before the input-only augmentations (rings, density drop, ground cut),
        farthest-point sampled to every level's size. The net sees its pc2 sample; the loss measures the
        distance to other samples of the same surfaces, so moving points onto the input's pc2 points — its
        sampling pattern, which a LiDAR's rings tie to the sensor — no longer lowers the loss, only landing
        on the surfaces does (docs/learned-flow.md, third round).
    view_mask: the Chamfer term leaves out the frame-t points whose camera-motion target (p + sf_s) falls
        outside frame t+1's view (image bounds, in front of the camera, nearer than the far limit the
        cache was built with, ``filters.far_max_z``) and the frame-(t+1) points that were outside frame t's
        view. They have no counterpart in the other cloud, so the Chamfer term can only pull them onto wrong
        points. Needs no labels, only the
        pose stage one used. Meant for caches built with ``--filters.occlusion false``, whose clouds keep
        such points as LiDAR test clouds do (docs/learned-flow.md, third round). False = the paper.
    static_anchor: weight of the static-flow anchor at every level (a departure; 0 = the paper): the mean
        length ‖f_o − sf_s‖ (metres) over the frame-t points whose static target p + sf_s lands on the
        surface frame t+1's depth map sees, i.e. the points the camera's motion alone explains
        (:mod:`training.losses.static_anchor`; docs/learned-flow.md, sixth round). Needs no labels, only
        stage one's pose and depth.
    anchor_tol_m, anchor_tol_rel: a point counts as explained by the camera's motion when its static
        target lies within max(anchor_tol_m metres, anchor_tol_rel × its depth) of the surface the depth
        map sees, measured along the viewing ray.
    ego_motion: weight of the ego-motion term at every level (a departure; 0 = the paper): the mean
        distance between the flow of the rigid motion the net's ego head fitted and stage one's static
        flow, over all points (:mod:`training.losses.ego_motion`; docs/learned-flow.md, seventh round).
        Needs ``model.ego_head``; no labels, only stage one's pose.
    gate_pull: weight of the gate pull at every level (a departure; 0 = the paper): the mean squared
        distance (m²) between each point's own flow and the ego head's output, with the output held fixed,
        in both passes; it pulls the own flow that the gate holds at the camera's motion back to it, so that
        it cannot stray until the gate lets it through (:mod:`training.losses.gate_pull`;
        docs/learned-flow.md, twelfth round). Needs ``model.ego_head``; meant with
        ``model.ego_open_gradient``. A held point's own flow settles ``2 d / w`` off the output, ``d`` the
        distance to its nearest frame-2 sample: at 1 (as strong as the Chamfer term, β3 = 1) it goes past
        that sample, at 4 it stops halfway (thirteenth round).
    chamfer_truncate: metres; > 0: every level's Chamfer term counts a nearest-neighbour distance above
        this as this, with no gradient (NSFP's truncation; :func:`training.losses.chamfer.chamfer`), so points
        without a counterpart in the other cloud stop pulling the flow (a departure; docs/learned-flow.md,
        twelfth round). 0 = the paper's untruncated eq. 13.
    chamfer_plane: λ in [0, 1]; > 0: every level's Chamfer pair counts ``(1 − λ)`` of its squared distance
        plus ``λ`` of its squared component along the surface normal at the pair's frame-(t+1) point (normals
        from the point's 8 nearest frame-(t+1) points; :func:`training.losses.chamfer.chamfer`). A plain
        point-to-point distance pulls a point that lands between two samples of a surface onto one of them;
        the normal component pulls onto the surface only (a departure; docs/learned-flow.md, fourteenth
        round). 0 = the paper's eq. 13.
    laplacian_plane: λ in [0, 1]; > 0: every level's Laplacian term counts ``(1 − λ)`` of its squared
        difference plus ``λ`` of its squared component along the surface normal at the warped point's nearest
        frame-(t+1) point (:func:`training.losses.laplacian.laplacian`). The Laplacian of a sample lies
        mostly along its surface and differs between two samples of the same surface, so its plain form
        pulls static points along the surface at the true flow as the point-to-point Chamfer term does
        (a departure; docs/learned-flow.md, fourteenth round). 0 = the paper's eq. 16.
    flow_smooth: weight of the flow smoothness term at every level (a departure; 0 = the paper): the mean
        length ‖r_i − r_j‖ (metres) of the flow's departure from the camera's motion, ``r = f_o − sf_s``,
        over each frame-t point's ``laplacian_k`` nearest frame-t points (:mod:`training.losses.flow_smooth`).
        It reads frame t and stage one's pose alone, so unlike the Chamfer, Laplacian and depth terms its
        least value does not depend on where frame (t+1)'s samples fell (docs/learned-flow.md, fifteenth
        round).
    plane_where_held: the plane forms (``chamfer_plane``, ``laplacian_plane``) count only where the net's ego
        head holds a point at its fitted rigid motion: each frame-t point's λ is scaled by ``1 − m``, ``m``
        the head's gate (0 held … 1 own flow), and a frame-(t+1) point's Chamfer pair by that of its nearest
        warped point. Where the gate lets a mover's own flow through, the pair counts point to point, which
        holds the mover's flow along its own surface (needs ``model.ego_head``; a departure;
        docs/learned-flow.md, sixteenth round). False = λ everywhere.
    finest_only: departure terms counted at the finest level only, a comma list of ``ego`` (``ego_motion``),
        ``pull`` (``gate_pull``) and ``smooth`` (``flow_smooth``); the coarser levels leave them out (an
        ablation: docs/learned-flow.md, twenty-second round). Empty = every level.
    """

    beta: tuple[float, float, float, float] = (0.1, 0.1, 1.0, 0.3)
    alpha: tuple[float, ...] = (0.02, 0.04, 0.08, 0.16)
    alpha_order: AlphaOrder = "released"
    use_depth: bool = True
    use_ds: bool = True
    use_chamfer: bool = True
    use_laplacian: bool = True
    depth_variant: DepthVariant = "paper"
    laplacian_k: int = 10
    interp_k: int = 5
    eps: float = 1e-3
    depth_edge_tolerance: float = 0.05
    depth_norm: str = "l1"
    knn_backend: KnnBackend = "auto"
    pc2_target: Pc2Target = "level"
    view_mask: bool = False
    static_anchor: float = 0.0
    anchor_tol_m: float = 0.1
    anchor_tol_rel: float = 0.02
    ego_motion: float = 0.0
    gate_pull: float = 0.0
    chamfer_truncate: float = 0.0
    chamfer_plane: float = 0.0
    laplacian_plane: float = 0.0
    flow_smooth: float = 0.0
    plane_where_held: bool = False
    finest_only: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        self.finest_only = tuple(str(t) for t in self.finest_only)  # type: ignore[assignment]
        if not set(self.finest_only) <= FINEST_ONLY_TERMS.keys():
            raise ConfigError(f"finest_only names terms of {tuple(FINEST_ONLY_TERMS)}, got {self.finest_only}")
        self.beta = tuple(float(b) for b in self.beta)  # type: ignore[assignment]
        self.alpha = tuple(float(a) for a in self.alpha)
        if len(self.beta) != 4:
            raise ConfigError(f"beta must have 4 weights (depth, ds, chamfer, laplacian), got {self.beta}")
        if not self.alpha:
            raise ConfigError("alpha must have at least one level factor")
        if any(w < 0 for w in self.beta + self.alpha):
            raise ConfigError(f"loss weights must be non-negative, got beta={self.beta} alpha={self.alpha}")
        if self.static_anchor < 0 or not self.anchor_tol_m > 0 or self.anchor_tol_rel < 0:
            raise ConfigError(f"need static_anchor >= 0, anchor_tol_m > 0 and anchor_tol_rel >= 0, got "
                              f"{self.static_anchor}, {self.anchor_tol_m}, {self.anchor_tol_rel}")
        if not (0 <= self.chamfer_plane <= 1 and 0 <= self.laplacian_plane <= 1):
            raise ConfigError(f"need 0 <= chamfer_plane, laplacian_plane <= 1, got {self.chamfer_plane}, "
                              f"{self.laplacian_plane}")
        if self.chamfer_truncate < 0:
            raise ConfigError(f"need chamfer_truncate >= 0 (metres; 0 = none), got {self.chamfer_truncate}")
        if self.ego_motion < 0 or self.gate_pull < 0 or self.flow_smooth < 0:
            raise ConfigError(f"need ego_motion >= 0, gate_pull >= 0 and flow_smooth >= 0, got {self.ego_motion}, "
                              f"{self.gate_pull}, {self.flow_smooth}")
        if self.alpha_order not in ALPHA_ORDERS:
            raise ConfigError(f"alpha_order must be one of {ALPHA_ORDERS}, got {self.alpha_order!r}")
        if self.depth_variant not in DEPTH_VARIANTS:
            raise ConfigError(f"depth_variant must be one of {DEPTH_VARIANTS}, got {self.depth_variant!r}")
        if self.laplacian_k < 1 or self.interp_k < 1:
            raise ConfigError(f"laplacian_k and interp_k must be ≥ 1, got {self.laplacian_k}, {self.interp_k}")
        if self.pc2_target not in PC2_TARGETS:
            raise ConfigError(f"pc2_target must be one of {PC2_TARGETS}, got {self.pc2_target!r}")

    def coarse(self) -> "LossWeights":
        """The weights of the levels below the finest: these, with the ``finest_only`` terms' weights at 0."""
        if not self.finest_only:
            return self
        return replace(self, finest_only=(), **{FINEST_ONLY_TERMS[t]: 0.0 for t in self.finest_only})


@dataclass
class TrainConfig(RunConfig):
    """A whole run. ``steps`` counts optimiser steps (global batches of ``optim.batch_size`` pairs).

    epochs: when > 0, overrides ``steps`` (ceil(epochs · training pairs / batch size)).
    threads: torch intra-op threads of each training process (0 = leave torch's default); on a small
        machine with loader workers, fewer threads than cores avoids oversubscription.
    sync_bn: under DDP, batch norm uses the statistics of the global batch (so P processes with a global
        batch B train like one process with B); false = per-process statistics, as plain DDP does.
    deterministic: ``torch.use_deterministic_algorithms`` (warn only); on the CPU a run is repeatable
        with a fixed ``threads`` either way.
    select_by: the held-out score ``best.pt`` minimises: ``val_l0`` (the finest level's loss, needs no
        labels), ``val_loss`` (the whole multi-level loss) or ``val_epe3d`` (needs ground-truth flow;
        synthetic data only). See :mod:`training.selection`.
    model_name: the flow net, by its name in training.model.registry (halflownet = the paper's
        HALFlowNet); the model.* options are that net's architecture. Stored in the checkpoints.
    cache: stage-one cache folder (<out>/<dataset>/<config-hash>, written by monoflow-preprocess).
    run_dir: run folder (config.json, train.csv / val.csv, latest.pt, best.pt); an existing one is refused
        unless --resume or --overwrite.
    steps: optimiser steps of the run (global batches of optim.batch_size pairs).
    seed: seed of every RNG (Python, numpy, torch) and of the point sampling.
    amp: mixed-precision training (CUDA).
    """

    run_dir: str = "runs/flow"
    cache: str = "cache/synthetic"
    epochs: float = 0.0
    threads: int = 0
    amp: bool = False
    sync_bn: bool = True
    select_by: str = "val_l0"
    model_name: str = DEFAULT_NET
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    model: FlowNetConfig = field(default_factory=HALFlowConfig, metadata={"class_from": ("model_name", config_class)})
    loss: LossWeights = field(default_factory=LossWeights)
