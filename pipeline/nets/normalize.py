"""Image normalisation shared by the depth and pose nets (SC-SfMLearner's)."""

from __future__ import annotations

from torch import Tensor

IMAGE_MEAN = 0.45
IMAGE_STD = 0.225


def normalize_image(images: Tensor) -> Tensor:
    """RGB in [0, 255] (uint8 or float, any layout) → ``(x / 255 − 0.45) / 0.225`` as a float tensor.

    Floating inputs keep their dtype; integer inputs become float32. 0 ↦ −2.0, 255 ↦ 2.444….
    """
    x = images if images.is_floating_point() else images.float()
    return (x / 255.0 - IMAGE_MEAN) / IMAGE_STD
