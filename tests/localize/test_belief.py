"""The pose belief: the map's surface, the contact / no-contact likelihood, fusion, symmetry, degenerate touches."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize import BeliefCalibration, LocalizationMap, StackedMaps, empty_belief
from tactojax.localize._belief import belief_terms, calibrated_log_likelihood, remember, touch_terms
from tactojax.localize._likelihood import LikelihoodSettings, point_log_likelihoods
from tactojax.localize._localize import jitted_update as update
from tactojax.localize._points import TouchEvidence, touch_evidence
from tactojax.localize._surface import MapSurface, build_map_surface
from tactojax.mapping import pack_heightmaps

CALIBRATION = BeliefCalibration(temperature=jnp.float32(0.1), appearance=jnp.float32(1.0),
                                fusion_exponent=jnp.float32(0.5))


def _evidence(touch, view, settings):
    return touch_evidence(touch, view.mm_per_px, contact_count=settings.contact_points,
                          free_count=settings.free_points)


def test_surface_matches_a_brute_force_reference(bumps_map, bumps_view, synthetic):
    """Signed distance to the tangent plane of the nearest stored point (NumPy, all points
    indented at least ``min_depth_mm``), at points near the surface; the stored points
    themselves lie on it."""
    surface = bumps_view.surface
    depth = -np.asarray(bumps_map.points)[..., 2]
    valid = np.asarray(bumps_map.point_valid) & (depth >= synthetic.surface.min_depth_mm)
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


def test_shallow_stored_points_make_no_surface(bumps_map, bumps_view, synthetic):
    """A map whose every imprint is only grazed (indented less than ``min_depth_mm``: the gel's
    skirt around an edge) knows no surface; the same points, trusted, make one."""
    surface = dataclasses.replace(synthetic.surface, min_depth_mm=0.3)
    grazed = bumps_map.replace(packed_heightmaps=pack_heightmaps(
        jnp.minimum(bumps_map.heightmaps, 0.9 * surface.min_depth_mm), bumps_map.masks))
    probes = jnp.asarray(np.asarray(grazed.points_object)[np.asarray(grazed.point_valid)][::11])
    _, known = build_map_surface(grazed, surface, grid_like=bumps_view.surface).signed_distance(probes)
    assert not np.any(np.asarray(known))
    trusted = dataclasses.replace(surface, min_depth_mm=0.0)
    distance, known = build_map_surface(grazed, trusted, grid_like=bumps_view.surface).signed_distance(probes)
    assert np.all(np.asarray(known)) and np.median(np.abs(np.asarray(distance))) < 0.02


def test_a_surface_without_imprints_keeps_the_full_maps_shapes(bumps_map, bumps_view, synthetic):
    """Leave-one-out builds each fold's surface on the full map's grid: with some imprints left
    out, or all of them, its arrays keep the full map's shapes (one compilation), and with all
    of them left out it knows nothing."""
    full = bumps_view.surface
    for left_out in (np.arange(len(bumps_view)) < 3, np.ones(len(bumps_view), bool)):
        fold = build_map_surface(bumps_map, synthetic.surface, exclude=left_out, grid_like=full)
        assert fold.blocks.shape == full.blocks.shape and fold.block_index.shape == full.block_index.shape
    _, known = fold.signed_distance(jnp.asarray(np.asarray(bumps_map.points_object)[0, :10], jnp.float32))
    assert not np.any(np.asarray(known)) and np.all(np.isnan(np.asarray(fold.distance)))


def _trilinear_reference(dense, origin, pitch, points):
    """NumPy: trilinear interpolation over the known (finite) corners of each point's cell, weights
    renormalised; unknown (0) outside the grid or with no known corner."""
    shape = np.array(dense.shape)
    values, known = [], []
    for p in points:
        cell = (p - origin) / pitch
        if np.any(cell < 0) or np.any(cell > shape - 1):
            values.append(0.0), known.append(False)
            continue
        low = np.clip(np.floor(cell), 0, shape - 2).astype(int)
        total = weighted = 0.0
        for corner in np.ndindex(2, 2, 2):
            value = dense[tuple(low + corner)]
            if np.isfinite(value):
                w = np.prod([f if c else 1 - f for c, f in zip(corner, cell - low)]) + 1e-6
                total, weighted = total + w, weighted + w * value
        values.append(weighted / total if total > 0 else 0.0), known.append(total > 0)
    return np.array(values), np.array(known)


def test_sparse_surface_reads_like_its_dense_grid():
    """Stored in blocks (only those with a known cell), the grid reads as the dense one does;
    padding to a larger shape changes no read."""
    rng = np.random.default_rng(4)
    shape, origin, pitch = (13, 10, 7), np.array([-1.0, 2.0, 0.5]), 0.5
    dense = np.where(rng.uniform(size=shape) < 0.15, rng.uniform(-3.0, 3.0, shape), np.nan).astype(np.float32)
    dense[:5] = np.nan  # whole unknown blocks
    points = origin + rng.uniform(-1.0, np.array(shape) * pitch + 0.5, (400, 3))
    points = np.concatenate([points, origin + np.argwhere(np.isfinite(dense))[:20] * pitch])  # exactly on cells
    # The grid it represents: extended to whole blocks of 4 cells with unknown ones.
    whole = np.pad(dense, [(0, -n % 4) for n in shape], constant_values=np.nan)
    expected, expected_known = _trilinear_reference(whole, origin, pitch, points)
    surface = MapSurface.from_dense(dense, origin, pitch)
    assert surface.blocks.shape[0] < np.prod(surface.block_index.shape) + 1  # not every block is stored
    np.testing.assert_allclose(np.asarray(surface.distance), whole, atol=0)  # NaN where NaN
    for stored in (surface, surface.padded_to((6, 5, 4), surface.blocks.shape[0] + 3)):
        value, known = stored.signed_distance(jnp.asarray(points, jnp.float32))
        np.testing.assert_array_equal(np.asarray(known), expected_known)
        np.testing.assert_allclose(np.asarray(value), expected, atol=1e-5)
    nearest, nearest_known = surface.signed_distance(jnp.asarray(points[-20:], jnp.float32), interpolate=False)
    assert np.all(np.asarray(nearest_known))
    np.testing.assert_allclose(np.asarray(nearest), dense[np.isfinite(dense)][:20], atol=1e-5)


def test_likelihood_matches_a_numpy_reference():
    """A planar signed-distance field (trilinear interpolation is then exact), known for x < 1 mm."""
    pitch, shape = 0.5, (13, 11, 9)
    origin = np.array([-3.0, -2.5, -2.0])
    normal = np.array([0.1, -0.05, 1.0]) / np.linalg.norm([0.1, -0.05, 1.0])
    centre = np.array([0.0, 0.0, -0.6])
    cells = origin + np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), -1) * pitch
    field = np.where(cells[..., 0] < 1.0, (cells - centre) @ normal, np.nan)
    surface = MapSurface.from_dense(field, origin, pitch)
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


def test_no_contact_points_are_drawn_beside_the_contact_first():
    """The band is SciPy's square dilation of the mask; the band's free pixels come first, then
    the rest of the free pixels; a band of 0 mm draws over the whole pad as before."""
    from scipy.ndimage import binary_dilation

    from tactojax.localize import Touch
    from tactojax.localize._points import near_contact

    mask = np.zeros((40, 50), bool)
    mask[18:21, 30:33] = True  # a pinpoint contact
    mask[5, 5] = True
    for radius in (0, 1, 4):
        expected = binary_dilation(mask, structure=np.ones((2 * radius + 1,) * 2, bool)) if radius else mask
        np.testing.assert_array_equal(np.asarray(near_contact(jnp.asarray(mask), radius)), expected)
    mm_per_px, band_mm = 0.2, 1.0  # 5 px
    band = binary_dilation(mask, structure=np.ones((11, 11), bool)) & ~mask
    heightmap = jnp.where(jnp.asarray(mask), 0.5, 0.0)
    touch = Touch(heightmap=heightmap, mask=jnp.asarray(mask), feature=jnp.zeros(4), opening=jnp.float32(10.0))
    x, y = np.meshgrid((np.arange(50) - 24.5) * mm_per_px, (np.arange(40) - 19.5) * mm_per_px)
    for count in (32, 256):  # fewer free points than the band holds, and more
        evidence = touch_evidence(touch, mm_per_px, contact_count=16, free_count=count, free_band_mm=band_mm)
        free = np.asarray(evidence.free)
        assert np.all(np.asarray(evidence.free_valid)) and np.allclose(free[:, 2], 0.0)
        col = np.rint(free[:, 0] / mm_per_px + 24.5).astype(int)
        row = np.rint(free[:, 1] / mm_per_px + 19.5).astype(int)
        in_band = band[row, col]
        assert not mask[row, col].any()
        assert len(set(zip(row, col))) == count  # without replacement
        assert in_band[:min(count, band.sum())].all() and not in_band[band.sum():].any()
    uniform = touch_evidence(touch, mm_per_px, contact_count=16, free_count=256, free_band_mm=0.0)
    col = np.rint(np.asarray(uniform.free)[:, 0] / mm_per_px + 24.5).astype(int)
    row = np.rint(np.asarray(uniform.free)[:, 1] / mm_per_px + 19.5).astype(int)
    assert band[row, col].mean() < 0.5  # the band is a tenth of the pad
    free = np.asarray(uniform.free)
    assert np.allclose(x[row, col], free[:, 0]) and np.allclose(y[row, col], free[:, 1])


def test_one_touch_off_the_grid_is_found(bumps_view, synthetic, belief_settings):
    view = bumps_view
    T_true = synthetic.sensor_pose(1.5, -1.0)  # between grid presses (4 x 3 mm apart)
    touch = synthetic.touch(synthetic.bumps, T_true)
    belief = update(view, empty_belief(view, belief_settings), touch, jaxlie.SE3.identity(), belief_settings)
    error = np.linalg.norm(np.asarray(belief.best.translation() - T_true.translation()))
    assert error < 0.5
    assert float(jnp.sum(belief.probabilities)) == pytest.approx(1.0, abs=1e-5)
    assert 0.0 <= float(belief.probability_within()) <= 1.0 + 1e-6
    assert int(belief.touches) == 1 and np.isfinite(float(belief.log_evidence))


def test_the_reported_probability_reads_the_touches_contact_area(bumps_view, synthetic, belief_settings):
    """Each touch's contact area (its mask, mm²) is remembered, and P(within 2 mm) is the mass near
    the best times P(search found) at the touches' count and mean area: a calibration whose
    search misses less after large touches reports more for the same belief of large ones."""
    from tactojax.localize._map import REFERENCE_CONTACT_MM2

    view = bumps_view
    belief = empty_belief(view, belief_settings)
    areas = []
    for x, y in ((1.5, -1.0), (-2.0, 1.0)):
        touch = synthetic.touch(synthetic.bumps, synthetic.sensor_pose(x, y))
        areas.append(float(np.sum(np.asarray(touch.mask))) * view.mm_per_px**2)
        belief = update(view, belief, touch, synthetic.sensor_pose(x, y), belief_settings)
    np.testing.assert_allclose(np.asarray(belief.contact_mm2)[:2], areas, rtol=1e-5)
    assert float(belief.mean_contact_mm2) == pytest.approx(np.mean(areas), rel=1e-5)
    blind = belief.replace(calibration=belief.calibration.replace(
        found_offset=jnp.float32(0.5), found_slope=jnp.float32(0.0), found_contact=jnp.float32(0.0)))
    aware = blind.replace(calibration=blind.calibration.replace(found_contact=jnp.float32(2.0)))
    ratio = float(aware.probability_within()) / float(blind.probability_within())
    log_area = math.log(np.mean(areas) / REFERENCE_CONTACT_MM2)
    expected = (1 + math.exp(-0.5)) / (1 + math.exp(-(0.5 + 2.0 * log_area)))
    assert ratio == pytest.approx(expected, rel=1e-4)
    assert np.mean(areas) > REFERENCE_CONTACT_MM2 and ratio > 1.0  # larger touches than the reference


def test_the_truth_against_the_best_says_which_of_search_and_likelihood_missed(bumps_view, synthetic,
                                                                             belief_settings):
    """At the true pose, refined by the belief's own ICP, a touch on the bumps scores at least as
    well as the belief's best (found: the best is the truth); a pose 4 mm off, refined from there,
    scores worse (the likelihood would not have preferred it). Both equal the weighing by hand."""
    from tactojax.localize._belief import weigh
    from tactojax.localize.evaluation import truth_against_best

    T_true = synthetic.sensor_pose(1.5, -1.0)
    touch = synthetic.touch(synthetic.bumps, T_true)
    belief = update(bumps_view, empty_belief(bumps_view, belief_settings), touch, jaxlie.SE3.identity(),
                    belief_settings)
    best, truth = (float(x) for x in truth_against_best(bumps_view, belief, T_true, belief_settings))
    assert best == pytest.approx(float(weigh(bumps_view, belief, belief.best, belief_settings)), abs=1e-4)
    assert truth >= float(weigh(bumps_view, belief, T_true, belief_settings)) - 1e-5
    assert truth >= best - 0.05
    _, off = (float(x) for x in truth_against_best(bumps_view, belief, synthetic.sensor_pose(5.5, -1.0),
                                                   belief_settings))
    assert off < best


def test_stacked_maps_localize_every_map_as_the_map_itself(bumps_view, ridges_view, synthetic, belief_settings):
    """StackedMaps concatenates maps of different sizes (imprints, surface grid, symmetry copies)
    without padding each: one compiled update takes (stack, index) for every map, and finds
    what the map alone finds; StackedMaps.map gives each map back as it was given."""
    larger = ridges_view.padded_to(len(ridges_view) + 7)
    turn = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(jnp.pi)).wxyz_xyz[None]
    wider = MapSurface.from_dense(np.pad(np.asarray(larger.surface.distance), 5, constant_values=np.nan),
                                  larger.surface.origin - 5 * larger.surface.pitch_mm, larger.surface.pitch_mm)
    larger = larger.replace(surface=wider,
                            symmetries=jaxlie.SE3(jnp.concatenate([larger.symmetries.wxyz_xyz, turn])))
    stack = StackedMaps.from_maps([bumps_view, larger, bumps_view])  # the largest map not last
    assert stack.window_size == len(larger) and len(stack) == 3
    # Memory: the maps' own imprints and surface blocks, no padding.
    assert stack.imprints.openings.shape[0] == 2 * len(bumps_view) + len(larger)
    assert stack.blocks.shape[0] == 2 * bumps_view.surface.blocks.shape[0] + larger.surface.blocks.shape[0] - 2
    for original, index in ((bumps_view, 0), (larger, 1), (bumps_view, 2)):
        given = stack.map(index)
        for name in ("packed_heightmaps", "features", "points", "points_valid", "imprint_valid", "centres"):
            np.testing.assert_array_equal(getattr(given, name), getattr(original, name), err_msg=name)
        np.testing.assert_array_equal(given.surface.distance, original.surface.distance)
        assert given.symmetric == original.symmetric
        view = stack.view(index)
        assert len(view) == stack.window_size and int(jnp.sum(view.imprint_valid)) == int(jnp.sum(original.imprint_valid))
        # The surface read through the stack's flat index equals the map's own, known or not.
        points = jnp.asarray(np.random.default_rng(index).uniform(-12, 12, (500, 3)) * [1, 1, 0.3], jnp.float32)
        for interpolate in (True, False):
            for got, want in zip(view.surface.signed_distance(points, interpolate=interpolate),
                                 original.surface.signed_distance(points, interpolate=interpolate)):
                np.testing.assert_array_equal(got, want)
    assert not stack.map(0).symmetric and stack.map(1).symmetric and not stack.map(2).symmetric
    places = ((1.5, -1.0), (-2.0, 2.5))
    touches = [synthetic.touch(synthetic.bumps, synthetic.sensor_pose(x, y)) for x, y in places]
    program = jax.jit(lambda stack, index, belief, touch, pose: update(stack.view(index), belief, touch, pose,
                                                                         belief_settings))
    alone = empty_belief(bumps_view, belief_settings)
    for t, (x, y) in zip(touches, places):
        alone = update(bumps_view, alone, t, synthetic.sensor_pose(x, y), belief_settings)
    for index in (0, 2):  # before the largest map and after it
        belief = empty_belief(stack.view(index), belief_settings)
        for t, (x, y) in zip(touches, places):
            belief = program(stack, index, belief, t, synthetic.sensor_pose(x, y))
        np.testing.assert_allclose(belief.best.wxyz_xyz, alone.best.wxyz_xyz, atol=1e-4)
        assert float(belief.probability_within()) == pytest.approx(float(alone.probability_within()), abs=1e-4)
    program(stack, 1, empty_belief(stack.view(1), belief_settings), touches[0], synthetic.sensor_pose(*places[0]))
    assert program._cache_size() == 1  # one program for every map
    window = stack.window(2)  # from the host: the map's window, reading the stack's blocks (no copy)
    assert window.surface.blocks is stack.blocks and len(window) == stack.window_size
    np.testing.assert_array_equal(window.imprint_valid, stack.view(2).imprint_valid)
    with pytest.raises(IndexError, match="map 3 of a stack of 3"):
        stack.window(3)
    with pytest.raises(ValueError, match="mm_per_px"):
        StackedMaps.from_maps([bumps_view, bumps_view.replace(mm_per_px=bumps_view.mm_per_px * 2)])


def test_two_touches_fuse_as_brute_force_enumeration(bumps_view, synthetic, belief_settings):
    """The fused weights are the softmax of the calibrated sum of per-touch cues, recomputed
    here touch by touch (Python loop) at the belief's own hypotheses; the touches' sensor poses
    are given in a world frame where the object sits at ``T_world_object``."""
    view = bumps_view.replace(calibration=CALIBRATION)
    T_world_object = jaxlie.SE3.exp(jnp.array([40.0, -25.0, 300.0, 0.3, -0.2, 1.1]))
    T_first, T_second = synthetic.sensor_pose(-2.0, 1.0), synthetic.sensor_pose(3.0, -2.5)
    belief = empty_belief(view, belief_settings)
    assert bool(jnp.all(belief.calibration.appearance == CALIBRATION.appearance))
    touches = []
    for T in (T_first, T_second):
        touch = synthetic.touch(synthetic.bumps, T)
        belief = update(view, belief, touch, T_world_object @ T, belief_settings)
        # The touch's pose relative to the first, as the kinematics give it (float32 world poses).
        T_first_second = (T_world_object @ T_first).inverse() @ (T_world_object @ T)
        touches.append((_evidence(touch, view, belief_settings), touch.feature / jnp.linalg.norm(touch.feature),
                        T_first_second))
    valid = np.isfinite(np.asarray(belief.log_weights))
    terms_at = jax.jit(touch_terms, static_argnames=("settings",))  # one touch at one pose
    scores = []
    for m in np.flatnonzero(valid):
        hypothesis = jax.tree.map(lambda x: x[m], belief.T_object_reference)
        terms = [terms_at(view, evidence, feature, hypothesis @ T_rel, belief_settings)
                 for evidence, feature, T_rel in touches]
        geometry, similarity = (sum(float(t[i]) for t in terms) for i in (0, 1))
        scores.append(float(calibrated_log_likelihood(CALIBRATION, geometry, similarity, jnp.int32(2))))
    scores = np.array(scores)
    expected = np.exp(scores - scores.max()) / np.exp(scores - scores.max()).sum()
    np.testing.assert_allclose(np.asarray(belief.probabilities)[valid], expected, rtol=1e-3, atol=1e-5)
    log_evidence = scores.max() + np.log(np.exp(scores - scores.max()).sum())
    assert float(belief.log_evidence) == pytest.approx(log_evidence, rel=1e-4, abs=1e-3)
    assert 2.0 ** -0.5 * 0.1 == pytest.approx(float(calibrated_log_likelihood(CALIBRATION, 1.0, 0.0, jnp.int32(2))))
    # The reference is the first touch; the object's pose in the world follows from the kinematics.
    error = np.linalg.norm(np.asarray(belief.best.translation() - T_first.translation()))
    assert error < 0.5
    np.testing.assert_allclose(np.asarray(belief.T_world_reference.wxyz_xyz),
                               np.asarray((T_world_object @ T_first).wxyz_xyz), atol=1e-5)
    assert np.linalg.norm(np.asarray(belief.T_world_object.translation() - T_world_object.translation())) < 0.5
    second = belief.sensor_pose(T_world_object @ T_second)  # the second touch, in the object frame
    np.testing.assert_allclose(np.asarray(second.wxyz_xyz), np.asarray(belief.touch_pose(1).wxyz_xyz), atol=1e-4)
    assert np.linalg.norm(np.asarray(second.translation() - T_second.translation())) < 0.5


def test_cues_sum_over_the_touches_held_and_never_read_an_empty_slot(bumps_view, synthetic, belief_settings):
    """A belief of three slots holding two touches: its cues at a hypothesis are the two
    touches' own, summed (touch by touch here); the empty slot, though it holds a valid-looking
    touch, is never read (the belief's touches fill its first slots)."""
    settings = dataclasses.replace(belief_settings, max_touches=3)
    belief = empty_belief(bumps_view, settings)
    touches = []
    for x, y in ((-2.0, 1.0), (3.0, -2.5)):
        T = synthetic.sensor_pose(x, y)
        touch = synthetic.touch(synthetic.bumps, T)
        touches.append((_evidence(touch, bumps_view, settings), touch.feature / jnp.linalg.norm(touch.feature), T))
        belief = remember(belief, touches[-1][0], touch.feature, jnp.float32(1.0), touches[0][2].inverse() @ T)
    assert np.asarray(belief.touch_valid).tolist() == [True, True, False]
    stray = touches[0][0]  # a whole touch in the empty slot, valid points and all
    belief = belief.replace(evidence=jax.tree.map(lambda slots, x: slots.at[2].set(x), belief.evidence, stray),
                            features=belief.features.at[2].set(touches[0][1]))
    hypothesis = synthetic.sensor_pose(-1.5, 0.5)
    geometry, similarity = jax.jit(belief_terms, static_argnames=("settings",))(bumps_view, belief, hypothesis,
                                                                                 settings)
    terms = [touch_terms(bumps_view, evidence, feature, hypothesis @ touches[0][2].inverse() @ T, settings)
             for evidence, feature, T in touches]
    assert float(geometry) == pytest.approx(sum(float(t[0]) for t in terms), rel=1e-4)
    assert float(similarity) == pytest.approx(sum(float(t[1]) for t in terms), rel=1e-4)


def test_symmetric_map_keeps_both_copies_and_counts_them_as_one(synthetic, belief_settings):
    """An object that a half turn about z maps onto itself: a touch is then equally likely at
    its pose and at its turned copy; the belief keeps both, and given the symmetry,
    P(within 2 mm) and the modes count them as one pose."""
    def surface_fn(x, y):
        return 0.5 * (synthetic.bumps(x, y) + synthetic.bumps(-x, -y))

    symmetry = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(np.pi))
    poses = [synthetic.sensor_pose(x, y) for x, y in synthetic.grid]
    tactile_map = synthetic.make_map(surface_fn, poses + [symmetry @ T for T in poses], "symmetric", points=512)
    T_true = synthetic.sensor_pose(2.5, 1.5)
    touch = synthetic.touch(surface_fn, T_true)
    identity = jaxlie.SE3.identity().wxyz_xyz
    symmetric = LocalizationMap.from_tactile_map(
        tactile_map, surface=synthetic.surface, symmetries=jaxlie.SE3(jnp.stack([identity, symmetry.wxyz_xyz])))
    # Without the symmetry (the identity twice: the same shapes, one compilation).
    plain = symmetric.replace(symmetries=jaxlie.SE3(jnp.stack([identity, identity])))
    settings = dataclasses.replace(belief_settings, sources=8)
    beliefs = {name: update(view, empty_belief(view, settings), touch, jaxlie.SE3.identity(), settings)
               for name, view in (("plain", plain), ("symmetric", symmetric))}
    belief = beliefs["symmetric"]
    for copy in (T_true, symmetry @ T_true):
        distance = np.linalg.norm(np.asarray(belief.T_object_reference.translation() - copy.translation()), axis=-1)
        assert np.any((distance < 0.5) & (np.asarray(belief.probabilities) > 0.2))
    _, plain_mass = beliefs["plain"].modes()
    _, symmetric_mass = belief.modes()
    assert np.sort(np.asarray(plain_mass))[-2] > 0.3  # two modes of similar weight
    assert np.max(np.asarray(symmetric_mass)) > 0.9  # one mode, up to the symmetry
    # P(within 2 mm): the mass near the best, times P(the search found the truth's mode).
    found = float(belief.calibration.found_probability(belief.touches, belief.mean_contact_mm2))
    assert float(beliefs["plain"].probability_within()) < 0.7 * found
    assert float(belief.probability_within()) > 0.9 * found


def test_a_touch_free_to_slide_keeps_its_spread(bumps_view, ridges_view, synthetic, belief_settings):
    """Parallel ridges: a touch slid along them feels the same, so the belief must not be sure
    of where it is along them; on the bumps (every direction observable) it is far surer. The best
    hypothesis's probes sit 3 mm (the touch's cloud RMSE, measured here point by point) away."""
    from tactojax.localize._belief import neighbourhood_probes

    within = {}
    for name, view, yaw in (("bumps", bumps_view, 0.0), ("ridges", ridges_view, 10.0)):
        T_true = synthetic.sensor_pose(1.53, -0.96, yaw)  # off the presses' pixel grid, as a new touch is
        touch = synthetic.touch(getattr(synthetic, name), T_true)
        belief = update(view, empty_belief(view, belief_settings), touch, jaxlie.SE3.identity(), belief_settings)
        # The mass near the best (P(within 2 mm) before the search's miss rate).
        within[name] = float(belief.probability_within()) / float(
            belief.calibration.found_probability(belief.touches, belief.mean_contact_mm2))
        probes = neighbourhood_probes(view, belief, belief.best, belief_settings.probe_mm)
        evidence = _evidence(touch, view, belief_settings)
        points = np.asarray(evidence.contact)[np.asarray(evidence.contact_valid)]
        centre = np.asarray(belief.best.as_matrix(), np.float64)
        for probe in np.asarray(probes.as_matrix(), np.float64):
            moved = points @ (probe[:3, :3] - centre[:3, :3]).T + (probe[:3, 3] - centre[:3, 3])
            assert np.sqrt(np.mean(np.sum(moved**2, axis=1))) == pytest.approx(belief_settings.probe_mm, rel=0.1)
    # Off the presses' pixel grid the bumps give 0.73-0.78 (0.78 here); the 0.95 of a touch on the
    # grid came from its points lying exactly on the surface grid's cell faces.
    assert within["bumps"] > 0.7
    assert within["ridges"] < 0.5


@pytest.mark.parametrize("case", ["no contact", "one pixel", "off the map"])
def test_belief_never_holds_nan(bumps_view, synthetic, belief_settings, case):
    view = bumps_view
    touch = synthetic.touch(synthetic.bumps, synthetic.sensor_pose(0.0, 0.0)).replace(feature=view.features[0])
    if case == "no contact":
        touch = touch.replace(heightmap=jnp.zeros_like(touch.heightmap), mask=jnp.zeros_like(touch.mask))
    elif case == "one pixel":
        touch = touch.replace(mask=jnp.zeros_like(touch.mask).at[10, 10].set(True))
    else:
        heightmap, mask = synthetic.render(synthetic.bumps, synthetic.sensor_pose(60.0, 60.0, z=-3.0))
        mask = mask | (np.arange(mask.shape[1])[None, :] < 4)
        touch = touch.replace(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask))
    belief = update(view, empty_belief(view, belief_settings), touch, jaxlie.SE3.identity(), belief_settings)
    assert np.all(np.isfinite(np.asarray(belief.T_object_reference.wxyz_xyz)))
    assert not np.any(np.isnan(np.asarray(belief.log_weights)))
    assert np.isfinite(float(belief.probability_within()))
    assert np.all(np.isfinite(np.asarray(belief.T_world_object.wxyz_xyz)))
    if case == "no contact":  # nothing changes: still no hypothesis, no touch remembered
        assert np.all(np.isneginf(np.asarray(belief.log_weights)))
        assert float(belief.probability_within()) == 0.0 and int(belief.touches) == 0
        assert np.isneginf(float(belief.log_evidence))


def test_screened_candidates_are_the_exhaustive_best(bumps_view, synthetic, belief_settings):
    """Coarse to fine: screening with a quarter of the points keeps the best candidates that
    scoring every candidate with all the points (vmapped over sources and offsets) finds."""
    from tactojax.localize._belief import candidates, remember
    from tactojax.localize._correspondences import valid_centroid
    from tactojax.localize._likelihood import align_depth, log_likelihood
    from tactojax.localize._retrieval import rank_imprints

    view = bumps_view
    surface = view.surface
    feature = view.features[12]
    touch = synthetic.touch(synthetic.bumps, synthetic.sensor_pose(2.2, -1.1, 6.0)).replace(feature=feature)
    settings = dataclasses.replace(belief_settings, screened=24)  # of 4 sources x 27 offsets = 108
    evidence = _evidence(touch, view, settings)
    belief = remember(empty_belief(view, settings), evidence, feature, jnp.float32(1.0), jaxlie.SE3.identity())
    poses, scores = jax.jit(candidates, static_argnames=("settings",))(
        view, belief, evidence, feature, jnp.float32(20.0), jaxlie.SE3.identity(), settings)
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
    # (the grid's candidates come first; registrations from the sources may follow)
    np.testing.assert_allclose(np.asarray(scores)[:settings.new_hypotheses], best, rtol=1e-4, atol=1e-3)
    assert np.isfinite(np.asarray(poses.wxyz_xyz)).all()


def test_object_probability_is_the_softmax_of_every_maps_evidence(bumps_view, ridges_view, synthetic,
                                                                  belief_settings):
    """P(object) over two maps from the same touches: the softmax of each map's belief's log
    evidence, enumerated here map by map with the belief itself."""
    from tactojax.localize.evaluation import TestEpisodes, identify_episodes

    T_first, T_second = synthetic.sensor_pose(-2.0, 1.0), synthetic.sensor_pose(3.0, -2.5)
    touches = [synthetic.touch(synthetic.bumps, T) for T in (T_first, T_second)]
    poses = jaxlie.SE3(jnp.stack([T_first.wxyz_xyz, T_second.wxyz_xyz]))
    stack = lambda field: jnp.stack([getattr(t, field) for t in touches])  # noqa: E731
    episodes = TestEpisodes(
        heightmaps=stack("heightmap").reshape(1, 2, 1, *touches[0].heightmap.shape),
        masks=stack("mask").reshape(1, 2, 1, *touches[0].mask.shape),
        features=stack("feature").reshape(1, 2, 1, -1), openings=jnp.full((1, 2), 20.0),
        T_object_sensor=jaxlie.SE3(poses.wxyz_xyz.reshape(1, 2, 1, 7)),
        cloud_mean=jnp.zeros((1, 2, 1, 3)), cloud_covariance=jnp.zeros((1, 2, 1, 3, 3)))
    catalog = [bumps_view, ridges_view]
    probability = identify_episodes(catalog, episodes, fingers=1, calibration=CALIBRATION, settings=belief_settings)
    assert probability.shape == (1, 2, 2)
    evidence = []
    for view in catalog:
        view = view.replace(calibration=CALIBRATION)
        belief = empty_belief(view, belief_settings)
        for touch, T in zip(touches, (T_first, T_second)):
            belief = update(view, belief, touch, T, belief_settings)
        evidence.append(float(belief.log_evidence))
    expected = np.exp(np.array(evidence) - max(evidence))
    np.testing.assert_allclose(probability[0, 1], expected / expected.sum(), rtol=1e-4, atol=1e-6)
    assert probability[0, 1, 0] > 0.99  # the touches are of the bumps
