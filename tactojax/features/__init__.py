"""Imprint features for retrieval (paper section VI): ResNet / EfficientNet encoders. Pure JAX."""

from tactojax.features._resnet import RESNET_PRESETS as RESNET_PRESETS
from tactojax.features._resnet import BasicBlock as BasicBlock
from tactojax.features._resnet import Bottleneck as Bottleneck
from tactojax.features._resnet import ResNet as ResNet
from tactojax.features._resnet import ResNet18 as ResNet18
from tactojax.features._resnet import ResNet50 as ResNet50
from tactojax.features._resnet import ResNetTactile as ResNetTactile
from tactojax.features._resnet import ResNetTiny as ResNetTiny

__all__ = [
    "RESNET_PRESETS",
    "BasicBlock",
    "Bottleneck",
    "ResNet",
    "ResNet18",
    "ResNet50",
    "ResNetTactile",
    "ResNetTiny",
]
