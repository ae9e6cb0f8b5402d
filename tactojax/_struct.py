"""Frozen pytree dataclasses: ``flax.struct``'s API, with the class in the tree structure.

Every data type in tactojax is one of these (``@struct.dataclass``, ``struct.field(pytree_node=False)``
for static fields, ``.replace(**changes)``), imported as ``from tactojax import _struct as struct``.

Why not ``flax.struct`` itself: it registers classes with ``jax.tree_util.register_dataclass``, and
with JAX 0.10.2 the tree structures of two such classes compare *equal* whenever they have the same
number of array fields and equal static fields, whatever the classes and field names
(``tree_structure(Frustum(...)) == tree_structure(SquareFrustum(...))``), while their hashes differ.
``jax.jit`` finds a compiled program by the hash of its arguments' structure and confirms it by
equality, so when two hashes land in one bucket of its cache, a function traced for one class runs
the program of the other: silently wrong numbers, in one process out of many (seen in CI: a square
frustum's signed distances computed by the round frustum's program). ``register_pytree_with_keys``
compares node types, so each class keeps programs of its own.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

T = TypeVar("T")

__all__ = ["dataclass", "field"]


def field(*, pytree_node: bool = True, **kwargs: Any) -> Any:
    """A dataclass field; ``pytree_node=False`` makes it static (part of the tree structure, hashed
    by ``jax.jit``, never traced)."""
    metadata = {**kwargs.pop("metadata", {}), "pytree_node": pytree_node}
    return dataclasses.field(metadata=metadata, **kwargs)


def dataclass(cls: type[T] | None = None, /, **kwargs: Any) -> Any:
    """A frozen dataclass registered as a JAX pytree, with a ``replace(**changes)`` method.

    Array fields are the pytree's children (with attribute keys, for ``jax.tree_util`` paths);
    fields made with ``field(pytree_node=False)`` are static. Unflattening sets the fields
    directly, without ``__init__``, as transformations rebuild trees with placeholder leaves.
    """
    if cls is None:
        return lambda cls: dataclass(cls, **kwargs)
    if "replace" in cls.__dict__:
        raise TypeError(f"{cls.__name__} defines `replace`, which struct.dataclass provides")
    cls = dataclasses.dataclass(frozen=True, **kwargs)(cls)
    fields = dataclasses.fields(cls)
    children = tuple(f.name for f in fields if f.metadata.get("pytree_node", True))
    static = tuple(f.name for f in fields if not f.metadata.get("pytree_node", True))
    keys = tuple(jax.tree_util.GetAttrKey(name) for name in children)

    def flatten(tree):
        return [getattr(tree, name) for name in children], tuple(getattr(tree, name) for name in static)

    def flatten_with_keys(tree):
        return list(zip(keys, (getattr(tree, name) for name in children))), tuple(getattr(tree, name) for name in static)

    def unflatten(static_values, child_values):
        tree = object.__new__(cls)
        for name, value in zip(children, child_values):
            object.__setattr__(tree, name, value)
        for name, value in zip(static, static_values):
            object.__setattr__(tree, name, value)
        return tree

    jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten_func=flatten)
    cls.replace = lambda self, **changes: dataclasses.replace(self, **changes)
    cls.replace.__doc__ = "A copy with the given fields changed (``dataclasses.replace``)."
    return cls
