"""Object identification among several tactile maps (paper section VII).

A query belongs to the object whose map holds the most similar imprint (cosine similarity of
features, among imprints whose gripper opening is within the CTI threshold). Maps of different
sizes are padded and stacked once, so identification jits once for a set of maps.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int
from tqdm.auto import tqdm

from tactojax import _struct as struct
from tactojax.localize._compile import top_level_jit
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM
from tactojax.mapping import TactileMap


@struct.dataclass
class MapLibrary:
    """The features of M object maps, padded to a common K (fixed shapes)."""

    features: Float[Array, "M K F"]
    """Unit-normalised once here (zero for padding), as :class:`LocalizationMap`'s, so that a
    touch's cosine similarities are one product (issue 17)."""
    openings: Float[Array, "M K"]
    valid: Bool[Array, "M K"]
    """Real, valid imprints (False for padding)."""
    object_ids: tuple[str, ...] = struct.field(pytree_node=False)

    @staticmethod
    def from_maps(maps) -> MapLibrary:
        """Stack the features of several maps (all with the same feature length F)."""
        maps = list(maps)
        if not maps:
            raise ValueError("need at least one map")
        dims = {int(m.features.shape[1]) for m in maps}
        if len(dims) != 1 or 0 in dims:
            raise ValueError(f"every map needs features of one common length > 0, got lengths {sorted(dims)}")
        size = max(len(m) for m in maps)

        def pad(x, fill):
            x = np.asarray(x)
            return np.concatenate([x, np.full((size - len(x), *x.shape[1:]), fill, x.dtype)])

        features = jnp.asarray(np.stack([pad(m.features, 0.0) for m in maps]), jnp.float32)
        return MapLibrary(
            features=features / jnp.maximum(jnp.linalg.norm(features, axis=-1, keepdims=True), 1e-12),
            openings=jnp.asarray(np.stack([pad(m.openings, np.inf) for m in maps]), jnp.float32),
            valid=jnp.asarray(np.stack([pad(m.imprint_valid, False) for m in maps])),
            object_ids=tuple(m.object_id for m in maps))


def identify(
    library: MapLibrary,
    query_feature: Float[Array, "F"],
    query_opening: Float[Array, ""],
    *,
    max_opening_difference_mm: float | Float[Array, ""] = MAX_OPENING_DIFFERENCE_MM,
    exclude: Int[Array, "M"] | None = None,
) -> tuple[Int[Array, ""], Float[Array, "M"]]:
    """The object whose map holds the imprint most similar to the query.

    Args:
        library: the stacked maps.
        query_feature: (F,) the query's features.
        query_opening: its gripper opening, mm.
        max_opening_difference_mm: only imprints whose opening differs by less are compared.
        exclude: (M,) one imprint index per map never compared (leave-one-out), -1 for none.

    Returns:
        the index of the object (into ``library.object_ids``), and (M,) the best similarity in
        every map (-inf where no imprint passes the opening filter).
    """
    exclude = jnp.full(library.valid.shape[0], -1) if exclude is None else exclude
    similarities = library.features @ (query_feature / jnp.maximum(jnp.linalg.norm(query_feature), 1e-12))
    index = jnp.arange(library.valid.shape[1])
    eligible = (library.valid & (jnp.abs(library.openings - query_opening) < max_opening_difference_mm)
                & (index[None, :] != exclude[:, None]))
    best = jnp.max(jnp.where(eligible, similarities, -jnp.inf), axis=1)
    return jnp.argmax(best), best


@top_level_jit
def _identify_batch(library, features, openings, own_map, own_index, max_opening_difference_mm):
    def one(feature, opening, own, index):
        exclude = jnp.where(jnp.arange(library.valid.shape[0]) == own, index, -1)
        return identify(library, feature, opening, max_opening_difference_mm=max_opening_difference_mm,
                        exclude=exclude)
    return jax.vmap(one)(features, openings, own_map, own_index)


@dataclass
class IdentificationResult:
    """Leave-one-out identification over the imprints of several maps."""

    object_ids: tuple[str, ...]
    true: np.ndarray
    """(Q,) object of every query."""
    predicted: np.ndarray
    """(Q,) identified object."""
    similarities: np.ndarray
    """(Q, M) best similarity in every map."""

    def accuracy(self) -> float:
        """Top-1 accuracy over all queries."""
        return float(np.mean(self.true == self.predicted))

    def confusion(self) -> np.ndarray:
        """(M, M) counts: row = true object, column = identified object."""
        count = len(self.object_ids)
        matrix = np.zeros((count, count), np.int64)
        np.add.at(matrix, (self.true, self.predicted), 1)
        return matrix

    def summary(self) -> dict:
        """JSON-ready: accuracy, per-object accuracy and the confusion matrix."""
        confusion = self.confusion()
        per_object = confusion.diagonal() / np.maximum(confusion.sum(axis=1), 1)
        return {"objects": list(self.object_ids), "queries": int(len(self.true)), "top1": self.accuracy(),
                "per_object_top1": {name: float(a) for name, a in zip(self.object_ids, per_object)},
                "confusion": confusion.tolist()}


def evaluate_identification(
    maps,
    *,
    max_opening_difference_mm: float = MAX_OPENING_DIFFERENCE_MM,
    chunk_size: int = 256,
    progress: bool = False,
) -> IdentificationResult:
    """Identify every valid imprint of every map, held out of its own map (paper section VII).

    Args:
        maps: :class:`~tactojax.mapping.TactileMap` objects of different objects, with features.
        max_opening_difference_mm: CTI's opening filter, mm.
        chunk_size: queries per vmapped batch (fixed: one compilation).
        progress: show a progress bar.

    Returns:
        :class:`IdentificationResult`.
    """
    maps: list[TactileMap] = list(maps)
    library = MapLibrary.from_maps(maps)
    own_map = np.concatenate([np.full(int(np.sum(m.imprint_valid)), i) for i, m in enumerate(maps)])
    own_index = np.concatenate([np.flatnonzero(np.asarray(m.imprint_valid)) for m in maps])
    features = np.asarray(library.features)[own_map, own_index]
    openings = np.asarray(library.openings)[own_map, own_index]
    count = len(own_map)
    padding = -count % chunk_size
    pad = lambda x: np.concatenate([x, np.repeat(x[-1:], padding, axis=0)])  # noqa: E731
    features, openings, own_map_p, own_index_p = pad(features), pad(openings), pad(own_map), pad(own_index)
    predicted, similarities = [], []
    for start in tqdm(range(0, count + padding, chunk_size), desc="identify", disable=not progress):
        part = slice(start, start + chunk_size)
        guess, best = _identify_batch(library, features[part], openings[part], own_map_p[part], own_index_p[part],
                                      jnp.float32(max_opening_difference_mm))
        predicted.append(np.asarray(guess))
        similarities.append(np.asarray(best))
    return IdentificationResult(object_ids=library.object_ids, true=own_map,
                                predicted=np.concatenate(predicted)[:count],
                                similarities=np.concatenate(similarities)[:count])
