"""Shape models on disk: training pairs from datasets, model checkpoints, resumable train states.

Checkpoint format (``.msgpack``, no pickle, written atomically): a msgpack map
``{"format": "tactojax-shape-model", "version": 2, "preset", "sensor", "mm_per_px",
"color_gain", "background": (H, W, 3) float32, "params": nested map of float32 arrays,
"metadata": JSON string}``. Version 1 had no ``color_gain``; its models used 8., arrays encoded by ``flax.serialization``. A training state adds ``"opt_state"``,
``"step"`` and ``"history"`` under ``"format": "tactojax-shape-train-state"``.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
from flax import serialization

from tactojax.shape import ShapeData, ShapeModel, TrainConfig, TrainState, make_optimizer
from tactojax.shape._models import build_network
from tactojax.storage._atomic import atomic_write_bytes
from tactojax.storage._checkpoint import BUNDLED_DIR, CorruptCheckpointError, read_checkpoint_payload
from tactojax.storage._dataset import open_dataset

MODEL_FORMAT = "tactojax-shape-model"
STATE_FORMAT = "tactojax-shape-train-state"
VERSION = 2
READABLE_VERSIONS = (1, 2)
VERSION_1_COLOR_GAIN = 8.0
"""The colour gain every version-1 checkpoint was trained with."""


def load_shape_data(paths, *, objects: list[str] | None = None) -> ShapeData:
    """Read (image, heightmap, mask) pairs from one or more datasets with ground truth.

    Args:
        paths: dataset directories (one sensor and resolution across all).
        objects: keep only these object ids (default all).
    """
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not paths:
        raise ValueError("no dataset given")
    fields = ["image", "heightmap", "mask", "object_id"]
    parts, sensors = [], set()
    for path in paths:
        dataset = open_dataset(path)
        missing = [f for f in fields if f not in dataset.fields]
        if missing:
            raise ValueError(f"dataset {path} has no {', '.join(missing)}: not a simulated dataset")
        sensor = dataset.metadata.get("sensor", {})
        sensors.add((sensor.get("name", ""), sensor.get("mm_per_px"),
                     tuple(dataset.schema["image"]["shape"])))
        parts.append(dataset.read(fields))
    if len(sensors) > 1:
        raise ValueError(f"datasets mix sensors or resolutions: {sorted(map(str, sensors))}")
    (name, mm_per_px, _), = sensors
    if mm_per_px is None:
        raise ValueError(f"dataset {paths[0]} does not record mm_per_px in its sensor metadata")
    merged = {f: np.concatenate([p[f] for p in parts]) for f in fields}
    data = ShapeData(images=merged["image"], heightmaps=merged["heightmap"].astype(np.float32),
                     masks=merged["mask"].astype(bool), object_ids=merged["object_id"].astype(str),
                     mm_per_px=float(mm_per_px), sensor=name)
    if objects is not None:
        unknown = sorted(set(objects) - set(data.objects))
        if unknown:
            raise ValueError(f"objects {unknown} are not in the data (have {data.objects})")
        data = data.take(np.isin(data.object_ids, objects))
    if len(data) == 0:
        raise ValueError("the datasets hold no imprints")
    return data


def _model_fields(model: ShapeModel) -> dict:
    return {
        "preset": model.preset, "sensor": model.sensor, "mm_per_px": float(model.mm_per_px),
        "color_gain": float(model.color_gain),
        "background": np.asarray(model.background, np.float32),
        "params": serialization.to_state_dict(jax.device_get(model.params)),
    }


def save_shape_model(path, model: ShapeModel, *, metadata: dict | None = None) -> Path:
    """Write a model checkpoint atomically (see the module docstring for the format)."""
    payload = {"format": MODEL_FORMAT, "version": VERSION, **_model_fields(model),
               "metadata": json.dumps(metadata or {})}
    path = Path(path)
    atomic_write_bytes(path, serialization.msgpack_serialize(payload))
    return path


def _read(path, expected_format: str) -> dict:
    return read_checkpoint_payload(path, expected_format, READABLE_VERSIONS)


def _model_from_payload(payload: dict, path) -> ShapeModel:
    try:
        preset = str(payload["preset"])
        version_1 = payload["version"] == 1
        color_gain = VERSION_1_COLOR_GAIN if version_1 else float(payload["color_gain"])
        background = np.asarray(payload["background"], np.float32)
        params = payload["params"]
        if preset != "lookup":  # check the weights against the architecture
            template = jax.eval_shape(  # shapes only: nothing is computed or compiled
                build_network(preset, float(payload["mm_per_px"])).init,
                jax.random.key(0), np.zeros((*background.shape[:2], 5), np.float32))["params"]
            params = serialization.from_state_dict(template, params)
            shapes = jax.tree.map(np.shape, params) == jax.tree.map(np.shape, template)
            if not shapes:
                raise ValueError("weight shapes do not match the architecture")
        else:
            params = {k: np.asarray(v, np.float32) for k, v in params.items()}
    except (KeyError, ValueError, TypeError) as error:
        raise CorruptCheckpointError(f"{path}: malformed shape model ({error})") from None
    # On the device once: a model of NumPy arrays would be copied to an accelerator at every call.
    params, background = jax.device_put((params, background))
    return ShapeModel(params=params, background=background, preset=preset,
                      mm_per_px=float(payload["mm_per_px"]), sensor=str(payload["sensor"]),
                      color_gain=color_gain)


def load_shape_model(path) -> ShapeModel:
    """Read a model checkpoint written by :func:`save_shape_model`."""
    return _model_from_payload(_read(path, MODEL_FORMAT), path)


def shape_model_metadata(path) -> dict:
    """The metadata dict saved with a model checkpoint (training data, config, metrics)."""
    return json.loads(_read(path, MODEL_FORMAT).get("metadata", "{}"))


def save_train_state(path, state: TrainState, config: TrainConfig) -> Path:
    """Write a resumable training state atomically."""
    payload = {"format": STATE_FORMAT, "version": VERSION, **_model_fields(state.model),
               "opt_state": serialization.to_state_dict(jax.device_get(state.opt_state)),
               "step": int(state.step), "history": np.asarray(state.history),
               "config": json.dumps(config.__dict__)}
    path = Path(path)
    atomic_write_bytes(path, serialization.msgpack_serialize(payload))
    return path


def load_train_state(path, config: TrainConfig) -> TrainState:
    """Read a training state; ``config`` must match the one it was saved with."""
    payload = _read(path, STATE_FORMAT)
    saved = json.loads(payload["config"])
    if saved != json.loads(json.dumps(config.__dict__)):
        changed = sorted(k for k in saved if saved[k] != config.__dict__.get(k))
        raise ValueError(f"cannot resume {path}: training settings changed ({', '.join(changed)})")
    model = _model_from_payload(payload, path)
    template = make_optimizer(config, model.preset).init(model.params)
    opt_state = serialization.from_state_dict(template, payload["opt_state"])
    return TrainState(model=model, opt_state=opt_state, step=int(payload["step"]),
                      history=np.asarray(payload["history"], np.float32))


def bundled_shape_models() -> list[str]:
    """Names of the shape models shipped with the package (``bundled:NAME``)."""
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.msgpack") if not p.stem.startswith("features-"))


def resolve_shape_model(name_or_path) -> ShapeModel:
    """Load ``bundled:NAME`` (a shipped checkpoint) or a checkpoint path."""
    text = str(name_or_path)
    if text.startswith("bundled:"):
        name = text.removeprefix("bundled:")
        path = BUNDLED_DIR / f"{name}.msgpack"
        if not path.is_file():
            raise FileNotFoundError(f"no bundled shape model {name!r}; have {bundled_shape_models()}")
        return load_shape_model(path)
    return load_shape_model(text)
