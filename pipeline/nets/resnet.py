"""ResNet-18 / ResNet-50 image encoders, parameter-compatible with torchvision.

The module tree (and therefore every state-dict key) matches ``torchvision.models.resnet18`` /
``resnet50`` exactly: ``conv1, bn1, layer1..layer4`` made of ``BasicBlock`` (``conv1 bn1 conv2 bn2``) or
``Bottleneck`` (``conv1 bn1 conv2 bn2 conv3 bn3``, stride on the 3×3 conv, i.e. "ResNet v1.5"), the
projection shortcut as ``downsample.0`` (1×1 conv) / ``downsample.1`` (BN), and the classifier ``fc``
(kept although an encoder never uses it, so that ImageNet and SC-SfMLearner checkpoints load strictly).

``num_input_images`` stacks that many RGB images on the channel axis (the pose net takes 2, i.e. a
6-channel ``conv1``), as Monodepth2 / SC-SfMLearner do. Nothing is downloaded: weights are initialised as
torchvision does (Kaiming-normal, fan-out, for convolutions; BN weight 1, bias 0; ``fc`` PyTorch default).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn


def _conv3x3(in_ch: int, out_ch: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_ch, out_ch, kernel_size=3, stride=stride, padding=1, bias=False)


def _conv1x1(in_ch: int, out_ch: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_ch, out_ch, kernel_size=1, stride=stride, bias=False)


class BasicBlock(nn.Module):
    """Two 3×3 convolutions with a residual connection (ResNet-18/34)."""

    expansion = 1

    def __init__(self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None) -> None:
        super().__init__()
        self.conv1 = _conv3x3(inplanes, planes, stride)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = _conv3x3(planes, planes)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample
        self.stride = stride

    def forward(self, x: Tensor) -> Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class Bottleneck(nn.Module):
    """1×1 → 3×3 (strided) → 1×1 ×4 convolutions with a residual connection (ResNet-50+)."""

    expansion = 4

    def __init__(self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None) -> None:
        super().__init__()
        self.conv1 = _conv1x1(inplanes, planes)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = _conv3x3(planes, planes, stride)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = _conv1x1(planes, planes * self.expansion)
        self.bn3 = nn.BatchNorm2d(planes * self.expansion)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample
        self.stride = stride

    def forward(self, x: Tensor) -> Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + identity)


@dataclass(frozen=True)
class ResNetSpec:
    """Block type and blocks per stage of a supported depth."""

    block: type[BasicBlock] | type[Bottleneck]
    layers: tuple[int, int, int, int]


RESNET_SPECS: dict[int, ResNetSpec] = {
    18: ResNetSpec(BasicBlock, (2, 2, 2, 2)),
    50: ResNetSpec(Bottleneck, (3, 4, 6, 3)),
}


class ResNet(nn.Module):
    """torchvision-layout ResNet. ``forward`` is the ImageNet classifier; encoders call the stages."""

    def __init__(self, num_layers: int = 18, num_input_images: int = 1, num_classes: int = 1000) -> None:
        super().__init__()
        if num_layers not in RESNET_SPECS:
            raise ValueError(f"ResNet depth must be one of {sorted(RESNET_SPECS)}, got {num_layers}")
        if num_input_images < 1:
            raise ValueError(f"num_input_images must be >= 1, got {num_input_images}")
        spec = RESNET_SPECS[num_layers]
        self.num_layers = num_layers
        self.num_input_images = num_input_images
        self.inplanes = 64
        self.conv1 = nn.Conv2d(3 * num_input_images, 64, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self.layer1 = self._make_layer(spec.block, 64, spec.layers[0], stride=1)
        self.layer2 = self._make_layer(spec.block, 128, spec.layers[1], stride=2)
        self.layer3 = self._make_layer(spec.block, 256, spec.layers[2], stride=2)
        self.layer4 = self._make_layer(spec.block, 512, spec.layers[3], stride=2)
        self.avgpool = nn.AdaptiveAvgPool2d((1, 1))
        self.fc = nn.Linear(512 * spec.block.expansion, num_classes)

        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.constant_(m.weight, 1.0)
                nn.init.constant_(m.bias, 0.0)

    def _make_layer(
        self, block: type[BasicBlock] | type[Bottleneck], planes: int, blocks: int, stride: int
    ) -> nn.Sequential:
        downsample = None
        if stride != 1 or self.inplanes != planes * block.expansion:
            downsample = nn.Sequential(
                _conv1x1(self.inplanes, planes * block.expansion, stride),
                nn.BatchNorm2d(planes * block.expansion),
            )
        layers = [block(self.inplanes, planes, stride, downsample)]
        self.inplanes = planes * block.expansion
        layers += [block(self.inplanes, planes) for _ in range(1, blocks)]
        return nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return self.fc(torch.flatten(self.avgpool(x), 1))


class ResnetEncoder(nn.Module):
    """Feature pyramid of a ResNet: the backbone lives at ``self.encoder`` (keys ``encoder.*``).

    ``forward(x)`` with x (B, 3·num_input_images, H, W), normalised (see :func:`normalize_image`), returns
    five maps at strides 2, 4, 8, 16, 32 with ``num_ch_enc`` channels:
    (64, 64, 128, 256, 512) for ResNet-18 and (64, 256, 512, 1024, 2048) for ResNet-50.
    """

    def __init__(self, num_layers: int = 18, num_input_images: int = 1) -> None:
        super().__init__()
        self.encoder = ResNet(num_layers, num_input_images)
        e = RESNET_SPECS[num_layers].block.expansion
        self.num_ch_enc: tuple[int, ...] = (64, 64 * e, 128 * e, 256 * e, 512 * e)

    def forward(self, x: Tensor) -> list[Tensor]:
        net = self.encoder
        f0 = net.relu(net.bn1(net.conv1(x)))
        f1 = net.layer1(net.maxpool(f0))
        f2 = net.layer2(f1)
        f3 = net.layer3(f2)
        f4 = net.layer4(f3)
        return [f0, f1, f2, f3, f4]
