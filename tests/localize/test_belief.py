"""The pose belief: the map's surface, the contact / no-contact likelihood, fusion, symmetry, degenerate touches."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize import (BeliefCalibration, BeliefSettings, CandidateGrid, LikelihoodSettings,
                               LocalizationMap, MapSurface, SurfaceSettings, TouchEvidence, build_map_surface,
                               empty_belief, point_log_likelihoods, touch_evidence, update_belief)
from tactojax.localize._belief import calibrated_log_likelihood, touch_terms

SETTINGS = BeliefSettings(sources=4, grid=CandidateGrid(shift_mm=1.5, shift_steps=1, turn_deg=5.0, turn_steps=1),
                          new_hypotheses=6, hypotheses=8, refine=4, max_touches=2)
SURFACE = SurfaceSettings(pitch_mm=0.25, reach_mm=1.0, margin_mm=2.0)
CALIBRATION = BeliefCalibration(temperature=jnp.float32(0.1), appearance=jnp.float32(1.0),
                                fusion_exponent=jnp.float32(0.5))

update = jax.jit(update_belief, static_argnames=("settings",))


@pytest.fixture(scope="module")
def bumps(bumps_map):
    return LocalizationMap.from_tactile_map(bumps_map), build_map_surface(bumps_map, SURFACE)


def _touch(synthetic, T):
    heightmap, mask = synthetic.render(synthetic.bumps, T)
    return jnp.asarray(heightmap), jnp.asarray(mask)


def _empty(view, **options):
    return empty_belief(SETTINGS, 64, 64, view.features.shape[1], **options)


def test_surface_matches_a_brute_force_reference(bumps_map, bumps):
    """Signed distance to the tangent plane of the nearest stored point (NumPy, all points), at
    points near the surface; the stored points themselves lie on it."""
    _, surface = bumps
    valid = np.asarray(bumps_map.point_valid)
    points = np.asarray(bumps_map.points_object)[valid]
    normals = np.asarray(bumps_map.normals_object)[valid]
    rng = np.random.default_rng(0)
    probes = points[rng.choice(len(points), 200)] + rng.normal(0, 0.3, (200, 3))
    distance, known = surface.signed_distance(jnp.asarray(probes, jnp.float32))
    nearest = np.argmin(np.linalg.norm(probes[:, None] - points[None], axis=-1), axis=1)
    expected = np.sum((probes - points[nearest]) * normals[nearest], axis=-1)
    assert np.asarray(known).mean() > 0.95
    # Trilinear interpolation of a piecewise-planar field: close to the exact value, not equal.
    np.testing.assert_allclose(np.asarray(distance)[np.asarray(known)], expected[np.asarray(known)], atol=0.08)
    on_surface, _ = surface.signed_distance(jnp.asarray(points[::7], jnp.float32))
    assert np.median(np.abs(np.asarray(on_surface))) < 0.02
    far, far_known = surface.signed_distance(jnp.asarray([[0.0, 0.0, 50.0], [500.0, 0.0, 0.0]]))
    assert not np.any(np.asarray(far_known)) and np.all(np.asarray(far) == 0.0)


def test_likelihood_matches_a_numpy_reference():
    """A planar signed-distance field (trilinear interpolation is then exact), known for x < 1 mm."""
    pitch, shape = 0.5, (13, 11, 9)
    origin = np.array([-3.0, -2.5, -2.0])
    normal = np.array([0.1, -0.05, 1.0]) / np.linalg.norm([0.1, -0.05, 1.0])
    centre = np.array([0.0, 0.0, -0.6])
    cells = origin + np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), -1) * pitch
    field = np.where(cells[..., 0] < 1.0, (cells - centre) @ normal, np.nan)
    surface = MapSurface(distance=jnp.asarray(field, jnp.float32), origin=jnp.asarray(origin, jnp.float32),
                         pitch_mm=pitch)
    rng = np.random.default_rng(0)
    contact = np.stack([rng.uniform(-2.4, 0.4, 20), rng.uniform(-1.9, 1.9, 20), rng.uniform(-1.2, 0.0, 20)], -1)
    contact = np.concatenate([contact, [[2.5, 0.0, -0.5]]])  # where the map knows nothing
    free = np.stack([rng.uniform(-2.4, 0.4, 10), rng.uniform(-1.9, 1.9, 10), rng.uniform(-1.6, 0.0, 10)], -1)
    settings = LikelihoodSettings()
    evidence = TouchEvidence(contact=jnp.asarray(contact, jnp.float32), contact_valid=jnp.ones(len(contact), bool),
                             free=jnp.asarray(free, jnp.float32), free_valid=jnp.ones(len(free), bool))
    for T in (jaxlie.SE3.identity(), jaxlie.SE3.from_translation(jnp.array([0.1, -0.2, 0.15]))):
        contact_ll, free_ll = point_log_likelihoods(surface, T, evidence, settings)
        shift = np.asarray(T.translation())
        sigma, uniform = settings.sigma_mm, 1 / settings.range_mm
        expected = []
        for p in contact[:-1] + shift:
            d = (p - centre) @ normal
            gauss = math.exp(-0.5 * (d / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
            expected.append(math.log((1 - settings.outlier) * gauss + settings.outlier * uniform))
        expected.append(math.log(uniform))
        np.testing.assert_allclose(np.asarray(contact_ll), expected, rtol=1e-4, atol=1e-4)
        inside = [((p - centre) @ normal) < -settings.margin_mm for p in free + shift]
        expected_free = [math.log(settings.violation) if i else math.log1p(-settings.violation) for i in inside]
        np.testing.assert_allclose(np.asarray(free_ll), expected_free, rtol=1e-5)


def test_one_touch_off_the_grid_is_found(bumps, synthetic, bumps_map):
    view, surface = bumps
    T_true = synthetic.sensor_pose(1.5, -1.0)  # between grid presses (4 x 3 mm apart)
    heightmap, mask = _touch(synthetic, T_true)
    evidence = touch_evidence(heightmap, mask, view.mm_per_px)
    feature = jnp.asarray(synthetic.make_map(synthetic.bumps, [T_true]).features[0])
    belief = update(view, surface, _empty(view), evidence, feature, jnp.float32(20.0), jaxlie.SE3.identity(),
                    SETTINGS)
    error = np.linalg.norm(np.asarray(belief.best.translation() - T_true.translation()))
    assert error < 0.5
    assert float(jnp.sum(belief.probabilities)) == pytest.approx(1.0, abs=1e-5)
    assert 0.0 <= float(belief.probability_within()) <= 1.0 + 1e-6


def test_two_touches_fuse_as_brute_force_enumeration(bumps, synthetic):
    """The fused weights are the softmax of the calibrated sum of per-touch cues, recomputed
    here touch by touch (Python loop) at the belief's own hypotheses."""
    view, surface = bumps
    T_first, T_second = synthetic.sensor_pose(-2.0, 1.0), synthetic.sensor_pose(3.0, -2.5)
    belief = _empty(view, calibration=CALIBRATION)
    touches = []
    for T in (T_first, T_second):
        heightmap, mask = _touch(synthetic, T)
        evidence = touch_evidence(heightmap, mask, view.mm_per_px)
        feature = jnp.asarray(synthetic.make_map(synthetic.bumps, [T]).features[0])
        belief = update(view, surface, belief, evidence, feature, jnp.float32(20.0), T_first.inverse() @ T, SETTINGS)
        touches.append((evidence, feature / jnp.linalg.norm(feature), T_first.inverse() @ T))
    valid = np.isfinite(np.asarray(belief.log_weights))
    scores = []
    for m in np.flatnonzero(valid):
        hypothesis = jax.tree.map(lambda x: x[m], belief.T_object_reference)
        terms = [touch_terms(view, surface, evidence, feature, hypothesis @ T_rel, SETTINGS)
                 for evidence, feature, T_rel in touches]
        geometry, similarity = (sum(float(t[i]) for t in terms) for i in (0, 1))
        scores.append(float(calibrated_log_likelihood(CALIBRATION, geometry, similarity, jnp.int32(2))))
    scores = np.array(scores)
    expected = np.exp(scores - scores.max()) / np.exp(scores - scores.max()).sum()
    np.testing.assert_allclose(np.asarray(belief.probabilities)[valid], expected, rtol=1e-3, atol=1e-5)
    log_evidence = scores.max() + np.log(np.exp(scores - scores.max()).sum())
    assert float(belief.log_evidence) == pytest.approx(log_evidence, rel=1e-4, abs=1e-3)
    assert 2.0 ** -0.5 * 0.1 == pytest.approx(float(calibrated_log_likelihood(CALIBRATION, 1.0, 0.0, jnp.int32(2))))
    error = np.linalg.norm(np.asarray(belief.best.translation() - T_first.translation()))
    assert error < 0.5


def test_symmetric_map_keeps_both_copies_and_counts_them_as_one(synthetic):
    """An object that a half turn about z maps onto itself: a touch is then equally likely at
    its pose and at its turned copy; the belief keeps both, and given the symmetry,
    P(within 2 mm) and the modes count them as one pose."""
    def surface_fn(x, y):
        return 0.5 * (synthetic.bumps(x, y) + synthetic.bumps(-x, -y))

    symmetry = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(np.pi))
    poses = [synthetic.sensor_pose(x, y) for x, y in synthetic.grid]
    tactile_map = synthetic.make_map(surface_fn, poses + [symmetry @ T for T in poses], "symmetric", points=512)
    view, surface = LocalizationMap.from_tactile_map(tactile_map), build_map_surface(tactile_map, SURFACE)
    T_true = synthetic.sensor_pose(2.5, 1.5)
    heightmap, mask = synthetic.render(surface_fn, T_true)
    evidence = touch_evidence(jnp.asarray(heightmap), jnp.asarray(mask), view.mm_per_px)
    feature = jnp.asarray(synthetic.make_map(surface_fn, [T_true]).features[0])
    symmetries = jaxlie.SE3(jnp.stack([jaxlie.SE3.identity().wxyz_xyz, symmetry.wxyz_xyz]))
    beliefs = {}
    for name, options in (("plain", {}), ("symmetric", {"symmetries": symmetries})):
        beliefs[name] = update(view, surface, _empty(view, **options), evidence, feature, jnp.float32(20.0),
                               jaxlie.SE3.identity(), dataclasses.replace(SETTINGS, sources=8))
    belief = beliefs["symmetric"]
    for copy in (T_true, symmetry @ T_true):
        distance = np.linalg.norm(np.asarray(belief.T_object_reference.translation() - copy.translation()), axis=-1)
        assert np.any((distance < 0.5) & (np.asarray(belief.probabilities) > 0.2))
    _, plain_mass = beliefs["plain"].modes()
    _, symmetric_mass = belief.modes()
    assert np.sort(np.asarray(plain_mass))[-2] > 0.3  # two modes of similar weight
    assert np.max(np.asarray(symmetric_mass)) > 0.9  # one mode, up to the symmetry
    assert float(beliefs["plain"].probability_within()) < 0.7
    assert float(belief.probability_within()) > 0.9


@pytest.mark.parametrize("case", ["no contact", "one pixel", "off the map"])
def test_belief_never_holds_nan(bumps, synthetic, case):
    view, surface = bumps
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
    belief = update(view, surface, _empty(view), evidence, feature, jnp.float32(20.0), jaxlie.SE3.identity(),
                    SETTINGS)
    assert np.all(np.isfinite(np.asarray(belief.T_object_reference.wxyz_xyz)))
    assert not np.any(np.isnan(np.asarray(belief.log_weights)))
    assert np.isfinite(float(belief.probability_within()))
    if case == "no contact":
        assert np.all(np.isneginf(np.asarray(belief.log_weights)))
        assert float(belief.probability_within()) == 0.0


def test_screened_candidates_are_the_exhaustive_best(bumps, synthetic):
    """Coarse to fine: screening with a quarter of the points keeps the best candidates that
    scoring every candidate with all the points (vmapped over sources and offsets) finds."""
    import dataclasses

    from tactojax.localize._belief import candidates, remember
    from tactojax.localize._correspondences import valid_centroid
    from tactojax.localize._likelihood import align_depth, log_likelihood
    from tactojax.localize._retrieval import rank_imprints

    view, surface = bumps
    heightmap, mask = _touch(synthetic, synthetic.sensor_pose(2.2, -1.1, 6.0))
    evidence = touch_evidence(heightmap, mask, view.mm_per_px)
    feature = view.features[12]
    settings = dataclasses.replace(SETTINGS, screened=24)  # of 4 sources x 27 offsets = 108
    belief = remember(_empty(view), evidence, feature, jaxlie.SE3.identity())
    poses, scores = jax.jit(candidates, static_argnames=("settings",))(
        view, surface, belief, evidence, feature, jnp.float32(20.0), jaxlie.SE3.identity(), settings)
    sources, _, valid = rank_imprints(view.features @ (feature / jnp.linalg.norm(feature)), view.openings,
                                      view.imprint_valid, jnp.float32(20.0), settings.sources)
    offsets = settings.grid.offsets(valid_centroid(evidence.contact, evidence.contact_valid))
    pairs_source = jnp.repeat(sources[valid], settings.grid.size)
    pairs_offset = jax.tree.map(lambda x: jnp.tile(x, (int(valid.sum()), 1)), offsets)

    @jax.jit
    @jax.vmap
    def every_candidate(source, T):  # each with all the touch's points, no screening
        T = align_depth(surface, jax.tree.map(lambda x: x[source], view.T_object_sensor) @ T, evidence)
        return log_likelihood(surface, T, evidence, settings.coarse)

    exhaustive = np.asarray(every_candidate(pairs_source, pairs_offset))
    assert exhaustive.shape == (int(valid.sum()) * settings.grid.size,)
    best = np.sort(exhaustive)[::-1][:settings.new_hypotheses]
    np.testing.assert_allclose(np.asarray(scores), best, rtol=1e-4, atol=1e-3)
    assert np.isfinite(np.asarray(poses.wxyz_xyz)).all()


def test_object_probability_is_the_softmax_of_every_maps_evidence(bumps_map, ridges_map, synthetic):
    """P(object) over two maps from the same touches: the softmax of each map's belief's log
    evidence, enumerated here map by map with the belief itself."""
    from tactojax.localize import TestEpisodes, identify_episodes

    T_first, T_second = synthetic.sensor_pose(-2.0, 1.0), synthetic.sensor_pose(3.0, -2.5)
    touches = [_touch(synthetic, T) for T in (T_first, T_second)]
    features = jnp.asarray(synthetic.make_map(synthetic.bumps, [T_first, T_second]).features)
    poses = jaxlie.SE3(jnp.stack([T_first.wxyz_xyz, T_second.wxyz_xyz]))
    episodes = TestEpisodes(
        heightmaps=jnp.stack([h for h, _ in touches]).reshape(1, 2, 1, *touches[0][0].shape),
        masks=jnp.stack([m for _, m in touches]).reshape(1, 2, 1, *touches[0][1].shape),
        features=features.reshape(1, 2, 1, -1), openings=jnp.full((1, 2), 20.0),
        T_object_sensor=jaxlie.SE3(poses.wxyz_xyz.reshape(1, 2, 1, 7)),
        cloud_mean=jnp.zeros((1, 2, 1, 3)), cloud_covariance=jnp.zeros((1, 2, 1, 3, 3)))
    catalog = [(LocalizationMap.from_tactile_map(m), build_map_surface(m, SURFACE), None) for m in (bumps_map, ridges_map)]
    probability = identify_episodes(catalog, episodes, fingers=1, calibration=CALIBRATION, settings=SETTINGS)
    assert probability.shape == (1, 2, 2)
    evidence = []
    for view, surface, _ in catalog:
        belief = _empty(view, calibration=CALIBRATION)
        for (heightmap, mask), feature, T in zip(touches, features, (T_first, T_second)):
            belief = update(view, surface, belief, touch_evidence(heightmap, mask, view.mm_per_px), feature,
                            jnp.float32(20.0), T_first.inverse() @ T, SETTINGS)
        evidence.append(float(belief.log_evidence))
    expected = np.exp(np.array(evidence) - max(evidence))
    np.testing.assert_allclose(probability[0, 1], expected / expected.sum(), rtol=1e-4, atol=1e-6)
    assert probability[0, 1, 0] > 0.99  # the touches are of the bumps
