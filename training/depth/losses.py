"""SC-SfMLearner's self-supervised losses for the depth and pose nets.

Images here are RGB in [0, 1] (B, 3, H, W); depths are the nets' ``1/disp`` (B, 1, H, W), metres up to the
nets' unknown scale. For a target/reference pair with ``T = T_{t→r}``:

* photometric: per pixel ``(1 − w)·clamp(|I_t − I_r→t|, 0, 1) + w·(1 − SSIM)/2`` (w = 0.85; SSIM on 3×3
  windows with reflection padding, C1 = 0.01², C2 = 0.03²), multiplied by the self-discovered mask
  ``1 − D_diff``, averaged over valid pixels;
* geometry consistency: ``D_diff = |D_t→r − D_r(u', v')| / (D_t→r + D_r(u', v'))`` (clamped to [0, 1]),
  averaged over valid pixels;
* valid pixels: the warp lands inside the reference image (and in front of its camera) and, with
  auto-masking, the warped error is below the un-warped (static-scene) error;
* smoothness: ``mean |∂x d̂| e^{−|∂x I|} + mean |∂y d̂| e^{−|∂y I|}`` with ``d̂ = d / mean(d)`` per image
  (d the disparity, or the depth as the released code passes);
* with antisymmetrised poses (not in the released recipe): ``mean ‖(net(a,b) + net(b,a)) / 2‖₁`` of the pose
  vectors, so that the raw net a checkpoint carries becomes antisymmetric too.

Both losses are summed over both neighbours and both directions (t→r with ``pose_net(t, r)`` and r→t with
``pose_net(r, t)``) and over the scales used; smoothness over the three frames at the finest scale.
Coarser disparity scales are scored either at full resolution (upsampled, SC-SfMLearner's default) or on
area-downsampled images with K scaled (SfMLearner's pyramid, whose coarse levels widen the basin of
convergence for the large image motions of a forward-driving camera at the start of training).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from training.depth.config import DepthLossConfig
from training.depth.warp import inverse_warp

SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def ssim_loss(x: Tensor, y: Tensor) -> Tensor:
    """Per-pixel ``clamp((1 − SSIM(x, y)) / 2, 0, 1)`` on 3×3 windows (reflection-padded), (B, C, H, W)."""
    x = F.pad(x, (1, 1, 1, 1), mode="reflect")
    y = F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x = F.avg_pool2d(x, 3, 1)
    mu_y = F.avg_pool2d(y, 3, 1)
    sigma_x = F.avg_pool2d(x * x, 3, 1) - mu_x * mu_x
    sigma_y = F.avg_pool2d(y * y, 3, 1) - mu_y * mu_y
    sigma_xy = F.avg_pool2d(x * y, 3, 1) - mu_x * mu_y
    num = (2 * mu_x * mu_y + SSIM_C1) * (2 * sigma_xy + SSIM_C2)
    den = (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (sigma_x + sigma_y + SSIM_C2)
    return ((1 - num / den) / 2).clamp(0, 1)


def mean_on_mask(values: Tensor, mask: Tensor, min_fraction: float) -> Tensor:
    """Mean of ``values`` (B, C, H, W) over pixels where ``mask`` (B, 1, H, W) is 1.

    0 (with no gradient) unless more than ``min_fraction`` of the pixels are valid. No host sync (CUDA).
    """
    count = mask.sum()
    mean = (values * mask).sum() / (count.clamp(min=1.0) * values.shape[1])
    return torch.where(count > min_fraction * mask.numel(), mean, values.sum() * 0.0)


@dataclass
class PairLoss:
    """The two terms of one directed pair, plus the fraction of valid pixels (a diagnostic)."""

    photo: Tensor
    geometry: Tensor
    valid_fraction: Tensor


def pairwise_loss(tgt_img: Tensor, ref_img: Tensor, tgt_depth: Tensor, ref_depth: Tensor, T_tgt_to_ref: Tensor,
                  K: Tensor, cfg: DepthLossConfig) -> PairLoss:
    """Photometric and geometry-consistency loss of warping ``ref`` into ``tgt`` (see the module docstring)."""
    w = inverse_warp(ref_img, tgt_depth, ref_depth, T_tgt_to_ref, K, cfg.padding_mode)
    diff_img = (tgt_img - w.image).abs().clamp(0, 1)
    diff_depth = ((w.computed_depth - w.projected_depth).abs()
                  / (w.computed_depth + w.projected_depth)).clamp(0, 1)
    valid = w.valid
    if cfg.with_auto_mask:
        static = (tgt_img - ref_img).abs().mean(dim=1, keepdim=True)
        valid = (diff_img.mean(dim=1, keepdim=True) < static).to(valid.dtype) * valid
    if cfg.with_ssim:
        diff_img = (1 - cfg.ssim_weight) * diff_img + cfg.ssim_weight * ssim_loss(tgt_img, w.image)
    if cfg.with_mask:
        diff_img = diff_img * (1 - diff_depth)
    return PairLoss(photo=mean_on_mask(diff_img, valid, cfg.min_valid_fraction),
                    geometry=mean_on_mask(diff_depth, valid, cfg.min_valid_fraction),
                    valid_fraction=valid.mean().detach())


def smooth_loss(disp: Tensor, img: Tensor) -> Tensor:
    """Edge-aware smoothness of mean-normalised ``disp`` (B, 1, H, W) with image ``img`` (B, C, H, W)."""
    d = disp / (disp.mean(dim=(2, 3), keepdim=True) + 1e-7)
    grad_d_x = (d[:, :, :, :-1] - d[:, :, :, 1:]).abs()
    grad_d_y = (d[:, :, :-1, :] - d[:, :, 1:, :]).abs()
    grad_i_x = (img[:, :, :, :-1] - img[:, :, :, 1:]).abs().mean(dim=1, keepdim=True)
    grad_i_y = (img[:, :, :-1, :] - img[:, :, 1:, :]).abs().mean(dim=1, keepdim=True)
    return (grad_d_x * torch.exp(-grad_i_x)).mean() + (grad_d_y * torch.exp(-grad_i_y)).mean()


@dataclass
class SnippetInputs:
    """What the loss needs for a batch of 3-frame snippets (target = the middle frame).

    images: [I_{t−1}, I_t, I_{t+1}], each (B, 3, H, W) in [0, 1];
    disps: per frame, the net's disparities at the scales used (finest first), each (B, 1, h, w);
    poses: per neighbour r ∈ (t−1, t+1): (T_{t→r}, T_{r→t}), each (B, 4, 4);
    K: (B, 3, 3) intrinsics at the images' size;
    pose_symmetric: with antisymmetrised poses, the (2B, 6) symmetric remainders ``(net(a,b) + net(b,a)) / 2``.
    """

    images: list[Tensor]
    disps: list[list[Tensor]]
    poses: list[tuple[Tensor, Tensor]]
    K: Tensor
    pose_symmetric: Tensor | None = None


def _full_res(x: Tensor, hw: tuple[int, int]) -> Tensor:
    return x if tuple(x.shape[-2:]) == hw else F.interpolate(x, size=hw, mode="nearest")


def downscale_intrinsics(K: Tensor, sx: float, sy: float) -> Tensor:
    """K of an image area-resampled by (sx, sy) ≤ 1, exact for pixel centres: ``u' = sx (u + ½) − ½``."""
    out = K.clone()
    out[..., 0, 0] = K[..., 0, 0] * sx
    out[..., 0, 1] = K[..., 0, 1] * sx
    out[..., 0, 2] = (K[..., 0, 2] + 0.5) * sx - 0.5
    out[..., 1, 1] = K[..., 1, 1] * sy
    out[..., 1, 2] = (K[..., 1, 2] + 0.5) * sy - 0.5
    return out


def scale_views(images: list[Tensor], disps: list[list[Tensor]], K: Tensor, s: int, mode: str
                ) -> tuple[list[Tensor], list[Tensor], Tensor]:
    """Images, depths and K at which scale ``s`` is scored.

    ``upsample`` (SC-SfMLearner, Monodepth2): the scale's disparity is upsampled (nearest) to the full image;
    ``downsample`` (SfMLearner): the images are area-downsampled to the disparity's size and K scaled.
    """
    hw = tuple(images[0].shape[-2:])
    if mode == "upsample" or tuple(disps[0][s].shape[-2:]) == hw:
        return images, [1.0 / _full_res(d[s], hw) for d in disps], K
    h, w = disps[0][s].shape[-2:]
    small = [F.interpolate(img, size=(h, w), mode="area") for img in images]
    return small, [1.0 / d[s] for d in disps], downscale_intrinsics(K, w / hw[1], h / hw[0])


def snippet_loss(inputs: SnippetInputs, cfg: DepthLossConfig) -> tuple[Tensor, dict[str, float]]:
    """Total weighted loss and its terms (floats) for a batch of snippets."""
    images, K = inputs.images, inputs.K
    hw = tuple(images[1].shape[-2:])
    n_scales = max(1, min(cfg.num_scales, min(len(d) for d in inputs.disps)))
    tgt = 1
    photo = images[0].new_zeros(())
    geometry = images[0].new_zeros(())
    valid_fracs = []
    for s in range(n_scales):
        imgs, depths, Ks = scale_views(images, inputs.disps, K, s, cfg.scale_mode)
        for r, (T_t_r, T_r_t) in zip((0, 2), inputs.poses):
            fwd = pairwise_loss(imgs[tgt], imgs[r], depths[tgt], depths[r], T_t_r, Ks, cfg)
            bwd = pairwise_loss(imgs[r], imgs[tgt], depths[r], depths[tgt], T_r_t, Ks, cfg)
            photo = photo + fwd.photo + bwd.photo
            geometry = geometry + fwd.geometry + bwd.geometry
            valid_fracs += [fwd.valid_fraction, bwd.valid_fraction]
    smooth = images[0].new_zeros(())
    for d, img in zip(inputs.disps, images):
        field = d[0] if cfg.smooth_on == "disparity" else 1.0 / d[0]
        smooth = smooth + smooth_loss(field, F.interpolate(img, size=field.shape[-2:], mode="area")
                                      if tuple(field.shape[-2:]) != hw else img)
    total = cfg.photo_weight * photo + cfg.smooth_weight * smooth + cfg.geometry_weight * geometry
    terms = {"photo": float(photo.detach()), "geometry": float(geometry.detach()), "smooth": float(smooth.detach()),
             "valid_fraction": float(torch.stack(valid_fracs).mean())}
    if inputs.pose_symmetric is not None:
        symmetric = inputs.pose_symmetric.abs().sum(-1).mean()
        total = total + cfg.pose_symmetric_weight * symmetric
        terms["pose_symmetric"] = float(symmetric.detach())
    return total, terms
