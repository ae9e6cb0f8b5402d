"""tactojax._struct: pytree dataclasses whose tree structures tell their classes apart.

The reference for "same structure" is what ``jax.jit`` relies on: two trees may share a compiled
program only if their structures compare equal, and structures of different classes must not.
"""

from __future__ import annotations

import dataclasses
import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import tactojax
from tactojax import _struct as struct
from tactojax.objects import Frustum, SquareFrustum, placed


@struct.dataclass
class _Disc:
    radius: jax.Array
    label: str = struct.field(pytree_node=False, default="disc")


@struct.dataclass
class _Square:
    side: jax.Array
    label: str = struct.field(pytree_node=False, default="disc")


def test_classes_with_the_same_fields_have_different_structures():
    disc, square = _Disc(jnp.float32(1.0)), _Square(jnp.float32(1.0))
    assert jax.tree.structure(disc) != jax.tree.structure(square)
    assert jax.tree.structure(disc) == jax.tree.structure(_Disc(jnp.float32(2.0)))
    assert jax.tree.structure(disc) != jax.tree.structure(_Disc(jnp.float32(1.0), label="other"))


def test_round_and_square_frustums_never_share_a_program():
    """The CI failure: a square frustum's distances computed by a round frustum's program."""
    round_, square = (placed(kind(jnp.float32(20.0), jnp.float32(9.5), jnp.float32(20.0))) for kind in (Frustum, SquareFrustum))
    assert jax.tree.structure(round_) != jax.tree.structure(square)
    sdf = jax.jit(lambda solid, points: solid.sdf(points))
    points = jnp.asarray(np.random.default_rng(0).normal(size=(64, 3)) * 15.0, jnp.float32)
    for solid in (round_, square, round_, square):
        np.testing.assert_allclose(sdf(solid, points), solid.sdf(points), atol=1e-5)


def test_fields_keys_replace_and_frozen():
    disc = _Disc(jnp.float32(1.0), label="a")
    assert jax.tree.leaves(disc) == [disc.radius]
    (path, _), = jax.tree_util.tree_flatten_with_path(disc)[0]
    assert jax.tree_util.keystr(path) == ".radius"
    moved = jax.tree.map(lambda x: x + 1.0, disc)
    assert isinstance(moved, _Disc) and float(moved.radius) == 2.0 and moved.label == "a"
    assert float(disc.replace(radius=jnp.float32(3.0)).radius) == 3.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        disc.radius = jnp.float32(0.0)
    doubled = jax.jit(lambda d: d.replace(radius=2.0 * d.radius))(disc)
    assert isinstance(doubled, _Disc) and float(doubled.radius) == 2.0


def test_no_module_registers_with_flax_struct():
    """flax.struct's classes compare equal across types (see tactojax._struct): one mechanism only."""
    package = pathlib.Path(tactojax.__file__).parent
    flax_import = re.compile(r"^\s*(from flax import struct|from flax\.struct import|import flax\.struct)", re.MULTILINE)
    offenders = [str(path.relative_to(package)) for path in package.rglob("*.py") if flax_import.search(path.read_text())]
    assert offenders == []
