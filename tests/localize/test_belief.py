"""The pose belief: local views, the contact / no-contact likelihood, fusion, degenerate touches."""

import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize import (BeliefSettings, CandidateGrid, LikelihoodSettings, LocalizationMap, SurfaceViews,
                               ViewSettings, build_surface_views, empty_belief, point_log_likelihoods,
                               touch_evidence, update_belief)
from tactojax.localize._belief import touch_log_likelihood

SETTINGS = BeliefSettings(sources=4, grid=CandidateGrid(shift_mm=1.5, shift_steps=1, turn_deg=5.0, turn_steps=1),
                          new_hypotheses=6, hypotheses=4, refine=4, max_touches=2)
VIEWS = ViewSettings(pitch_mm=0.5, margin_mm=2.0, neighbours=6)

update = jax.jit(update_belief, static_argnames=("settings",))


@pytest.fixture(scope="module")
def bumps(bumps_map):
    view = LocalizationMap.from_tactile_map(bumps_map)
    return view, jax.jit(build_surface_views, static_argnums=1)(view, VIEWS)


def _touch(synthetic, T):
    heightmap, mask = synthetic.render(synthetic.bumps, T)
    return jnp.asarray(heightmap), jnp.asarray(mask)


def test_view_of_an_imprint_holds_its_own_surface(bumps):
    view, views = bumps
    k = 12
    evidence = touch_evidence(view.heightmaps[k], view.masks[k], view.mm_per_px)
    surface, known, _ = views.lookup(jnp.full(64, k), evidence.contact)
    use = np.asarray(known & evidence.contact_valid)
    assert use.sum() >= 0.9 * int(evidence.contact_valid.sum())
    np.testing.assert_allclose(np.asarray(surface)[use], np.asarray(evidence.contact[:, 2])[use], atol=0.05)


def test_likelihood_matches_a_numpy_reference():
    """A planar surface (bilinear interpolation is then exact) with a free region, point by point."""
    rows, cols, pitch = 9, 11, 0.5
    x = (np.arange(cols) - (cols - 1) / 2) * pitch
    y = (np.arange(rows) - (rows - 1) / 2) * pitch
    gx, gy = np.meshgrid(x, y, indexing="xy")
    plane = lambda px, py: -0.6 + 0.1 * px - 0.05 * py  # noqa: E731
    surface = np.where(gx < 1.0, plane(gx, gy), np.nan)  # known where x < 1 mm
    free = np.where(gx >= 1.25, 0.0, -np.inf)  # free beyond
    views = SurfaceViews(surface_z=jnp.asarray(surface[None], jnp.float32), free_z=jnp.asarray(free[None], jnp.float32),
                         neighbours=jnp.zeros((1, 1), jnp.int32), neighbours_valid=jnp.ones((1, 1), bool),
                         pitch_mm=pitch)
    rng = np.random.default_rng(0)
    contact = np.stack([rng.uniform(-2.4, 0.4, 20), rng.uniform(-1.9, 1.9, 20), rng.uniform(-1.0, -0.2, 20)], -1)
    contact = np.concatenate([contact, [[2.0, 0.0, -0.5]]])  # in free space
    free_points = np.stack([rng.uniform(-2.4, 0.4, 10), rng.uniform(-1.9, 1.9, 10), np.zeros(10)], -1)
    settings = LikelihoodSettings()
    from tactojax.localize import TouchEvidence

    evidence = TouchEvidence(contact=jnp.asarray(contact, jnp.float32), contact_valid=jnp.ones(len(contact), bool),
                             free=jnp.asarray(free_points, jnp.float32), free_valid=jnp.ones(len(free_points), bool))
    contact_ll, free_ll = point_log_likelihoods(views, jnp.int32(0), jaxlie.SE3.identity(), evidence, settings)

    sigma, uniform = settings.sigma_mm, 1 / settings.range_mm
    expected = []
    for px, py, pz in contact[:-1]:
        r = pz - plane(px, py)
        gauss = math.exp(-0.5 * (r / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
        expected.append(math.log((1 - settings.outlier) * gauss + settings.outlier * uniform))
    expected.append(math.log(settings.violation))  # contact 2 mm deep into seen-free space
    np.testing.assert_allclose(np.asarray(contact_ll), expected, rtol=1e-4, atol=1e-4)
    pressed = [plane(px, py) < -settings.margin_mm for px, py, _ in free_points]
    expected_free = [math.log(settings.violation) if p else math.log1p(-settings.violation) for p in pressed]
    np.testing.assert_allclose(np.asarray(free_ll), expected_free, rtol=1e-5)


def test_one_touch_off_the_grid_is_found(bumps, synthetic, bumps_map):
    view, views = bumps
    T_true = synthetic.sensor_pose(1.5, -1.0)  # between grid presses (4 x 3 mm apart)
    heightmap, mask = _touch(synthetic, T_true)
    evidence = touch_evidence(heightmap, mask, view.mm_per_px)
    feature = jnp.asarray(synthetic.make_map(synthetic.bumps, [T_true]).features[0])
    belief = update(view, views, empty_belief(SETTINGS, 64, 64), evidence, feature, jnp.float32(20.0),
                    jaxlie.SE3.identity(), SETTINGS)
    error = np.linalg.norm(np.asarray(belief.best.translation() - T_true.translation()))
    assert error < 0.5
    assert float(jnp.sum(belief.probabilities)) == pytest.approx(1.0, abs=1e-5)
    assert 0.0 <= float(belief.probability_within()) <= 1.0 + 1e-6


def test_two_touches_fuse_as_brute_force_enumeration(bumps, synthetic):
    """The fused weights are the softmax of the summed per-touch log-likelihoods, recomputed here
    touch by touch (Python loop) at the belief's own hypotheses."""
    view, views = bumps
    T_first, T_second = synthetic.sensor_pose(-2.0, 1.0), synthetic.sensor_pose(3.0, -2.5)
    belief = empty_belief(SETTINGS, 64, 64)
    touches = []
    for T in (T_first, T_second):
        heightmap, mask = _touch(synthetic, T)
        evidence = touch_evidence(heightmap, mask, view.mm_per_px)
        feature = jnp.asarray(synthetic.make_map(synthetic.bumps, [T]).features[0])
        belief = update(view, views, belief, evidence, feature, jnp.float32(20.0), T_first.inverse() @ T, SETTINGS)
        touches.append((evidence, T_first.inverse() @ T))
    valid = np.isfinite(np.asarray(belief.log_weights))
    scores = []
    for m in np.flatnonzero(valid):
        hypothesis = jax.tree.map(lambda x: x[m], belief.T_object_reference)
        scores.append(sum(float(touch_log_likelihood(view, views, evidence, hypothesis @ T_rel, SETTINGS.likelihood))
                          for evidence, T_rel in touches))
    scores = np.array(scores)
    expected = np.exp(scores - scores.max()) / np.exp(scores - scores.max()).sum()
    np.testing.assert_allclose(np.asarray(belief.probabilities)[valid], expected, rtol=1e-3, atol=1e-5)
    error = np.linalg.norm(np.asarray(belief.best.translation() - T_first.translation()))
    assert error < 0.5


def test_symmetric_map_keeps_both_copies(synthetic):
    """A map holding every press twice, the second copy turned 180 degrees about the object z:
    a touch is then equally likely at both, and the belief keeps both."""
    grid = [(x, y) for x, y in synthetic.grid if abs(x) <= 4 and abs(y) <= 3]
    symmetry = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(np.pi))
    poses = [synthetic.sensor_pose(x, y) for x, y in grid]
    heightmaps = [synthetic.render(synthetic.bumps, T) for T in poses]
    doubled = synthetic.make_map(synthetic.bumps, poses + poses, "doubled")
    T_all = jaxlie.SE3(jnp.concatenate([jnp.stack([p.wxyz_xyz for p in poses]),
                                        jnp.stack([(symmetry @ p).wxyz_xyz for p in poses])]))
    stacked = jnp.asarray(np.stack([h for h, _ in heightmaps] * 2))
    doubled = doubled.replace(T_object_sensor=T_all, heightmaps=stacked)
    view = LocalizationMap.from_tactile_map(doubled)
    views = build_surface_views(view, VIEWS)
    T_true = synthetic.sensor_pose(0.0, 0.0)
    heightmap, mask = _touch(synthetic, T_true)
    evidence = touch_evidence(heightmap, mask, view.mm_per_px)
    belief = update(view, views, empty_belief(SETTINGS, 64, 64), evidence, view.features[len(poses) // 2],
                    jnp.float32(20.0), jaxlie.SE3.identity(), SETTINGS)
    _, mass = belief.modes()
    copies = [T_true, symmetry @ T_true]
    for copy in copies:
        distance = np.linalg.norm(np.asarray(belief.T_object_reference.translation() - copy.translation()), axis=-1)
        assert np.any((distance < 0.5) & (np.asarray(belief.probabilities) > 0.2))
    assert np.sort(np.asarray(mass))[-2] > 0.3  # two modes of similar weight


@pytest.mark.parametrize("case", ["no contact", "one pixel", "off the map"])
def test_belief_never_holds_nan(bumps, synthetic, case):
    view, views = bumps
    heightmap, mask = _touch(synthetic, synthetic.sensor_pose(0.0, 0.0))
    feature = view.features[0]
    if case == "no contact":
        heightmap, mask = jnp.zeros_like(heightmap), jnp.zeros_like(mask)
    elif case == "one pixel":
        mask = jnp.zeros_like(mask).at[10, 10].set(True)
    else:
        heightmap, mask = _touch(synthetic, synthetic.sensor_pose(60.0, 60.0, z=-3.0))
        mask = mask | (jnp.arange(mask.shape[1])[None, :] < 4)
    evidence = touch_evidence(heightmap, mask, view.mm_per_px)
    belief = update(view, views, empty_belief(SETTINGS, 64, 64), evidence, feature, jnp.float32(20.0),
                    jaxlie.SE3.identity(), SETTINGS)
    assert np.all(np.isfinite(np.asarray(belief.T_object_reference.wxyz_xyz)))
    assert not np.any(np.isnan(np.asarray(belief.log_weights)))
    assert np.isfinite(float(belief.probability_within()))
    if case == "no contact":
        assert np.all(np.isneginf(np.asarray(belief.log_weights)))
        assert float(belief.probability_within()) == 0.0


def test_screened_candidates_are_the_exhaustive_best(bumps, synthetic):
    """Coarse to fine: screening with a quarter of the points keeps the best candidates that
    scoring every candidate with all the points (a Python loop over sources and offsets) finds."""
    import dataclasses

    from tactojax.localize._belief import candidates
    from tactojax.localize._correspondences import valid_centroid
    from tactojax.localize._likelihood import align_depth, log_likelihood
    from tactojax.localize._retrieval import rank_imprints

    view, views = bumps
    heightmap, mask = _touch(synthetic, synthetic.sensor_pose(2.2, -1.1, 6.0))
    evidence = touch_evidence(heightmap, mask, view.mm_per_px)
    feature = view.features[12]
    settings = dataclasses.replace(SETTINGS, screened=24)  # of 4 sources x 27 offsets = 108
    poses, scores = jax.jit(candidates, static_argnames=("settings",))(view, views, evidence, feature, jnp.float32(20.0),
                                                                     settings)
    sources, _, valid = rank_imprints(view.features @ (feature / jnp.linalg.norm(feature)), view.openings,
                                      view.imprint_valid, jnp.float32(20.0), settings.sources)
    offsets = settings.grid.offsets(valid_centroid(evidence.contact, evidence.contact_valid))
    pairs_source = jnp.repeat(sources[valid], settings.grid.size)
    pairs_offset = jax.tree.map(lambda x: jnp.tile(x, (int(valid.sum()), 1)), offsets)

    @jax.jit
    @jax.vmap
    def every_candidate(source, T):  # each with all the touch's points, no screening
        return log_likelihood(views, source, align_depth(views, source, T, evidence), evidence, settings.coarse)

    exhaustive = np.asarray(every_candidate(pairs_source, pairs_offset))
    assert exhaustive.shape == (int(valid.sum()) * settings.grid.size,)
    best = np.sort(exhaustive)[::-1][:settings.new_hypotheses]
    np.testing.assert_allclose(np.asarray(scores), best, rtol=1e-4, atol=1e-3)
    assert np.isfinite(np.asarray(poses.wxyz_xyz)).all()
