"""Analytic solids (pure JAX, differentiable in their parameters).

Every solid is a frozen pytree with two views of the same shape, both broadcasting over the
leading axes of their inputs:

* ``sdf(points) -> distances``: negative inside, positive outside, mm. ``Sphere``, ``Box``,
  ``Cylinder`` and ``Frustum`` give exact Euclidean distances; ``SquareFrustum`` and
  ``Difference`` give a bound that is exact on the surface (for fitting shapes to points).
* ``ray_interval(origins, directions) -> (enter, exit)``: the first stretch of each ray
  ``o + t d``, t >= 0, inside the solid, in closed form (for exact ray casting); empty as
  ``(inf, -inf)``, ``enter == 0`` when the origin is inside.

Each solid is centred at its own origin with its axis of revolution / extrusion along z.
``Difference`` needs convex operands (every primitive here is convex).
"""

from __future__ import annotations

from typing import Protocol

import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float

from tactojax import _struct as struct
from tactojax.objects import _intervals as iv
from tactojax.objects._intervals import Interval


class Solid(Protocol):
    """Anything with a signed distance function in mm."""

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]: ...

    def ray_interval(self, origins: Float[Array, "*rays 3"], directions: Float[Array, "*rays 3"]) -> Interval: ...


def _norm(x: Float[Array, "*batch n"]) -> Float[Array, "*batch"]:
    # sqrt with a floor: exact above 1e-12 mm^2, and a finite gradient at the origin.
    return jnp.sqrt(jnp.maximum(jnp.sum(x * x, axis=-1), 1e-24))


@struct.dataclass
class Sphere:
    """Ball of ``radius`` mm centred at the origin."""

    radius: Float[Array, ""]

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        return _norm(points) - self.radius

    def ray_interval(self, origins, directions) -> Interval:
        a = jnp.sum(directions * directions, -1)
        b = 2.0 * jnp.sum(origins * directions, -1)
        c = jnp.sum(origins * origins, -1) - self.radius**2
        first, _ = iv.quadratic(a, b, c)
        return iv.ahead(first)


@struct.dataclass
class Box:
    """Axis-aligned box with ``half_extents`` (3,) mm."""

    half_extents: Float[Array, "3"]

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        q = jnp.abs(points) - self.half_extents
        outside = _norm(jnp.maximum(q, 0.0))
        outside = jnp.where(jnp.all(q <= 0.0, axis=-1), 0.0, outside)
        return outside + jnp.minimum(jnp.max(q, axis=-1), 0.0)

    def ray_interval(self, origins, directions) -> Interval:
        return iv.ahead(iv.intersect(*(iv.slab(axis, self.half_extents[axis], origins, directions)
                                       for axis in range(3))))


@struct.dataclass
class Cylinder:
    """Capped cylinder of ``radius`` mm along z, from -half_length to +half_length."""

    radius: Float[Array, ""]
    half_length: Float[Array, ""]

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        q = jnp.stack(
            [_norm(points[..., :2]) - self.radius, jnp.abs(points[..., 2]) - self.half_length],
            axis=-1,
        )
        outside = _norm(jnp.maximum(q, 0.0))
        outside = jnp.where(jnp.all(q <= 0.0, axis=-1), 0.0, outside)
        return outside + jnp.minimum(jnp.max(q, axis=-1), 0.0)

    def ray_interval(self, origins, directions) -> Interval:
        o, d = origins[..., :2], directions[..., :2]
        a = jnp.sum(d * d, -1)
        b = 2.0 * jnp.sum(o * d, -1)
        c = jnp.sum(o * o, -1) - self.radius**2
        side, _ = iv.quadratic(a, b, c)
        return iv.ahead(iv.intersect(side, iv.slab(2, self.half_length, origins, directions)))


@struct.dataclass
class Frustum:
    """Truncated cone along z: radius ``bottom_radius`` at z = -half_length, ``top_radius`` at +half_length.

    Exact distance, from the 2-D distance to the trapezoidal half cross-section.
    """

    bottom_radius: Float[Array, ""]
    top_radius: Float[Array, ""]
    half_length: Float[Array, ""]

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        r = _norm(points[..., :2])
        z = points[..., 2]
        h, r1, r2 = self.half_length, self.bottom_radius, self.top_radius
        # Distance to the caps' segments.
        cap_radius = jnp.where(z < 0.0, r1, r2)
        ca = jnp.stack([r - jnp.minimum(r, cap_radius), jnp.abs(z) - h], axis=-1)
        # Distance to the slanted side segment from (r1, -h) to (r2, h).
        k1 = jnp.stack([r2, h])
        k2 = jnp.stack([r2 - r1, 2.0 * h])
        q = jnp.stack([r, z], axis=-1)
        along = jnp.clip(jnp.sum((k1 - q) * k2, axis=-1) / jnp.sum(k2 * k2), 0.0, 1.0)
        cb = q - k1 + k2 * along[..., None]
        inside = (cb[..., 0] < 0.0) & (ca[..., 1] < 0.0)
        distance = jnp.sqrt(
            jnp.maximum(jnp.minimum(jnp.sum(ca * ca, -1), jnp.sum(cb * cb, -1)), 1e-24)
        )
        return jnp.where(inside, -distance, distance)

    def ray_interval(self, origins, directions) -> Interval:
        # Inside: x^2 + y^2 <= (r_mid + k z)^2 within the slab, where r_mid + k z > 0 (both radii
        # are positive, so the cone's apex and its other nappe lie outside the slab).
        r_mid = 0.5 * (self.bottom_radius + self.top_radius)
        k = 0.5 * (self.top_radius - self.bottom_radius) / self.half_length
        ox, oy, oz = origins[..., 0], origins[..., 1], origins[..., 2]
        dx, dy, dz = directions[..., 0], directions[..., 1], directions[..., 2]
        radius_at_origin = r_mid + k * oz
        a = dx * dx + dy * dy - (k * dz) ** 2
        b = 2.0 * (ox * dx + oy * dy - k * dz * radius_at_origin)
        c = ox * ox + oy * oy - radius_at_origin**2
        first, second = iv.quadratic(a, b, c)
        height = iv.slab(2, self.half_length, origins, directions)
        return iv.ahead(iv.pick_nonempty(iv.intersect(first, height), iv.intersect(second, height)))


@struct.dataclass
class SquareFrustum:
    """Truncated square pyramid along z: side ``bottom_side`` at z = -half_length, ``top_side`` at +half_length.

    Distance bound: the largest signed distance to its six face planes (exact on faces).
    """

    bottom_side: Float[Array, ""]
    top_side: Float[Array, ""]
    half_length: Float[Array, ""]

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        z = points[..., 2]
        h = self.half_length
        # Half side a(z) = a0 + s z, face plane |x| - s z - a0 = 0 with normal (1, -s)/sqrt(1+s^2).
        a0 = 0.25 * (self.bottom_side + self.top_side)
        s = 0.25 * (self.top_side - self.bottom_side) / h
        scale = jnp.sqrt(1.0 + s * s)
        side_x = (jnp.abs(points[..., 0]) - s * z - a0) / scale
        side_y = (jnp.abs(points[..., 1]) - s * z - a0) / scale
        caps = jnp.abs(z) - h
        return jnp.maximum(jnp.maximum(side_x, side_y), caps)

    def ray_interval(self, origins, directions) -> Interval:
        a0 = 0.25 * (self.bottom_side + self.top_side)
        s = 0.25 * (self.top_side - self.bottom_side) / self.half_length
        faces = [iv.slab(2, self.half_length, origins, directions)]
        for axis in (0, 1):
            for sign in (1.0, -1.0):
                # sign * p[axis] - s z <= a0
                normal = jnp.zeros(3).at[axis].set(sign).at[2].set(-s)
                faces.append(iv.half_space(normal, a0, origins, directions))
        return iv.ahead(iv.intersect(*faces))


@struct.dataclass
class Placed:
    """A solid moved by the rigid transform ``T_parent_solid`` (mm)."""

    solid: Solid
    T_parent_solid: jaxlie.SE3

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        # p_solid = R^T (p_parent - t), as a matrix product: much faster than broadcasting
        # quaternion products over millions of points.
        rotation = self.T_parent_solid.rotation().as_matrix()
        return self.solid.sdf((points - self.T_parent_solid.translation()) @ rotation)

    def ray_interval(self, origins, directions) -> Interval:
        rotation = self.T_parent_solid.rotation().as_matrix()
        return self.solid.ray_interval((origins - self.T_parent_solid.translation()) @ rotation,
                                       directions @ rotation)


@struct.dataclass
class Union:
    """Union of solids (minimum of their distances)."""

    solids: tuple[Solid, ...]

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        distances = jnp.stack([solid.sdf(points) for solid in self.solids], axis=0)
        return jnp.min(distances, axis=0)

    def ray_interval(self, origins, directions) -> Interval:
        return iv.union_first(*(solid.ray_interval(origins, directions) for solid in self.solids))


@struct.dataclass
class Difference:
    """``solid`` with ``cut`` removed."""

    solid: Solid
    cut: Solid

    def sdf(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
        return jnp.maximum(self.solid.sdf(points), -self.cut.sdf(points))

    def ray_interval(self, origins, directions) -> Interval:
        return iv.difference_first(self.solid.ray_interval(origins, directions),
                                   self.cut.ray_interval(origins, directions))


def placed(solid: Solid, *, translation=(0.0, 0.0, 0.0), rotation: jaxlie.SO3 | None = None) -> Placed:
    """Convenience: ``Placed`` from a translation (mm) and an optional rotation."""
    rotation = jaxlie.SO3.identity() if rotation is None else rotation
    T = jaxlie.SE3.from_rotation_and_translation(rotation, jnp.asarray(translation, jnp.float32))
    return Placed(solid, T)
