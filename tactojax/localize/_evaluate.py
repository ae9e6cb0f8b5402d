"""Leave-one-out evaluation of localization on a map (paper section VI, Table III, Fig. 7).

Each valid imprint in turn is the query; the map without it (``exclude``) is searched. The
error of an estimate is the RMSE between the held-out imprint's stored cloud at its true and
at its estimated pose (the paper's metric), plus translation and rotation errors of the
sensor pose and, given the object's symmetries, the symmetry-aware RMSE. Queries run vmapped
in fixed-size chunks, sharded over the devices (a mesh with one ``batch`` axis), so each method
compiles once per map size.

The belief also reads the map's surface, which holds every imprint's points: it is rebuilt
without the queries, fold by fold (``folds`` interleaved folds of the queries, each held out of
the surface and of retrieval together: a harder test than leaving one imprint out, since each
query's neighbours in its fold are gone too).
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass, field

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray
from tqdm.auto import tqdm

from tactojax.localize._baselines import baseline_estimate, estimate_pose, parse_method
from tactojax.localize._candidates import CandidateGrid
from tactojax.localize._compile import top_level_jit
from tactojax.localize._correspondences import matvec, valid_centroid
from tactojax.localize._icp import IcpSettings
from tactojax.localize._map import BeliefCalibration, LocalizationMap, map_touch
from tactojax.localize._points import POINTS_PER_TOUCH, contact_points
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM
from tactojax.localize._sharded import batch_mesh, in_batches, over_batch, run_sharded
from tactojax.localize._surface import build_map_surface
from tactojax.mapping import TactileMap

HISTOGRAM_EDGES_MM = tuple(float(x) for x in np.arange(0.0, 85.0, 5.0))
"""RMSE histogram bins, mm (the paper's histograms span 0-80 mm); larger errors overflow."""

MAP_FRACTIONS = (0.1, 0.25, 0.5, 0.75, 1.0)
"""Map sizes of the paper's Fig. 7 (fractions of the touches)."""

BELIEF_BATCH_SIZE = 4
"""Queries a device localizes at once with the belief (vmapped)."""

LEAVE_ONE_OUT_GRID = CandidateGrid(shift_mm=5.0, turn_deg=10.0)
"""The belief's candidate grid on leave-one-out: twice the default's extent (+-10 mm, +-20
degrees), with as many candidates. A new grasp lies at most half a mapping-grid step from a
stored imprint (5 mm, 10 degrees on the paper's protocol), which the default grid spans; a
held-out imprint's nearest stored neighbours sit a whole step away (10 mm, or 20 degrees), where
no default candidate reaches (on the scissors: median 14.6 mm with the default grid, 2.9 mm with
this one)."""

def cloud_rmse(
    points: Float[Array, "P 3"], valid: Bool[Array, "P"], T_a: jaxlie.SE3, T_b: jaxlie.SE3
) -> Float[Array, ""]:
    """RMSE (mm) between a cloud placed by ``T_a`` and by ``T_b`` (the paper's metric)."""
    squared = jnp.sum((T_a @ points - T_b @ points) ** 2, axis=-1)
    return jnp.sqrt(jnp.sum(jnp.where(valid, squared, 0.0)) / jnp.maximum(jnp.sum(valid), 1))


def cloud_moments(points: Float[Array, "P 3"], valid: Bool[Array, "P"]) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """Mean (mm) and covariance (mm^2) of the valid points: all :func:`moment_rmse` needs."""
    mean = valid_centroid(points, valid)
    centred = jnp.where(valid[:, None], points - mean, 0.0)
    return mean, centred.T @ centred / jnp.maximum(jnp.sum(valid), 1)


def moment_rmse(
    mean: Float[Array, "3"], covariance: Float[Array, "3 3"], T_a: jaxlie.SE3, T_b: jaxlie.SE3
) -> Float[Array, "..."]:
    """:func:`cloud_rmse` from the cloud's moments, exactly, for many poses at once.

    With ``A = R_a - R_b``, the mean of ``|T_a p - T_b p|^2`` over the cloud is
    ``tr(A C A^T) + |T_a mu - T_b mu|^2`` (mean ``mu``, covariance ``C``): a sum of two
    non-negative terms (no cancellation), and O(1) per pose pair instead of O(P). ``T_a`` and
    ``T_b`` broadcast (e.g. one true pose against every symmetric copy of an estimate).
    """
    R_a, R_b = T_a.rotation().as_matrix(), T_b.rotation().as_matrix()
    A = R_a - R_b
    offset = matvec(A, mean) + T_a.translation() - T_b.translation()
    spread = jnp.einsum("...ij,jk,...ik->...", A, covariance, A)
    return jnp.sqrt(jnp.maximum(spread, 0.0) + jnp.sum(offset**2, axis=-1))


def closest_turn_about_axis(
    mean: Float[Array, "T 3"], covariance: Float[Array, "T 3 3"], valid: Bool[Array, "T"], T_a: jaxlie.SE3,
    T_b: jaxlie.SE3, axis: Float[Array, "3"], centre: Float[Array, "3"]
) -> jaxlie.SE3:
    """The turn about a continuous symmetry axis that brings clouds placed by ``T_b`` closest to
    the same clouds placed by ``T_a`` (their mean squared distance, averaged over the valid
    clouds), in closed form: the continuous part of a symmetry-aware error.

    With ``u = T_a p - c`` and ``v = T_b p - c`` (``c`` on the axis ``n``), turning ``v`` by
    ``theta`` about ``n`` leaves ``|u - R v|^2 = |u|^2 + |v|^2 - 2 (n.u)(n.v) - 2 (q_c cos theta +
    q_s sin theta)``, with ``q_c = tr M - n^T M n``, ``q_s = sum_ij [n]x_ij M_ij`` and ``M = E[u v^T]
    = R_a C R_b^T + m_a m_b^T`` (``m`` the placed mean minus ``c``). Its minimum is at
    ``theta = atan2(q_s, q_c)``.

    Args:
        mean, covariance: (T, 3) and (T, 3, 3) the clouds' moments (:func:`cloud_moments`), mm.
        valid: (T,) which clouds count.
        T_a, T_b: (T,) the clouds' poses, object frame.
        axis: (3,) unit axis of the object's continuous rotational symmetry, object frame; zeros
            for none (the identity is returned).
        centre: (3,) a point on the axis, mm.

    Returns:
        the turn, an object-frame transform (rotation about the axis through ``centre``).
    """
    R_a, R_b = T_a.rotation().as_matrix(), T_b.rotation().as_matrix()  # (T, 3, 3)
    m_a = matvec(R_a, mean) + T_a.translation() - centre
    m_b = matvec(R_b, mean) + T_b.translation() - centre
    M = jnp.einsum("tij,tjk,tlk->til", R_a, covariance, R_b) + m_a[:, :, None] * m_b[:, None, :]
    M = jnp.sum(jnp.where(valid[:, None, None], M, 0.0), axis=0)
    skew = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    q_cos = jnp.trace(M) - axis @ M @ axis
    q_sin = jnp.sum(skew * M)
    rotation = jaxlie.SO3.exp(axis * jnp.arctan2(q_sin, q_cos))
    return jaxlie.SE3.from_rotation_and_translation(rotation, centre - rotation @ centre)


def closest_copy_square(
    mean: Float[Array, "T 3"], covariance: Float[Array, "T 3 3"], valid: Bool[Array, "T"], T_true: jaxlie.SE3,
    T_estimate: jaxlie.SE3, symmetries: jaxlie.SE3, symmetry_axis: Float[Array, "3"],
    symmetry_centre: Float[Array, "3"]
) -> Float[Array, ""]:
    """The least summed squared RMSE (mm^2) of the valid clouds (T,) between their true poses and
    a symmetric copy of their estimated ones: over every copy ``S_s T_estimate``, each also turned
    to its closest about the continuous symmetry axis (:func:`closest_turn_about_axis`; a zero
    axis turns nothing)."""
    per_touch = jax.vmap(moment_rmse)  # over clouds, each with its own moments

    def copy_square(S):
        copy = S @ T_estimate
        turn = closest_turn_about_axis(mean, covariance, valid, T_true, copy, symmetry_axis, symmetry_centre)
        squares = [jnp.sum(jnp.where(valid, per_touch(mean, covariance, T_true, T) ** 2, 0.0))
                   for T in (copy, turn @ copy)]
        return jnp.minimum(*squares)

    # A loop over the copies, not a vmap: vmapped copies nested in the new-grasps evaluation's
    # vmaps (beliefs x poses x hypotheses) crash XLA's default CPU fusion emitters (jaxlib 0.10.2:
    # a segmentation fault with two or more copies; tests/localize/test_symmetric_error.py).
    return jnp.min(jax.lax.map(copy_square, symmetries))


def pose_errors(
    points: Float[Array, "P 3"],
    valid: Bool[Array, "P"],
    T_true: jaxlie.SE3,
    T_estimate: jaxlie.SE3,
    symmetries: jaxlie.SE3 | None = None,
    symmetry_axis: Float[Array, "3"] | None = None,
    symmetry_centre: Float[Array, "3"] | None = None,
) -> dict[str, Float[Array, ""]]:
    """RMSE (mm), translation (mm) and rotation (deg) errors of one estimate.

    Args:
        points, valid: (P, 3) the held-out imprint's cloud, sensor frame, mm, and its mask.
        T_true, T_estimate: true and estimated sensor poses in the object frame.
        symmetries: optional (S,) object-frame transforms mapping the object onto itself; the
            symmetry-aware RMSE is ``min_s RMSE(T_true p, S_s T_estimate p)``.
        symmetry_axis, symmetry_centre: (3,) the axis of a continuous rotational symmetry and a
            point on it (object frame; a zero axis for none): every copy is then also turned
            about it to its closest (:func:`closest_turn_about_axis`), so that the error does not
            depend on how finely ``symmetries`` samples the turns.

    Returns:
        ``{"rmse", "translation", "rotation", "symmetric_rmse"}`` (the last equals ``rmse``
        without symmetries).
    """
    rmse = cloud_rmse(points, valid, T_true, T_estimate)
    difference = T_true.inverse() @ T_estimate
    rotation = jnp.rad2deg(jnp.linalg.norm(difference.rotation().log()))
    translation = jnp.linalg.norm(T_true.translation() - T_estimate.translation())
    symmetric = rmse
    if symmetries is not None:
        mean, covariance = cloud_moments(points, valid)
        one = lambda T: jax.tree.map(lambda x: x[None], T)  # noqa: E731  (a set of one cloud)
        no_axis = jnp.zeros(3)
        square = closest_copy_square(mean[None], covariance[None], jnp.ones(1, bool), one(T_true), one(T_estimate),
                                     symmetries, no_axis if symmetry_axis is None else symmetry_axis,
                                     no_axis if symmetry_centre is None else symmetry_centre)
        symmetric = jnp.minimum(rmse, jnp.sqrt(square))
    return {"rmse": rmse, "translation": translation, "rotation": rotation, "symmetric_rmse": symmetric}


def oracle_imprints(
    view: LocalizationMap,
    points: Float[Array, "P 3"],
    valid: Bool[Array, "P"],
    T_true: jaxlie.SE3,
    opening: Float[Array, ""],
    n: int,
    *,
    exclude: int | Int[Array, ""] = -1,
    max_opening_difference_mm: float | Float[Array, ""] = MAX_OPENING_DIFFERENCE_MM,
) -> tuple[Int[Array, "n"], Bool[Array, "n"]]:
    """The n map imprints whose poses are truly nearest (cloud RMSE) to a query's true pose.

    A diagnostic ("oracle retrieval"): registration started from these separates the errors of
    retrieval from those of registration. The same opening filter as CTI applies.
    """
    errors = moment_rmse(*cloud_moments(points, valid), T_true, view.T_object_sensor)  # (K,), O(K)
    index = jnp.arange(len(view))
    eligible = (view.imprint_valid & (jnp.abs(view.openings - opening) < max_opening_difference_mm)
                & (index != exclude))
    _, indices = jax.lax.top_k(jnp.where(eligible, -errors, -jnp.inf), n)
    return indices, eligible[indices]


@functools.partial(top_level_jit,
                   static_argnames=("method", "settings", "points_per_touch", "oracle", "batch_size", "mesh"))
def _baseline_queries(shared, queries, method, settings, points_per_touch, oracle, batch_size, mesh):
    """Baseline estimates and errors of (Q,) held-out queries, ``batch_size`` at a time on each
    device of ``mesh``."""
    def one(shared, query):
        key, view, max_opening_difference_mm = shared
        exclude, cloud, valid, T = query
        touch = map_touch(view, exclude)
        if oracle and method.kind != "random":
            indices, indices_valid = oracle_imprints(
                view, cloud, valid, T, touch.opening, max(method.n, 1), exclude=exclude,
                max_opening_difference_mm=max_opening_difference_mm)
            points, points_valid = contact_points(touch, view.mm_per_px, points_per_touch)
            estimate = estimate_pose(view, points, points_valid, indices, indices_valid, method, settings=settings)
        else:
            estimate = baseline_estimate(jax.random.fold_in(key, exclude), view, touch, method, settings=settings,
                                         points_per_touch=points_per_touch,
                                         max_opening_difference_mm=max_opening_difference_mm, exclude=exclude)
        errors = pose_errors(cloud, valid, T, estimate.T_object_sensor, view.symmetries, view.symmetry_axis,
                             view.symmetry_centre)
        return estimate.T_object_sensor, jnp.float32(jnp.nan), estimate.imprint_index, errors

    return over_batch(lambda shared, queries: in_batches(lambda q: one(shared, q), queries, batch_size), mesh)(
        shared, queries)


@functools.partial(top_level_jit, static_argnames=("settings", "batch_size", "mesh"))
def _belief_queries(view, queries, settings, batch_size, mesh):
    """The belief's estimates and errors of (Q,) held-out queries, ``batch_size`` at a time on
    each device of ``mesh``."""
    from tactojax.localize._belief import empty_belief, update_belief  # (which imports this module's metric)

    def one(view, query):
        exclude, cloud, valid, T = query
        belief = update_belief(view, empty_belief(view, settings), map_touch(view, exclude), jaxlie.SE3.identity(),
                               settings, exclude=exclude)
        errors = pose_errors(cloud, valid, T, belief.best, view.symmetries, view.symmetry_axis, view.symmetry_centre)
        return belief.best, belief.probability_within(), jnp.int32(-1), errors

    return over_batch(lambda view, queries: in_batches(lambda q: one(view, q), queries, batch_size), mesh)(
        view, queries)


@dataclass
class LocalizationErrors:
    """Per-query errors of one method on one map, and their summary."""

    method: str
    queries: np.ndarray
    """(Q,) indices of the query imprints in the map."""
    rmse: np.ndarray
    """(Q,) cloud RMSE, mm."""
    translation: np.ndarray
    """(Q,) sensor translation error, mm."""
    rotation: np.ndarray
    """(Q,) sensor rotation error, degrees."""
    symmetric_rmse: np.ndarray
    """(Q,) symmetry-aware cloud RMSE, mm (= rmse without symmetries)."""
    probability: np.ndarray
    """(Q,) the belief's P(rmse <= 2 mm) (NaN for the baselines)."""
    imprint_index: np.ndarray
    """(Q,) the map imprint each baseline estimate started from (-1: none, or the belief)."""
    histogram_edges_mm: tuple[float, ...] = field(default=HISTOGRAM_EDGES_MM)

    def histogram(self, values: np.ndarray | None = None) -> list[int]:
        """Counts of the RMSEs in the bins, plus one last count for everything beyond."""
        values = self.rmse if values is None else values
        edges = np.asarray(self.histogram_edges_mm)
        counts, _ = np.histogram(np.clip(values, edges[0], None), bins=np.append(edges, np.inf))
        return counts.tolist()

    def summary(self) -> dict:
        """JSON-ready summary: medians, means, fractions under 2/5/10 mm, histogram."""
        def stats(x):
            return {"median": float(np.median(x)), "mean": float(np.mean(x)),
                    "p25": float(np.percentile(x, 25)), "p75": float(np.percentile(x, 75))}
        return {
            "method": self.method, "queries": int(len(self.rmse)),
            "rmse_mm": stats(self.rmse), "symmetric_rmse_mm": stats(self.symmetric_rmse),
            "translation_mm": stats(self.translation), "rotation_deg": stats(self.rotation),
            "within_mm": {str(t): float(np.mean(self.rmse <= t)) for t in (1, 2, 5, 10)},
            "symmetric_within_mm": {str(t): float(np.mean(self.symmetric_rmse <= t)) for t in (1, 2, 5, 10)},
            "histogram": {"edges_mm": list(self.histogram_edges_mm), "counts": self.histogram(),
                          "symmetric_counts": self.histogram(self.symmetric_rmse)},
        }

    def to_dict(self) -> dict:
        """Everything (per-query arrays as lists) for JSON."""
        return {name: (value.tolist() if isinstance(value, np.ndarray) else value)
                for name, value in asdict(self).items()}


def evaluate_localization(
    key: PRNGKeyArray,
    tactile_map: TactileMap,
    methods=("belief", "cti-icp-5"),
    *,
    calibration: BeliefCalibration | None = None,
    symmetries: jaxlie.SE3 | None = None,
    settings: IcpSettings = IcpSettings(),
    belief_settings=None,
    points_per_touch: int = POINTS_PER_TOUCH,
    queries=None,
    map_valid=None,
    oracle: bool = False,
    folds: int = 10,
    max_opening_difference_mm: float = MAX_OPENING_DIFFERENCE_MM,
    chunk_size: int = 32,
    pad_to_multiple: int = 256,
    devices=None,
    progress: bool = False,
) -> dict[str, LocalizationErrors]:
    """Leave-one-out localization errors of several methods on one map (paper Table III).

    Args:
        key: PRNG key.
        tactile_map: the map, with features.
        methods: ``"belief"`` and baselines (see :func:`~tactojax.localize.baselines.localize_baseline`).
        calibration: the belief's scales (default: uncalibrated).
        symmetries: (S,) the object's symmetric copies modulo turns about its continuous axis,
            for the symmetry-aware RMSE (default: the catalog's for a catalog object; see
            :attr:`~tactojax.localize.LocalizationMap.symmetries`).
        settings: ICP parameters of the baselines.
        belief_settings: the belief's parameters (default :class:`~tactojax.localize.BeliefSettings`
            with :data:`LEAVE_ONE_OUT_GRID`).
        points_per_touch: contact points of the ICP baselines.
        queries: indices of the imprints to query (default: every valid imprint).
        map_valid: (K,) optional mask of the imprints that form the map (map-size study);
            queried imprints are excluded from the map in any case.
        oracle: the baselines retrieve the imprints truly nearest to each query instead of the
            most similar (a diagnostic that separates retrieval from registration errors).
        folds: the belief's queries are held out of the map's surface in this many folds.
        max_opening_difference_mm: CTI's opening filter, mm.
        chunk_size: queries a device localizes at once with a baseline (vmapped; the belief: 4).
        pad_to_multiple: pad the map with invalid imprints to a multiple of this many, so that
            maps of similar sizes share compilations (1: no padding).
        devices: the devices the queries are sharded over (default: every local device).
        progress: show a progress bar (per chunk).

    Returns:
        ``{method name: LocalizationErrors}``.
    """
    from tactojax.localize._belief import BeliefSettings  # (which imports this module's metric)

    belief_settings = BeliefSettings(grid=LEAVE_ONE_OUT_GRID) if belief_settings is None else belief_settings
    view = LocalizationMap.from_tactile_map(tactile_map, calibration=calibration, symmetries=symmetries)
    view = view.padded(pad_to_multiple)
    if map_valid is not None:
        view = view.with_imprint_valid(jnp.asarray(map_valid, bool))
    if queries is None:
        queries = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
    queries = np.asarray(queries, np.int64)
    if len(queries) == 0:
        raise ValueError("no query imprints to evaluate")
    count = len(queries)
    mesh = batch_mesh(devices)
    results = {}
    for name in methods:
        method = parse_method(name)
        if method.kind == "belief":
            fold_of = np.arange(count) % max(1, min(folds, count))
            groups = [(np.flatnonzero(fold_of == f), _without(tactile_map, view, queries[fold_of == f]))
                      for f in range(fold_of.max() + 1)]
            largest = max(len(positions) for positions, _ in groups)  # one shape for every fold
            batch_size = min(BELIEF_BATCH_SIZE, largest)
            program = functools.partial(_belief_queries, settings=belief_settings, batch_size=batch_size, mesh=mesh)
        else:
            groups = [(np.arange(count), view)]
            batch_size = min(chunk_size, count)
            program = functools.partial(_baseline_queries, method=method, settings=settings,
                                        points_per_touch=points_per_touch, oracle=oracle, batch_size=batch_size,
                                        mesh=mesh)
        placed, outputs = [], []
        map_points = tactile_map.points  # decoded once (the map stores pixel indices)
        with tqdm(total=count, desc=f"{tactile_map.object_id} {method.name}", unit="query",
                  disable=not progress) as bar:
            for positions, group_view in groups:
                index = jnp.asarray(queries[positions], jnp.int32)
                batch = (index, map_points[index], tactile_map.valid[index],
                         jax.tree.map(lambda x: x[index], tactile_map.T_object_sensor))
                shared = (group_view if method.kind == "belief"
                          else (key, group_view, jnp.float32(max_opening_difference_mm)))
                outputs.append(run_sharded(program, shared, batch, mesh=mesh, per_device=batch_size, bar=bar))
                placed.append(positions)
        order = np.argsort(np.concatenate(placed))
        _, probability, imprint_index, errors = jax.tree.map(lambda *x: np.concatenate(x)[order], *outputs)
        results[method.name] = LocalizationErrors(
            method=method.name, queries=queries, rmse=errors["rmse"], translation=errors["translation"],
            rotation=errors["rotation"], symmetric_rmse=errors["symmetric_rmse"],
            probability=probability, imprint_index=imprint_index)
    return results


def _without(tactile_map: TactileMap, view: LocalizationMap, held_out: np.ndarray) -> LocalizationMap:
    """The map without the imprints ``held_out``: switched off, and out of its surface."""
    mask = np.zeros(len(tactile_map), bool)
    mask[held_out] = True
    return view.with_imprint_valid(~mask).replace(surface=build_map_surface(tactile_map, exclude=mask,
                                                                            grid_like=view.surface))


def map_size_study(
    key: PRNGKeyArray,
    tactile_map: TactileMap,
    methods=("cti", "cti-icp-1", "cti-icp-5"),
    *,
    fractions=MAP_FRACTIONS,
    max_queries: int | None = None,
    **options,
) -> dict[float, dict[str, LocalizationErrors]]:
    """Errors against maps built from a random fraction of the touches (paper Fig. 7).

    For a fraction f < 1, a random f of the valid imprints forms the map and the held-out
    imprints are the queries (at most ``max_queries`` of them, drawn at random); f = 1 is
    leave-one-out. The map keeps its shape (imprints are switched off), so nothing recompiles.

    Returns:
        ``{fraction: {method name: LocalizationErrors}}``.
    """
    valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
    results = {}
    for fraction in fractions:
        seed = np.asarray(jax.random.key_data(jax.random.fold_in(key, int(fraction * 1000)))).ravel()[-1]
        rng = np.random.default_rng(int(seed))
        if fraction >= 1.0:
            map_valid, queries = None, valid
        else:
            chosen = rng.choice(valid, size=max(1, int(round(fraction * len(valid)))), replace=False)
            map_valid = np.zeros(len(tactile_map), bool)
            map_valid[chosen] = True
            queries = np.setdiff1d(valid, chosen)
        if max_queries is not None and len(queries) > max_queries:
            queries = np.sort(rng.choice(queries, size=max_queries, replace=False))
        results[float(fraction)] = evaluate_localization(key, tactile_map, methods, queries=queries,
                                                         map_valid=map_valid, **options)
    return results
