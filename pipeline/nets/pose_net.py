"""PoseResNet: SC-SfMLearner's relative-pose network (6-channel ResNet-18 encoder + conv head).

State-dict layout (checkpoint-compatible with SC-SfMLearner's ``exp_pose_model_best.pth.tar``):
``encoder.encoder.*`` (torchvision-layout ResNet with a 6-channel ``conv1``, incl. the unused ``fc``) and
``decoder.net.0..3.*``: squeeze 1×1 (512→256), 3×3 (256→256), 3×3 (256→256), 1×1 (256→6), all with bias.

Convention — verified against SC-SfMLearner's training code: there ``pose = pose_net(tgt_img, ref_img)`` is
handed to ``inverse_warp2(ref_img, tgt_depth, ref_depth, pose, K)``, which back-projects the *target* depth
into target-camera points P_tgt, computes ``[R | t] · P_tgt`` and projects that with K to sample the
*reference* image and depth. So the 6-vector of ``pose_net(a, b)`` is ``T_{a→b}``, mapping camera-a
coordinates to camera-b coordinates, ``p_b = R p_a + t`` (docs/design.md §2's ``T_{1→2}`` is ``pose_net(img1, img2)``).
Its camera-to-world pose accumulates as ``Pose_b = Pose_a · inv(T_{a→b})``.

Output vector: ``[tx, ty, tz, rx, ry, rz]`` — translation in the depth net's (unknown) scale, Euler angles
in radians with ``R = Rx·Ry·Rz`` (see :func:`core.geometry.pose_vec_to_mat`).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from pipeline.nets.resnet import ResnetEncoder

POSE_SCALE = 0.01
"""The head's raw output is multiplied by this (SC-SfMLearner / Monodepth2)."""


class PoseDecoder(nn.Module):
    """Head on the last encoder map: ReLU(squeeze) → ReLU(3×3) → ReLU(3×3) → 1×1 → spatial mean · 0.01."""

    def __init__(self, num_ch_enc: tuple[int, ...], scale: float = POSE_SCALE) -> None:
        super().__init__()
        self.scale = scale
        self.net = nn.ModuleList(
            [
                nn.Conv2d(num_ch_enc[-1], 256, 1),
                nn.Conv2d(256, 256, 3, 1, 1),
                nn.Conv2d(256, 256, 3, 1, 1),
                nn.Conv2d(256, 6, 1),
            ]
        )
        self.relu = nn.ReLU()

    def forward(self, last_feature: Tensor) -> Tensor:
        out = last_feature
        for i, conv in enumerate(self.net):
            out = conv(out)
            if i < 3:
                out = self.relu(out)
        return self.scale * out.mean(dim=(2, 3))


class PoseResNet(nn.Module):
    """``forward(img_a, img_b)`` with normalised (B, 3, H, W) images → (B, 6) vector of ``T_{a→b}``."""

    def __init__(self, num_layers: int = 18) -> None:
        super().__init__()
        self.num_layers = num_layers
        self.encoder = ResnetEncoder(num_layers, num_input_images=2)
        self.decoder = PoseDecoder(self.encoder.num_ch_enc)

    def forward(self, img_a: Tensor, img_b: Tensor) -> Tensor:
        if img_a.shape != img_b.shape or img_a.dim() != 4 or img_a.shape[1] != 3:
            raise ValueError(
                f"PoseResNet expects two (B, 3, H, W) images of one shape, got {tuple(img_a.shape)} "
                f"and {tuple(img_b.shape)}"
            )
        features = self.encoder(torch.cat([img_a, img_b], dim=1))
        return self.decoder(features[-1])
