"""How much can the touches of a new-grasps episode tell at all? The share any estimator could place within 2 mm.

A belief can only be as sure as its touches allow. A grasp that presses the middle of a flat face
says nothing about where along the face it was: every pose that slides the touches along it fits
them exactly. This script measures, for every episode of a new-grasps test set and every number
of fused grasps, how far the true pose can move along the directions its touches leave free
while every touch still fits the object's *true* surface (the simulator's solid) as well as at
the truth: exact contact points no farther from it than ``--tolerance-mm`` beyond their fit at
the truth (by default the belief's own contact noise, 0.25 mm), and no exact no-contact point
of the gel pressed into it by more than that. The touches are the simulator's (exact heightmaps
and contact masks), so neither the map nor the shape model limits anything here: what remains
is what the grasps felt.

The directions searched are the free ones of the touches' Gauss-Newton information about the
pose against the cloud-RMSE metric (as the belief's neighbourhood probes find them), with the
turn about a continuous symmetry axis left out (it moves nothing a symmetric error counts):
on a flat face, its two slides and its turn. The edges a touch saw constrain those only in
combination, so a random search among them finds the longest run of fitting poses. Those
poses form an interval of length ``L`` (the cloud RMSE between its ends). With nothing else to
prefer one of them, the truth is anywhere in it, and an ideal estimator (its middle) is within
2 mm with probability ``min(1, 4 / L)``. The mean of that over the episodes is the **ceiling**
on the share within 2 mm.

It is an upper bound: it is local (a look-alike pose elsewhere on the object is not counted),
the interval is one line (a touch free to move in a plane is counted as free along a line), the
search may miss its longest, and the touches are exact. A flat face's slide fits exactly
whatever the tolerance; on a curved surface the interval grows with it (``--tolerance-mm 0.1``:
a sensor better than ours).

    python benchmarks/belief_ceiling.py gum_box.npz --test data/t-gum_box --json ceiling.json
    python benchmarks/belief_ceiling.py --quick   # smoke run: 2 episodes of 2 grasps, scissors on a 20 mm map

Primitive catalog objects (the gum box) read their exact signed distance; mesh objects (the YCB
scans) take about a minute for trimesh's. 2-4 minutes per object of 32 episodes on 2 CPU cores.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.geometry import heightmap_to_points
from tactojax.localize import BeliefSettings, LocalizationMap, MapSurface

try:  # run as ``python benchmarks/belief_ceiling.py`` or as a module
    from benchmarks._common import format_table, machine_info, map_paths, write_json
    from benchmarks.belief_limits import (REACH_MM, add_test_set_arguments, exact_touches, load_test_set,
                                          true_distance, true_surface)
except ImportError:
    from _common import format_table, machine_info, map_paths, write_json
    from belief_limits import (REACH_MM, add_test_set_arguments, exact_touches, load_test_set, true_distance,
                               true_surface)

POINTS = 128
"""Contact and no-contact points drawn from each exact touch (at random, every pixel when fewer)."""
FREE_HEIGHT_MM = 0.08
"""Outside the contact mask, a pixel indented less than this is a no-contact point (as the
likelihood draws them), mm."""
SEARCH_MM = 30.0
"""How far along a direction the fit is followed, each way (the cloud RMSE of the motion), mm."""
STEP_MM = 0.5
"""Step of that search, mm."""
NULL_INFORMATION = 1e-3
"""A motion of unit cloud RMSE that moves the contact points' distances to the surface by at
most about sqrt(this) mm RMS (0.03 mm) counts as free: a flat face's slides and turn."""
DIRECTIONS = 24
"""Directions tried per round of the search among the free ones."""
ROUNDS = 4
"""Rounds of that search."""
TOLERANCE_MM = BeliefSettings().likelihood.sigma_mm
"""How much worse than at the truth a pose's touches may fit and still count as fitting: the
belief's own noise on a contact point's distance to the surface (0.25 mm), mm."""


def episode_points(episodes, view: LocalizationMap, e: int, grasps: int, rng: np.random.Generator):
    """Episode ``e``'s first ``grasps`` grasps (every finger), at their true poses, object frame:
    (N, 3) contact points and their validity, (N, 3) no-contact points and their validity."""
    contact, contact_valid, free, free_valid = [], [], [], []
    for g in range(grasps):
        for f in range(episodes.masks.shape[2]):
            heightmap, mask = np.asarray(episodes.heightmaps[e, g, f]), np.asarray(episodes.masks[e, g, f])
            T_object_sensor = jax.tree.map(lambda x: x[e, g, f], episodes.T_object_sensor)
            points = np.asarray(T_object_sensor @ heightmap_to_points(jnp.asarray(heightmap), view.mm_per_px))
            for chosen, out, out_valid in ((mask, contact, contact_valid),
                                           (~mask & (heightmap < FREE_HEIGHT_MM), free, free_valid)):
                index = np.flatnonzero(chosen.reshape(-1))
                index = rng.choice(index, min(POINTS, len(index)), replace=False)
                drawn = np.zeros((POINTS, 3), np.float32)
                drawn[:len(index)] = points.reshape(-1, 3)[index]
                out.append(drawn)
                out_valid.append(np.arange(POINTS) < len(index))
            if not mask.any():  # a touch without contact gives no evidence at all (as the belief)
                free_valid[-1][:] = False
    return (jnp.asarray(np.concatenate(contact)), jnp.asarray(np.concatenate(contact_valid)),
            jnp.asarray(np.concatenate(free)), jnp.asarray(np.concatenate(free_valid)))


def free_directions(surface: MapSurface, points, valid, symmetry_axis, symmetry_centre):
    """(6, 6) motions (translation, rotation about the points' centroid; object frame) of unit
    cloud RMSE, in the columns, from the least to the most constrained by the contact points'
    signed distances; and (6,) which of them are free (their information at most
    ``NULL_INFORMATION``, the least constrained always). The turn about ``symmetry_axis`` (zeros:
    none) is left out: it is the last column and never free."""
    count = jnp.maximum(jnp.sum(valid), 1).astype(jnp.float32)
    centre = jnp.sum(jnp.where(valid[:, None], points, 0.0), axis=0) / count

    def moved(delta):
        return jnp.where(valid[:, None], _motion(delta, centre) @ points, 0.0)

    def distances(delta):
        distance, known = surface.signed_distance(moved(delta))
        return jnp.where(valid & known, distance, 0.0)

    J = jax.jacfwd(distances)(jnp.zeros(6))
    K = jax.jacfwd(moved)(jnp.zeros(6))
    information = J.T @ J / count
    metric = jnp.einsum("pik,pil->kl", K, K) / count + 1e-6 * jnp.eye(6)
    lower = jnp.linalg.cholesky(metric)
    whiten = jax.scipy.linalg.solve_triangular(lower, jnp.eye(6), lower=True)  # L^-1
    # The symmetry's turn, as a motion about the centroid: rotation axis, translation axis x (c - s).
    generator = jnp.concatenate([jnp.cross(symmetry_axis, centre - symmetry_centre), symmetry_axis])
    g = lower.T @ generator
    g = g / jnp.maximum(jnp.linalg.norm(g), 1e-12)
    project = jnp.eye(6) - jnp.outer(g, g)  # the identity when there is no axis (g = 0)
    values, vectors = jnp.linalg.eigh(project @ whiten @ information @ whiten.T @ project + 1e9 * jnp.outer(g, g))
    return whiten.T @ vectors, (values <= jnp.maximum(values[0], NULL_INFORMATION)) & (values < 1e8)


def _motion(delta, centre) -> jaxlie.SE3:
    """exp(delta) with its rotation about ``centre``."""
    about = jaxlie.SE3.from_translation(centre)
    return about @ jaxlie.SE3.exp(delta) @ about.inverse()


def fit_profile(surface: MapSurface, contact, contact_valid, free, free_valid, direction, steps):
    """Along ``direction`` (unit cloud RMSE), at every step ``t`` (mm): the worst contact fit
    (95th percentile of |signed distance|), the deepest no-contact point (-min signed distance),
    and the cloud RMSE of the motion, mm."""
    count = jnp.maximum(jnp.sum(contact_valid), 1).astype(jnp.float32)
    centre = jnp.sum(jnp.where(contact_valid[:, None], contact, 0.0), axis=0) / count

    def at(t):
        T = _motion(t * direction, centre)
        moved = jax.vmap(lambda p: T @ p)(contact)
        distance, known = surface.signed_distance(moved)
        fit = jnp.nanpercentile(jnp.where(contact_valid & known, jnp.abs(distance), jnp.nan), 95.0)
        fit = jnp.where(jnp.any(contact_valid & ~known), jnp.inf, fit)  # off the object's shell
        free_distance, free_known = surface.signed_distance(jax.vmap(lambda p: T @ p)(free))
        pressed = jnp.max(jnp.where(free_valid & free_known, -free_distance, -jnp.inf))
        rmse = jnp.sqrt(jnp.sum(jnp.where(contact_valid, jnp.sum((moved - contact) ** 2, -1), 0.0)) / count)
        return fit, pressed, rmse

    return jax.vmap(at)(steps)


def fitting_intervals(fit, pressed, rmse, tolerance_mm: float) -> np.ndarray:
    """(D,) per direction (rows of (D, S) profiles over steps symmetric about t = 0), the cloud
    RMSE between the two ends of the contiguous run of steps around t = 0 whose touches fit
    within ``tolerance_mm`` of their fit at the truth, mm."""
    zero = fit.shape[1] // 2
    good = (fit <= fit[:, zero:zero + 1] + tolerance_mm) & (
        pressed <= np.maximum(pressed[:, zero:zero + 1], 0.0) + tolerance_mm)
    plus = np.sum(np.cumprod(good[:, zero + 1:], axis=1), axis=1)  # good steps in a row after t = 0
    minus = np.sum(np.cumprod(good[:, :zero][:, ::-1], axis=1), axis=1)
    rows = np.arange(len(fit))
    return rmse[rows, zero + plus] + rmse[rows, zero - minus]


def longest_interval(surface: MapSurface, contact, contact_valid, free, free_valid, symmetry_axis, symmetry_centre,
                     tolerance_mm: float, rng: np.random.Generator) -> float:
    """The longest fitting interval (mm) over motions among the free directions
    (:func:`free_directions`): a random search, each round around the best so far with half the
    spread. On a flat face the free directions are its two slides and its turn, which the
    edges a touch saw constrain only in combination: the slide that follows an edge is found
    by the search, not by the linearisation."""
    basis, free_mask = (np.asarray(x) for x in _free_directions(surface, contact, contact_valid, symmetry_axis,
                                                                  symmetry_centre))
    steps = jnp.arange(-SEARCH_MM, SEARCH_MM + STEP_MM / 2, STEP_MM)

    def unit(c):
        c = np.where(free_mask, c, 0.0)
        return c / np.maximum(np.linalg.norm(c, axis=-1, keepdims=True), 1e-12)

    coefficients = np.concatenate([np.eye(6)[free_mask], unit(rng.normal(size=(DIRECTIONS, 6)))])[:DIRECTIONS]
    rounds = ROUNDS
    if free_mask.sum() == 1:  # one free direction: nothing to search
        coefficients, rounds = coefficients[:1], 1
    best, best_length = coefficients[0], -1.0
    for round_ in range(rounds):
        directions = jnp.asarray(coefficients @ basis.T, jnp.float32)  # (D, 6)
        profile = [np.asarray(x) for x in _profiles(surface, contact, contact_valid, free, free_valid, directions,
                                                    steps)]
        lengths = fitting_intervals(*profile, tolerance_mm)
        if lengths.max() > best_length:
            best, best_length = coefficients[int(np.argmax(lengths))], float(lengths.max())
        spread = 0.4 * 0.5 ** round_
        coefficients = unit(best + spread * rng.normal(size=(DIRECTIONS, 6)))
        coefficients[0] = best
    return best_length


_free_directions = jax.jit(free_directions)
_profiles = jax.jit(jax.vmap(fit_profile, in_axes=(None, None, None, None, None, 0, None)))


def ceiling_rows(view: LocalizationMap, exact_view: LocalizationMap, episodes, tolerance_mm: float,
                 progress: bool = True) -> tuple[list[dict], np.ndarray]:
    """Per number of fused grasps: the ceiling on the share within 2 mm, the share of episodes
    whose fitting interval is at most 4 mm long, and its median length; and (E, G) every
    episode's interval length, mm."""
    count, grasps = episodes.masks.shape[:2]
    length = np.zeros((count, grasps))
    rng = np.random.default_rng(0)
    for e in range(count):
        for g in range(grasps):
            contact, contact_valid, free, free_valid = episode_points(episodes, view, e, g + 1, rng)
            if not bool(jnp.any(contact_valid)):
                length[e, g] = np.inf  # nothing felt yet
                continue
            length[e, g] = longest_interval(exact_view.surface, contact, contact_valid, free, free_valid,
                                            view.symmetry_axis, view.symmetry_centre, tolerance_mm, rng)
        if progress:
            print(f"episode {e + 1}/{count}: fitting interval after each grasp "
                  + ", ".join(f"{x:.1f}" for x in length[e]) + " mm", flush=True)
    # Poses that fit more touches fit fewer: each count's longest interval is at least every later one's.
    length = np.maximum.accumulate(length[:, ::-1], axis=1)[:, ::-1]
    with np.errstate(divide="ignore"):  # an interval of length 0 is determined: 4 / 0 = inf, within 2 mm surely
        share = 4.0 / length
    rows = [{"grasps": g + 1, "ceiling_within_2mm": float(np.mean(np.minimum(1.0, share[:, g]))),
             "determined_share": float(np.mean(length[:, g] <= 4.0)),
             "median_interval_mm": float(np.median(length[:, g]))} for g in range(grasps)]
    return rows, length


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_test_set_arguments(parser)
    parser.add_argument("--tolerance-mm", type=float, default=TOLERANCE_MM,
                        help="how much worse than at the truth a pose's touches may fit and still count as fitting "
                             f"(default {TOLERANCE_MM}: the belief's contact noise)")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    view, name, test, episodes, _ = load_test_set(args)
    distance, _ = true_distance(view, name)
    exact_view = true_surface(view, distance, np.abs(distance) <= REACH_MM)
    rows, length = ceiling_rows(view, exact_view, exact_touches(episodes, test, name), args.tolerance_mm)
    print(format_table(["grasps", "ceiling: share within 2 mm", "episodes determined to 4 mm", "median interval (mm)"],
                       [[r["grasps"], f"{100 * r['ceiling_within_2mm']:.0f} %", f"{100 * r['determined_share']:.0f} %",
                         f"{r['median_interval_mm']:.1f}"] for r in rows]))
    print(f"{name}: {length.shape[0]} episodes x {episodes.masks.shape[2]} finger(s); the simulator's touches on "
          f"the object's true surface, fit within {args.tolerance_mm} mm of the truth's")
    if args.json:
        write_json(args.json, {"object": name, "map": (map_paths(args) or [name])[0], "test": str(test),
                               "tolerance_mm": args.tolerance_mm, "per_grasps": rows,
                               "interval_mm": np.where(np.isfinite(length), length, -1.0).tolist(),
                               "machine": machine_info()})


if __name__ == "__main__":
    main()
