"""Pose beliefs as the commands print and write them: the modes, poses as numbers."""

from __future__ import annotations

import numpy as np


def wxyz_xyz(T) -> list[float]:
    """A pose as 7 JSON numbers (wxyz, then xyz in mm)."""
    return _rounded(T.wxyz_xyz)


def _rounded(wxyz_xyz) -> list[float]:
    return np.asarray(wxyz_xyz, np.float64).round(6).tolist()


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

    from tactojax.localize import belief_digest

    digest = jax.device_get(belief_digest(belief, modes))
    listed = [{"probability": float(p), "T_world_object_wxyz_xyz": _rounded(T_world),
               "T_object_sensor_wxyz_xyz": _rounded(T_object)}
              for p, T_world, T_object in zip(digest.mode_probability, digest.mode_T_world_object,
                                               digest.mode_T_object_sensor) if p >= MIN_MODE_PROBABILITY]
    return {"T_world_object_wxyz_xyz": _rounded(digest.T_world_object),
            "T_object_sensor_wxyz_xyz": _rounded(digest.T_object_sensor),
            "probability_within_2mm": float(digest.probability_within),
            "touches": int(digest.touches), "log_evidence": float(digest.log_evidence), "modes": listed}
