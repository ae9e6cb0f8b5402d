"""PoseEstimate: what a localization method returns for one tactile imprint."""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct


@struct.dataclass
class PoseEstimate:
    """The estimated pose of the sensor that took a query imprint, in the object (map) frame.

    Every field broadcasts over leading batch axes (a vmapped call returns a batched estimate).
    The pose is never NaN: a method that cannot estimate it (no retrieved imprint, too few
    correspondences, a singular system) returns its start pose with ``converged`` False.
    """

    T_object_sensor: jaxlie.SE3
    """Estimated sensor pose in the object frame, mm."""
    score: Float[Array, ""]
    """Robust RMS of the point-to-plane residuals at the estimate, mm (lower is better)."""
    overlap: Float[Array, ""]
    """Fraction of the query points that found a correspondence in the map at the estimate."""
    converged: Bool[Array, ""]
    """True when the method finished normally (ICP: the step fell below the tolerance)."""
    iterations: Int[Array, ""]
    """ICP iterations run (0 for retrieval-only methods)."""
    imprint_index: Int[Array, ""]
    """The map imprint the estimate started from (the closest one for CTI; -1: none)."""

    @staticmethod
    def failed(T_object_sensor: jaxlie.SE3, imprint_index=-1) -> PoseEstimate:
        """An estimate that did not converge, at ``T_object_sensor``."""
        return PoseEstimate(
            T_object_sensor=T_object_sensor,
            score=jnp.float32(0.0),
            overlap=jnp.float32(0.0),
            converged=jnp.bool_(False),
            iterations=jnp.int32(0),
            imprint_index=jnp.int32(imprint_index),
        )
