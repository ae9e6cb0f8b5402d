"""What localization reads from a tactile map (:class:`LocalizationMap`), and a touch (:class:`Touch`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Float16, Int

from tactojax import _struct as struct
from tactojax.localize._surface import MapSurface, SurfaceSettings, build_map_surface
from tactojax.mapping import TactileMap, unpack_heightmaps
from tactojax.objects import ObjectSymmetry

MAP_POINTS = 64
"""Contact points per imprint that a :class:`LocalizationMap` keeps (registration and tracking)."""


FOUND_CONTACT_GROWTH = 1.75
"""How much the log-odds that the search found the truth's mode grow per e-fold of the touches'
mean contact area (:attr:`BeliefCalibration.found_contact`), one value for every map: fit on the
five catalog objects' calibration grasps at all four turns pooled (seed 1313, 64 episodes x 3
grasps x 2 fingers each, every map its own offset and slope; the pooled log loss is within 1 nat
in 833 of its minimum from 1.25 to 2.25). A few dozen episodes of one object rarely hold enough
small touches to fit it per map (the gum box's and the marker's: 1-2 % under 10 mm²)."""

DEFAULT_FOUND = {"found_offset": 2.75, "found_slope": 1.25, "found_contact": FOUND_CONTACT_GROWTH}
"""P(the search found the truth's mode) of :meth:`BeliefCalibration.default`: fit by
:func:`~tactojax.localize.evaluation.fit_found_probability` on the five catalog objects' seed-900
calibration grasps pooled, under the default scales, on maps of the paper's 10 mm grid (what
``tactojax map`` and ``map-catalog`` build; ``benchmarks/default_calibration.py``): 0.94 after
one touch of 20 mm², 0.08 after one of 1 mm², 0.99 after six of 20 mm². Before the contact area
entered it, the fit was the grid's corner (1.00 after any number of touches): pooled over the
objects, the mass near the best hypothesis matched the observed share, the pinpoint touches'
overconfidence offset by the full ones' underconfidence. A map whose search misses more (another
grid, another object) should be fit by ``tactojax calibrate-belief``. A stored fit from before
this term was fit takes this default too; one from before the contact area entered it, a
contact growth of 0 (as it was fit)."""

MIN_CONTACT_MM2 = 0.01
"""Contact areas are floored at this in :func:`found_log_odds` (a belief holds only touches with
contact; the floor keeps a degenerate area finite), mm²."""

REFERENCE_CONTACT_MM2 = 20.0
"""The contact area at which ``found_offset`` is the log-odds that the search found the truth's
mode after one touch, mm² (about the median touch of the catalog objects' new grasps: 500
pixels of the GelSlim's 0.2 mm ones)."""


def found_log_odds(offset, slope, contact, touches, contact_mm2, *, xp=np):
    """Log-odds that the search found the truth's mode (:meth:`BeliefCalibration.found_probability`)
    after ``touches`` touches of mean contact area ``contact_mm2`` (mm²), in ``xp`` (numpy for the
    calibration's grid searches, ``jax.numpy`` in the belief); arrays broadcast."""
    log_touches = xp.log(xp.maximum(xp.asarray(touches), 1))
    log_area = xp.log(xp.maximum(xp.asarray(contact_mm2), MIN_CONTACT_MM2) / REFERENCE_CONTACT_MM2)
    return offset + slope * log_touches + contact * log_area


@struct.dataclass
class BeliefCalibration:
    """The belief's likelihood scales, fit on the map's own touches (:func:`~tactojax.localize.fit_calibration`).

    One touch's log-likelihood at a hypothesis is ``temperature * geometry + appearance *
    similarity``; the sum over the ``n`` touches a belief holds is scaled by
    ``n ** -fusion_exponent`` (touches of one object are not independent evidence: 0 would
    multiply them as if they were, 1 would count them all as one).

    The belief's hypotheses come from a finite search (retrieval, a grid of offsets, ICP), and
    its weights are a posterior only over what that search found: after one touch, the true
    pose's mode is among them in 45-69 % of four catalog objects' calibration grasps on their
    10 mm maps (97 % of the tape roll's).
    So the reported P(within 2 mm) is the mass near the best hypothesis times the probability
    that the search found the truth's mode at all (:meth:`found_probability`), fit on the same
    calibration grasps: ``sigmoid(found_offset + found_slope * log n + found_contact * log(a /
    REFERENCE_CONTACT_MM2))`` for ``n`` touches of mean contact area ``a``. A pinpoint touch (a
    jaw grazing an edge: a few dozen pixels) leaves the search far more often without the truth
    than a full one: on the scissors' and the screwdriver's grasps at all four turns, one-touch
    beliefs under 10 mm² of contact said 0.30 where 5-9 % were right, with one term for all
    (the full touches' beliefs were underconfident by as much). The offset and slope are fit per
    map; the growth with the area is the library's :data:`FOUND_CONTACT_GROWTH`.
    """

    temperature: Float[Array, ""]
    """Scale of the geometric log-likelihood (an effective share of independent points)."""
    appearance: Float[Array, ""]
    """Weight of the cosine similarity between the touch's features and the stored imprints'."""
    fusion_exponent: Float[Array, ""]
    """How much the evidence of several touches is discounted (see above)."""
    found_offset: Float[Array, ""] = np.float32(8.0)
    """Log-odds that the search found the true pose's mode, after one touch of
    :data:`REFERENCE_CONTACT_MM2` (8, the default here: it always does, as before this was fit)."""
    found_slope: Float[Array, ""] = np.float32(0.0)
    """Their growth with the log of the touch count."""
    found_contact: Float[Array, ""] = np.float32(0.0)
    """Their growth with the log of the touches' mean contact area (relative to
    :data:`REFERENCE_CONTACT_MM2`; 0: independent of it)."""

    def found_probability(self, touches: Int[Array, "*N"],
                          contact_mm2: Float[Array, "*N"] | float = REFERENCE_CONTACT_MM2) -> Float[Array, "*N"]:
        """P(the hypotheses of a belief of ``touches`` touches, of mean contact area
        ``contact_mm2`` (mm²; default: the reference area), hold the true pose's mode)."""
        return jax.nn.sigmoid(found_log_odds(self.found_offset, self.found_slope, self.found_contact, touches,
                                             contact_mm2, xp=jnp))

    @staticmethod
    def default() -> BeliefCalibration:
        """The scales of a map without a fit of its own (before :func:`fit_calibration`): the
        element-wise median of the five catalog objects' fits (``tactojax calibrate-belief`` on
        their seed-900 calibration grasps, the bundled encoder; docs/localization.md). The
        appearance weight belongs to that encoder's kind of features: fit a map whose features
        come from another kind.

        Measured on objects none of those fits saw (ten YCB scans left out of an encoder trained
        the same way), against the earlier default (temperature 0.1, no appearance, no discount
        of repeated touches): the true pose's likelihood after 2 grasps x 2 fingers was higher
        on all five scans evaluated, and identification among 15 objects rose from 76.2 / 92.1 %
        to 80.4 / 93.8 % after 1 / 2 grasps."""
        return BeliefCalibration(temperature=jnp.float32(0.0795), appearance=jnp.float32(6.36),
                                 fusion_exponent=jnp.float32(0.5),
                                 **{name: jnp.float32(value) for name, value in DEFAULT_FOUND.items()})


@struct.dataclass
class LocalizationMap:
    """One object's map as localization uses it: the stored imprints (no images, no names), the
    whole map's surface, the object's symmetries and the belief's calibration.

    Correspondences are found by projecting into the stored heightmaps, and touches are scored
    against the surface's signed-distance grid, so nothing is built at query time. Only
    ``mm_per_px`` (and the surface's pitch) is static, so every map of one sensor, size K and
    surface grid shares one compiled localization.
    """

    packed_heightmaps: Float16[Array, "K H W"]
    """Predicted heightmaps, mm (>= 0), each in its imprint's sensor frame, float16 with the
    contact mask in the sign bit (:func:`~tactojax.mapping.pack_heightmaps`; a correspondence
    needs its pixel in contact)."""
    T_object_sensor: jaxlie.SE3
    """(K,) sensor pose of every imprint in the object frame, mm."""
    openings: Float[Array, "K"]
    """Gripper openings, mm."""
    features: Float[Array, "K F"]
    """Feature vectors for retrieval, L2-normalised (cosine similarity = dot product)."""
    imprint_valid: Bool[Array, "K"]
    """Which imprints belong to the map (a map-size study switches imprints off here)."""
    points: Float[Array, "K Q 3"]
    """A few contact points of every imprint, object frame, mm."""
    normals: Float[Array, "K Q 3"]
    """Unit surface normals at ``points``, object frame."""
    points_valid: Bool[Array, "K Q"]
    """Which of them are real."""
    centres: Float[Array, "K 3"]
    """Centroid of every imprint's contact points, object frame, mm (spatial neighbours)."""
    surface: MapSurface
    """The whole map's signed-distance surface (the belief's likelihood reads it)."""
    symmetries: jaxlie.SE3
    """(S,) object-frame transforms that map the object onto itself (identity first), one per
    copy that no turn about ``symmetry_axis`` reaches (:meth:`~tactojax.objects.ObjectSymmetry.copies`)."""
    symmetry_axis: Float[Array, "3"]
    """Unit axis of the object's continuous rotational symmetry, object frame (zeros for none):
    every symmetry-aware distance (the evaluation's errors, the belief's modes and confidence)
    turns each copy about it to the closest, exactly."""
    symmetry_centre: Float[Array, "3"]
    """A point on that axis, object frame, mm."""
    calibration: BeliefCalibration
    """The belief's likelihood scales for this map."""
    mm_per_px: float = struct.field(pytree_node=False)
    """Pixel pitch of the heightmaps, mm."""

    @staticmethod
    def from_tactile_map(tactile_map: TactileMap, *, calibration: BeliefCalibration | None = None,
                         symmetries: jaxlie.SE3 | None = None,
                         continuous_symmetry: tuple[Float[Array, "3"], Float[Array, "3"]] | None = None,
                         surface: SurfaceSettings | MapSurface | None = None,
                         points_per_imprint: int = MAP_POINTS) -> LocalizationMap:
        """The localization view of a :class:`~tactojax.mapping.TactileMap` (builds its surface
        on the host: about 1-4 s for the catalog maps).

        Args:
            tactile_map: the map.
            calibration: the belief's scales (:func:`~tactojax.localize.fit_calibration`, stored
                in the map file by ``tactojax calibrate-belief``; default: uncalibrated).
            symmetries: (S,) the object's symmetric copies modulo turns about its continuous
                axis (default: the map's :attr:`~tactojax.mapping.TactileMap.object_symmetry`).
                A sampled continuous group (:meth:`~tactojax.objects.ObjectSymmetry.transforms`)
                gives the same distances, more slowly.
            continuous_symmetry: ``(axis, centre)``, the unit axis of the object's continuous
                rotational symmetry and a point on it (object frame, mm); zeros for none
                (default: the map's, as ``symmetries``).
            surface: the grid itself, built before from this map (:func:`build_map_surface`;
                a map file stores its own, :func:`~tactojax.io.stored_surface`), which saves
                rebuilding it; else how to build it (None: the default :class:`SurfaceSettings`).
            points_per_imprint: contact points kept per imprint (the first ones of the map's
                random sample).
        """
        # On the host (NumPy, and decoding in fixed chunks): nothing here compiles per map size,
        # so a catalog of maps of many sizes builds in a time that grows with its imprints only.
        count = min(points_per_imprint, tactile_map.valid.shape[1])
        geometry = tactile_map.host_geometry()
        all_valid = np.asarray(tactile_map.valid)
        all_points = geometry["points_object"]
        centres = (np.sum(np.where(all_valid[..., None], all_points, 0.0), axis=1)
                   / np.maximum(np.sum(all_valid, axis=1), 1)[:, None]).astype(np.float32)
        features = np.asarray(tactile_map.features, np.float32)
        features = features / np.maximum(np.linalg.norm(features, axis=-1, keepdims=True), 1e-12)
        view = LocalizationMap(
            packed_heightmaps=tactile_map.packed_heightmaps,
            T_object_sensor=tactile_map.T_object_sensor, openings=tactile_map.openings,
            features=jnp.asarray(features), imprint_valid=tactile_map.imprint_valid,
            points=jnp.asarray(all_points[:, :count]), normals=jnp.asarray(geometry["normals_object"][:, :count]),
            points_valid=jnp.asarray(all_valid[:, :count]), centres=jnp.asarray(centres),
            surface=surface if isinstance(surface, MapSurface) else build_map_surface(
                tactile_map, SurfaceSettings() if surface is None else surface,
                geometry=None if tactile_map.surface_pixels is not None
                else {**geometry, "valid": np.asarray(tactile_map.point_valid)}),
            symmetries=tactile_map.object_symmetry.copies() if symmetries is None else symmetries,
            **_continuous_symmetry(tactile_map.object_symmetry, continuous_symmetry),
            calibration=BeliefCalibration.default() if calibration is None else calibration,
            mm_per_px=float(tactile_map.mm_per_px))
        return jax.tree.map(_strong, view)

    def __len__(self) -> int:
        return int(self.openings.shape[0])

    @property
    def symmetric(self) -> bool:
        """Whether the object has a symmetry beyond the identity: a continuous axis, or a copy
        that is not the identity (the identity copies :class:`~tactojax.localize.StackedMaps`
        pads with do not count). Host-side (reads the arrays)."""
        copies = np.asarray(self.symmetries.wxyz_xyz)
        identity = np.asarray(jaxlie.SE3.identity().wxyz_xyz)
        return bool(np.any(np.asarray(self.symmetry_axis) != 0) or np.any(np.abs(copies[1:] - identity) > 1e-6))

    def padded(self, multiple: int) -> LocalizationMap:
        """The map padded with invalid imprints to a multiple of ``multiple`` imprints.

        Maps of similar sizes then share one compilation of everything that reads them.
        """
        return self.padded_to(len(self) + (-len(self) % max(int(multiple), 1)))

    def padded_to(self, count: int) -> LocalizationMap:
        """The map padded with invalid imprints to ``count`` imprints (at least its own)."""
        extra = count - len(self)
        if extra <= 0:
            return self

        def pad(x):  # on the host (no program per map size); packed heightmaps: -0.0 is off contact
            x = np.asarray(x)
            fill = -0.0 if x.dtype == np.float16 else 0
            return jnp.asarray(np.concatenate([x, np.full((extra, *x.shape[1:]), fill, x.dtype)]))

        per_imprint = self.replace(T_object_sensor=jaxlie.SE3(self.T_object_sensor.wxyz_xyz), surface=None,
                                   symmetries=None, symmetry_axis=None, symmetry_centre=None, calibration=None)
        view = jax.tree.map(pad, per_imprint)
        poses = np.array(view.T_object_sensor.wxyz_xyz)
        poses[len(self):] = np.asarray(jaxlie.SE3.identity().wxyz_xyz)
        return view.replace(T_object_sensor=jaxlie.SE3(jnp.asarray(poses)),
                            surface=self.surface, symmetries=self.symmetries, symmetry_axis=self.symmetry_axis,
                            symmetry_centre=self.symmetry_centre, calibration=self.calibration)

    def imprints_near(self, T_object_sensor: jaxlie.SE3, centre: Float[Array, "3"], count: int, *,
                      max_facing_deg: float = 60.0) -> tuple[Int[Array, "count"], Bool[Array, "count"]]:
        """The stored imprints that saw the surface where a touch lands: the ``count`` whose
        contact centres are nearest ``centre`` (object frame, mm), among those whose sensor faced
        the surface within ``max_facing_deg`` of the touch's sensor at ``T_object_sensor`` (the
        other side of a thin part is not the same surface). Nearest first; and which are real
        (a map of fewer than ``count`` imprints pads with unreal ones). The one neighbour rule
        of registration, tracking and the belief's appearance cue."""
        axis = T_object_sensor.rotation().as_matrix()[:, 2]
        axes = self.T_object_sensor.rotation().as_matrix()[..., :, 2]
        facing = self.imprint_valid & (axes @ axis >= jnp.cos(jnp.deg2rad(max_facing_deg)))
        score, nearest = jax.lax.top_k(jnp.where(facing, -jnp.linalg.norm(self.centres - centre, axis=-1), -jnp.inf),
                                       min(count, len(self)))
        missing = count - nearest.shape[0]
        return jnp.pad(nearest, (0, missing)), jnp.pad(jnp.isfinite(score), (0, missing))

    def with_imprint_valid(self, imprint_valid: Bool[Array, "K"]) -> LocalizationMap:
        """The same map with only ``imprint_valid & self.imprint_valid`` imprints in it."""
        imprint_valid = jnp.asarray(imprint_valid, bool)
        if imprint_valid.shape[0] < len(self):  # a mask over the unpadded imprints
            imprint_valid = jnp.concatenate([imprint_valid, jnp.zeros(len(self) - imprint_valid.shape[0], bool)])
        return self.replace(imprint_valid=self.imprint_valid & imprint_valid)


@struct.dataclass
class Touch:
    """One touch of one finger: its predicted local shape, features and gripper opening.

    Its sensor pose comes separately, from the robot's kinematics (see
    :func:`~tactojax.localize.localize`)."""

    heightmap: Float[Array, "H W"]
    """Predicted heightmap, mm, in the touch's sensor frame."""
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


def canonical_touch(touch: Touch) -> Touch:
    """The touch with strongly typed arrays (a Python float opening would recompile)."""
    mask = touch.mask
    if not (isinstance(mask, jax.Array) and mask.dtype == bool):
        mask = jnp.asarray(mask, bool)
    return Touch(heightmap=_strong(touch.heightmap), mask=mask,
                 feature=_strong(touch.feature), opening=_strong(touch.opening))


def as_localization_map(tactile_map: TactileMap | LocalizationMap) -> LocalizationMap:
    """A :class:`LocalizationMap` from either map type."""
    if isinstance(tactile_map, LocalizationMap):
        return tactile_map
    return LocalizationMap.from_tactile_map(tactile_map)


def map_touch(view: LocalizationMap, index: int | Int[Array, ""]) -> Touch:
    """Imprint ``index`` of a map as a touch (leave-one-out evaluation)."""
    heightmap, mask = unpack_heightmaps(view.packed_heightmaps[index])
    return Touch(heightmap=heightmap, mask=mask, feature=view.features[index], opening=view.openings[index])


def _continuous_symmetry(symmetry: ObjectSymmetry, given) -> dict[str, jax.Array]:
    """``given`` (axis, centre), else the group's continuous symmetry axis and a point on it
    (zeros for a group without one)."""
    axis, centre = given if given is not None else symmetry.continuous_axis()
    return {"symmetry_axis": jnp.asarray(axis, jnp.float32), "symmetry_centre": jnp.asarray(centre, jnp.float32)}
