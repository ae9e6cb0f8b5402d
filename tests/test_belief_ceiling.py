"""``benchmarks/belief_ceiling.py`` against the geometry of a box, where the answer is known.

A patch pressed into a flat face slides freely along it until it reaches the face's end: the
fitting interval along the free direction is the face's length less the patch's. A patch at a
corner, its gel seeing free space past both edges, cannot move at all.
"""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.localize import MapSurface

HALF = np.array([20.0, 5.0, 15.0])  # the box's half extents, mm
PITCH = 0.5


@pytest.fixture(scope="module")
def ceiling():
    root = str(Path(__file__).resolve().parents[1])
    sys.path.insert(0, root)
    try:
        from benchmarks import belief_ceiling
    finally:
        sys.path.remove(root)
    return belief_ceiling


@pytest.fixture(scope="module")
def box_surface() -> MapSurface:
    """The box's exact signed distance (mm, > 0 outside) on a grid covering it and 10 mm around."""
    axes = [np.arange(-h - 10.0, h + 10.0 + PITCH / 2, PITCH) for h in HALF]
    cells = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    q = np.abs(cells) - HALF
    distance = np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(-1), 0.0)
    return MapSurface.from_dense(distance.astype(np.float32), np.array([a[0] for a in axes], np.float32), PITCH)


def patch(x_range, z_range, *, free_x=None, free_z=None):
    """Contact points on the box's +y face over x_range x z_range (1 mm grid), and no-contact
    points of the gel plane 1 mm inside that face's plane (where a 1 mm press puts the gel)
    over free_x x z_range and x_range x free_z."""
    def grid(xs, zs, y):
        x, z = np.meshgrid(np.arange(*xs, 1.0), np.arange(*zs, 1.0), indexing="ij")
        return np.stack([x.ravel(), np.full(x.size, y), z.ravel()], -1)

    contact = grid(x_range, z_range, HALF[1])
    free = [grid(free_x, z_range, HALF[1] - 1.0)] if free_x else []
    free += [grid(x_range, free_z, HALF[1] - 1.0)] if free_z else []
    free = np.concatenate(free) if free else np.zeros((1, 3))
    as_jax = lambda p: jnp.asarray(p, jnp.float32)  # noqa: E731
    return (as_jax(contact), jnp.ones(len(contact), bool), as_jax(free),
            jnp.asarray(np.ones(len(free), bool) if free_x or free_z else np.zeros(1, bool)))


def longest(ceiling, surface, points):
    return ceiling.longest_interval(surface, *points, jnp.zeros(3), jnp.zeros(3), ceiling.TOLERANCE_MM,
                                    np.random.default_rng(0))


def test_a_flat_press_is_free_to_slide_and_turn_in_its_face(ceiling, box_surface):
    contact, contact_valid, _, _ = patch((-4, 5), (-4, 5))
    basis, free = (np.asarray(x) for x in ceiling.free_directions(box_surface, contact, contact_valid, jnp.zeros(3),
                                                                   jnp.zeros(3)))
    assert free.sum() == 3
    # The free motions: slides along x and z, the turn about the face normal y; none moves along y.
    assert np.allclose(basis[[1, 3, 5]][:, free], 0.0, atol=1e-3)


def test_a_patch_below_an_edge_slides_along_the_edge_to_the_face_ends(ceiling, box_surface):
    # Contact 8 mm wide reaching the box's top edge, and the gel free above it: only the slide
    # along x keeps every point fitting, and the search must find it among the face's free motions.
    length = longest(ceiling, box_surface, patch((-4, 5), (HALF[2] - 6, HALF[2] + 0.5),
                                                 free_z=(HALF[2] + 1, HALF[2] + 4)))
    # The patch (x in [-4, 4]) stays on the face (x in [-20, 20]) for 16 mm each way; the
    # tolerance lets its end row hang out by up to 0.25 mm, the search steps by 0.5 mm.
    assert 31.0 <= length <= 33.5


def test_a_patch_at_a_corner_cannot_move(ceiling, box_surface):
    points = patch((HALF[0] - 8, HALF[0] + 0.5), (HALF[2] - 6, HALF[2] + 0.5),
                   free_x=(HALF[0] + 1, HALF[0] + 4), free_z=(HALF[2] + 1, HALF[2] + 4))
    assert longest(ceiling, box_surface, points) <= 1.5


def test_a_turn_about_the_symmetry_axis_is_never_free(ceiling, box_surface):
    # The box declared symmetric about its face normal through the patch: the turn in the face
    # moves nothing a symmetric error counts, so only the two slides are left free.
    contact, contact_valid, _, _ = patch((-4, 5), (-4, 5))
    centre = jnp.mean(contact, axis=0)
    basis, free = (np.asarray(x) for x in ceiling.free_directions(box_surface, contact, contact_valid,
                                                                   jnp.array([0.0, 1.0, 0.0]), centre))
    assert free.sum() == 2
    assert np.allclose(basis[3:][:, free], 0.0, atol=1e-3)  # no turn among them
