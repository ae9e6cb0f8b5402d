"""Imprint features for retrieval (paper section VI): plain convolutional, ResNet and EfficientNet encoders. Pure JAX."""

from tactojax.features._contrastive import ContrastiveConfig as ContrastiveConfig
from tactojax.features._contrastive import ContrastiveState as ContrastiveState
from tactojax.features._contrastive import PoseNeighbours as PoseNeighbours
from tactojax.features._contrastive import contrastive_loss as contrastive_loss
from tactojax.features._contrastive import estimate_background as estimate_background
from tactojax.features._contrastive import make_train_step as make_train_step
from tactojax.features._contrastive import split_held_out as split_held_out
from tactojax.features._contrastive import train_encoder as train_encoder
from tactojax.features._distill import distillation_loss as distillation_loss
from tactojax.features._convert import StateDictMismatchError as StateDictMismatchError
from tactojax.features._convert import drop_classifier as drop_classifier
from tactojax.features._convert import efficientnet_lite_variables as efficientnet_lite_variables
from tactojax.features._convert import torch_to_flax_variables as torch_to_flax_variables
from tactojax.features._convert import torchvision_resnet_variables as torchvision_resnet_variables
from tactojax.features._efficientnet import LITE0_STAGES as LITE0_STAGES
from tactojax.features._efficientnet import BlockStage as BlockStage
from tactojax.features._efficientnet import EfficientNetLite as EfficientNetLite
from tactojax.features._efficientnet import EfficientNetLite0 as EfficientNetLite0
from tactojax.features._efficientnet import EfficientNetLiteTiny as EfficientNetLiteTiny
from tactojax.features._efficientnet import MBConvBlock as MBConvBlock
from tactojax.features._encoder import ARCHITECTURES as ARCHITECTURES
from tactojax.features._encoder import Encoder as Encoder
from tactojax.features._encoder import apply_encoder as apply_encoder
from tactojax.features._encoder import build_encoder as build_encoder
from tactojax.features._encoder import encode_image as encode_image
from tactojax.features._encoder import encode_images as encode_images
from tactojax.features._encoder import init_encoder as init_encoder
from tactojax.features._encoder import pixel_encoder as pixel_encoder
from tactojax.features._encoder import with_background as with_background
from tactojax.features._plain import PLAIN_PRESETS as PLAIN_PRESETS
from tactojax.features._plain import PlainConvNet as PlainConvNet
from tactojax.features._plain import PlainTactile as PlainTactile
from tactojax.features._plain import PlainTiny as PlainTiny
from tactojax.features._plain import space_to_depth as space_to_depth
from tactojax.features._pretrained import EFFICIENTNET_LITE_MEAN as EFFICIENTNET_LITE_MEAN
from tactojax.features._pretrained import EFFICIENTNET_LITE_STD as EFFICIENTNET_LITE_STD
from tactojax.features._pretrained import IMAGENET_IMAGE_SIZE as IMAGENET_IMAGE_SIZE
from tactojax.features._pretrained import IMAGENET_MEAN as IMAGENET_MEAN
from tactojax.features._pretrained import IMAGENET_STD as IMAGENET_STD
from tactojax.features._pretrained import efficientnet_lite0_weights_path as efficientnet_lite0_weights_path
from tactojax.features._pretrained import imagenet_efficientnet_lite0 as imagenet_efficientnet_lite0
from tactojax.features._pretrained import load_torchvision_resnet as load_torchvision_resnet
from tactojax.features._resnet import RESNET_PRESETS as RESNET_PRESETS
from tactojax.features._resnet import BasicBlock as BasicBlock
from tactojax.features._resnet import Bottleneck as Bottleneck
from tactojax.features._resnet import ResNet as ResNet
from tactojax.features._resnet import ResNet18 as ResNet18
from tactojax.features._resnet import ResNet50 as ResNet50
from tactojax.features._resnet import ResNetTactile as ResNetTactile
from tactojax.features._resnet import ResNetTiny as ResNetTiny
from tactojax.features._touches import TouchData as TouchData
from tactojax.features._touches import per_object_retrieval as per_object_retrieval
from tactojax.features._touches import pose_distances as pose_distances
from tactojax.features._touches import positive_pair_mask as positive_pair_mask
from tactojax.features._touches import symmetric_pose_distances as symmetric_pose_distances
from tactojax.features._touches import retrieval_accuracy as retrieval_accuracy

__all__ = [
    "ContrastiveConfig",
    "ContrastiveState",
    "PoseNeighbours",
    "contrastive_loss",
    "distillation_loss",
    "estimate_background",
    "make_train_step",
    "split_held_out",
    "train_encoder",
    "ARCHITECTURES",
    "Encoder",
    "apply_encoder",
    "build_encoder",
    "encode_image",
    "encode_images",
    "init_encoder",
    "pixel_encoder",
    "with_background",
    "TouchData",
    "per_object_retrieval",
    "pose_distances",
    "positive_pair_mask",
    "symmetric_pose_distances",
    "retrieval_accuracy",
    "StateDictMismatchError",
    "drop_classifier",
    "efficientnet_lite_variables",
    "torch_to_flax_variables",
    "torchvision_resnet_variables",
    "LITE0_STAGES",
    "BlockStage",
    "EfficientNetLite",
    "EfficientNetLite0",
    "EfficientNetLiteTiny",
    "MBConvBlock",
    "PLAIN_PRESETS",
    "PlainConvNet",
    "PlainTactile",
    "PlainTiny",
    "space_to_depth",
    "EFFICIENTNET_LITE_MEAN",
    "EFFICIENTNET_LITE_STD",
    "IMAGENET_IMAGE_SIZE",
    "IMAGENET_MEAN",
    "IMAGENET_STD",
    "efficientnet_lite0_weights_path",
    "imagenet_efficientnet_lite0",
    "load_torchvision_resnet",
    "RESNET_PRESETS",
    "BasicBlock",
    "Bottleneck",
    "ResNet",
    "ResNet18",
    "ResNet50",
    "ResNetTactile",
    "ResNetTiny",
]
