"""SC-SfMLearner depth (DispResNet) and pose (PoseResNet) networks in plain torch.

Importing this package imports torch; CLIs import it inside their commands.
"""

from pipeline.nets.checkpoint import (
    load_depth_net,
    load_imagenet_encoder,
    load_pose_net,
    read_state_dict,
    save_checkpoint,
)
from pipeline.nets.depth_net import DispResNet, disp_to_depth
from pipeline.nets.inference import DepthPoseRunner, resolve_device
from pipeline.nets.normalize import normalize_image
from pipeline.nets.pose_net import PoseResNet
from pipeline.nets.resnet import ResNet, ResnetEncoder

__all__ = [
    "DepthPoseRunner",
    "DispResNet",
    "PoseResNet",
    "ResNet",
    "ResnetEncoder",
    "disp_to_depth",
    "load_depth_net",
    "load_imagenet_encoder",
    "load_pose_net",
    "normalize_image",
    "read_state_dict",
    "resolve_device",
    "save_checkpoint",
]
