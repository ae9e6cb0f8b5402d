"""TactileMap: the imprints of one object, placed in the object frame (paper section V)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Float16, Int, UInt8

from tactojax import _struct as struct
from tactojax.mapping._packing import pixel_points, unpack_heightmaps
from tactojax.objects import ObjectSymmetry, object_symmetry


_decode_points = jax.jit(jax.vmap(pixel_points, in_axes=(0, 0, None)), static_argnums=2)


@functools.partial(jax.jit, static_argnums=3)
def _decode_in_object_frame(packed, pixels, wxyz_xyz, mm_per_px: float):
    """Imprints' points and normals in the sensor frame, then in the object frame."""
    points, normals = _decode_points(packed, pixels, mm_per_px)
    T = jaxlie.SE3(wxyz_xyz)
    return (points, normals, jax.vmap(lambda T, p: T @ p)(T, points),
            jax.vmap(lambda T, n: T.rotation() @ n)(T, normals))


@struct.dataclass
class TactileMap:
    """K imprints of one object, each with its predicted heightmap and contact points.

    The map frame is the *object* frame: every imprint is placed by the gripper kinematics,
    ``T_object_sensor = T_world_object^-1 @ sensor_pose(T_world_gripper, opening)``. For an
    object fixed in the world (a real recording) the object frame is the world frame; the
    mapping protocol turns the object, so it is not.

    Shapes are fixed (K imprints, P points each, padding masked by ``imprint_valid`` and
    ``valid``) so that everything that reads a map jits once per map size.

    The imprints are stored compactly (about 45 kB each for a 120 x 160 px sensor and P = 1024,
    see :mod:`tactojax.mapping._packing`): heightmaps and masks packed into one float16 array,
    points as pixel indices; ``heightmaps``, ``masks``, ``points`` and ``normals`` decode them.
    """

    images: UInt8[Array, "K H W 3"] | None
    """Tactile images, RGB uint8 (what localization features are computed from); None when the
    map was stored without them (its features stay usable; :meth:`stored_images`)."""
    packed_heightmaps: Float16[Array, "K H W"]
    """Heightmaps *predicted* by the shape model from the images, mm (>= 0), float16, with the
    predicted contact mask in the sign bit (:func:`~tactojax.mapping.pack_heightmaps`)."""
    point_pixels: Int[Array, "K P"]
    """P contact pixels per imprint sampled from the predicted mask (row * W + col; uint16 when
    the image has at most 65536 pixels)."""
    valid: Bool[Array, "K P"]
    """Which of the P points are real (an imprint with fewer contact pixels pads)."""
    T_object_sensor: jaxlie.SE3
    """(K,) sensor pose of every imprint in the map (object) frame, mm."""
    openings: Float[Array, "K"]
    """Gripper opening of every imprint, mm (CTI retrieval compares openings)."""
    features: Float[Array, "K F"]
    """Feature vector of every imprint for retrieval (F = 0 until an encoder fills it)."""
    imprint_valid: Bool[Array, "K"]
    """Which imprints are real (False: padding, and imprints with no contact at all)."""
    object_id: str = struct.field(pytree_node=False)
    """The mapped object's name."""
    mm_per_px: float = struct.field(pytree_node=False)
    """Pixel pitch of the images and heightmaps, mm."""
    sensor: str = struct.field(pytree_node=False, default="")
    """Name of the sensor that recorded the imprints."""
    symmetry: ObjectSymmetry | None = struct.field(pytree_node=False, default=None)
    """The object's symmetry group as recorded when it was mapped (declared by the catalog,
    measured from a mesh: :func:`~tactojax.objects.detect_symmetry`); None for a map that
    recorded none (then the catalog's, by object id: :attr:`object_symmetry`)."""
    surface_pixels: Int[Array, "K S"] | None = None
    """S pixels per imprint sampled from the shape model's *whole* predicted contact mask, which the
    map's surface (:func:`~tactojax.localize.build_map_surface`) is built from; None for a map
    written before they were kept (its surface then comes from the contact points). The contact
    points keep only the contact the image observes (:func:`~tactojax.mapping.observed_contact`):
    retrieval and registration must not lean on the false plateaus a misjudged edge leaves. The
    surface is better served by all of it: on a flat face the observed contact is a band along the
    visible edges, so a map of observed contact only knew 57 % of the gum box's surface, and a
    touch reaching past what it knew was scored as floating in space."""
    surface_valid: Bool[Array, "K S"] | None = None
    """Which of the S surface pixels are real (None when ``surface_pixels`` is)."""

    def __len__(self) -> int:
        return int(self.openings.shape[0])

    @property
    def object_symmetry(self) -> ObjectSymmetry:
        """The object's symmetry group: the recorded one, else the catalog's for a catalog
        object (maps written before symmetries were recorded), else none."""
        return self.symmetry if self.symmetry is not None else object_symmetry(self.object_id)

    @property
    def image_shape(self) -> tuple[int, int]:
        """(H, W) of the stored images and heightmaps."""
        return tuple(self.packed_heightmaps.shape[1:3])

    @property
    def heightmaps(self) -> Float[Array, "K H W"]:
        """Predicted heightmaps, mm (>= 0), float32."""
        return unpack_heightmaps(self.packed_heightmaps)[0]

    @property
    def masks(self) -> Bool[Array, "K H W"]:
        """Predicted contact masks."""
        return unpack_heightmaps(self.packed_heightmaps)[1]

    @property
    def points(self) -> Float[Array, "K P 3"]:
        """The P contact points per imprint, sensor frame, mm."""
        return self._points_and_normals()[0]

    @property
    def normals(self) -> Float[Array, "K P 3"]:
        """Unit surface normals at ``points`` (pointing out of the object), sensor frame."""
        return self._points_and_normals()[1]

    def _points_and_normals(self):
        return _decode_points(self.packed_heightmaps, self.point_pixels, self.mm_per_px)

    def stored_images(self) -> UInt8[Array, "K H W 3"]:
        """The tactile images; a clear error for a map stored without them.

        Raises:
            ValueError: the map keeps no images (features from another encoder need them).
        """
        if self.images is None:
            raise ValueError(f"the map of {self.object_id!r} stores no images (a compact map): its own features "
                             "are usable, but encoding them anew needs the images; rebuild the map with "
                             "`tactojax map --keep-images`, or convert the original map with "
                             "`tactojax compact --keep-images`")
        return self.images

    @property
    def points_object(self) -> Float[Array, "K P 3"]:
        """Contact points in the map (object) frame, mm."""
        return jax.vmap(lambda T, p: T @ p)(self.T_object_sensor, self.points)

    @property
    def normals_object(self) -> Float[Array, "K P 3"]:
        """Unit normals in the map (object) frame."""
        return jax.vmap(lambda T, n: T.rotation() @ n)(self.T_object_sensor, self.normals)

    def host_geometry(self, chunk: int = 64, *, surface: bool = False) -> dict[str, np.ndarray]:
        """The decoded contact points as NumPy arrays, computed ``chunk`` imprints at a time (the
        last chunk padded): one compilation serves every map of one image size and point count,
        where the properties compile once per map size K (a catalog of maps of different sizes
        would compile one program per map).

        Args:
            chunk: imprints decoded per call.
            surface: decode the surface pixels instead (:attr:`surface_pixels`; the contact
                points for a map without them), with their validity as ``"valid"``.

        Returns:
            ``{"points", "normals"}`` (K, P, 3) in the sensor frame and ``{"points_object",
            "normals_object"}`` (K, P, 3) in the object frame, float32, mm; with ``surface``, also
            ``"valid"`` (K, S) (real imprints only).
        """
        pixels, valid = ((self.surface_pixels, self.surface_valid) if surface and self.surface_pixels is not None
                         else (self.point_pixels, self.valid))
        count, parts = len(self), []
        arrays = [np.asarray(x) for x in (self.packed_heightmaps, pixels, self.T_object_sensor.wxyz_xyz)]
        for start in range(0, count, chunk):
            index = np.minimum(np.arange(start, start + chunk), count - 1)  # host indexing: no program per K
            outputs = _decode_in_object_frame(*(jnp.asarray(x[index]) for x in arrays), self.mm_per_px)
            parts.append([np.asarray(x)[:min(chunk, count - start)] for x in outputs])
        names = ("points", "normals", "points_object", "normals_object")
        if parts:
            geometry = {name: np.concatenate(column) for name, column in zip(names, zip(*parts))}
        else:
            geometry = {name: np.zeros((0, pixels.shape[1], 3), np.float32) for name in names}
        if surface:
            geometry["valid"] = np.asarray(valid) & np.asarray(self.imprint_valid)[:, None]
        return geometry

    @property
    def point_valid(self) -> Bool[Array, "K P"]:
        """``valid`` restricted to real imprints."""
        return self.valid & self.imprint_valid[:, None]

    def with_features(self, features: Float[Array, "K F"]) -> TactileMap:
        """The same map with new feature vectors (one row per imprint)."""
        features = jnp.asarray(features, jnp.float32)
        if features.ndim != 2 or features.shape[0] != len(self):
            raise ValueError(f"features must be ({len(self)}, F), got {features.shape}")
        return self.replace(features=features)

    def subset(self, index) -> TactileMap:
        """The imprints at ``index`` (an integer array, slice or boolean mask over K)."""
        return jax.tree.map(lambda x: x[index], self)
