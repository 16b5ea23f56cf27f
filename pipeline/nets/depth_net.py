"""DispResNet: SC-SfMLearner's single-image depth network (ResNet encoder + Monodepth2 decoder).

State-dict layout (checkpoint-compatible with SC-SfMLearner's ``dispnet_model_best.pth.tar``):

* ``encoder.encoder.*`` — a torchvision-layout ResNet-18/50 (including the unused ``fc``);
* ``decoder.decoder.0..9.conv.conv.*`` — the up-convolutions, ordered (upconv 4,0), (upconv 4,1), …,
  (upconv 0,0), (upconv 0,1); each is a :class:`ConvBlock` (reflection-padded 3×3 conv + ELU);
* ``decoder.decoder.10..13.conv.*`` — the disparity heads of scales 0..3 (:class:`Conv3x3`).

Output: disparity ``disp = 10·sigmoid(x) + 0.01`` ∈ (0.01, 10.01), so depth ``= 1/disp`` ∈ (≈0.1, 100)
in units of an unknown, per-network scale ("metres up to scale"). In training mode the net returns the
four scales [H, H/2, H/4, H/8] (finest first), each (B, 1, h, w); in eval mode only the finest (B, 1, H, W).
H and W must be multiples of 32.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from pipeline.nets.resnet import ResnetEncoder

DISP_ALPHA = 10.0
"""Disparity range: disp = DISP_ALPHA · sigmoid(x) + DISP_BETA."""
DISP_BETA = 0.01
DECODER_CHANNELS = (16, 32, 64, 128, 256)
"""Decoder channels per scale 0..4 (scale s has stride 2**s)."""
NUM_SCALES = 4


class Conv3x3(nn.Module):
    """Reflection-pad by 1 then 3×3 convolution (with bias); keys ``conv.weight``, ``conv.bias``."""

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.pad = nn.ReflectionPad2d(1)
        self.conv = nn.Conv2d(int(in_channels), int(out_channels), 3)

    def forward(self, x: Tensor) -> Tensor:
        return self.conv(self.pad(x))


class ConvBlock(nn.Module):
    """:class:`Conv3x3` followed by ELU; keys ``conv.conv.weight``, ``conv.conv.bias``."""

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.conv = Conv3x3(in_channels, out_channels)
        self.nonlin = nn.ELU(inplace=True)

    def forward(self, x: Tensor) -> Tensor:
        return self.nonlin(self.conv(x))


class DepthDecoder(nn.Module):
    """Monodepth2 decoder with skips; ``forward(features)`` → disparities of scales 0..3, finest first."""

    def __init__(self, num_ch_enc: tuple[int, ...], alpha: float = DISP_ALPHA, beta: float = DISP_BETA) -> None:
        super().__init__()
        self.alpha = alpha
        self.beta = beta
        ch = DECODER_CHANNELS
        blocks: list[nn.Module] = []
        for i in range(4, -1, -1):  # coarse to fine: module index 2·(4−i) is upconv (i,0), +1 is (i,1)
            blocks.append(ConvBlock(num_ch_enc[-1] if i == 4 else ch[i + 1], ch[i]))
            blocks.append(ConvBlock(ch[i] + (num_ch_enc[i - 1] if i > 0 else 0), ch[i]))
        for s in range(NUM_SCALES):  # module index 10 + s
            blocks.append(Conv3x3(ch[s], 1))
        self.decoder = nn.ModuleList(blocks)

    def forward(self, features: list[Tensor]) -> list[Tensor]:
        x = features[-1]
        disps: list[Tensor] = []
        for i in range(4, -1, -1):
            x = self.decoder[2 * (4 - i)](x)
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            if i > 0:
                x = torch.cat([x, features[i - 1]], dim=1)
            x = self.decoder[2 * (4 - i) + 1](x)
            if i < NUM_SCALES:
                disps.append(self.alpha * torch.sigmoid(self.decoder[10 + i](x)) + self.beta)
        return disps[::-1]


class DispResNet(nn.Module):
    """Disparity from one normalised RGB image (B, 3, H, W); see the module docstring for outputs."""

    def __init__(self, num_layers: int = 18) -> None:
        super().__init__()
        self.num_layers = num_layers
        self.encoder = ResnetEncoder(num_layers, num_input_images=1)
        self.decoder = DepthDecoder(self.encoder.num_ch_enc)

    def forward(self, x: Tensor) -> list[Tensor] | Tensor:
        if x.dim() != 4 or x.shape[1] != 3:
            raise ValueError(f"DispResNet expects (B, 3, H, W) images, got shape {tuple(x.shape)}")
        if x.shape[-2] % 32 or x.shape[-1] % 32:
            raise ValueError(f"DispResNet needs H and W divisible by 32, got {x.shape[-2]}×{x.shape[-1]}")
        disps = self.decoder(self.encoder(x))
        return disps if self.training else disps[0]


def disp_to_depth(disp: Tensor) -> Tensor:
    """Depth (same units as the net's scale) from disparity: ``1 / disp``."""
    return 1.0 / disp
