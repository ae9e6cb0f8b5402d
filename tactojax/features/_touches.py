"""Touches with known poses, and how well features retrieve a touch's pose neighbours.

Retrieval as the paper's CTI uses it (section VI): a query imprint is matched to the stored
imprint of the same object with the highest cosine similarity among those whose gripper
opening is within 2 mm of the query's. Here that match is scored by *pose*: it is a hit when
the matched sensor pose, in the object frame, is within ``neighbour_mm`` and ``neighbour_deg``
of the query's (a "pose neighbour"). The same pose test defines the positive pairs of the
contrastive training (:mod:`tactojax.features._contrastive`).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

OPENING_WINDOW_MM = 2.0
"""CTI compares only imprints whose gripper openings differ by less than this (paper: 2 mm)."""
NEIGHBOUR_MM = 12.0
NEIGHBOUR_DEG = 30.0
"""A retrieved pose is a hit within these of the query's: on a 10 mm mapping grid, the next
grasp along the grid (10 mm, same orientation) or the next yaw at the same place (20 deg)."""
MM_PER_RADIAN = NEIGHBOUR_MM / math.radians(NEIGHBOUR_DEG)
"""How a rotation weighs against a translation when choosing the closest symmetric copy."""


@dataclasses.dataclass(frozen=True)
class TouchData:
    """K imprints of one or more objects with their sensor poses, in host memory."""

    images: np.ndarray
    """(K, H, W, 3) uint8 RGB."""
    object_index: np.ndarray
    """(K,) int32 index into ``objects``."""
    positions: np.ndarray
    """(K, 3) float32 sensor origin in the object frame, mm (``T_object_sensor.translation()``)."""
    rotations: np.ndarray
    """(K, 3, 3) float32 sensor orientation in the object frame (``T_object_sensor.rotation()``)."""
    openings: np.ndarray
    """(K,) float32 gripper opening, mm."""
    objects: tuple[str, ...]
    """Object names."""
    symmetries: tuple[np.ndarray, ...] = ()
    """Per object, (S, 4, 4) float32 transforms ``T_object_object'`` that map the object onto
    itself, identity first (``ObjectSymmetry.transforms``); empty: no symmetry known."""

    def __len__(self) -> int:
        return len(self.images)

    def take(self, indices) -> TouchData:
        """The touches at ``indices`` (an index array or a boolean mask)."""
        return dataclasses.replace(
            self, images=self.images[indices], object_index=self.object_index[indices],
            positions=self.positions[indices], rotations=self.rotations[indices],
            openings=self.openings[indices])

    def select_objects(self, names) -> TouchData:
        """Only the touches of the named objects (object indices are kept)."""
        wanted = [self.objects.index(n) for n in names]
        return self.take(np.isin(self.object_index, wanted))

    def symmetry(self, index: int) -> np.ndarray:
        """(S, 4, 4) symmetry transforms of object ``index`` (just the identity if unknown)."""
        return self.symmetries[index] if self.symmetries else np.eye(4, dtype=np.float32)[None]


def pose_distances(
    positions_a: Float[Array, "A 3"],
    rotations_a: Float[Array, "A 3 3"],
    positions_b: Float[Array, "B 3"],
    rotations_b: Float[Array, "B 3 3"],
) -> tuple[Float[Array, "A B"], Float[Array, "A B"]]:
    """Pairwise (position distance in mm, cosine of the rotation angle) between two pose sets.

    The angle of ``R_a^T R_b`` satisfies ``cos(angle) = (trace(R_a^T R_b) - 1) / 2``;
    comparing cosines avoids the arccos (and its infinite slope at 0).
    """
    delta = positions_a[:, None, :] - positions_b[None, :, :]
    distance = jnp.sqrt(jnp.sum(delta**2, axis=-1))
    trace = jnp.einsum("aij,bij->ab", rotations_a, rotations_b)
    return distance, jnp.clip((trace - 1.0) / 2.0, -1.0, 1.0)


@functools.partial(jax.jit, static_argnames="mm_per_radian")
def symmetric_pose_distances(
    positions_a: Float[Array, "A 3"],
    rotations_a: Float[Array, "A 3 3"],
    positions_b: Float[Array, "B 3"],
    rotations_b: Float[Array, "B 3 3"],
    transforms: Float[Array, "S 4 4"],
    mm_per_radian: float = MM_PER_RADIAN,
) -> tuple[Float[Array, "A B"], Float[Array, "A B"]]:
    """:func:`pose_distances` to the closest symmetric copy of each pose b.

    Every pose b is also taken as ``T_s @ T_b`` for each symmetry transform ``T_s`` of the
    object; for each pair the copy of smallest ``distance + mm_per_radian * angle`` is kept
    (its distance and its rotation cosine are returned). With only the identity this is
    :func:`pose_distances`.
    """
    def closer(carry, transform):
        best_cost, best_distance, best_cos = carry
        rotation, translation = transform[:3, :3], transform[:3, 3]
        distance, cos_angle = pose_distances(positions_a, rotations_a, positions_b @ rotation.T + translation,
                                             jnp.einsum("ij,bjk->bik", rotation, rotations_b))
        cost = distance + mm_per_radian * jnp.arccos(cos_angle)
        better = cost < best_cost
        return (jnp.where(better, cost, best_cost), jnp.where(better, distance, best_distance),
                jnp.where(better, cos_angle, best_cos)), None

    shape = (positions_a.shape[0], positions_b.shape[0])
    initial = (jnp.full(shape, jnp.inf), jnp.full(shape, jnp.inf), jnp.full(shape, -1.0))
    (_, distance, cos_angle), _ = jax.lax.scan(closer, initial, jnp.asarray(transforms, jnp.float32))
    return distance, cos_angle


def positive_pair_mask(
    object_index: Int[Array, "B"],
    positions: Float[Array, "B 3"],
    rotations: Float[Array, "B 3 3"],
    *,
    max_distance_mm: float,
    max_angle_rad: float,
    transforms: Float[Array, "S 4 4"] | None = None,
) -> Bool[Array, "B B"]:
    """Which pairs of touches are pose neighbours: same object, sensor positions within
    ``max_distance_mm`` and orientations within ``max_angle_rad`` (the diagonal is True),
    up to the symmetry ``transforms`` of the object when given (one group for all touches)."""
    if transforms is None:
        distance, cos_angle = pose_distances(positions, rotations, positions, rotations)
    else:
        distance, cos_angle = symmetric_pose_distances(positions, rotations, positions, rotations, transforms)
    same = object_index[:, None] == object_index[None, :]
    return same & (distance <= max_distance_mm) & (cos_angle >= math.cos(max_angle_rad) - 1e-6)


def object_pose_distances(
    touches: TouchData, members: np.ndarray, others: np.ndarray, *, symmetric: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(distance mm, rotation cosine), (len(members), len(others)), between touches of one
    object, up to its symmetries when ``symmetric``."""
    obj = int(touches.object_index[members[0]]) if len(members) else 0
    transforms = touches.symmetry(obj) if symmetric else np.eye(4, dtype=np.float32)[None]
    distance, cos_angle = symmetric_pose_distances(
        touches.positions[members], touches.rotations[members], touches.positions[others],
        touches.rotations[others], jnp.asarray(transforms, jnp.float32))
    return np.asarray(distance), np.asarray(cos_angle)


def retrieval_accuracy(
    features: Float[Array, "K F"],
    touches: TouchData,
    *,
    queries: Bool[Array, "K"] | None = None,
    opening_window_mm: float = OPENING_WINDOW_MM,
    neighbour_mm: float = NEIGHBOUR_MM,
    neighbour_deg: float = NEIGHBOUR_DEG,
    symmetric: bool = True,
) -> dict:
    """Leave-one-out CTI retrieval scored by pose (see the module docstring).

    Each query is matched against every *other* touch of its object whose opening is within
    ``opening_window_mm`` (the candidates); the top-1 is the candidate of highest cosine
    similarity.

    Args:
        features: (K, F) unit feature vectors of ``touches``.
        touches: the touches with their poses and openings.
        queries: (K,) which touches to query (default all).
        opening_window_mm, neighbour_mm, neighbour_deg: see the module constants.
        symmetric: compare poses up to the object's symmetries (``touches.symmetries``): on a
            tape roll, a match rotated about the roll's axis found the contact exactly.

    Returns:
        ``{"queries": number with at least one candidate, "top1_rate": fraction whose top-1 is a
        pose neighbour, "oracle_rate": fraction that have any pose-neighbour candidate,
        "chance_rate": expected rate of a uniformly random candidate, "median_top1_mm" and
        "median_top1_deg": median distance and angle between the query's and the top-1's
        poses, "per_query": {"index", "top1", "distance_mm", "angle_deg", "hit"}}``.
    """
    features = np.asarray(features, np.float32)
    queries = np.ones(len(touches), bool) if queries is None else np.asarray(queries, bool)
    cos_limit = math.cos(math.radians(neighbour_deg)) - 1e-6
    rows = {"index": [], "top1": [], "distance_mm": [], "angle_deg": [], "hit": []}
    oracle, chance = [], []
    for obj in np.unique(touches.object_index):
        members = np.flatnonzero(touches.object_index == obj)
        asked = members[queries[members]]
        if len(asked) == 0:
            continue
        similarity = features[asked] @ features[members].T
        distance, cos_angle = object_pose_distances(touches, asked, members, symmetric=symmetric)
        gap = np.abs(touches.openings[asked][:, None] - touches.openings[members][None, :])
        candidate = (gap <= opening_window_mm) & (asked[:, None] != members[None, :])
        neighbour = (distance <= neighbour_mm) & (cos_angle >= cos_limit)
        has = candidate.any(axis=1)
        best = np.argmax(np.where(candidate, similarity, -np.inf), axis=1)
        pick = np.arange(len(asked))
        for name, values in (("index", asked), ("top1", members[best]), ("distance_mm", distance[pick, best]),
                             ("angle_deg", np.degrees(np.arccos(np.clip(cos_angle[pick, best], -1, 1)))),
                             ("hit", neighbour[pick, best])):
            rows[name].append(values[has])
        oracle.append((candidate & neighbour).any(axis=1)[has])
        chance.append(((candidate & neighbour).sum(1) / np.maximum(candidate.sum(1), 1))[has])
    per_query = {k: np.concatenate(v) if v else np.zeros(0) for k, v in rows.items()}
    count = len(per_query["index"])
    mean = lambda parts: float(np.mean(np.concatenate(parts))) if count else float("nan")  # noqa: E731
    median = lambda name: float(np.median(per_query[name])) if count else float("nan")  # noqa: E731
    return {"queries": count, "top1_rate": float(np.mean(per_query["hit"])) if count else float("nan"),
            "oracle_rate": mean(oracle), "chance_rate": mean(chance),
            "median_top1_mm": median("distance_mm"), "median_top1_deg": median("angle_deg"),
            "per_query": per_query}


def per_object_retrieval(features: Float[Array, "K F"], touches: TouchData, **options) -> dict[str, dict]:
    """:func:`retrieval_accuracy` of each object separately (without ``per_query``), by name."""
    results = {}
    for index, name in enumerate(touches.objects):
        mask = touches.object_index == index
        if mask.any():
            result = retrieval_accuracy(features, touches, queries=mask, **options)
            results[name] = {k: v for k, v in result.items() if k != "per_query"}
    return results
