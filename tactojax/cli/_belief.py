"""Pose beliefs as the commands print and write them: the modes, poses as numbers."""

from __future__ import annotations

import numpy as np


def wxyz_xyz(T) -> list[float]:
    """A pose as 7 JSON numbers (wxyz, then xyz in mm)."""
    return np.asarray(T.wxyz_xyz, np.float64).round(6).tolist()


def position_and_angles(T) -> tuple[str, str]:
    """A pose as printable text: position (mm) and roll, pitch, yaw (degrees)."""
    translation = np.asarray(T.translation())
    angles = np.rad2deg(np.asarray(T.rotation().as_rpy_radians(), np.float64))
    return ", ".join(f"{x:.2f}" for x in translation), ", ".join(f"{a:.1f}" for a in angles)


MIN_MODE_PROBABILITY = 1e-3
"""Modes less probable than this are not listed."""


def belief_summary(belief, modes: int = 3) -> dict:
    """What the commands report of one object's :class:`~tactojax.localize.PoseBelief` (JSON-ready).

    ``T_world_object`` is the object's most likely pose in the frame the touches' sensor poses
    were given in; ``T_object_sensor`` the first touch's sensor in the object frame; ``modes``
    the ``modes`` most probable modes (symmetric copies in one; at least
    :data:`MIN_MODE_PROBABILITY`), each with both poses and its probability.
    """
    import jax

    mode_of, mass = jax.device_get(belief.modes())
    del mode_of
    order = [int(i) for i in np.argsort(-mass)[:modes] if mass[i] >= MIN_MODE_PROBABILITY]
    take = lambda T, i: jax.tree.map(lambda x: x[i], T)  # noqa: E731
    listed = []
    for index in order:
        T_object_sensor = take(belief.T_object_reference, index)
        listed.append({"probability": float(mass[index]),
                       "T_world_object_wxyz_xyz": wxyz_xyz(belief.T_world_reference @ T_object_sensor.inverse()),
                       "T_object_sensor_wxyz_xyz": wxyz_xyz(T_object_sensor)})
    return {"T_world_object_wxyz_xyz": wxyz_xyz(belief.T_world_object),
            "T_object_sensor_wxyz_xyz": wxyz_xyz(belief.best),
            "probability_within_2mm": float(belief.probability_within(2.0)),
            "touches": int(belief.touches), "log_evidence": float(belief.log_evidence), "modes": listed}
