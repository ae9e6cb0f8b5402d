"""Kinematic noise: what an imperfect arm and gripper do to the placement of imprints."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float, PRNGKeyArray


@dataclass(frozen=True)
class KinematicNoise:
    """Independent Gaussian errors of every grasp's recorded gripper pose and opening.

    The pose error is applied in the gripper frame, ``T_world_gripper @ exp(delta)``, with
    ``delta`` drawn per grasp: the arm's absolute positioning error, not its repeatability.
    """

    translation_mm: float = 0.0
    """Standard deviation of the position error along each gripper axis, mm."""
    rotation_deg: float = 0.0
    """Standard deviation of the orientation error about each gripper axis, degrees."""
    opening_mm: float = 0.0
    """Standard deviation of the measured jaw opening, mm."""


NOISE_LEVELS = {
    "none": KinematicNoise(),
    "low": KinematicNoise(translation_mm=0.1, rotation_deg=0.1, opening_mm=0.05),
    "realistic": KinematicNoise(translation_mm=0.5, rotation_deg=0.5, opening_mm=0.1),
    "high": KinematicNoise(translation_mm=1.0, rotation_deg=1.0, opening_mm=0.2),
}
"""Named noise levels. ``low``: a well-calibrated arm (repeatability-class errors); ``realistic``:
a calibrated industrial arm's absolute accuracy (about 0.5 mm, 0.5 deg) and a WSG-50-class
opening reading (0.1 mm); ``high``: an uncalibrated setup."""


def perturb_kinematics(
    key: PRNGKeyArray,
    T_world_gripper: jaxlie.SE3,
    openings: Float[Array, "K"],
    noise: KinematicNoise,
) -> tuple[jaxlie.SE3, Float[Array, "K"]]:
    """Gripper poses and openings as a noisy robot would report them.

    Args:
        key: PRNG key.
        T_world_gripper: (K,) true gripper poses, mm.
        openings: (K,) true jaw openings, mm.
        noise: the error model.

    Returns:
        (noisy T_world_gripper (K,), noisy openings (K,) clipped at 0).
    """
    count = openings.shape[0]
    translation_key, rotation_key, opening_key = jax.random.split(key, 3)
    delta = jnp.concatenate([
        noise.translation_mm * jax.random.normal(translation_key, (count, 3)),
        jnp.deg2rad(noise.rotation_deg) * jax.random.normal(rotation_key, (count, 3)),
    ], axis=-1)
    noisy_pose = T_world_gripper @ jaxlie.SE3.exp(delta)
    noisy_opening = jnp.maximum(openings + noise.opening_mm * jax.random.normal(opening_key, (count,)), 0.0)
    return noisy_pose, noisy_opening
