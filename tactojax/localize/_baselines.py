"""The paper's one-touch methods (section VI, Table III), kept as baselines beside the belief.

- ``"random"``: the pose of a random stored imprint;
- ``"cti"``: the pose of the closest tactile imprint (cosine similarity of features, among
  imprints whose gripper opening differs by less than 2 mm);
- ``"cti-icp-N"``: ICP of the touch's contact points against the union of the N most similar
  imprints, started at the closest one (the paper's CTI-ICP-N).

:func:`localize_baseline` runs one of them on one touch, jitted; the library's answer is the
pose belief (:func:`~tactojax.localize.localize`).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from tactojax.geometry import take
from tactojax.localize._compile import top_level_jit
from tactojax.localize._icp import IcpSettings, fit_quality, icp
from tactojax.localize._map import LocalizationMap, Touch, canonical_touch
from tactojax.localize._points import POINTS_PER_TOUCH, contact_points
from tactojax.localize._pose import PoseEstimate
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM, rank_imprints

PAPER_METHODS = ("random", "cti", "cti-icp-1", "cti-icp-5")
"""The methods of the paper's Table III."""

_PATTERN = re.compile(r"^(random|cti|belief|cti-icp-(\d+))$")


@dataclass(frozen=True)
class Method:
    """A parsed method name (static)."""

    kind: str
    """``"belief"`` (the library's: :func:`~tactojax.localize.localize`), or a baseline:
    ``"random"``, ``"cti"``, ``"cti-icp"``."""
    n: int
    """Imprints retrieved (N); 1 for CTI, 0 for RANDOM."""

    @property
    def name(self) -> str:
        return self.kind if self.kind in ("random", "cti", "belief") else f"{self.kind}-{self.n}"


def parse_method(method: str | Method) -> Method:
    """Parse ``"belief"``, ``"random"``, ``"cti"`` or ``"cti-icp-N"`` (N >= 1)."""
    if isinstance(method, Method):
        return method
    match = _PATTERN.match(method.strip().lower())
    if match is None or int(match.group(2) or 1) < 1:
        raise ValueError(f"unknown localization method {method!r}: use belief, or a baseline: random, cti or "
                         "cti-icp-N with N >= 1")
    if match.group(1) in ("random", "cti", "belief"):
        return Method(match.group(1), 1 if match.group(1) == "cti" else 0)
    return Method("cti-icp", int(match.group(2)))


def random_estimate(key: PRNGKeyArray, view: LocalizationMap, exclude) -> PoseEstimate:
    """RANDOM: the pose of a uniformly drawn stored imprint (never ``exclude``)."""
    index = jnp.arange(len(view))
    eligible = view.imprint_valid & (index != exclude)
    choice = jax.random.categorical(key, jnp.where(eligible, 0.0, -jnp.inf))
    estimate = PoseEstimate.failed(take(view.T_object_sensor, choice), choice)
    return estimate.replace(converged=jnp.any(eligible))


def estimate_pose(
    view: LocalizationMap,
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    indices: Int[Array, "N"],
    indices_valid: Bool[Array, "N"],
    method: str | Method,
    *,
    settings: IcpSettings = IcpSettings(),
) -> PoseEstimate:
    """CTI or CTI-ICP-N from the retrieved imprints (most similar first): the registration step
    of :func:`localize_baseline`, after retrieval (:func:`closest_imprints`).

    Args:
        view: the map.
        points: (P, 3) the touch's contact points, sensor frame, mm; points_valid (P,).
        indices: (N,) retrieved imprints, most similar first; indices_valid (N,).
        method: ``"cti"`` or ``"cti-icp-N"`` (N = ``len(indices)``).
        settings: ICP parameters.

    Returns:
        the estimate; with no valid retrieved imprint, the identity pose, not converged.
    """
    method = parse_method(method)
    any_valid = indices_valid[0]
    first = indices[0]
    T_first = take(view.T_object_sensor, first)
    if method.kind == "cti":
        score, overlap, _ = fit_quality(view, indices[:1], indices_valid[:1], points, points_valid,
                                        T_first, settings)
        # Retrieval alone does not need contact, but a touch without any is no localization.
        estimate = PoseEstimate(T_object_sensor=T_first, score=score, overlap=overlap,
                                converged=any_valid & jnp.any(points_valid), iterations=jnp.int32(0),
                                imprint_index=first.astype(jnp.int32))
    elif method.kind == "cti-icp":
        estimate = icp(view, indices, indices_valid, points, points_valid, T_first, settings)
        estimate = estimate.replace(imprint_index=first.astype(jnp.int32))
    else:
        raise ValueError(f"estimate_pose does not handle method {method.name!r}")
    # No retrieved imprint: no estimate (identity pose, not converged).
    return jax.tree.map(lambda a, b: jnp.where(any_valid, a, b), estimate,
                        PoseEstimate.failed(jaxlie.SE3.identity(), -1))


def baseline_estimate(
    key: PRNGKeyArray,
    view: LocalizationMap,
    touch: Touch,
    method: Method,
    *,
    settings: IcpSettings = IcpSettings(),
    points_per_touch: int = POINTS_PER_TOUCH,
    max_opening_difference_mm: float | Float[Array, ""] = MAX_OPENING_DIFFERENCE_MM,
    exclude: int | Int[Array, ""] = -1,
) -> PoseEstimate:
    """:func:`localize_baseline` for one touch without the jit (vmap it for batches)."""
    if method.kind == "random":
        return random_estimate(key, view, exclude)
    if method.kind == "belief":
        raise ValueError("the belief is not a one-touch baseline: use tactojax.localize.localize")
    feature = touch.feature / jnp.maximum(jnp.linalg.norm(touch.feature), 1e-12)
    indices, _, valid = rank_imprints(
        view.features @ feature, view.openings, view.imprint_valid, touch.opening, method.n,
        max_opening_difference_mm=max_opening_difference_mm, exclude=exclude)
    points, points_valid = contact_points(touch, view.mm_per_px, points_per_touch)
    return estimate_pose(view, points, points_valid, indices, valid, method, settings=settings)


@functools.partial(top_level_jit, static_argnames=("method", "settings", "points_per_touch"))
def _localize_baseline(key, view, touch, exclude, max_opening_difference_mm, method, settings, points_per_touch):
    return baseline_estimate(key, view, touch, method, settings=settings, points_per_touch=points_per_touch,
                             max_opening_difference_mm=max_opening_difference_mm, exclude=exclude)


def localize_baseline(
    key: PRNGKeyArray,
    view: LocalizationMap,
    touch: Touch,
    *,
    method: str | Method = "cti-icp-5",
    settings: IcpSettings = IcpSettings(),
    points_per_touch: int = POINTS_PER_TOUCH,
    max_opening_difference_mm: float = MAX_OPENING_DIFFERENCE_MM,
    exclude: int | Int[Array, ""] = -1,
) -> PoseEstimate:
    """The pose of the sensor that took ``touch`` in the object (map) frame, by one of the
    paper's one-touch methods (section VI).

    Jitted: compiled once per map size, method and settings; the map, the touch, ``exclude``
    and the opening threshold are traced, so repeated calls never recompile.

    Args:
        key: PRNG key (RANDOM's draw; the other methods are deterministic).
        view: the object's map (:meth:`LocalizationMap.from_tactile_map`).
        touch: the touch.
        method: ``"random"``, ``"cti"`` or ``"cti-icp-N"``.
        settings: ICP parameters.
        points_per_touch: contact points drawn from the touch for ICP.
        max_opening_difference_mm: CTI's opening filter, mm.
        exclude: a map imprint never used (leave-one-out), -1 for none.

    Returns:
        :class:`PoseEstimate`; never NaN (``converged`` False when it failed).

    Raises:
        ValueError: the touch's mask is empty (no contact), or the method is not a baseline.
    """
    method = parse_method(method)
    if method.kind == "belief":
        raise ValueError("the belief is not a one-touch baseline: use tactojax.localize.localize")
    if not isinstance(touch.mask, jax.core.Tracer) and not np.any(np.asarray(touch.mask)):
        raise ValueError("the touch shows no contact (its mask is empty): there is nothing to localize")
    # NumPy scalars, not jnp.asarray: they travel with the call instead of costing a device
    # dispatch each (about 0.3 ms per touch on CPU), and are strongly typed (no recompilation).
    exclude = exclude.astype(jnp.int32) if isinstance(exclude, jax.Array) else np.int32(exclude)
    return _localize_baseline(key, view, canonical_touch(touch), exclude, np.float32(max_opening_difference_mm),
                              method, settings, points_per_touch)
