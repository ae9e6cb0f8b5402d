"""Point-to-plane ICP against stored imprints, robust and trimmed, with a fixed iteration count.

Each iteration (1) matches the query points to the candidate imprints by projection
(:func:`find_correspondences`), (2) weights the matches (robust kernel x trimming), and (3)
takes one pose step (:func:`pose_step`: Gauss-Newton, or jaxopt Levenberg-Marquardt) on the
weighted point-to-surface residuals. The loop is a ``jax.lax.scan`` of fixed length whose
updates freeze once the step falls below the tolerance, so the result is differentiable (with
respect to the query points, hence to the query heightmap) and compiles once.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int

from tactojax.localize._correspondences import (candidate_poses, candidate_surfaces, find_correspondences, matvec,
                                                 nearest_correspondences, transform_points, valid_centroid)
from tactojax.localize._map import LocalizationMap
from tactojax.localize._pose import PoseEstimate
from tactojax.localize._solvers import SOLVERS, pose_step
from tactojax.shape import order_statistics

ROBUST_LOSSES = ("huber", "geman-mcclure", "none")
ASSOCIATIONS = ("projective", "nearest")


@dataclass(frozen=True)
class IcpSettings:
    """ICP parameters (static: hashable, one compilation per setting)."""

    iterations: int = 10
    """Fixed number of iterations (updates freeze after convergence)."""
    max_distance_mm: float = 3.0
    """Correspondences with a larger point-to-plane residual are rejected, mm."""
    robust_loss: str = "geman-mcclure"
    """Robust kernel on the residuals: one of ``ROBUST_LOSSES``."""
    robust_scale_mm: float = 0.5
    """Scale of the robust kernel, mm."""
    trim_fraction: float = 0.9
    """Only this fraction of the valid correspondences with the smallest residuals is used."""
    max_step_mm: float = 5.0
    """Largest translation of one step, mm (rotation is limited to max_step_mm / cloud radius)."""
    tolerance_mm: float = 0.01
    """Converged when a step moves the cloud by less than this, mm."""
    min_correspondences: int = 12
    """Fewer valid correspondences: no step, and the estimate is not converged."""
    solver: str = "gauss-newton"
    """Pose update: one of ``SOLVERS``."""
    association: str = "projective"
    """Correspondences: ``"projective"`` (into the stored heightmaps: exact surfaces, narrow
    basin) or ``"nearest"`` (nearest stored contact point in 3D: the classical ICP, wider basin)."""
    lm_iterations: int = 3
    """Levenberg-Marquardt iterations per ICP iteration (solver "levenberg-marquardt")."""

    def __post_init__(self):
        if self.solver not in SOLVERS:
            raise ValueError(f"unknown solver {self.solver!r}; choose one of {SOLVERS}")
        if self.association not in ASSOCIATIONS:
            raise ValueError(f"unknown association {self.association!r}; choose one of {ASSOCIATIONS}")
        if self.robust_loss not in ROBUST_LOSSES:
            raise ValueError(f"unknown robust loss {self.robust_loss!r}; choose one of {ROBUST_LOSSES}")
        if self.iterations < 1 or not 0 < self.trim_fraction <= 1:
            raise ValueError("need iterations >= 1 and 0 < trim_fraction <= 1")


def robust_weights(residual: Float[Array, "P"], valid: Bool[Array, "P"], settings: IcpSettings) -> Float[Array, "P"]:
    """IRLS weights of the residuals: robust kernel x trimming x validity (0 for invalid)."""
    scale = settings.robust_scale_mm
    if settings.robust_loss == "huber":
        weight = jnp.minimum(1.0, scale / jnp.maximum(jnp.abs(residual), 1e-12))
    elif settings.robust_loss == "geman-mcclure":
        weight = (scale**2 / (scale**2 + residual**2)) ** 2
    else:
        weight = jnp.ones_like(residual)
    if settings.trim_fraction < 1.0:
        magnitude = jnp.where(valid, jnp.abs(residual), jnp.inf)
        count = jnp.sum(valid)
        keep = jnp.maximum(jnp.ceil(settings.trim_fraction * count).astype(jnp.int32), 1)
        # The trimming threshold, read at every ICP iteration: selected, not sorted (a sort is
        # slow on a CPU; the same element either way, see order_statistics).
        threshold = order_statistics(magnitude, jnp.clip(keep - 1, 0, residual.shape[0] - 1)[None])[0]
        valid = valid & (jnp.abs(residual) <= threshold)
    return jnp.where(valid, weight, 0.0)


def _exp(delta: Float[Array, "6"]) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """``jaxlie.SE3.exp(delta)`` as a 3 x 3 rotation matrix and a translation (mm).

    ``delta`` is (translation, rotation vector), as in jaxlie. Rodrigues' formulas,
    ``R = I + a K + b K^2`` and ``t = (I + b K + c K^2) translation`` with ``K`` the
    cross-product matrix of the rotation vector, compile to a few fused kernels where
    quaternion algebra takes dozens of scalar ones. Near zero, a, b and c come from their
    Taylor series (no 0 / 0).
    """
    translation, omega = delta[:3], delta[3:]
    angle_squared = jnp.sum(omega**2)
    small = angle_squared < 1e-2
    safe = jnp.where(small, 1.0, angle_squared)  # keeps the branch not taken (and its gradient) finite
    angle = jnp.sqrt(safe)

    def series(c0, c2, c4):  # c0 - c2 angle^2 + c4 angle^4
        return c0 - angle_squared * (c2 - angle_squared * c4)

    a = jnp.where(small, series(1.0, 1 / 6, 1 / 120), jnp.sin(angle) / angle)
    b = jnp.where(small, series(1 / 2, 1 / 24, 1 / 720), (1.0 - jnp.cos(angle)) / safe)
    c = jnp.where(small, series(1 / 6, 1 / 120, 1 / 5040), (angle - jnp.sin(angle)) / (safe * angle))
    x, y, z = omega
    zero = jnp.zeros_like(x)
    skew = jnp.array([[zero, -z, y], [z, zero, -x], [-y, x, zero]])
    identity = jnp.eye(3, dtype=delta.dtype)
    skew_squared = omega[:, None] * omega[None, :] - angle_squared * identity
    return identity + a * skew + b * skew_squared, matvec(identity + b * skew + c * skew_squared, translation)


def fit_quality(
    view: LocalizationMap,
    candidates: Int[Array, "N"] | Int[Array, "P N"],
    candidate_valid: Bool[Array, "N"] | Bool[Array, "P N"],
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    T_object_sensor: jaxlie.SE3,
    settings: IcpSettings,
    *,
    blocks: int = 1,
    active_blocks: Int[Array, ""] | None = None,
) -> tuple[Float[Array, ""], Float[Array, ""], Int[Array, ""]]:
    """Robust residual RMS (mm), overlap fraction and match count of a pose against candidates.

    Always measured with the projective association (the exact stored surfaces), whichever
    association the ICP used, so that scores compare across settings. ``blocks`` and
    ``active_blocks``: as :func:`find_correspondences`.
    """
    matches = find_correspondences(view, candidates, candidate_valid, transform_points(T_object_sensor, points),
                                   points_valid, settings.max_distance_mm, blocks=blocks, active_blocks=active_blocks)
    weight = robust_weights(matches.residual, matches.valid, settings)
    score = jnp.sqrt(jnp.sum(weight * matches.residual**2) / jnp.maximum(jnp.sum(weight), 1e-12))
    count = jnp.sum(matches.valid)
    overlap = count / jnp.maximum(jnp.sum(points_valid), 1)
    return score, overlap.astype(score.dtype), count


def icp(
    view: LocalizationMap,
    candidates: Int[Array, "N"] | Int[Array, "P N"],
    candidate_valid: Bool[Array, "N"] | Bool[Array, "P N"],
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    T_start: jaxlie.SE3,
    settings: IcpSettings = IcpSettings(),
    *,
    blocks: int = 1,
    active_blocks: Int[Array, ""] | None = None,
) -> PoseEstimate:
    """Register query points to the union of N stored imprints, from a start pose.

    Args:
        view: the map.
        candidates: (N,) indices of the imprints to register against, or (P, N): each point its
            own (projective association only; e.g. the points of several touches, each against
            the imprints around where it lands).
        candidate_valid: which of them are real, shaped as ``candidates``.
        points: (P, 3) query contact points, query sensor frame, mm.
        points_valid: (P,) which points are real.
        T_start: initial sensor pose in the object frame.
        settings: ICP parameters (static).
        blocks, active_blocks: the points come in ``blocks`` equal blocks, of which only the
            first ``active_blocks`` can hold valid points (e.g. the touches a belief holds, each
            a block): the others are never looked up (:func:`find_correspondences`; per-point
            candidates and the projective association only).

    Returns:
        :class:`PoseEstimate` (``imprint_index`` -1: the caller knows where it started).
    """
    per_point = candidates.ndim == 2
    if settings.association == "nearest" and (per_point or active_blocks is not None):
        raise ValueError("per-point candidates and blocks of points need the projective association "
                         "(the nearest association registers every point against one shared set of imprints)")
    T_sensor_candidate = candidate_poses(view, candidates)
    # Shared candidates: their surfaces copied once (one gather a lookup instead of two).
    # Per-point ones are looked up in the map itself (a copy would be P x N heightmaps).
    surfaces = None if per_point else candidate_surfaces(view, candidates)
    count = jnp.maximum(jnp.sum(points_valid), 1)
    centroid_sensor = valid_centroid(points, points_valid)
    spread = jnp.sqrt(jnp.sum(jnp.where(points_valid, jnp.sum((points - centroid_sensor) ** 2, -1), 0.0)) / count)
    radius = jnp.maximum(spread, 1.0)  # lever arm converting rotation steps into mm

    def residuals_at(moved, center, matches, sqrt_weight):
        def residual_fn(delta):  # point-to-plane against the fixed matches, step at `center`
            stepped = transform_points(jaxlie.SE3.exp(delta), moved - center) + center
            return sqrt_weight * jnp.sum(matches.normal * (stepped - matches.target), axis=-1)
        return residual_fn

    def iteration(carry, _):
        rotation, translation, done, iterations = carry  # the pose, as matrices (see _exp)
        moved = matvec(rotation, points) + translation
        if settings.association == "nearest":
            matches = nearest_correspondences(view, candidates, candidate_valid, moved, points_valid,
                                              settings.max_distance_mm)
        else:
            matches = find_correspondences(view, candidates, candidate_valid, moved, points_valid,
                                           settings.max_distance_mm, T_sensor_candidate=T_sensor_candidate,
                                           surfaces=surfaces, blocks=blocks, active_blocks=active_blocks)
        weight = robust_weights(matches.residual, matches.valid, settings)
        enough = jnp.sum(weight > 0) >= settings.min_correspondences
        center = matvec(rotation, centroid_sensor) + translation
        sqrt_weight = jnp.sqrt(weight)
        residual_fn = residuals_at(moved, center, matches, sqrt_weight)
        # d/d(delta) of n . (exp(delta) (x - c) + c - p) at 0: [n, (x - c) x n].
        jacobian = sqrt_weight[:, None] * jnp.concatenate(
            [matches.normal, jnp.cross(moved - center, matches.normal)], axis=-1)
        delta, ok = pose_step(residual_fn, settings.solver, jacobian=jacobian,
                              lm_iterations=settings.lm_iterations)
        delta = jnp.where(ok & enough, delta, 0.0)
        # Limit the step (a bad linearisation far from the surface must not throw the pose away).
        move = jnp.linalg.norm(delta[:3]) + radius * jnp.linalg.norm(delta[3:])
        delta = delta * jnp.minimum(1.0, settings.max_step_mm / jnp.maximum(move, 1e-12))
        move = jnp.minimum(move, settings.max_step_mm)
        # The step is taken about `center`: x -> R_step (x - c) + c + t_step, after the pose.
        step_rotation, step_translation = _exp(delta)
        rotation = jnp.where(done, rotation, step_rotation @ rotation)
        translation = jnp.where(done, translation,
                                matvec(step_rotation, translation - center) + center + step_translation)
        iterations = iterations + jnp.where(done, 0, 1)
        done = done | (move < settings.tolerance_mm) | ~enough
        return (rotation, translation, done, iterations), None

    init = (T_start.rotation().as_matrix(), T_start.translation(), jnp.bool_(False), jnp.int32(0))
    (rotation, translation, done, iterations), _ = jax.lax.scan(iteration, init, None, length=settings.iterations)
    # Back to a quaternion, on the start's side (q and -q are the same rotation).
    quaternion = jaxlie.SO3.from_matrix(rotation).wxyz
    quaternion = jnp.where(quaternion @ T_start.rotation().wxyz < 0, -quaternion, quaternion)
    T = jaxlie.SE3(jnp.concatenate([quaternion, translation]))
    finite = jnp.all(jnp.isfinite(T.wxyz_xyz))
    T = jax.tree.map(lambda a, b: jnp.where(finite, a, b), T, T_start)
    T = jaxlie.SE3(T.wxyz_xyz.at[:4].set(T.wxyz_xyz[:4] / jnp.linalg.norm(T.wxyz_xyz[:4])))
    score, overlap, matched = fit_quality(view, candidates, candidate_valid, points, points_valid, T, settings,
                                          blocks=blocks, active_blocks=active_blocks)
    converged = done & finite & (matched >= settings.min_correspondences)
    return PoseEstimate(T_object_sensor=T, score=score, overlap=overlap, converged=converged,
                        iterations=iterations, imprint_index=jnp.int32(-1))
