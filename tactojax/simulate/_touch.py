"""One jaw touching an object: gel rays -> ray casting -> contact -> tactile image."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from tactojax.geometry import pixel_grid
from tactojax.objects import MeshSolid, RayHits, TactileObject, raycast
from tactojax.sensor import Contact, SensorSpec, add_sensor_noise, press, render_image


@functools.partial(jax.jit, static_argnames=("height_px", "width_px", "mm_per_px"))
def pad_rays(
    T_object_pad: jaxlie.SE3, height_px: int, width_px: int, mm_per_px: float
) -> tuple[Float[Array, "*batch H W 3"], Float[Array, "*batch H W 3"]]:
    """Rays from every pixel of a flat pad (gel) along its +z axis, in the object frame.

    Args:
        T_object_pad: pad pose(s) in the object frame, batch shape (*batch).
        height_px, width_px, mm_per_px: the pad's pixel grid (static).

    Returns:
        origins and unit directions, each (*batch, H, W, 3), mm.
    """
    xy = pixel_grid(height_px, width_px, mm_per_px)
    rotation = T_object_pad.rotation().as_matrix()[..., None, None, :, :]  # (*batch, 1, 1, 3, 3)
    translation = T_object_pad.translation()[..., None, None, :]
    # p_object = R [x, y, 0] + t, as a matrix product (jaxlie's broadcast apply is much slower).
    origins = jnp.einsum("...ij,...j->...i", rotation[..., :2], xy) + translation
    directions = jnp.broadcast_to(rotation[..., 2], origins.shape)
    return origins, directions


_raycast_jit = jax.jit(raycast, static_argnames=("max_distance",))


def cast_rays(
    obj: TactileObject, origins: Float[Array, "*rays 3"], directions: Float[Array, "*rays 3"],
    *, max_distance: float,
) -> RayHits:
    """First hits of rays (object frame, mm) with an analytic (JAX) or mesh (Embree) object."""
    if isinstance(obj.solid, MeshSolid):
        hits = obj.solid.cast(np.asarray(origins), np.asarray(directions), max_distance=max_distance)
        return jax.tree.map(jnp.asarray, hits)
    return _raycast_jit(obj.solid, origins, directions, max_distance=float(max_distance))


@jax.jit
def _press_and_render(
    spec: SensorSpec,
    keys: PRNGKeyArray,
    distances: Float[Array, "B H W"],
    hit: Bool[Array, "B H W"],
    depth_mm: Float[Array, "B"],
) -> tuple[Contact, Float[Array, "B H W 3"]]:
    def one(key, distance, hit_, depth):
        contact = press(spec, distance, hit_, depth)
        image = add_sensor_noise(key, spec, render_image(spec, contact.heightmap))
        return contact, image

    return jax.vmap(one)(keys, distances, hit, depth_mm)


def touch(
    key: PRNGKeyArray,
    spec: SensorSpec,
    obj: TactileObject,
    T_object_sensor_start: jaxlie.SE3,
    depth_mm: Float[Array, "B"],
    *,
    max_distance: float,
) -> tuple[Contact, Float[Array, "B H W 3"], Bool[Array, "B"]]:
    """Advance a batch of sensors along their +z onto the object and press in by ``depth_mm``.

    Args:
        key: PRNG key for the camera noise.
        spec: the sensor.
        obj: the touched object.
        T_object_sensor_start: (B,) sensor poses before closing, in the object frame.
        depth_mm: (B,) penetration depth past first contact, mm.
        max_distance: how far each jaw can travel, mm.

    Returns:
        contact (batch B), images (B, H, W, 3) in [0, 1], and ``collides`` (B,): the gel started
        inside the object, so the touch is not physical.
    """
    origins, directions = pad_rays(T_object_sensor_start, spec.height_px, spec.width_px, spec.mm_per_px)
    hits = cast_rays(obj, origins, directions, max_distance=max_distance)
    keys = jax.random.split(key, depth_mm.shape[0])
    contact, images = _press_and_render(spec, keys, hits.distance, hits.hit, jnp.asarray(depth_mm, jnp.float32))
    collides = jnp.any(hits.starts_inside, axis=(-2, -1))
    return contact, images, collides
