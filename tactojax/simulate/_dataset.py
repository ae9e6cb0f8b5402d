"""Imprint datasets: simulate a protocol straight to disk (``tactojax.io.load_imprints`` reads them back).

Records follow ``tactojax.simulate.simulate_protocol``: ``image`` (H, W, 3) uint8 RGB,
``heightmap`` (H, W) float32 mm, ``mask`` (H, W) bool, ``T_world_sensor``, ``T_world_gripper``,
``T_world_object`` (7,) float32 as jaxlie's wxyz + xyz (mm), ``opening_mm``, ``depth_mm``,
``object_id`` (str) and the protocol's grasp parameters. The dataset metadata names the sensor
(preset, resolution, mm per pixel), the protocol and its settings, and the grasp settings; a
dataset holds one sensor and one protocol, and several objects can be appended to it.

New-grasps datasets (``GraspsProtocol``) also hold ``episode``, ``grasp`` and ``finger`` (int64):
episode ids are unique within a dataset, each run continuing after the largest id already
there (so an episode is also unique per ``(object_id, episode)``). Slip datasets
(``SlipProtocol``) hold ``sequence`` and ``frame`` (int64) the same way: sequence ids continue
after the largest one already there, frames count 0 .. frames - 1 within a sequence.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax

from tactojax.objects import TactileObject
from tactojax.sensor import SensorSpec
from tactojax.simulate._grasp import GraspConfig
from tactojax.simulate._protocols import CalibrationProtocol, GraspsProtocol, MappingProtocol
from tactojax.simulate._run import simulate_protocol
from tactojax.simulate._slip import SlipProtocol
from tactojax.storage._dataset import DatasetWriter, open_dataset


def sensor_metadata(spec: SensorSpec) -> dict:
    """The sensor entry of a dataset's metadata (what ``read_grasps`` and map building read)."""
    return {"name": spec.name, "height_px": spec.height_px, "width_px": spec.width_px,
            "mm_per_px": spec.mm_per_px, "gel_thickness_mm": spec.gel_thickness_mm}


def dataset_metadata(spec: SensorSpec, protocol, config: GraspConfig) -> dict:
    """The metadata that must agree between everything written to one dataset."""
    return {
        "sensor": sensor_metadata(spec),
        "protocol": {"name": protocol.name, **dataclasses.asdict(protocol)},
        "grasp": dataclasses.asdict(config),
    }


def symmetry_key(object_id: str) -> str:
    """The dataset metadata key of an object's symmetry group (:meth:`~tactojax.objects.ObjectSymmetry.to_json`)."""
    return f"symmetry:{object_id}"


def simulate_to_dataset(
    path: str | Path,
    key: jax.Array,
    spec: SensorSpec,
    obj: TactileObject,
    protocol: MappingProtocol | CalibrationProtocol | GraspsProtocol | SlipProtocol,
    *,
    config: GraspConfig = GraspConfig(),
    batch_size: int = 16,
    chunk_size: int = 64,
    progress: bool = True,
) -> int:
    """Simulate ``protocol`` on ``obj`` and append its imprints to the dataset at ``path``.

    Crash-safe: an interrupted run leaves a readable dataset of the chunks already written.
    New grasps: episodes are numbered on from the largest ``episode`` already in the dataset;
    slip sequences likewise (``sequence``).

    Returns:
        The number of imprints written (grasps that missed are skipped).
    """
    # The object's symmetry travels with its touches (a map of a mesh records it: maps and
    # evaluations then need neither the catalog nor the mesh).
    metadata = {**dataset_metadata(spec, protocol, config), symmetry_key(obj.name): obj.symmetry.to_json()}
    written = 0
    with DatasetWriter(path, metadata=metadata, chunk_size=chunk_size) as writer:
        numbered = {GraspsProtocol: "episode", SlipProtocol: "sequence"}.get(type(protocol))
        first = _next_id(path, numbered) if numbered else 0
        for records in simulate_protocol(key, spec, obj, protocol, config=config,
                                         batch_size=batch_size, progress=progress):
            if first:
                records = {**records, numbered: records[numbered] + first}
            for i in range(len(records["image"])):
                writer.append({name: values[i] for name, values in records.items()})
                written += 1
    return written


def _next_id(path: str | Path, field: str) -> int:
    """One past the largest ``field`` id (episode, sequence) of the dataset at ``path`` (0 if none yet)."""
    if not (Path(path) / "manifest.json").exists():
        return 0
    dataset = open_dataset(path)
    if field not in dataset.fields or len(dataset) == 0:
        return 0
    return int(dataset.read([field])[field].max()) + 1
