"""What localization reads from a tactile map, and a query imprint."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from tactojax.mapping import TactileMap

MAP_POINTS = 64
"""Contact points per imprint that a :class:`LocalizationMap` keeps for consistency checks."""


@struct.dataclass
class LocalizationMap:
    """The stored imprints of one object as localization uses them (no images, no names).

    Correspondences are found by projecting into the stored heightmaps, so nothing is built
    at query time; the fields are the map's own arrays (no copy). Only ``mm_per_px`` is
    static, so every map of one sensor and size K shares one compiled localization.
    """

    heightmaps: Float[Array, "K H W"]
    """Predicted heightmaps, mm (>= 0), each in its imprint's sensor frame."""
    masks: Bool[Array, "K H W"]
    """Contact masks (a correspondence needs its pixel in contact)."""
    T_object_sensor: jaxlie.SE3
    """(K,) sensor pose of every imprint in the object frame, mm."""
    openings: Float[Array, "K"]
    """Gripper openings, mm."""
    features: Float[Array, "K F"]
    """Feature vectors for retrieval, L2-normalised (cosine similarity = dot product)."""
    imprint_valid: Bool[Array, "K"]
    """Which imprints belong to the map (a map-size study switches imprints off here)."""
    points: Float[Array, "K Q 3"]
    """A few contact points of every imprint, object frame, mm (consistency checks)."""
    normals: Float[Array, "K Q 3"]
    """Unit surface normals at ``points``, object frame."""
    points_valid: Bool[Array, "K Q"]
    """Which of them are real."""
    centres: Float[Array, "K 3"]
    """Centroid of every imprint's contact points, object frame, mm (spatial neighbours)."""
    mm_per_px: float = struct.field(pytree_node=False)
    """Pixel pitch of the heightmaps, mm."""

    @staticmethod
    def from_tactile_map(tactile_map: TactileMap, *, points_per_imprint: int = MAP_POINTS) -> LocalizationMap:
        """The localization view of a :class:`~tactojax.mapping.TactileMap`.

        Args:
            tactile_map: the map.
            points_per_imprint: contact points kept per imprint for consistency checks (the
                first ones of the map's random sample).
        """
        count = min(points_per_imprint, tactile_map.points.shape[1])
        points_valid = tactile_map.valid[:, :count]
        points = jax.vmap(lambda T, p: T @ p)(tactile_map.T_object_sensor, tactile_map.points[:, :count])
        normals = jax.vmap(lambda T, n: T.rotation() @ n)(tactile_map.T_object_sensor, tactile_map.normals[:, :count])
        all_points, all_valid = tactile_map.points_object, tactile_map.valid
        centres = (jnp.sum(jnp.where(all_valid[..., None], all_points, 0.0), axis=1)
                   / jnp.maximum(jnp.sum(all_valid, axis=1), 1)[:, None])
        features = tactile_map.features
        features = features / jnp.maximum(jnp.linalg.norm(features, axis=-1, keepdims=True), 1e-12)
        view = LocalizationMap(
            heightmaps=tactile_map.heightmaps, masks=tactile_map.masks,
            T_object_sensor=tactile_map.T_object_sensor, openings=tactile_map.openings,
            features=features, imprint_valid=tactile_map.imprint_valid,
            points=points, normals=normals, points_valid=points_valid, centres=centres,
            mm_per_px=float(tactile_map.mm_per_px))
        return jax.tree.map(_strong, view)

    def __len__(self) -> int:
        return int(self.openings.shape[0])

    def padded(self, multiple: int) -> LocalizationMap:
        """The map padded with invalid imprints to a multiple of ``multiple`` imprints.

        Maps of similar sizes then share one compilation of everything that reads them.
        """
        count = len(self)
        extra = -count % max(int(multiple), 1)
        if extra == 0:
            return self

        def pad(x):
            return jnp.concatenate([x, jnp.zeros((extra, *x.shape[1:]), x.dtype)])

        view = jax.tree.map(pad, self.replace(T_object_sensor=jaxlie.SE3(self.T_object_sensor.wxyz_xyz)))
        identity = jnp.broadcast_to(jaxlie.SE3.identity().wxyz_xyz, (extra, 7))
        return view.replace(T_object_sensor=jaxlie.SE3(view.T_object_sensor.wxyz_xyz.at[count:].set(identity)))

    def with_imprint_valid(self, imprint_valid: Bool[Array, "K"]) -> LocalizationMap:
        """The same map with only ``imprint_valid & self.imprint_valid`` imprints in it."""
        imprint_valid = jnp.asarray(imprint_valid, bool)
        if imprint_valid.shape[0] < len(self):  # a mask over the unpadded imprints
            imprint_valid = jnp.concatenate([imprint_valid, jnp.zeros(len(self) - imprint_valid.shape[0], bool)])
        return self.replace(imprint_valid=self.imprint_valid & imprint_valid)


@struct.dataclass
class Query:
    """A new tactile imprint to localize: its predicted local shape, features and opening."""

    heightmap: Float[Array, "H W"]
    """Predicted heightmap, mm, query sensor frame."""
    mask: Bool[Array, "H W"]
    """Predicted contact mask."""
    feature: Float[Array, "F"]
    """Feature vector (same encoder as the map's)."""
    opening: Float[Array, ""]
    """Gripper opening, mm."""


def _strong(x):
    """The array with a fixed (not weak) dtype, so that jit caches do not split on weak types."""
    if isinstance(x, jax.Array) and not x.weak_type:
        return x  # already what jit wants: no copy, no dispatch (this runs on every touch)
    x = jnp.asarray(x)
    return jnp.asarray(x, dtype=x.dtype)


def canonical_query(query: Query) -> Query:
    """The query with strongly typed arrays (a Python float opening would recompile)."""
    mask = query.mask
    if not (isinstance(mask, jax.Array) and mask.dtype == bool):
        mask = jnp.asarray(mask, bool)
    return Query(heightmap=_strong(query.heightmap), mask=mask,
                 feature=_strong(query.feature), opening=_strong(query.opening))


def as_localization_map(tactile_map: TactileMap | LocalizationMap) -> LocalizationMap:
    """A :class:`LocalizationMap` from either map type."""
    if isinstance(tactile_map, LocalizationMap):
        return tactile_map
    return LocalizationMap.from_tactile_map(tactile_map)


def map_query(tactile_map: TactileMap | LocalizationMap, index: int | Int[Array, ""]) -> Query:
    """Imprint ``index`` of a map as a query (leave-one-out evaluation)."""
    view = as_localization_map(tactile_map)
    return Query(heightmap=view.heightmaps[index], mask=view.masks[index],
                 feature=view.features[index], opening=view.openings[index])
