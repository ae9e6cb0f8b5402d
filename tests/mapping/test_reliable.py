"""Contact refinement for shape fits: the membrane skirt and depth the sensor observed.

* ``membrane_skirt`` on the simulator's own gel model (``max(rigid, G * rigid)``, then smoothed as
  a shape model smooths): the refined mask of a flat punch is the geometric contact patch (the
  closed-form rectangle) while a threshold mask spills over it; a convex cap keeps nearly all of
  its patch.
* ``depth_observed`` against a scipy reference (``np.gradient`` slopes, ``ndimage.label``
  components that hold a pixel at rest), under jit and without, vmapped against a loop.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from tactojax.mapping import depth_observed, membrane_skirt
from tactojax.sensor import gaussian_blur

MM_PER_PX = 0.2
GEL_SMOOTHING_MM = 0.5  # the gelslim preset's elastic smoothing
SHAPE = (60, 80)


def _predicted(rigid: np.ndarray) -> jnp.ndarray:
    """The gel over a rigid indentation (the simulator's model), smoothed by one pixel as a
    shape model's prediction is."""
    rigid = jnp.asarray(rigid, jnp.float32)
    gel = jnp.maximum(rigid, gaussian_blur(rigid, GEL_SMOOTHING_MM / MM_PER_PX))
    return gaussian_blur(gel, 1.0)


def _extent(mask) -> tuple[int, int, int, int]:
    mask = np.asarray(mask)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max())


def _punch() -> np.ndarray:
    """A flat face pressed 1 mm: rows 20-39, columns 25-54."""
    rigid = np.zeros(SHAPE, np.float32)
    rigid[20:40, 25:55] = 1.0
    return rigid


def _cap(radius_mm: float, depth_mm: float = 1.0, *, cylinder: bool) -> np.ndarray:
    rows, cols = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    x, y = (cols - 40) * MM_PER_PX, (rows - 30) * MM_PER_PX
    r2 = x**2 if cylinder else x**2 + y**2
    return np.maximum(np.sqrt(np.maximum(radius_mm**2 - r2, 0.0)) - (radius_mm - depth_mm), 0.0).astype(np.float32)


def test_skirt_removal_cuts_a_flat_contact_at_its_edge():
    rigid = _punch()
    heightmap = _predicted(rigid)
    mask = heightmap > 0.05  # a threshold contact mask spills over the edge by a few pixels
    assert _extent(mask) == (16, 43, 21, 58)
    contact = mask & ~membrane_skirt(heightmap, MM_PER_PX)
    assert _extent(contact) == _extent(rigid > 0)  # the geometric patch, to the pixel
    np.testing.assert_array_equal(np.asarray(contact), rigid > 0)


@pytest.mark.parametrize("radius_mm, cylinder, kept", [(25.0, True, 0.95), (11.0, True, 0.9), (10.0, False, 0.85)])
def test_skirt_removal_keeps_convex_contacts(radius_mm, cylinder, kept):
    rigid = _cap(radius_mm, cylinder=cylinder)
    heightmap = _predicted(rigid)
    contact = (heightmap > 0.05) & ~membrane_skirt(heightmap, MM_PER_PX)
    patch = rigid > 1e-3
    assert np.sum(np.asarray(contact) & patch) >= kept * patch.sum()
    # What is dropped is the rim: the middle third of the patch is all kept (away from the image
    # border, which the blurs, zero outside the image, bend).
    rows, cols = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    distance = np.abs(cols - 40) if cylinder else np.hypot(cols - 40, rows - 30)
    middle = patch & (distance * MM_PER_PX < np.sqrt(2 * radius_mm) / 3) & (rows >= 5) & (rows < SHAPE[0] - 5)
    assert np.all(np.asarray(contact)[middle])


def test_depth_is_observed_on_gentle_contacts_not_beyond_cliffs():
    punch = _predicted(_punch())  # a plateau behind a 1 mm cliff (slopes above 1)
    assert float(jnp.max(jnp.linalg.norm(jnp.stack(jnp.gradient(punch)), axis=0))) / MM_PER_PX > 1.0
    assert not np.any(np.asarray(depth_observed(punch, MM_PER_PX))[_punch() > 0])
    cap = _predicted(_cap(25.0, cylinder=True))
    assert np.mean(np.asarray(depth_observed(cap, MM_PER_PX))[_cap(25.0, cylinder=True) > 1e-3]) > 0.9


def _depth_observed_reference(heightmap: np.ndarray, max_slope: float, rest_depth_mm: float) -> np.ndarray:
    rows, cols = np.gradient(np.asarray(heightmap, np.float64))
    passable = np.hypot(rows, cols) / MM_PER_PX < max_slope
    labels, _ = ndimage.label(passable, structure=np.ones((3, 3), bool))
    seeds = np.unique(labels[passable & (heightmap < rest_depth_mm)])
    return np.isin(labels, seeds[seeds > 0])


def _random_heightmaps(count: int) -> np.ndarray:
    """Bumps, plateaus and cliffs: rest pixels, gentle slopes and steep bands in every map."""
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    maps = []
    for _ in range(count):
        heightmap = np.zeros(SHAPE)
        for _ in range(4):
            r, c, width = rng.uniform(0, SHAPE[0]), rng.uniform(0, SHAPE[1]), rng.uniform(3, 15)
            heightmap += rng.uniform(0.2, 1.0) * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2 * width**2))
        r0, c0 = rng.integers(5, 30), rng.integers(5, 40)
        heightmap[r0:r0 + 20, c0:c0 + 30] += rng.uniform(0.3, 1.0)  # a plateau with cliffs
        maps.append(heightmap)
    return np.asarray(maps, np.float32)


def test_depth_observed_matches_a_scipy_reference_jit_and_vmap():
    heightmaps = _random_heightmaps(4)
    expected = np.stack([_depth_observed_reference(h, 0.5, 0.02) for h in heightmaps])
    assert expected.any() and not expected.all()  # both kinds of pixel in the test
    compiled = jax.jit(depth_observed, static_argnames=("mm_per_px",))
    batched = jax.vmap(lambda h: depth_observed(h, MM_PER_PX))(jnp.asarray(heightmaps))
    for index, heightmap in enumerate(heightmaps):
        plain = depth_observed(jnp.asarray(heightmap), MM_PER_PX)
        np.testing.assert_array_equal(np.asarray(plain), expected[index])
        np.testing.assert_array_equal(np.asarray(compiled(jnp.asarray(heightmap), mm_per_px=MM_PER_PX)),
                                      expected[index])
        np.testing.assert_array_equal(np.asarray(batched[index]), expected[index])
    # Other thresholds, same reference.
    loose = depth_observed(jnp.asarray(heightmaps[0]), MM_PER_PX, max_slope=2.0, rest_depth_mm=0.1)
    np.testing.assert_array_equal(np.asarray(loose), _depth_observed_reference(heightmaps[0], 2.0, 0.1))


def test_membrane_skirt_matches_a_numpy_laplacian():
    heightmap = _random_heightmaps(1)[0]
    padded = np.pad(heightmap.astype(np.float64), 1, mode="reflect", reflect_type="odd")  # linear across the border
    laplacian = (padded[2:, 1:-1] + padded[:-2, 1:-1] + padded[1:-1, 2:] + padded[1:-1, :-2]
                 - 4 * heightmap) / MM_PER_PX**2
    for curvature in (0.0, 0.25, 1.0):
        skirt = np.asarray(membrane_skirt(jnp.asarray(heightmap), MM_PER_PX, curvature_per_mm=curvature))
        decided = np.abs(laplacian - curvature) > 1e-4  # float32 rounding at the threshold
        np.testing.assert_array_equal(skirt[decided], (laplacian > curvature)[decided])
