"""Interactive 3-D views of maps, touches, pose estimates and beliefs with rerun (``rerun-sdk``).

``rerun`` is imported lazily (optional extra ``viz``): importing tactojax never imports it.
Everything is in millimetres. The entity tree of a recording:

* ``maps/<object>``: the object frame (``Transform3D``: the map's place in the viewer, maps side by
  side ``spacing_mm`` apart along x; ``TransformAxes3D``), static. Under it, in the object frame:
  ``points`` (``Points3D``: the stitched contact cloud, coloured by height z in the object frame,
  viridis) and ``imprint_frames`` (``Arrows3D``: each stored imprint's sensor frame, x red,
  y green, z blue; ``axis_mm`` long).
* On the ``touch`` sequence timeline, under ``maps/<object>`` of each touch's object:
  ``touch/points`` (the touch's contact cloud at its true pose) and ``touch/true_frame``;
  ``estimate/frame`` (the estimated sensor frame), ``estimate/true_frame``, ``estimate/error``
  (a line from the true to the estimated sensor origin), ``estimate/points`` (the touch's cloud
  at the estimated pose, with a test dataset); ``belief`` (``Arrows3D``: every hypothesis's
  sensor z axis, length and opacity growing with its probability, and ``Points3D`` at their
  origins, radius growing with it). ``metrics/translation_error_mm`` and
  ``metrics/probability`` are scalars on the same timeline.
* ``live/...`` for ``tactojax localize-live --view``: ``live/image``, ``live/probability_within_2mm``
  (the belief's P(within 2 mm)), ``live/object_probability/<object>`` (P(object) of every map),
  and ``maps/<object>/live`` (the estimated sensor frame, on frames with an estimate) on the
  ``frame`` timeline.

Estimates (:func:`read_estimates`) are a JSON list of objects, a single object (``tactojax
localize --json``), or an object with an ``estimates`` list (``tactojax localize-live --json``;
its frames without an estimate are left out).
Each entry: ``object_id``; ``T_object_sensor_wxyz_xyz`` (7 numbers, wxyz then xyz in mm) and
optionally ``T_object_sensor_true_wxyz_xyz``, ``probability`` (or ``probability_within_2mm``,
a belief's P(within 2 mm), or ``confidence``), ``touch``
(the touch's index in the test dataset, default the entry's position) and ``belief``: a list
of ``{"T_object_sensor_wxyz_xyz": [...], "probability": p}`` hypotheses (a pose belief). An
entry may hold only a ``belief``; its most probable hypothesis is then the estimate.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import jaxlie
import numpy as np
from jaxtyping import Float

AXIS_COLORS = np.array([[230, 40, 40], [40, 200, 40], [50, 90, 240]], np.uint8)
"""Colours of a frame's x, y and z axes."""


def require_rerun():
    """The ``rerun`` module, or an ImportError saying how to install it."""
    try:
        import rerun
    except ImportError:
        raise ImportError("the 3-D view needs rerun: pip install 'tactojax[viz]'") from None
    return rerun


def new_recording(application_id: str = "tactojax"):
    """A new ``rerun.RecordingStream`` (attach a sink: ``.save(path)``, ``.serve_grpc()``, ``.spawn()``)."""
    return require_rerun().RecordingStream(application_id)


def entity_name(object_id: str) -> str:
    """An object id as one entity path component (letters, digits, ``_``, ``-``, ``.``)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", object_id) or "_"


def height_colors(points: Float[np.ndarray, "M 3"]) -> np.ndarray:
    """(M, 3) uint8 viridis colours of the points' z, from their lowest to their highest."""
    from matplotlib import colormaps

    z = points[:, 2] if len(points) else np.zeros(0)
    span = float(z.max() - z.min()) if len(z) else 0.0
    scaled = (z - z.min()) / span if span > 0 else np.zeros_like(z)
    return (colormaps["viridis"](scaled)[:, :3] * 255).astype(np.uint8)


def frame_arrows(wxyz_xyz: Float[np.ndarray, "K 7"], axis_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(3K, 3) origins, (3K, 3) vectors and (3K, 3) colours drawing K frames' x, y, z axes."""
    poses = jaxlie.SE3(np.asarray(wxyz_xyz, np.float64).reshape(-1, 7))
    rotations = np.asarray(poses.rotation().as_matrix())  # (K, 3, 3), columns are the axes
    origins = np.repeat(np.asarray(poses.translation()), 3, axis=0)
    vectors = (np.transpose(rotations, (0, 2, 1)) * axis_mm).reshape(-1, 3)
    return origins, vectors, np.tile(AXIS_COLORS, (len(rotations), 1))


def log_maps(recording, tactile_maps: Sequence, *, spacing_mm: float | None = None, voxel_mm: float = 0.5,
             axis_mm: float = 3.0) -> dict[str, np.ndarray]:
    """Log each map's cloud (coloured by height) and imprint frames in its object frame (static).

    Args:
        recording: a ``rerun.RecordingStream``.
        tactile_maps: the maps (``TactileMap``).
        spacing_mm: distance between neighbouring object frames along x in the viewer (default:
            the largest map's extent plus 30 mm).
        voxel_mm: voxel size of the logged cloud, mm (0: every point).
        axis_mm: length of the imprint frames' axes, mm.

    Returns:
        ``{object_id: (3,) offset of its object frame in the viewer, mm}``.
    """
    rr = require_rerun()
    from tactojax.mapping import stitched_point_cloud

    clouds = [stitched_point_cloud(tactile_map, voxel_mm=voxel_mm)[0] for tactile_map in tactile_maps]
    if spacing_mm is None:
        extents = [float(np.ptp(cloud[:, 0])) if len(cloud) else 0.0 for cloud in clouds]
        spacing_mm = max(extents, default=0.0) + 30.0
    offsets = {}
    for index, (tactile_map, cloud) in enumerate(zip(tactile_maps, clouds)):
        root = f"maps/{entity_name(tactile_map.object_id)}"
        offsets[tactile_map.object_id] = np.array([index * spacing_mm, 0.0, 0.0])
        recording.log(root, rr.Transform3D(translation=offsets[tactile_map.object_id]),
                      rr.TransformAxes3D(axis_length=10.0), static=True)
        recording.log(f"{root}/points", rr.Points3D(cloud, colors=height_colors(cloud), radii=0.15), static=True)
        valid = np.asarray(tactile_map.imprint_valid)
        origins, vectors, colors = frame_arrows(np.asarray(tactile_map.T_object_sensor.wxyz_xyz)[valid], axis_mm)
        recording.log(f"{root}/imprint_frames", rr.Arrows3D(origins=origins, vectors=vectors, colors=colors),
                      static=True)
    return offsets


def log_touch(recording, touch: int, object_id: str, points_sensor: Float[np.ndarray, "P 3"],
              T_object_sensor: Float[np.ndarray, "7"], *, axis_mm: float = 5.0) -> None:
    """Log one test touch's contact cloud and sensor frame at its true pose, at ``touch`` on its timeline."""
    rr = require_rerun()
    root = f"maps/{entity_name(object_id)}/touch"
    recording.set_time("touch", sequence=touch)
    points = np.asarray(jaxlie.SE3(np.asarray(T_object_sensor, np.float64)) @ np.asarray(points_sensor, np.float64))
    recording.log(f"{root}/points", rr.Points3D(points, colors=[255, 140, 0], radii=0.2))
    recording.log(f"{root}/true_frame", _frame(T_object_sensor, axis_mm))


def log_estimate(recording, entry: Mapping, *, points_sensor: np.ndarray | None = None,
                 axis_mm: float = 5.0) -> None:
    """Log one estimate (and its true pose and belief, when given) at ``entry["touch"]``.

    ``entry`` is one item of :func:`read_estimates`; ``points_sensor`` the touch's contact cloud
    in the sensor frame (drawn at the estimated pose).
    """
    rr = require_rerun()
    root = f"maps/{entity_name(entry['object_id'])}"
    recording.set_time("touch", sequence=int(entry["touch"]))
    estimated = np.asarray(entry["T_object_sensor_wxyz_xyz"], np.float64)
    recording.log(f"{root}/estimate/frame", _frame(estimated, axis_mm))
    # What this entry lacks is cleared, so that the viewer does not show the previous entry's.
    for missing in ([] if points_sensor is not None else ["estimate/points"]) + \
            ([] if entry.get("T_object_sensor_true_wxyz_xyz") is not None else ["estimate/true_frame", "estimate/error"]) + \
            ([] if entry.get("belief") else ["belief"]):
        recording.log(f"{root}/{missing}", rr.Clear(recursive=False))
    if points_sensor is not None:
        points = np.asarray(jaxlie.SE3(estimated) @ np.asarray(points_sensor, np.float64))
        recording.log(f"{root}/estimate/points", rr.Points3D(points, colors=[0, 190, 255], radii=0.2))
    true = entry.get("T_object_sensor_true_wxyz_xyz")
    if true is not None:
        true = np.asarray(true, np.float64)
        recording.log(f"{root}/estimate/true_frame", _frame(true, axis_mm))
        recording.log(f"{root}/estimate/error", rr.LineStrips3D([[true[4:], estimated[4:]]], colors=[255, 60, 60]))
        recording.log("metrics/translation_error_mm", rr.Scalars(float(np.linalg.norm(true[4:] - estimated[4:]))))
    if entry.get("probability") is not None:
        recording.log("metrics/probability", rr.Scalars(float(entry["probability"])))
    if entry.get("belief"):
        log_belief(recording, root, entry["belief"], axis_mm=axis_mm)


def log_belief(recording, root: str, belief: Sequence[Mapping], *, axis_mm: float = 5.0) -> None:
    """Log a pose belief's hypotheses as sensor frames weighted by their probability (``root/belief``)."""
    rr = require_rerun()
    poses = np.array([h["T_object_sensor_wxyz_xyz"] for h in belief], np.float64)
    probabilities = np.array([h["probability"] for h in belief], np.float64)
    weight = probabilities / probabilities.max() if probabilities.max() > 0 else np.zeros_like(probabilities)
    se3 = jaxlie.SE3(poses)
    origins = np.asarray(se3.translation())
    z_axes = np.asarray(se3.rotation().as_matrix())[:, :, 2]
    alpha = (40 + 215 * weight).astype(np.uint8)
    colors = np.column_stack([np.full((len(poses), 3), [170, 60, 230], np.uint8), alpha])
    recording.log(f"{root}/belief", rr.Arrows3D(origins=origins, vectors=z_axes * axis_mm * (0.3 + 1.7 * weight[:, None]),
                                                colors=colors),
                  rr.Points3D(origins, colors=colors, radii=0.2 + 0.8 * weight))


def log_live_estimate(recording, frame: int, estimate: Mapping, *, image: np.ndarray | None = None,
                      axis_mm: float = 5.0) -> None:
    """Log one live estimate (``LiveEstimate.as_dict()``) and its camera image at ``frame``."""
    rr = require_rerun()
    recording.set_time("frame", sequence=int(frame))
    if image is not None:
        recording.log("live/image", rr.Image(image))
    recording.log("live/probability_within_2mm", rr.Scalars(float(estimate.get("probability_within_2mm", 0.0))))
    for object_id, probability in estimate.get("object_probabilities", {}).items():
        recording.log(f"live/object_probability/{entity_name(object_id)}", rr.Scalars(float(probability)))
    if estimate.get("object_id") is not None and estimate.get("T_object_sensor_wxyz_xyz") is not None:
        recording.log(f"maps/{entity_name(estimate['object_id'])}/live",
                      _frame(estimate["T_object_sensor_wxyz_xyz"], axis_mm))


def read_test_touches(path: str | os.PathLike, *, model: str | None = None, max_points: int = 2000) -> dict:
    """A test dataset's touches: object ids, true ``T_object_sensor`` and contact clouds (sensor frame).

    The clouds come from the dataset's true heightmaps (a simulated dataset), else from
    ``model``'s predictions (a recording). Each is subsampled to at most ``max_points``.

    Returns:
        ``{"object_id": (N,) str, "T_object_sensor": (N, 7), "points_sensor": list of (P_i, 3) mm}``.
    """
    from tactojax.geometry import heightmap_to_points
    from tactojax.io import open_dataset

    dataset = open_dataset(path)
    records = dataset.read(["T_world_sensor", "T_world_object", "object_id"])
    mm_per_px = float(dataset.metadata["sensor"]["mm_per_px"])
    if "heightmap" in dataset.schema and "mask" in dataset.schema:
        truth = dataset.read(["heightmap", "mask"])
        heightmaps, masks = truth["heightmap"], truth["mask"]
    else:
        from tactojax.io import resolve_shape_model
        from tactojax.shape import predict_batch

        if model is None:
            raise ValueError(f"{path} has no true heightmaps; give a shape model to predict them")
        images = dataset.read(["image"])["image"].astype(np.float32) / 255.0
        heightmaps, masks = (np.asarray(a) for a in predict_batch(resolve_shape_model(model), images))
    T_object_sensor = (jaxlie.SE3(records["T_world_object"].astype(np.float64)).inverse()
                       @ jaxlie.SE3(records["T_world_sensor"].astype(np.float64)))
    clouds = [_subsample(np.asarray(heightmap_to_points(h, mm_per_px))[m], max_points)
              for h, m in zip(heightmaps, masks.astype(bool))]
    return {"object_id": records["object_id"], "T_object_sensor": np.asarray(T_object_sensor.wxyz_xyz),
            "points_sensor": clouds}


def log_view(recording, tactile_maps: Sequence, *, test: str | os.PathLike | None = None,
             estimates: Sequence[Mapping] = (), model: str | None = None, voxel_mm: float = 0.5) -> dict:
    """Log maps, a test dataset's touches and estimates (with beliefs) into one recording.

    Estimates without a true pose take it from the test touch they name (``touch``), and are
    drawn with that touch's cloud at the estimated pose.

    Returns:
        Counts of what was logged: maps, map points, imprint frames, touches, estimates, beliefs.
    """
    from tactojax.mapping import stitched_point_cloud

    log_maps(recording, tactile_maps, voxel_mm=voxel_mm)
    counts = {"maps": len(tactile_maps),
              "map_points": sum(len(stitched_point_cloud(m, voxel_mm=voxel_mm)[0]) for m in tactile_maps),
              "imprint_frames": sum(int(np.asarray(m.imprint_valid).sum()) for m in tactile_maps),
              "touches": 0, "estimates": 0, "beliefs": 0}
    touches = read_test_touches(test, model=model) if test is not None else None
    if touches is not None:
        for index, (object_id, pose, points) in enumerate(zip(touches["object_id"], touches["T_object_sensor"],
                                                              touches["points_sensor"])):
            log_touch(recording, index, str(object_id), points, pose)
        counts["touches"] = len(touches["object_id"])
    for entry in estimates:
        points = None
        if touches is not None and 0 <= entry["touch"] < len(touches["object_id"]):
            points = touches["points_sensor"][entry["touch"]]
            if entry.get("T_object_sensor_true_wxyz_xyz") is None and \
                    str(touches["object_id"][entry["touch"]]) == entry["object_id"]:
                entry = dict(entry, T_object_sensor_true_wxyz_xyz=touches["T_object_sensor"][entry["touch"]].tolist())
        log_estimate(recording, entry, points_sensor=points)
        counts["estimates"] += 1
        counts["beliefs"] += bool(entry.get("belief"))
    return counts


def open_recording(*, save: str | os.PathLike | None = None, serve: bool = False, spawn: bool = False,
                   web_port: int = 9090, grpc_port: int = 9876, application_id: str = "tactojax"):
    """A recording with one sink: a ``.rrd`` file, rerun's web viewer on localhost, or a spawned viewer.

    Returns:
        (``rerun.RecordingStream``, the web viewer's URL with ``serve``, else None).
    """
    if sum([save is not None, serve, spawn]) != 1:
        raise ValueError("choose exactly one of save, serve and spawn")
    rr = require_rerun()
    recording = rr.RecordingStream(application_id)
    if save is not None:
        recording.save(save)
        return recording, None
    if spawn:
        recording.spawn()
        return recording, None
    from urllib.parse import quote

    grpc_url = recording.serve_grpc(grpc_port=grpc_port)
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=grpc_url)
    return recording, f"http://localhost:{web_port}/?url={quote(grpc_url, safe='')}"


def read_estimates(path: str | os.PathLike) -> list[dict]:
    """Read and check an estimates JSON (format in the module docstring); errors name the entry."""
    path = Path(path)
    try:
        payload = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"no estimates file {path}") from None
    except json.JSONDecodeError as error:
        raise ValueError(f"{path.name}: not valid JSON ({error})") from None
    if isinstance(payload, dict) and isinstance(payload.get("estimates"), list):  # localize-live --json
        payload = [entry for entry in payload["estimates"] if not isinstance(entry, dict)
                   or (entry.get("object_id") is not None and entry.get("T_object_sensor_wxyz_xyz") is not None)]
    elif isinstance(payload, dict):
        payload = [payload]
    if not isinstance(payload, list):
        raise ValueError(f"{path.name}: expected a list of estimates")
    entries = []
    for index, entry in enumerate(payload):
        label = f"{path.name} entry {index}"
        if not isinstance(entry, dict) or not isinstance(entry.get("object_id"), str):
            raise ValueError(f"{label}: expected an object with an 'object_id'")
        belief = entry.get("belief")
        if belief is not None:
            if not isinstance(belief, list) or not belief:
                raise ValueError(f"{label}: 'belief' must be a non-empty list of hypotheses")
            for k, hypothesis in enumerate(belief):
                if not isinstance(hypothesis, dict):
                    raise ValueError(f"{label} belief {k}: expected an object")
                _pose(hypothesis.get("T_object_sensor_wxyz_xyz"), f"{label} belief {k}")
                _probability(hypothesis.get("probability"), f"{label} belief {k}", required=True)
        checked = dict(entry, touch=int(entry.get("touch", index)), belief=belief)
        if "T_object_sensor_wxyz_xyz" not in entry:
            if not belief:
                raise ValueError(f"{label}: needs 'T_object_sensor_wxyz_xyz' or a 'belief'")
            best = max(belief, key=lambda h: h["probability"])
            checked.update(T_object_sensor_wxyz_xyz=best["T_object_sensor_wxyz_xyz"],
                           probability=entry.get("probability", best["probability"]))
        _pose(checked["T_object_sensor_wxyz_xyz"], label)
        if entry.get("T_object_sensor_true_wxyz_xyz") is not None:
            _pose(entry["T_object_sensor_true_wxyz_xyz"], f"{label} (true pose)")
        probability = checked.get("probability", entry.get("probability_within_2mm", entry.get("confidence")))
        checked["probability"] = _probability(probability, label, required=False)
        entries.append(checked)
    return entries


def _pose(value, label: str) -> np.ndarray:
    pose = np.asarray(value if value is not None else [], dtype=np.float64) if _numbers(value) else None
    if pose is None or pose.shape != (7,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{label}: a pose must be 7 finite numbers [qw, qx, qy, qz, x_mm, y_mm, z_mm], got {value!r}")
    if abs(np.linalg.norm(pose[:4]) - 1.0) > 1e-3:
        raise ValueError(f"{label}: the quaternion {pose[:4].tolist()} is not a unit quaternion")
    return pose


def _numbers(value) -> bool:
    return isinstance(value, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)


def _probability(value, label: str, *, required: bool) -> float | None:
    if value is None and not required:
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0.0 <= value <= 1.0:
        raise ValueError(f"{label}: 'probability' must be a number in [0, 1], got {value!r}")
    return float(value)


def _frame(wxyz_xyz, axis_mm: float):
    """One sensor frame as ``Arrows3D`` (x red, y green, z blue)."""
    rr = require_rerun()
    origins, vectors, colors = frame_arrows(np.asarray(wxyz_xyz, np.float64)[None], axis_mm)
    return rr.Arrows3D(origins=origins, vectors=vectors, colors=colors)


def _subsample(points: np.ndarray, max_points: int) -> np.ndarray:
    if len(points) <= max_points:
        return points
    return points[np.linspace(0, len(points) - 1, max_points).astype(int)]
