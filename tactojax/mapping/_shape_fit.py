"""Least-squares fits of the paper's Table II parametric shapes to a tactile map's point cloud.

Paper section V, Table II: the main dimensions of five known objects (cylinder, semicone,
double-cylinder, cuboid, semipyramid) are estimated from their tactile maps. Here each shape is
an analytic solid from ``tactojax.objects`` (the same differentiable SDFs the catalog uses) in
its own *shape frame*: axis along x, centred on its length, the wider / bigger end at -x (as in
the catalog objects). :func:`fit_shape`

1. initialises the shape frame from the valid points, without assuming the object is aligned
   with the map frame: the centroid and the longest principal direction (the shape axis); the
   cross-section centre from a circle fit (round shapes) or, for square cross-sections, the
   minimum-area bounding rectangle over a grid of roll angles (which also gives the roll); the
   end positions from axial quantiles; the sizes from median distances to the axis (and, for
   the double-cylinder, a coarse search over the step position);
2. refines pose (translation across the axis, rotation; about the axis only where it matters)
   and sizes together by robust least squares on the signed distance of every point to the
   surface, with a Cauchy loss of scale ``5 * robust_scale_mm`` and then ``robust_scale_mm``,
   so that a few percent of outliers hardly move the estimate;
3. pulls an end face that no point touched in to where the points on the surface stop, places a
   cuboid side that no point touched where the points on its neighbours stop (optionally from a
   second, full-resolution cloud: ``extent_points``), and reports the Table II parameters under
   the catalog objects' names (``TABLE2_PARAMETERS``) plus nuisance ones (length, top radius /
   side).

Sizes pass through a softplus, so radii, sides and lengths stay positive; an empty or degenerate
cloud comes back with finite numbers and ``converged=False``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct
from tactojax.mapping._least_squares import solve_least_squares
from tactojax.objects._object import TactileObject
from tactojax.objects._primitives import Box, Cylinder, Frustum, Solid, SquareFrustum, Union, placed

SHAPE_KINDS: tuple[str, ...] = ("cylinder", "semicone", "double-cylinder", "cuboid", "semipyramid")

TABLE2_PARAMETERS: dict[str, tuple[str, ...]] = {
    "cylinder": ("radius_mm",),
    "semicone": ("base_radius_mm", "slope_rad"),
    "double-cylinder": ("big_radius_mm", "small_radius_mm", "joint_mm"),
    "cuboid": ("side_1_mm", "side_2_mm"),
    "semipyramid": ("base_side_mm", "slope_rad"),
}
"""The parameters Table II reports per shape kind (lengths in mm, angles in rad)."""

_ALONG_X = jaxlie.SO3.from_y_radians(jnp.pi / 2)  # maps the solids' z axis onto x (as the catalog)
_FLIP = np.diag([-1.0, -1.0, 1.0]).astype(np.float32)  # turn by pi about z: x -> -x, y -> -y
_QUARTER_ROLL = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float32)  # by pi/2 about x: y -> z
_LEVI_CIVITA = np.zeros((3, 3, 3), np.float32)
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[_i, _j, _k], _LEVI_CIVITA[_j, _i, _k] = 1.0, -1.0

_MIN_SIZE_MM = 1e-3
_ROLL_STEPS = 24  # roll grid over [0, pi/2) for square cross-sections: 3.75 degree steps
_JOINT_STEPS = 17  # step-position grid for the double-cylinder, 10 % .. 90 % of the length
_COARSE_SCALE_FACTOR = 5.0  # Cauchy scale of the first stage, in units of robust_scale_mm
_INLIER_FACTOR = 3.0  # inliers: |distance| < 3 robust_scale_mm
_STEP_QUANTILE = 0.005  # the double cylinder's step: this quantile of the big side's axial positions
# (the membrane wrapping the step's edge smears a few hundred of ~10^5 points past it)
_END_QUANTILE = 0.0005  # untouched ends: this quantile of the on-surface points' axial positions
_TOUCHED_FRACTION = 0.1  # a cuboid side with fewer points than this fraction of the most-touched
# side's is untouched: what lies on it is its neighbours' spill-over (contact edges, stray skirt)
_SIDE_QUANTILE = 0.002  # untouched cuboid sides: this quantile of their neighbours' points' positions
# (a few hundred of ~10^5 neighbour points may be false contact at the foot of a cliff past the edge)


@struct.dataclass
class ShapeFit:
    """A parametric shape fitted to a point cloud (a pytree; vmappable over clouds)."""

    kind: str = struct.field(pytree_node=False)
    """Shape kind, one of ``SHAPE_KINDS``."""
    parameters: dict[str, Float[Array, ""]]
    """Named estimates: the Table II ones (``TABLE2_PARAMETERS[kind]``) plus nuisance ones
    (``length_mm``; ``top_radius_mm`` for the semicone, ``top_side_mm`` for the semipyramid).
    Lengths in mm, angles in rad."""
    T_object_shape: jaxlie.SE3
    """Fitted shape frame in the map (object) frame: x along the shape axis, pointing from the
    wider / bigger end to the other for semicone, semipyramid and double-cylinder (either way
    for cylinder and cuboid); origin on the axis, midway between the end faces; for the cuboid,
    y along the shorter side (``side_2_mm``), as in the catalog."""
    rms_residual_mm: Float[Array, ""]
    """Root-mean-square distance of the inlier points to the fitted surface, mm."""
    inlier_fraction: Float[Array, ""]
    """Fraction of the valid points within ``3 * robust_scale_mm`` of the surface, in [0, 1]."""
    converged: Bool[Array, ""]
    """The refinement met its tolerances, on enough valid points, with finite results."""
    iterations: Int[Array, ""]
    """Least-squares iterations used (both stages together)."""


# --------------------------------------------------------------------------- small helpers

def _softplus_inverse(x: Float[Array, "*batch"]) -> Float[Array, "*batch"]:
    x = jnp.maximum(x, _MIN_SIZE_MM)
    return x + jnp.log(-jnp.expm1(-x))


def _positive(u: Float[Array, "*batch"]) -> Float[Array, "*batch"]:
    return jax.nn.softplus(u) + _MIN_SIZE_MM


def _masked_quantiles(values: Float[Array, "N"], valid: Bool[Array, "N"],
                      quantiles: tuple[float, ...]) -> Float[Array, "Q"]:
    """Quantiles of the valid values (nearest rank, one sort); zeros when none is valid."""
    count = jnp.sum(valid)
    ordered = jnp.sort(jnp.where(valid, values, jnp.inf))
    rank = jnp.round(jnp.asarray(quantiles, values.dtype) * (count - 1)).astype(jnp.int32)
    return jnp.where(count > 0, ordered[jnp.clip(rank, 0, values.shape[0] - 1)], 0.0)


def _masked_median(values: Float[Array, "N"], valid: Bool[Array, "N"]) -> Float[Array, ""]:
    return _masked_quantiles(values, valid, (0.5,))[0]


def _principal_frame(points: Float[Array, "N 3"], valid: Bool[Array, "N"]):
    """Centroid (3,) and right-handed principal directions (3, 3), columns by decreasing variance."""
    w = valid.astype(points.dtype)
    count = jnp.maximum(jnp.sum(w), 1.0)
    centroid = jnp.sum(w[:, None] * points, axis=0) / count
    centred = (points - centroid) * w[:, None]
    _, vectors = jnp.linalg.eigh(centred.T @ centred / count)  # ascending eigenvalues
    vectors = vectors[:, ::-1]
    return centroid, vectors.at[:, 2].set(jnp.cross(vectors[:, 0], vectors[:, 1]))


def _circle_centre(yz: Float[Array, "N 2"], valid: Bool[Array, "N"]) -> Float[Array, "2"]:
    """Algebraic (Kasa) circle fit: the centre of the circle through the valid 2-D points."""
    w = valid.astype(yz.dtype)
    design = jnp.concatenate([yz, jnp.ones_like(yz[:, :1])], axis=1)
    normal = design.T @ (w[:, None] * design)
    normal = normal + (1e-6 * jnp.trace(normal) + 1e-9) * jnp.eye(3)
    coefficients = jnp.linalg.solve(normal, design.T @ (w * -jnp.sum(yz * yz, axis=1)))
    centre = -0.5 * coefficients[:2]
    return jnp.where(jnp.all(jnp.isfinite(centre)), centre, 0.0)


def _rotation_2d(angle: Float[Array, ""]) -> Float[Array, "2 2"]:
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.array([[c, -s], [s, c]])


def _check_kind(kind: str) -> str:
    canonical = kind.replace("_", "-") if isinstance(kind, str) else kind
    if canonical not in SHAPE_KINDS:
        raise ValueError(f"unknown shape kind {kind!r}; choose one of {', '.join(SHAPE_KINDS)}")
    return canonical


# --------------------------------------------------------------------------- shape models
#
# Parameters theta (a dict pytree, optimised together), relative to an initial frame:
#   "pose":  translation along the initial y and z, mm, then the rotation vector (rad) about
#            x, y, z (5,), or about y, z only (4,) for round shapes;
#   "axial": (2,) centre of the length along the shape axis, mm, and softplus^-1(length / mm);
#   "sizes": softplus^-1 of the kind's sizes, mm (see the solid functions below).

@dataclasses.dataclass(frozen=True)
class _Model:
    rolls: bool  # does a rotation about the axis change the shape?
    solid: Callable[..., Solid]  # (raw sizes, centre mm, length mm) -> solid in the shape frame


def _on_axis(solid: Solid, centre: Float[Array, ""]) -> Solid:
    """A solid whose axis is z, turned onto x and centred at ``centre`` along x (as the catalog)."""
    return placed(solid, translation=jnp.stack([centre, 0.0, 0.0]), rotation=_ALONG_X)


def _cylinder_solid(sizes, centre, length):  # sizes: radius
    return _on_axis(Cylinder(_positive(sizes[0]), 0.5 * length), centre)


def _semicone_solid(sizes, centre, length):  # sizes: radius at the -x end, at the +x end
    return _on_axis(Frustum(_positive(sizes[0]), _positive(sizes[1]), 0.5 * length), centre)


def _joint_position(sizes, centre, length):
    return centre - 0.5 * length + length * jax.nn.sigmoid(sizes[2])


def _double_cylinder_solid(sizes, centre, length):
    # sizes: radius from the -x end to the step, from the step to the +x end, logit of the step
    # position as a fraction of the length.
    start, end = centre - 0.5 * length, centre + 0.5 * length
    joint = _joint_position(sizes, centre, length)
    return Union((_on_axis(Cylinder(_positive(sizes[0]), 0.5 * (joint - start)), 0.5 * (start + joint)),
                  _on_axis(Cylinder(_positive(sizes[1]), 0.5 * (end - joint)), 0.5 * (joint + end))))


def _cuboid_solid(sizes, centre, length):  # sizes: half side along y, along z
    half = jnp.stack([0.5 * length, _positive(sizes[0]), _positive(sizes[1])])
    return placed(Box(half), translation=jnp.stack([centre, 0.0, 0.0]))


def _semipyramid_solid(sizes, centre, length):  # sizes: side at the -x end, at the +x end
    return _on_axis(SquareFrustum(_positive(sizes[0]), _positive(sizes[1]), 0.5 * length), centre)


_MODELS: dict[str, _Model] = {
    "cylinder": _Model(rolls=False, solid=_cylinder_solid),
    "semicone": _Model(rolls=False, solid=_semicone_solid),
    "double-cylinder": _Model(rolls=False, solid=_double_cylinder_solid),
    "cuboid": _Model(rolls=True, solid=_cuboid_solid),
    "semipyramid": _Model(rolls=True, solid=_semipyramid_solid),
}


def _update(pose: Float[Array, "P"], rolls: bool):
    """Rotation matrix (3, 3) and translation (3,) of a pose update, in the initial frame.

    The rotation is that of the unit quaternion along ``(1, omega / 2)``, in closed form (a
    handful of array ops: cheap to differentiate and to compile).
    """
    zero = jnp.zeros((1,), pose.dtype)
    v = 0.5 * (pose[2:5] if rolls else jnp.concatenate([zero, pose[2:4]]))
    vv = jnp.dot(v, v)
    cross = -jnp.tensordot(_LEVI_CIVITA, v, axes=([2], [0]))  # cross @ x = v x x
    rotation = ((1.0 - vv) * jnp.eye(3) + 2.0 * jnp.outer(v, v) + 2.0 * cross) / (1.0 + vv)
    return rotation, jnp.concatenate([zero, pose[:2]])


def _local_points(pose: Float[Array, "P"], points_initial: Float[Array, "N 3"], rolls: bool) -> Float[Array, "N 3"]:
    """Points given in the initial frame, in the frame moved by the pose update (mm)."""
    rotation, translation = _update(pose, rolls)
    return (points_initial - translation) @ rotation


def _distances(theta, points_initial: Float[Array, "N 3"], kind: str) -> Float[Array, "N"]:
    """Signed distance (mm) of each point (given in the initial frame) to the shape ``theta``."""
    model = _MODELS[kind]
    local = _local_points(theta["pose"], points_initial, model.rolls)
    return model.solid(theta["sizes"], theta["axial"][0], _positive(theta["axial"][1])).sdf(local)


# --------------------------------------------------------------------------- initialisation

def _initial_cross_section(kind: str, local: Float[Array, "N 3"], valid: Bool[Array, "N"]):
    """Cross-section centre (2,), roll (rad) and raw sizes, from points in the principal frame."""
    if kind in ("cuboid", "semipyramid"):
        # Minimum-area bounding rectangle over a grid of roll angles (robust 2 % quantiles).
        def bounds(angle):
            rolled = local[:, 1:] @ _rotation_2d(angle)
            return jnp.stack([_masked_quantiles(rolled[:, i], valid, (0.02, 0.98)) for i in range(2)])

        angles = jnp.arange(_ROLL_STEPS) * (0.5 * jnp.pi / _ROLL_STEPS)
        box = jax.vmap(bounds)(angles)  # (angles, 2 axes, low / high)
        extent = jnp.maximum(box[..., 1] - box[..., 0], _MIN_SIZE_MM)
        best = jnp.argmin(extent[:, 0] * extent[:, 1])
        centre = _rotation_2d(angles[best]) @ jnp.mean(box[best], axis=-1)
        half = 0.5 * extent[best]
        sides = half if kind == "cuboid" else jnp.full((2,), half[0] + half[1])
        return centre, angles[best], _softplus_inverse(sides)

    centre = _circle_centre(local[:, 1:], valid)
    radial = jnp.linalg.norm(local[:, 1:] - centre, axis=1)
    if kind in ("cylinder", "semicone"):
        radius = _masked_median(radial, valid)
        return centre, jnp.zeros(()), _softplus_inverse(jnp.full((1 if kind == "cylinder" else 2,), radius))

    # double-cylinder: coarse search over the step position, a median radius on either side.
    x = local[:, 0]
    start, end = _masked_quantiles(x, valid, (0.005, 0.995))

    def split(fraction):
        below = x < start + fraction * (end - start)
        r_below, r_above = _masked_median(radial, valid & below), _masked_median(radial, valid & ~below)
        deviation = jnp.abs(radial - jnp.where(below, r_below, r_above))
        return jnp.sum(jnp.where(valid, deviation, 0.0)), r_below, r_above

    fractions = jnp.linspace(0.1, 0.9, _JOINT_STEPS)
    deviations, r_below, r_above = jax.vmap(split)(fractions)
    best = jnp.argmin(deviations)
    sizes = jnp.stack([_softplus_inverse(r_below[best]), _softplus_inverse(r_above[best]),
                       jnp.log(fractions[best] / (1.0 - fractions[best]))])
    return centre, jnp.zeros(()), sizes


def _initial_guess(kind: str, points: Float[Array, "N 3"], valid: Bool[Array, "N"]):
    """Initial frame (rotation (3, 3), origin (3,) in the map frame) and parameters."""
    centroid, axes = _principal_frame(points, valid)
    local = (points - centroid) @ axes
    centre, roll, sizes = _initial_cross_section(kind, local, valid)
    start, end = _masked_quantiles(local[:, 0], valid, (0.005, 0.995))
    c, s = jnp.cos(roll), jnp.sin(roll)
    rolled = jnp.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    theta = {
        "pose": jnp.zeros((5 if _MODELS[kind].rolls else 4,)),
        "axial": jnp.stack([0.5 * (start + end), _softplus_inverse(end - start)]),
        "sizes": sizes,
    }
    theta = jax.tree.map(lambda leaf: jnp.where(jnp.isfinite(leaf), leaf, 0.0), theta)
    return axes @ rolled, centroid + axes[:, 1:] @ centre, theta


# --------------------------------------------------------------------------- reporting

def _big_cylinder_extent(kind: str, theta, points_initial, on_surface, axial) -> Float[Array, "2"]:
    """(lowest, highest) axial position of on-surface points on the bigger radius, mm (double
    cylinder only; +-inf otherwise or without such points)."""
    if kind != "double-cylinder":
        return jnp.array([jnp.inf, jnp.inf])
    local = _local_points(theta["pose"], points_initial, _MODELS[kind].rolls)
    radial = jnp.linalg.norm(local[:, 1:], axis=-1)
    r_start, r_end = _positive(theta["sizes"][0]), _positive(theta["sizes"][1])
    big = on_surface & (jnp.abs(radial - jnp.maximum(r_start, r_end)) < 0.25 * jnp.abs(r_start - r_end))
    low, high = _masked_quantiles(axial, big, (_STEP_QUANTILE, 1.0 - _STEP_QUANTILE))
    return jnp.where(jnp.any(big), jnp.stack([low, high]), jnp.inf)


def _untouched_sides(kind: str, theta, points_initial, on_surface, band) -> tuple[Array, Array]:
    """Where the cuboid's untouched sides go: (low (2,), high (2,)) positions along the shape
    frame's y and z, mm; +-inf for a touched side, for other kinds, or without touched neighbours.

    Each side counts the on-surface points nearest to it (within ``band`` of its plane); one
    with fewer than ``_TOUCHED_FRACTION`` of the most-touched side's is untouched and goes where
    the points on the touched sides across from it stop (the ``_SIDE_QUANTILE`` quantiles of
    their positions along its normal). The least squares cannot place it: no point lies on it,
    and the points on its neighbours only keep it from moving in.
    """
    infinite = jnp.full((2,), jnp.inf)
    if kind != "cuboid":
        return -infinite, infinite
    section = _local_points(theta["pose"], points_initial, _MODELS[kind].rolls)[:, 1:]
    gap = jnp.abs(section) - _positive(theta["sizes"][:2])  # signed distance to the y, z side planes
    on_plane = on_surface[:, None] & (jnp.abs(gap) < band)  # (N, 2): on a y side, on a z side
    nearest = jnp.argmax(gap, axis=1)[:, None] == jnp.arange(2)
    counts = jnp.stack([jnp.sum(on_plane & nearest & (section < 0), axis=0),
                        jnp.sum(on_plane & nearest & (section > 0), axis=0)], axis=-1)  # (axis, low / high)
    touched = counts >= _TOUCHED_FRACTION * jnp.max(counts)
    low, high = [], []
    for axis in range(2):
        across = 1 - axis  # the sides across whose points this axis's extent is read
        neighbours = on_plane[:, across]
        extent = _masked_quantiles(section[:, axis], neighbours, (_SIDE_QUANTILE, 1.0 - _SIDE_QUANTILE))
        usable = jnp.any(neighbours) & jnp.any(touched[across])
        low.append(jnp.where(usable & ~touched[axis, 0], extent[0], -jnp.inf))
        high.append(jnp.where(usable & ~touched[axis, 1], extent[1], jnp.inf))
    return jnp.stack(low), jnp.stack(high)


def _report(kind: str, theta, rotation_initial: Float[Array, "3 3"], origin_initial: Float[Array, "3"],
            axial_low: Float[Array, ""], axial_high: Float[Array, ""], step_axial: Float[Array, "2"],
            side_low: Float[Array, "2"], side_high: Float[Array, "2"]):
    """Named parameters and ``T_object_shape`` (bigger end at -x, centred on the length).

    An end face that no point touched is not pinned by the least squares (the cost is flat
    beyond the last point), so each end is first pulled in to ``axial_low`` / ``axial_high``
    (mm along the fitted axis), where the points on the surface stop; a touched end face
    already lies there. Sizes that vary along the axis are re-evaluated at the new ends.

    The double cylinder's step is not pinned either: the jaws cannot reach the small cylinder
    next to the step (the big one is in the way), so no point lies between where the big
    cylinder's touched surface stops and where the small one's starts, and the cost is flat
    there. The step goes where the big cylinder's surface stops (``step_axial``: its last
    on-surface point towards +x, and towards -x): a longer big cylinder would have been touched.

    A cuboid side that no point touched is not pinned either, so it goes where the points on
    its neighbours stop (``side_low`` / ``side_high``: position across the axis, along the
    shape frame's y and z, of the low and the high side; +-inf for a touched side).
    """
    model = _MODELS[kind]
    sizes = theta["sizes"]
    centre, fitted_length = theta["axial"][0], _positive(theta["axial"][1])
    fitted_start, fitted_end = centre - 0.5 * fitted_length, centre + 0.5 * fitted_length
    start = jnp.clip(axial_low, fitted_start, fitted_end)
    end = jnp.clip(axial_high, start, fitted_end)
    degenerate = end - start <= _MIN_SIZE_MM
    start, end = jnp.where(degenerate, fitted_start, start), jnp.where(degenerate, fitted_end, end)
    length = end - start

    def at_ends(value_start, value_end):  # a linear profile along the axis, at the new ends
        slope = (value_end - value_start) / fitted_length
        return value_start + slope * (start - fitted_start), value_start + slope * (end - fitted_start)

    flip = turn = jnp.asarray(False)
    side_middle = jnp.zeros((2,))
    if kind == "cylinder":
        parameters = {"radius_mm": _positive(sizes[0]), "length_mm": length}
    elif kind == "semicone":
        r_start, r_end = at_ends(_positive(sizes[0]), _positive(sizes[1]))
        base, top = jnp.maximum(r_start, r_end), jnp.minimum(r_start, r_end)
        flip = r_end > r_start
        parameters = {"base_radius_mm": base, "slope_rad": jnp.arctan2(base - top, length),
                      "top_radius_mm": top, "length_mm": length}
    elif kind == "double-cylinder":
        r_start, r_end = _positive(sizes[0]), _positive(sizes[1])
        flip = r_end > r_start
        step = jnp.where(flip, step_axial[0], step_axial[1])
        step = jnp.where(jnp.isfinite(step), step, _joint_position(sizes, centre, fitted_length))
        joint = jnp.clip(step, start, end) - start
        parameters = {"big_radius_mm": jnp.maximum(r_start, r_end),
                      "small_radius_mm": jnp.minimum(r_start, r_end),
                      "joint_mm": jnp.where(flip, length - joint, joint), "length_mm": length}
    elif kind == "cuboid":
        half = _positive(sizes[:2])
        high = jnp.where(jnp.isfinite(side_high), side_high, half)
        low = jnp.where(jnp.isfinite(side_low), side_low, -half)
        degenerate = high - low <= _MIN_SIZE_MM
        low, high = jnp.where(degenerate, -half, low), jnp.where(degenerate, half, high)
        side_middle = 0.5 * (low + high)
        half_y, half_z = 0.5 * (high - low)
        turn = half_y > half_z
        parameters = {"side_1_mm": 2.0 * jnp.maximum(half_y, half_z),
                      "side_2_mm": 2.0 * jnp.minimum(half_y, half_z), "length_mm": length}
    else:  # semipyramid
        s_start, s_end = at_ends(_positive(sizes[0]), _positive(sizes[1]))
        base, top = jnp.maximum(s_start, s_end), jnp.minimum(s_start, s_end)
        flip = s_end > s_start
        parameters = {"base_side_mm": base, "slope_rad": jnp.arctan2(base - top, 2.0 * length),
                      "top_side_mm": top, "length_mm": length}

    # p_object = origin_initial + rotation_initial (t_update + R_update p_shape), then the
    # origin moved to the middle of the length and the axes turned to the canonical ones.
    rotation_update, translation_update = _update(theta["pose"], model.rolls)
    rotation = rotation_initial @ rotation_update
    origin = (origin_initial + rotation_initial @ translation_update + rotation[:, 0] * 0.5 * (start + end)
              + rotation[:, 1:] @ side_middle)
    rotation = jnp.where(flip, rotation @ _FLIP, rotation)
    rotation = jnp.where(turn, rotation @ _QUARTER_ROLL, rotation)
    T_object_shape = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(rotation), origin)
    return parameters, T_object_shape


# --------------------------------------------------------------------------- the fit

def _clean(points, valid):
    points = jnp.asarray(points, jnp.float32)
    valid = jnp.asarray(valid, bool) & jnp.all(jnp.isfinite(points), axis=-1)
    return jnp.where(valid[:, None], points, 0.0), valid  # padding may hold anything


@functools.partial(jax.jit, static_argnames=("kind", "max_iterations"))
def _fit_shape(points, valid, extent_points, extent_valid, robust_scale_mm, *, kind: str,
               max_iterations: int) -> ShapeFit:
    points, valid = _clean(points, valid)
    extent_points, extent_valid = _clean(extent_points, extent_valid)
    scale = jnp.maximum(jnp.asarray(robust_scale_mm, jnp.float32), 1e-3)

    # 1. Initial frame and sizes from the cloud.
    rotation_initial, origin_initial, theta = _initial_guess(kind, points, valid)
    points_initial = (points - origin_initial) @ rotation_initial

    # 2. Robust refinement of pose and sizes: one traced solver (compiled once) run with a
    #    decreasing Cauchy scale, wide first, then robust_scale_mm.
    def stage(theta, stage_scale):
        result = solve_least_squares(lambda t: _distances(t, points_initial, kind), theta,
                                     max_iterations=max_iterations, robust_scale_mm=stage_scale,
                                     loss="cauchy", weights=valid.astype(jnp.float32))
        return result.theta, result

    _, stages = jax.lax.scan(stage, theta, jnp.stack([_COARSE_SCALE_FACTOR * scale, scale]))
    final = jax.tree.map(lambda leaf: leaf[-1], stages)
    theta = final.theta  # the solver keeps only parameters with a finite cost
    distances = jnp.where(valid, final.residuals, 0.0)

    # 3. Where the extent cloud's points on the surface (within 3 robust standard deviations of
    #    it, at most robust_scale_mm) stop along the axis, and across it for untouched cuboid
    #    sides. Nearly the extremes, not the extremes: an outlier displaced along the surface past
    #    an untouched end still lies on its extension.
    extent_initial = (extent_points - origin_initial) @ rotation_initial
    extent_distances = jnp.where(extent_valid, _distances(theta, extent_initial, kind), 0.0)
    sigma = 1.4826 * _masked_median(jnp.abs(extent_distances), extent_valid)
    band = jnp.minimum(3.0 * sigma, scale)
    on_surface = extent_valid & (jnp.abs(extent_distances) < band)
    axial = _local_points(theta["pose"], extent_initial, _MODELS[kind].rolls)[:, 0]
    axial_low, axial_high = _masked_quantiles(axial, on_surface, (_END_QUANTILE, 1.0 - _END_QUANTILE))
    axial_low = jnp.where(jnp.any(on_surface), axial_low, -jnp.inf)
    axial_high = jnp.where(jnp.any(on_surface), axial_high, jnp.inf)
    step_axial = _big_cylinder_extent(kind, theta, extent_initial, on_surface, axial)
    side_low, side_high = _untouched_sides(kind, theta, extent_initial, on_surface, band)
    parameters, T_object_shape = _report(kind, theta, rotation_initial, origin_initial, axial_low, axial_high,
                                         step_axial, side_low, side_high)

    # 4. Quality, with every number finite whatever came in.
    count = jnp.sum(valid)
    inlier = valid & (jnp.abs(distances) < _INLIER_FACTOR * scale)
    inliers = jnp.sum(inlier)
    rms = jnp.sqrt(jnp.sum(jnp.where(inlier, distances**2, 0.0)) / jnp.maximum(inliers, 1))
    finite = jnp.isfinite(rms) & jnp.all(jnp.isfinite(T_object_shape.wxyz_xyz))
    for value in parameters.values():
        finite = finite & jnp.isfinite(value)
    n_parameters = sum(leaf.size for leaf in jax.tree.leaves(theta))
    return ShapeFit(
        kind=kind,
        parameters={name: jnp.nan_to_num(value) for name, value in parameters.items()},
        T_object_shape=jaxlie.SE3(jnp.where(finite, T_object_shape.wxyz_xyz,
                                            jaxlie.SE3.identity().wxyz_xyz)),
        rms_residual_mm=jnp.nan_to_num(rms),
        inlier_fraction=inliers / jnp.maximum(count, 1),
        converged=final.converged & finite & (count >= 3 * n_parameters),
        iterations=jnp.sum(stages.iterations),
    )


def fit_shape(
    points: Float[Array, "N 3"],
    valid: Bool[Array, "N"],
    kind: str,
    *,
    robust_scale_mm: float = 0.5,
    max_iterations: int = 60,
    extent_points: Float[Array, "M 3"] | None = None,
    extent_valid: Bool[Array, "M"] | None = None,
) -> ShapeFit:
    """Fit a Table II shape (paper section V) to a point cloud by robust least squares.

    Compiled once per (kind, max_iterations, N). The object may sit in any pose in the map
    frame (its axis along the cloud's longest principal direction); points may cover only part
    of its surface (the sides and one end, say).

    Args:
        points: (N, 3) points in the map (object) frame, mm; invalid rows may hold anything.
        valid: (N,) bool, which points are real (False for padding).
        kind: one of ``SHAPE_KINDS`` (``"double_cylinder"``, the catalog name, is accepted).
        robust_scale_mm: scale of the final Cauchy loss, mm: a few times the point noise;
            points much farther than this from the surface barely count.
        max_iterations: cap on the Levenberg-Marquardt iterations of each of the two stages.
        extent_points, extent_valid: (M, 3) points, mm, and (M,) bool that say where the
            surface stops (untouched ends and cuboid sides, the double cylinder's step); default
            ``points``. Pass the full-resolution contact cloud when ``points`` is voxel-averaged
            (a voxel centroid sits up to half a voxel inside an edge) or holds only the points
            whose depth is trusted (an outline is right where a depth is not).

    Returns:
        :class:`ShapeFit`; ``converged=False`` (with finite numbers) when the fit failed or there
        were too few valid points (fewer than 3 per fitted parameter).

    Raises:
        ValueError: unknown kind, or points not of shape (N, 3) with a matching ``valid`` (the
            same for the extent cloud).
    """
    kind = _check_kind(kind)
    points, valid = jnp.asarray(points), jnp.asarray(valid)
    if extent_points is None and extent_valid is None:
        extent_points, extent_valid = points, valid
    elif extent_points is None or extent_valid is None:
        raise ValueError("give both extent_points and extent_valid, or neither")
    extent_points, extent_valid = jnp.asarray(extent_points), jnp.asarray(extent_valid)
    for name, (cloud, mask) in {"points": (points, valid), "extent_points": (extent_points, extent_valid)}.items():
        if cloud.ndim != 2 or cloud.shape[-1] != 3 or mask.shape != cloud.shape[:1]:
            raise ValueError(f"expected {name} (N, 3) and a matching (N,) mask, got {cloud.shape} and {mask.shape}")
    return _fit_shape(points, valid, extent_points, extent_valid, robust_scale_mm, kind=kind,
                      max_iterations=max_iterations)


def true_shape_parameters(obj: TactileObject, kind: str) -> dict[str, float]:
    """The catalog truth of a Table II object under the names :func:`fit_shape` reports.

    Args:
        obj: a catalog object lying along x (e.g. ``get_object("semicone")``).
        kind: its shape kind, one of ``SHAPE_KINDS``.

    Returns:
        ``{name: value}`` for ``TABLE2_PARAMETERS[kind]`` plus ``length_mm`` (the object's extent
        along x); mm and rad. For the double-cylinder, ``joint_mm`` is measured from the big end.

    Raises:
        ValueError: unknown kind, or the object does not carry those parameters.
    """
    kind = _check_kind(kind)
    missing = [name for name in TABLE2_PARAMETERS[kind] if name not in obj.parameters]
    if missing:
        raise ValueError(f"object {obj.name!r} has no {', '.join(missing)} among its parameters "
                         f"({', '.join(obj.parameters) or 'none'}); is it a {kind}?")
    truth = {name: float(obj.parameters[name]) for name in TABLE2_PARAMETERS[kind]}
    truth["length_mm"] = float(obj.extents[0])
    return truth


def shape_fit_errors(fit: ShapeFit, truth: dict[str, float]) -> dict[str, dict[str, float]]:
    """Estimates against the truth for the parameters Table II reports (nuisance ones left out).

    Args:
        fit: a single (unbatched) fit.
        truth: e.g. :func:`true_shape_parameters` of the object.

    Returns:
        ``{name: {"estimate", "true", "relative_error"}}`` with ``relative_error =
        |estimate - true| / |true|`` (a fraction, not percent).
    """
    errors = {}
    for name in TABLE2_PARAMETERS[_check_kind(fit.kind)]:
        estimate, true = float(fit.parameters[name]), float(truth[name])
        relative = abs(estimate - true) / abs(true) if true != 0 else math.inf
        errors[name] = {"estimate": estimate, "true": true, "relative_error": relative}
    return errors
