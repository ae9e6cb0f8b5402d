"""Build a TactileMap: predict every imprint's heightmap, sample its contact points, place it."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray
from tqdm.auto import tqdm

from tactojax.geometry import heightmap_normals, heightmap_to_points, sensor_pose
from tactojax.mapping._map import TactileMap
from tactojax.mapping._packing import pack_heightmaps, pixel_index_dtype
from tactojax.shape import ShapeModel, check_image, predict_batch

DEFAULT_POINTS_PER_IMPRINT = 1024
"""Contact points kept per imprint (about a fifth of a typical half-resolution patch)."""

SIGNAL_THRESHOLD = 0.05
"""Colour change against the background (max over RGB of the 3x3 mean, image in [0, 1]) that
counts as a clear observation of the surface slope; camera noise is about 0.013 (median)."""

OBSERVATION_RADIUS_MM = 3.0
"""Predicted contact pixels farther than this from any clear colour change are dropped."""


def observed_contact(
    image: Float[Array, "H W 3"],
    background: Float[Array, "H W 3"],
    mask: Bool[Array, "H W"],
    mm_per_px: float,
    *,
    threshold: float = SIGNAL_THRESHOLD,
    radius_mm: float = OBSERVATION_RADIUS_MM,
) -> Bool[Array, "H W"]:
    """The part of a predicted contact mask that the image actually observes.

    A camera-based sensor sees surface *slope* (colour changes); the height of a flat region
    is only carried over from its edges by the Poisson integration. Where the edges' slopes are
    misjudged (steep walls, a tilted face seen edge-on) that integration leaves plateaus of
    false contact across the rest of the gel, which would be placed centimetres off the object.
    Keeping only contact pixels within ``radius_mm`` of a clear colour change removes them; a
    flat face keeps a band along its visible edges, which fixes its depth.

    Args:
        image, background: (H, W, 3) RGB in [0, 1].
        mask: (H, W) predicted contact mask.
        mm_per_px: pixel pitch, mm.
        threshold: colour change that counts as a clear observation (see ``SIGNAL_THRESHOLD``).
        radius_mm: how far from one a contact pixel may be, mm.

    Returns:
        (H, W) mask, a subset of ``mask``.
    """
    # The 3x3 mean as a sum of shifted copies in the window's order (what ``reduce_window``
    # adds, to the bit), the max over RGB as two maxima, the square dilation as an "or" over
    # rows then over columns (2 x size, not size^2, per pixel): XLA fuses shifted copies into
    # a few loops, where its CPU ``reduce_window`` runs 2-3x slower (issue 17).
    height_px, width_px = mask.shape
    padded = jnp.pad(image - background, ((1, 1), (1, 1), (0, 0)))
    total = functools.reduce(jnp.add, [padded[i:i + height_px, j:j + width_px]
                                       for i in range(3) for j in range(3)])
    change = jnp.abs(total / 9.0)
    strong = jnp.maximum(jnp.maximum(change[..., 0], change[..., 1]), change[..., 2]) > threshold
    size = 2 * int(round(radius_mm / mm_per_px)) + 1
    near = _window_any(_window_any(strong, size, axis=0), size, axis=1)
    return mask & near


def _window_any(values: Bool[Array, "H W"], size: int, axis: int) -> Bool[Array, "H W"]:
    """Whether any value in a centred window of ``size`` (odd) pixels along ``axis`` is set
    (outside the image: unset)."""
    half, length = size // 2, values.shape[axis]
    padding = [(0, 0)] * values.ndim
    padding[axis] = (half, half)
    padded = jnp.pad(values, padding)
    return functools.reduce(jnp.logical_or, [jax.lax.slice_in_dim(padded, k, k + length, axis=axis)
                                             for k in range(size)])


DARK_FRACTION = 0.5
"""A frame darker on average than this fraction of the background frame is a camera fault
(off, covered, a black frame), not a touch: contact changes the gel's colour locally and
leaves its mean brightness near the background's."""


def shows_contact(image: Float[Array, "H W 3"], background: Float[Array, "H W 3"],
                  observed: Bool[Array, "H W"]) -> Bool[Array, ""]:
    """Whether a frame shows a touch: some observed contact (:func:`observed_contact`) in a lit frame.

    Args:
        image, background: (H, W, 3) RGB in [0, 1].
        observed: (H, W) observed contact mask of the frame.
    """
    lit = jnp.mean(image) > DARK_FRACTION * jnp.mean(background)
    return jnp.any(observed) & lit


CLEAR_CHANGE_MARGIN = 0.01
"""How far under ``SIGNAL_THRESHOLD`` (a fraction of it) :func:`may_show_contact` still calls a
colour change possibly clear: far beyond the float32 round-off between its NumPy arithmetic and
:func:`observed_contact`'s."""


def may_show_contact(image: np.ndarray, background: np.ndarray, *, threshold: float = SIGNAL_THRESHOLD) -> bool:
    """Whether a raw frame could show a touch, decided on the host without the shape model.

    :func:`observed_contact` keeps only predicted contact near a clear colour change (a 3x3
    mean change of at least ``threshold``). A frame with none anywhere therefore shows no
    contact (:func:`shows_contact` is False) whatever the model predicts. This finds such
    frames with one OpenCV box filter (about 0.05 ms at 120 x 160 px), so that the live loop
    runs no heightmap program on the frames between grasps. It errs only towards True: a change
    within ``CLEAR_CHANGE_MARGIN`` of ``threshold`` counts.

    Args:
        image: (H, W, 3) uint8 RGB frame.
        background: (H, W, 3) float32 RGB in [0, 1], the sensor's frame with nothing touching.
        threshold: what :func:`observed_contact` calls a clear change.

    Returns:
        False only if no pixel's 3x3 mean colour change comes within the margin of ``threshold``.
    """
    import cv2  # here: importing tactojax.mapping (and the features beneath it) loads no OpenCV

    change = np.asarray(image, np.float32) * np.float32(1.0 / 255.0) - background
    # Zeros beyond the border, as observed_contact pads; normalised by 9 at the border too.
    mean = cv2.boxFilter(change, -1, (3, 3), normalize=True, borderType=cv2.BORDER_CONSTANT)
    return bool(np.abs(mean).max() >= (1.0 - CLEAR_CHANGE_MARGIN) * threshold)


def sample_contact_pixels(
    key: PRNGKeyArray, mask: Bool[Array, "H W"], count: int
) -> tuple[Int[Array, "P"], Bool[Array, "P"]]:
    """``count`` contact pixels (row * W + col) drawn uniformly without replacement from the mask.

    Args:
        key: PRNG key.
        mask: (H, W) contact mask.
        count: P, the fixed number of pixels returned.

    Returns:
        pixel indices (P,) and valid (P,): False for the padding when the mask has fewer than P
        pixels.
    """
    flat_mask = mask.reshape(-1)
    # Random scores, contact pixels first: the top P are a uniform sample of the patch.
    scores = jax.random.uniform(key, flat_mask.shape) + flat_mask.astype(jnp.float32)
    _, index = jax.lax.top_k(scores, count)
    return index, flat_mask[index]


def sample_contact_points(
    key: PRNGKeyArray,
    heightmap: Float[Array, "H W"],
    mask: Bool[Array, "H W"],
    mm_per_px: float,
    count: int,
) -> tuple[Float[Array, "P 3"], Float[Array, "P 3"], Bool[Array, "P"]]:
    """``count`` contact points drawn uniformly without replacement from the mask
    (:func:`sample_contact_pixels`).

    Args:
        key: PRNG key.
        heightmap: (H, W) indentation depth, mm.
        mask: (H, W) contact mask.
        mm_per_px: pixel pitch, mm.
        count: P, the fixed number of points returned.

    Returns:
        points (P, 3) and unit normals (P, 3) in the sensor frame, mm, and valid (P,): False
        for the padding when the mask has fewer than P pixels.
    """
    index, valid = sample_contact_pixels(key, mask, count)
    points = heightmap_to_points(heightmap, mm_per_px).reshape(-1, 3)[index]
    normals = heightmap_normals(heightmap, mm_per_px).reshape(-1, 3)[index]
    return points, normals, valid


@functools.partial(jax.jit, static_argnames=("count", "observed_only"))
def _predict_and_sample(model: ShapeModel, keys, images, count: int, observed_only: bool):
    """(packed heightmaps, contact pixels and validity, surface pixels and validity) of a batch;
    the surface pixels are sampled from the whole predicted mask (the contact pixels' mask without
    ``observed_only``)."""
    heightmaps, predicted = predict_batch(model, images)
    masks = predicted
    if observed_only:
        observe = jax.vmap(observed_contact, in_axes=(0, None, 0, None))
        masks = observe(images, model.background, predicted, model.mm_per_px)
    sample = jax.vmap(sample_contact_pixels, in_axes=(0, 0, None))
    pixels, valid = sample(keys, masks, count)
    surface_keys = jax.vmap(lambda key: jax.random.fold_in(key, 1))(keys)
    surface_pixels, surface_valid = sample(surface_keys, predicted, count)
    return pack_heightmaps(heightmaps, masks), pixels, valid, surface_pixels, surface_valid


def build_tactile_map(
    model: ShapeModel,
    images: np.ndarray,
    T_world_gripper: jaxlie.SE3,
    openings: Float[Array, "K"],
    object_id: str,
    *,
    T_world_object: jaxlie.SE3 | None = None,
    points_per_imprint: int = DEFAULT_POINTS_PER_IMPRINT,
    observed_only: bool = True,
    batch_size: int = 32,
    key: PRNGKeyArray | None = None,
    keep_images: bool = True,
    progress: bool = True,
) -> TactileMap:
    """Stitch imprints into the object's tactile map (paper section V).

    Every heightmap is *predicted* from its image by ``model`` (never taken from a
    simulator's ground truth) and every imprint is placed by the gripper kinematics.

    Args:
        model: a trained shape model for the sensor that took the images.
        images: (K, H, W, 3) tactile images, uint8 or float in [0, 1].
        T_world_gripper: (K,) gripper poses at the imprints, mm.
        openings: (K,) jaw openings, mm.
        object_id: the object's name.
        T_world_object: (K,) object poses (the mapping protocol turns the object); default
            identity, i.e. the map frame is the world frame.
        points_per_imprint: P, contact points sampled per imprint.
        observed_only: keep only contact the image observes (:func:`observed_contact`) for the
            contact points; the stored masks are then those observed masks. The surface
            pixels (:attr:`TactileMap.surface_pixels`) are drawn from the whole predicted mask
            either way (without ``observed_only`` the map keeps none: they would be the contact
            points' kind).
        batch_size: images per prediction batch (the last batch is padded, so one compile).
        key: PRNG key for the point sampling (default ``jax.random.key(0)``).
        keep_images: keep the images in the map (features from another encoder need them).
        progress: show a progress bar.

    Returns:
        A :class:`TactileMap` of K imprints; imprints whose predicted mask is empty are kept
        with ``imprint_valid`` False.
    """
    images = np.asarray(images)
    check_image(model, images)
    if images.ndim != 4 or len(images) == 0:
        raise ValueError(f"images must be a non-empty (K, H, W, 3) stack, got shape {images.shape}")
    count = len(images)
    uint8 = images if images.dtype == np.uint8 else np.round(np.clip(images, 0, 1) * 255).astype(np.uint8)
    key = jax.random.key(0) if key is None else key
    parts = []
    bar = tqdm(total=count, desc=f"map {object_id}", unit="imprint", disable=not progress)
    for start in range(0, count, batch_size):
        index = np.minimum(np.arange(start, start + batch_size), count - 1)
        keys = jax.random.split(jax.random.fold_in(key, start), batch_size)
        batch = jnp.asarray(uint8[index], jnp.float32) / 255.0
        outputs = _predict_and_sample(model, keys, batch, points_per_imprint, observed_only)
        keep = min(batch_size, count - start)
        parts.append([np.asarray(x)[:keep] for x in outputs])
        bar.update(keep)
    bar.close()
    packed, pixels, valid, surface_pixels, surface_valid = (np.concatenate(column) for column in zip(*parts))
    index_dtype = pixel_index_dtype(*packed.shape[1:])
    T_object_sensor = sensor_pose(T_world_gripper, jnp.asarray(openings, jnp.float32))
    if T_world_object is not None:
        T_object_sensor = T_world_object.inverse() @ T_object_sensor
    return TactileMap(
        images=jnp.asarray(uint8) if keep_images else None,
        packed_heightmaps=jnp.asarray(packed),
        point_pixels=jnp.asarray(pixels.astype(index_dtype)),
        valid=jnp.asarray(valid),
        T_object_sensor=T_object_sensor,
        openings=jnp.asarray(openings, jnp.float32),
        features=jnp.zeros((count, 0), jnp.float32),
        imprint_valid=jnp.asarray(valid.any(axis=1)),
        object_id=object_id,
        mm_per_px=float(model.mm_per_px),
        sensor=model.sensor,
        surface_pixels=jnp.asarray(surface_pixels.astype(index_dtype)) if observed_only else None,
        surface_valid=jnp.asarray(surface_valid) if observed_only else None,
    )
