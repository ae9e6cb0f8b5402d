"""Dense candidate poses: stored imprint poses shifted and turned within the registration basin.

Stored imprints lie on the mapping grid (10 mm, 20 degrees apart on the paper's protocol),
while ICP converges from about 2 mm and 5 degrees. Around each source imprint, a candidate
moves the touch in the source's sensor plane by (dx, dy) and turns it about the gripper's
approach axis (the sensor's y axis: image rows run along the approach direction) by an angle,
about the touch's contact centroid so that the turn does not move the patch. The default grid,
2.5 mm x 5 degrees over +-5 mm x +-10 degrees, covers the space between grid imprints with every
point within the basin of some candidate.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float


@dataclass(frozen=True)
class CandidateGrid:
    """The offsets tried around every source imprint (static)."""

    shift_mm: float = 2.5
    """Step of the in-plane shifts, mm."""
    shift_steps: int = 2
    """Shifts run from -steps to +steps along x and y."""
    turn_deg: float = 5.0
    """Step of the turns about the approach axis, degrees."""
    turn_steps: int = 2
    """Turns run from -steps to +steps."""

    @property
    def size(self) -> int:
        """Candidates per source imprint."""
        return (2 * self.shift_steps + 1) ** 2 * (2 * self.turn_steps + 1)

    def offsets(self, centroid: Float[Array, "3"]) -> jaxlie.SE3:
        """(S,) ``T_source_sensor`` of the candidates, for a touch whose contact centroid is
        ``centroid`` (its sensor frame, mm). The zero offset comes first."""
        shifts = jnp.arange(-self.shift_steps, self.shift_steps + 1, dtype=jnp.float32) * self.shift_mm
        turns = jnp.deg2rad(jnp.arange(-self.turn_steps, self.turn_steps + 1, dtype=jnp.float32) * self.turn_deg)
        dx, dy, turn = (a.ravel() for a in jnp.meshgrid(shifts, shifts, turns, indexing="ij"))
        order = jnp.argsort(jnp.abs(dx) + jnp.abs(dy) + jnp.abs(turn), stable=True)
        dx, dy, turn = dx[order], dy[order], turn[order]

        def one(x, y, angle):
            about_centroid = (jaxlie.SE3.from_translation(centroid) @ jaxlie.SE3.from_rotation(
                jaxlie.SO3.from_y_radians(angle)) @ jaxlie.SE3.from_translation(-centroid))
            return jaxlie.SE3.from_translation(jnp.stack([x, y, 0.0])) @ about_centroid

        return jax.vmap(one)(dx, dy, turn)
