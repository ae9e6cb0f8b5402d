"""Rotational symmetries of catalog objects, for symmetry-aware localization errors.

A touch on a tape roll cannot tell where around the roll it is; a localizer that returns a
pose rotated about the roll's axis has found the contact exactly. The symmetry-aware error of
issue 5 takes the minimum of the plain error over the object's symmetry group, sampled as a
batch of object-frame transforms ``T_object_object'``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax.numpy as jnp
import jaxlie
import numpy as np

_AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


@dataclass(frozen=True)
class ObjectSymmetry:
    """A symmetry group: rotations about one axis (continuous or n-fold) times half-turn flips.

    Attributes:
        axis: ``"x"``, ``"y"`` or ``"z"``: the object-frame axis through ``centre`` that the
            object is (approximately) symmetric about; None for no rotational symmetry.
        fold: 0 for a continuous symmetry (sampled every ``step_deg``), else n for n-fold.
        flips: axes of extra half-turn symmetries (e.g. a roll that looks the same upside down).
        centre: (3,) a point on the axis, mm.
        exact: False where the symmetry is only approximate (a scanned marker's cap, a
            screwdriver's fluted handle).
    """

    axis: str | None = None
    fold: int = 0
    flips: tuple[str, ...] = ()
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    exact: bool = True

    def transforms(self, *, step_deg: float = 2.0) -> jaxlie.SE3:
        """The group as a batch of object-frame transforms, identity first.

        Args:
            step_deg: sampling step of a continuous symmetry, degrees.

        Returns:
            (S,) ``jaxlie.SE3``: every rotation maps the object onto itself (about ``centre``).
        """
        rotations = [np.eye(3)]
        if self.axis is not None:
            count = self.fold if self.fold > 0 else int(round(360.0 / step_deg))
            angles = np.arange(1, count) * (2 * np.pi / count)
            rotations += [_axis_angle(_AXES[self.axis], angle) for angle in angles]
        for flip in self.flips:
            half_turn = _axis_angle(_AXES[flip], np.pi)
            rotations += [half_turn @ rotation for rotation in rotations]
        matrices = np.stack(rotations)
        centre = np.asarray(self.centre, np.float64)
        translations = centre - matrices @ centre  # rotate about the centre, not the origin
        return jaxlie.SE3.from_rotation_and_translation(
            jaxlie.SO3.from_matrix(jnp.asarray(matrices, jnp.float32)), jnp.asarray(translations, jnp.float32))

    def copies(self) -> jaxlie.SE3:
        """The group's distinct copies once all turns about a continuous axis count as one (its
        quotient by those turns), identity first: the flips alone for a continuous symmetry, the
        whole group otherwise. With :meth:`continuous_axis` they give a symmetry-aware distance
        exactly (the closest turn is found in closed form), from 1-4 copies instead of the
        hundreds that :meth:`transforms` samples.

        Returns:
            (S,) ``jaxlie.SE3`` object-frame transforms (about ``centre``).
        """
        if self.axis is None or self.fold > 0:
            return self.transforms()
        return dataclasses.replace(self, axis=None).transforms()

    def continuous_axis(self) -> tuple[np.ndarray, np.ndarray]:
        """(3,) the unit axis of a continuous rotational symmetry and (3,) a point on it (object
        frame, mm); zeros for an object without one (none, or n-fold)."""
        if self.axis is None or self.fold > 0:
            return np.zeros(3, np.float32), np.zeros(3, np.float32)
        return _AXES[self.axis].astype(np.float32), np.asarray(self.centre, np.float32)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


NO_SYMMETRY = ObjectSymmetry()
