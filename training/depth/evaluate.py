"""Depth and pose metrics of the depth/pose nets (the community's protocols).

Depth (Eigen et al.; SC-SfMLearner's ``test_disp``): the prediction is resized (bilinear) to the ground
truth's size, pixels with ground truth in (min_depth, max_depth) are kept (Garg crop optionally), the
prediction is multiplied by ``median(gt) / median(pred)`` per image and clamped to the same range, then
AbsRel = mean |p − g| / g, SqRel = mean (p − g)² / g, RMSE = √mean (p − g)², RMSE-log, δ<1.25^k.
Ground truth: the dataset's dense ``depth_2`` maps (synthetic world) or the Velodyne scan projected into
the camera (KITTI, needs calib ``Tr``).

Pose: predicted ``T_{i→i+1}`` are chained into camera-to-first-frame poses ``Pose_{k+1} = Pose_k ·
inv(T_{k→k+1})``. ATE on every n-frame snippet (SfMLearner: positions relative to the snippet's first
frame, prediction scaled by the least-squares factor, ‖error‖ / n) with its rotation error; per-pair
relative errors (rotation angle, translation direction angle, translation after one least-squares scale);
and the KITTI devkit's segment errors t_rel (%) and r_rel (°/100 m) over segment lengths, after a global
least-squares scale of the whole trajectory. Units: metres of the ground truth, degrees.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from core.geometry import relative_pose, rotation_angle, se3_inverse
from pipeline.kitti.odometry import OdometrySequence
from pipeline.kitti.png16 import read_depth_png
from pipeline.sources import GT_DEPTH_DIR, project_lidar, read_frames, velo_to_cam
from training.depth.config import DepthEvalConfig

DEPTH_METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")


# --------------------------------------------------------------------------- depth


def depth_errors(gt: np.ndarray, pred: np.ndarray) -> dict[str, float]:
    """The seven standard depth errors of matched positive depths ``gt``, ``pred`` (1-D, metres)."""
    gt = gt.astype(np.float64)
    pred = pred.astype(np.float64)
    thresh = np.maximum(gt / pred, pred / gt)
    return {
        "abs_rel": float(np.mean(np.abs(gt - pred) / gt)),
        "sq_rel": float(np.mean((gt - pred) ** 2 / gt)),
        "rmse": float(np.sqrt(np.mean((gt - pred) ** 2))),
        "rmse_log": float(np.sqrt(np.mean((np.log(gt) - np.log(pred)) ** 2))),
        "a1": float(np.mean(thresh < 1.25)),
        "a2": float(np.mean(thresh < 1.25**2)),
        "a3": float(np.mean(thresh < 1.25**3)),
    }


def garg_crop(height: int, width: int) -> np.ndarray:
    """(H, W) bool: Garg et al.'s crop (rows 40.8–99.2 %, columns 3.6–96.4 %), the KITTI LiDAR convention."""
    mask = np.zeros((height, width), dtype=bool)
    mask[int(0.40810811 * height):int(0.99189189 * height), int(0.03594771 * width):int(0.96405229 * width)] = True
    return mask


def score_depth(pred: np.ndarray, gt: np.ndarray, cfg: DepthEvalConfig, crop: bool = False
                ) -> dict[str, float] | None:
    """Errors of one predicted depth map (h, w) against ground truth (H, W) (0 = none), median-scaled.

    Returns None when no pixel has valid ground truth. The dict also holds ``scale`` (the median ratio).
    """
    H, W = gt.shape
    if pred.shape != gt.shape:
        pred = cv2.resize(pred.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
    mask = np.isfinite(gt) & (gt > cfg.min_depth) & (gt < cfg.max_depth) & np.isfinite(pred) & (pred > 0)
    if crop:
        mask &= garg_crop(H, W)
    if not mask.any():
        return None
    g, p = gt[mask].astype(np.float64), pred[mask].astype(np.float64)
    scale = float(np.median(g) / np.median(p))
    p = np.clip(p * scale, cfg.min_depth, cfg.max_depth)
    return {**depth_errors(g, p), "scale": scale}


def ground_truth_depth(seq: OdometrySequence, pos: int) -> tuple[np.ndarray, str] | None:
    """(depth (H0, W0) metres at the native size, 'gt' | 'lidar') of position ``pos``, or None if neither exists."""
    path = seq.seq_dir / GT_DEPTH_DIR / (seq.image_path(pos).stem + ".png")
    if path.is_file():
        return read_depth_png(path), "gt"
    if seq.has_velodyne(pos) and seq.T_velo_to_cam is not None:
        return project_lidar(seq.read_velodyne(pos), velo_to_cam(seq), seq.K, seq.image_shape), "lidar"
    return None


def has_depth_ground_truth(seq: OdometrySequence) -> bool:
    return (seq.seq_dir / GT_DEPTH_DIR).is_dir() or (seq.velodyne_dir.is_dir() and seq.T_velo_to_cam is not None)


def spread(n: int, k: int) -> list[int]:
    """At most ``k`` positions evenly spread over 0..n−1 (all when n ≤ k)."""
    if n <= k:
        return list(range(n))
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, k)})


def evaluate_depth(runner, sequences: list[OdometrySequence], hw: tuple[int, int], cfg: DepthEvalConfig
                   ) -> dict[str, float]:
    """Mean depth errors over up to ``depth_frames_max`` frames per sequence; {} without ground truth.

    ``runner`` is a :class:`pipeline.nets.DepthPoseRunner` holding the depth net.
    """
    rows: list[dict[str, float]] = []
    for seq in sequences:
        if not has_depth_ground_truth(seq):
            continue
        positions = spread(len(seq), cfg.depth_frames_max)
        preds = runner.depth(read_frames(seq, positions, hw))
        for pred, pos in zip(preds, positions):
            found = ground_truth_depth(seq, pos)
            if found is None:
                continue
            gt, kind = found
            crop = cfg.garg_crop == "on" or (cfg.garg_crop == "auto" and kind == "lidar")
            row = score_depth(pred, gt, cfg, crop)
            if row is not None:
                rows.append(row)
    if not rows:
        return {}
    out = {k: float(np.mean([r[k] for r in rows])) for k in DEPTH_METRICS}
    out["depth_frames"] = len(rows)
    return out


# --------------------------------------------------------------------------- pose


def chain_poses(T_rel: np.ndarray) -> np.ndarray:
    """Camera-to-first poses (N+1, 4, 4) from N relative poses ``T_{k→k+1}``: Pose_{k+1} = Pose_k · inv(T)."""
    out = [np.eye(4)]
    for T in np.asarray(T_rel, dtype=np.float64):
        out.append(out[-1] @ se3_inverse(T))
    return np.stack(out)


def to_first(poses: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) re-expressed relative to the first: ``inv(Pose_0) · Pose_k``."""
    return se3_inverse(poses[0])[None] @ poses


def lsq_scale(gt_t: np.ndarray, pred_t: np.ndarray) -> float:
    """The factor s minimising ‖gt_t − s·pred_t‖² (vectors (…, 3)); 1 when the prediction is all zero."""
    den = float(np.sum(pred_t * pred_t))
    return float(np.sum(gt_t * pred_t) / den) if den > 0 else 1.0


def snippet_errors(gt: np.ndarray, pred: np.ndarray) -> tuple[float, float]:
    """SfMLearner's (ATE, RE) of one snippet: poses (n, 4, 4) relative to its first frame.

    ATE = ‖gt positions − s · predicted positions‖ / n with the least-squares s; RE = mean rotation angle
    of ``R_gt · R_pred⁻¹`` (radians).
    """
    n = gt.shape[0]
    s = lsq_scale(gt[:, :3, 3], pred[:, :3, 3])
    ate = float(np.linalg.norm(gt[:, :3, 3] - s * pred[:, :3, 3]))
    re = float(np.mean(rotation_angle(gt[:, :3, :3] @ np.swapaxes(pred[:, :3, :3], -1, -2))))
    return ate / n, re


def ate_snippets(gt_poses: np.ndarray, pred_rel: np.ndarray, snippet: int) -> dict[str, float]:
    """Mean ATE (metres) and RE (degrees) over every ``snippet``-frame window of a trajectory.

    ``gt_poses`` (N, 4, 4) camera-to-world, ``pred_rel`` (N−1, 4, 4) predicted ``T_{k→k+1}``.
    """
    N = gt_poses.shape[0]
    ates, res = [], []
    for a in range(0, N - snippet + 1):
        gt = to_first(gt_poses[a:a + snippet])
        pred = chain_poses(pred_rel[a:a + snippet - 1])
        ate, re = snippet_errors(gt, pred)
        ates.append(ate)
        res.append(re)
    if not ates:
        return {}
    return {"ate": float(np.mean(ates)), "ate_std": float(np.std(ates)), "ate_rot_deg": math.degrees(np.mean(res)),
            "ate_snippets": len(ates)}


def relative_errors(gt_rel: np.ndarray, pred_rel: np.ndarray) -> dict[str, float]:
    """Per-pair errors of predicted ``T_{k→k+1}`` (N, 4, 4) against the ground truth's, averaged.

    rot_err_deg: angle of ``R_gt^T R_pred``; rot_mag_gt_deg / rot_mag_pred_deg: the rotation angles;
    trans_dir_err_deg: angle between the translations (trans_dir_err_median_deg: its median, which one
    reversed pair cannot dominate); trans_err: ‖t_gt − s t_pred‖ with one least-squares s over all pairs
    (metres).
    """
    Rg, Rp = gt_rel[:, :3, :3], pred_rel[:, :3, :3]
    tg, tp = gt_rel[:, :3, 3], pred_rel[:, :3, 3]
    rot = np.degrees(rotation_angle(np.swapaxes(Rg, -1, -2) @ Rp))
    cos = np.sum(tg * tp, axis=1) / np.maximum(np.linalg.norm(tg, axis=1) * np.linalg.norm(tp, axis=1), 1e-12)
    s = lsq_scale(tg, tp)
    return {"rot_err_deg": float(np.mean(rot)),
            "rot_mag_gt_deg": float(np.mean(np.degrees(rotation_angle(Rg)))),
            "rot_mag_pred_deg": float(np.mean(np.degrees(rotation_angle(Rp)))),
            "trans_dir_err_deg": float(np.mean(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))),
            "trans_dir_err_median_deg": float(np.median(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))),
            "trans_err": float(np.mean(np.linalg.norm(tg - s * tp, axis=1))),
            "pairs": int(len(rot))}


def kitti_segment_errors(gt_poses: np.ndarray, pred_poses: np.ndarray, lengths: tuple[float, ...],
                         step: int = 10) -> dict[str, float]:
    """The KITTI odometry devkit's t_rel (%) and r_rel (°/100 m) over segments of ``lengths`` metres.

    Both trajectories (N, 4, 4) camera-to-world; the prediction's positions are first scaled by the
    least-squares factor against the ground truth's (both relative to their first frame). {} when the
    trajectory is shorter than the shortest segment.
    """
    gt = to_first(gt_poses)
    pred = to_first(pred_poses).copy()
    pred[:, :3, 3] *= lsq_scale(gt[:, :3, 3], pred[:, :3, 3])
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1))])
    t_errs, r_errs = [], []
    for first in range(0, len(gt), step):
        for length in lengths:
            ahead = np.nonzero(dist > dist[first] + length)[0]
            if ahead.size == 0:
                continue
            last = int(ahead[0])
            err = se3_inverse(relative_pose(pred[first], pred[last])) @ relative_pose(gt[first], gt[last])
            t_errs.append(np.linalg.norm(err[:3, 3]) / length)
            r_errs.append(float(rotation_angle(err[:3, :3])) / length)
    if not t_errs:
        return {}
    return {"t_rel_pct": 100.0 * float(np.mean(t_errs)), "r_rel_deg_per_100m": math.degrees(np.mean(r_errs)) * 100.0,
            "segments": len(t_errs)}


def consecutive_runs(seq: OdometrySequence) -> list[list[int]]:
    """Maximal runs of positions whose frame ids are consecutive."""
    runs: list[list[int]] = []
    for i, f in enumerate(seq.frames):
        if runs and seq.frames[runs[-1][-1]] == f - 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    return [r for r in runs if len(r) >= 2]


def predict_relative_poses(runner, seq: OdometrySequence, positions: list[int], hw: tuple[int, int]) -> np.ndarray:
    """``T_{k→k+1}`` (len−1, 4, 4) float64 of consecutive ``positions`` from the runner's pose net."""
    frames = read_frames(seq, positions, hw)
    return runner.pose(frames[:-1], frames[1:])


def evaluate_pose(runner, sequences: list[OdometrySequence], hw: tuple[int, int], cfg: DepthEvalConfig
                  ) -> dict[str, float]:
    """Pose errors (ATE-n, per-pair, KITTI segments) averaged over the sequences with poses; {} without."""
    per: list[dict[str, float]] = []
    for seq in sequences:
        if not seq.has_poses:
            continue
        for run in consecutive_runs(seq):
            gt_poses = seq.poses[run]
            gt_rel = np.stack([seq.relative_pose(a, b) for a, b in zip(run[:-1], run[1:])])
            pred_rel = predict_relative_poses(runner, seq, run, hw)
            row = {**relative_errors(gt_rel, pred_rel), **ate_snippets(gt_poses, pred_rel, cfg.snippet)}
            row.update(kitti_segment_errors(gt_poses, chain_poses(pred_rel), cfg.segment_lengths))
            per.append(row)
    if not per:
        return {}
    weights = np.array([r["pairs"] for r in per], dtype=np.float64)
    keys = set.intersection(*(set(r) for r in per))
    out = {k: float(np.average([r[k] for r in per], weights=weights)) for k in keys
           if k not in ("pairs", "ate_snippets", "segments")}
    out["pose_pairs"] = int(weights.sum())
    return out


def evaluate_nets(depth_net, pose_net, sequences: list[OdometrySequence], hw: tuple[int, int],
                  cfg: DepthEvalConfig, device="cpu", batch_size: int = 8) -> dict[str, float]:
    """Depth and pose metrics of the nets on ``sequences`` (frames resized to hw = (H, W)).

    The nets are put in eval mode on ``device`` (the caller restores train mode).
    """
    from pipeline.nets import DepthPoseRunner

    runner = DepthPoseRunner(depth_net, pose_net, device=device, batch_size=batch_size)
    out: dict[str, float] = {}
    if depth_net is not None:
        out.update(evaluate_depth(runner, sequences, hw, cfg))
    if pose_net is not None:
        out.update(evaluate_pose(runner, sequences, hw, cfg))
    return out


def evaluate_checkpoints(disp_checkpoint: str | Path, pose_checkpoint: str | Path | None, root: str,
                         sequences: list[str], camera: str, hw: tuple[int, int], cfg: DepthEvalConfig,
                         device="cpu") -> dict[str, float]:
    """Metrics of official-format checkpoints (loaded strictly, as stage one loads them)."""
    from pipeline.nets import load_depth_net, load_pose_net

    depth_net = load_depth_net(disp_checkpoint) if disp_checkpoint else None
    pose_net = load_pose_net(pose_checkpoint) if pose_checkpoint else None
    seqs = [OdometrySequence(root, s, camera=camera) for s in sequences]
    return evaluate_nets(depth_net, pose_net, seqs, hw, cfg, device)
