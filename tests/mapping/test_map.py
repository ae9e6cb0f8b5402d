"""TactileMap: built from predicted heightmaps, placed by the kinematics, saved, exported."""

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tactojax.geometry import T_gripper_sensor
from tactojax.io import CorruptMapError, export_ply, load_tactile_map, open_dataset, save_tactile_map
from tactojax.mapping import (NOISE_LEVELS, KinematicNoise, perturb_kinematics, sample_contact_points,
                              stitched_point_cloud, surface_distance, voxel_downsample)
from tactojax.objects import get_object


def _matrix(wxyz_xyz: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from (..., 7) wxyz + xyz, with scipy (independent of jaxlie)."""
    wxyz_xyz = np.asarray(wxyz_xyz, np.float64)
    matrix = np.zeros((*wxyz_xyz.shape[:-1], 4, 4))
    matrix[..., :3, :3] = Rotation.from_quat(wxyz_xyz[..., [1, 2, 3, 0]]).as_matrix()
    matrix[..., :3, 3] = wxyz_xyz[..., 4:]
    matrix[..., 3, 3] = 1.0
    return matrix


def test_imprints_are_placed_by_the_kinematics(cylinder_map, mapping_dataset):
    records = open_dataset(mapping_dataset).read(["T_world_gripper", "T_world_object", "opening_mm"])
    # T_object_sensor = T_world_object^-1 T_world_gripper T_gripper_sensor(opening), in numpy.
    T_gripper_sensor_np = np.stack([_matrix(np.asarray(T_gripper_sensor(jnp.float32(o)).wxyz_xyz))
                                    for o in records["opening_mm"]])
    expected = (np.linalg.inv(_matrix(records["T_world_object"])) @ _matrix(records["T_world_gripper"])
                @ T_gripper_sensor_np)
    points = np.asarray(cylinder_map.points, np.float64)
    expected_points = np.einsum("kij,kpj->kpi", expected[:, :3, :3], points) + expected[:, None, :3, 3]
    np.testing.assert_allclose(np.asarray(cylinder_map.points_object), expected_points, atol=2e-3)
    normals = np.einsum("kij,kpj->kpi", expected[:, :3, :3], np.asarray(cylinder_map.normals, np.float64))
    np.testing.assert_allclose(np.asarray(cylinder_map.normals_object), normals, atol=1e-4)


def test_map_points_lie_on_the_true_surface(cylinder_map):
    points, normals = stitched_point_cloud(cylinder_map)
    assert len(points) > 1000 and int(cylinder_map.imprint_valid.sum()) >= 0.9 * len(cylinder_map)
    distance = surface_distance(get_object("cylinder"), points)
    # Predicted heightmaps (lookup model, 0.4 mm/px), placed by exact kinematics.
    assert distance["median"] < 0.25 and distance["p95"] < 1.0
    # Normals point out of the object: along the SDF gradient.
    solid = get_object("cylinder").solid
    gradient = np.asarray(jax.vmap(jax.grad(solid.sdf))(jnp.asarray(points)))
    assert np.median(np.sum(gradient * normals, axis=1)) > 0.9


def test_surface_pixels_come_from_the_whole_predicted_mask(cylinder_map, mapping_dataset, lookup_model):
    from tactojax.io import read_grasps
    from tactojax.localize import build_map_surface
    from tactojax.shape import predict_batch

    images = read_grasps(mapping_dataset)["images"][:6]
    _, predicted = predict_batch(lookup_model, jnp.asarray(images, jnp.float32) / 255.0)
    surface_pixels, surface_valid = (np.asarray(x)[:6] for x in (cylinder_map.surface_pixels,
                                                                 cylinder_map.surface_valid))
    predicted = np.asarray(predicted).reshape(6, -1)
    # Every real surface pixel lies in the predicted mask; the contact points' mask (the observed
    # part of it) is a subset, so there are at least as many surface pixels as contact points.
    assert np.all(np.take_along_axis(predicted, surface_pixels.astype(int), axis=1)[surface_valid])
    assert np.all(predicted[np.asarray(cylinder_map.masks[:6]).reshape(6, -1)])
    assert np.all(surface_valid.sum(axis=1) >= np.asarray(cylinder_map.valid[:6]).sum(axis=1))
    # Decoded, they lie on the cylinder (its exact signed distance, an independent reference).
    geometry = cylinder_map.host_geometry(surface=True)
    deep = geometry["valid"] & (geometry["points"][..., 2] <= -0.3)
    distance = surface_distance(get_object("cylinder"), geometry["points_object"][deep])
    assert distance["median"] < 0.25
    # A map without surface pixels (written before them) builds its surface from its contact points.
    older = build_map_surface(cylinder_map.replace(surface_pixels=None, surface_valid=None))
    as_contact = build_map_surface(cylinder_map.replace(surface_pixels=cylinder_map.point_pixels,
                                                        surface_valid=cylinder_map.valid))
    np.testing.assert_array_equal(np.asarray(older.blocks), np.asarray(as_contact.blocks))


def test_sample_contact_points_draws_from_the_mask():
    heightmap = jnp.asarray(np.random.default_rng(0).uniform(0, 1, (12, 16)), jnp.float32)
    mask = jnp.zeros((12, 16), bool).at[3:6, 4:9].set(True)  # 15 contact pixels
    for count, expected_valid in [(8, 8), (32, 15)]:
        points, normals, valid = sample_contact_points(jax.random.key(1), heightmap, mask, 0.5, count)
        assert points.shape == (count, 3) and normals.shape == (count, 3)
        assert int(valid.sum()) == expected_valid
        chosen = np.asarray(points)[np.asarray(valid)]
        assert len(np.unique(chosen, axis=0)) == expected_valid  # no pixel twice
        # Each valid point is (x, y, -h) of a contact pixel.
        columns = np.round(chosen[:, 0] / 0.5 + 7.5).astype(int)
        rows = np.round(chosen[:, 1] / 0.5 + 5.5).astype(int)
        assert np.asarray(mask)[rows, columns].all()
        np.testing.assert_allclose(-chosen[:, 2], np.asarray(heightmap)[rows, columns], atol=1e-6)


def test_voxel_downsample_matches_a_dictionary_reference():
    rng = np.random.default_rng(0)
    points = rng.uniform(-5, 5, (500, 3))
    normals = rng.normal(size=(500, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    down, down_normals = voxel_downsample(points, normals, 2.0)
    cells: dict = {}
    for p in points:
        cells.setdefault(tuple(np.floor(p / 2.0).astype(int)), []).append(p)
    reference = np.array(sorted(np.mean(v, axis=0).tolist() for v in cells.values()))
    np.testing.assert_allclose(np.array(sorted(down.tolist())), reference, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(down_normals, axis=1), 1.0, atol=1e-5)


def test_save_load_round_trip_and_clear_errors(cylinder_map, tmp_path):
    path = save_tactile_map(tmp_path / "map.npz", cylinder_map, metadata={"note": "test"})
    loaded = load_tactile_map(path, images=True)
    assert loaded.object_id == cylinder_map.object_id and loaded.mm_per_px == cylinder_map.mm_per_px
    for a, b in zip(jax.tree.leaves(cylinder_map), jax.tree.leaves(loaded)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    path.with_name("cut.npz").write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CorruptMapError):
        load_tactile_map(path.with_name("cut.npz"))
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(CorruptMapError):
        load_tactile_map(tmp_path / "other.npz")
    with pytest.raises(FileNotFoundError):
        load_tactile_map(tmp_path / "missing.npz")
    wrong = cylinder_map.replace(valid=cylinder_map.valid[:, :10])
    save_tactile_map(tmp_path / "wrong.npz", wrong, surface=False)  # a file whose arrays disagree
    with pytest.raises(CorruptMapError, match="valid"):
        load_tactile_map(tmp_path / "wrong.npz")
    height, width = cylinder_map.image_shape
    past = cylinder_map.replace(surface_pixels=cylinder_map.surface_pixels.at[0, 0].set(height * width))
    save_tactile_map(tmp_path / "past.npz", past, surface=False)
    with pytest.raises(CorruptMapError, match="surface_pixels index past"):
        load_tactile_map(tmp_path / "past.npz")
    half = cylinder_map.replace(surface_valid=cylinder_map.surface_valid[:, :10])
    save_tactile_map(tmp_path / "half.npz", half, surface=False)
    with pytest.raises(CorruptMapError, match="surface_valid"):
        load_tactile_map(tmp_path / "half.npz")


def test_a_localization_map_gets_its_features_and_its_stored_calibration(cylinder_map, tiny_encoder_path, tmp_path):
    """A map as ``tactojax map`` writes it (no features) is encoded on load; a calibration fit
    with the same encoder is used, one fit with another is not."""
    from tactojax.io import load_encoder, load_localization_map
    from tactojax.localize import BeliefCalibration

    encoder_name = str(tiny_encoder_path)
    fit = {"temperature": 0.3, "appearance": 2.0, "fusion_exponent": 0.5, "encoder": encoder_name}
    path = save_tactile_map(tmp_path / "map.npz", cylinder_map.with_features(jnp.zeros((len(cylinder_map), 0))),
                            metadata={"belief_calibration": fit})
    view = load_localization_map(path, encoder_name=encoder_name)
    assert view.features.shape == (len(cylinder_map), load_encoder(tiny_encoder_path).feature_dim)
    assert float(view.calibration.temperature) == pytest.approx(0.3)
    other = save_tactile_map(tmp_path / "other.npz", cylinder_map, metadata={"belief_calibration": {
        **fit, "encoder": "another"}})
    assert float(load_localization_map(other, encoder_name=encoder_name).calibration.temperature) == pytest.approx(
        float(BeliefCalibration.default().temperature))  # the default scales


def test_ply_export_reads_back(cylinder_map, tmp_path):
    import trimesh

    count = export_ply(tmp_path / "map.ply", cylinder_map, voxel_mm=1.0)
    cloud = trimesh.load(tmp_path / "map.ply")
    expected, _ = stitched_point_cloud(cylinder_map, voxel_mm=1.0)
    assert count == len(expected) == len(cloud.vertices)
    np.testing.assert_allclose(np.asarray(cloud.vertices), expected, atol=1e-5)


def test_kinematic_noise_has_the_stated_spread():
    count = 4000
    poses = jaxlie.SE3.from_translation(jnp.zeros((count, 3)))
    openings = jnp.full((count,), 30.0)
    same_poses, same_openings = perturb_kinematics(jax.random.key(0), poses, openings, KinematicNoise())
    np.testing.assert_array_equal(np.asarray(same_openings), np.asarray(openings))
    np.testing.assert_allclose(np.asarray(same_poses.wxyz_xyz), np.asarray(poses.wxyz_xyz), atol=1e-7)
    noise = NOISE_LEVELS["realistic"]
    noisy, noisy_openings = perturb_kinematics(jax.random.key(0), poses, openings, noise)
    assert np.std(np.asarray(noisy.translation()), axis=0) == pytest.approx([noise.translation_mm] * 3, rel=0.1)
    angles = np.rad2deg(np.asarray(noisy.rotation().log()))
    assert np.std(angles, axis=0) == pytest.approx([noise.rotation_deg] * 3, rel=0.1)
    assert np.std(np.asarray(noisy_openings)) == pytest.approx(noise.opening_mm, rel=0.1)


def test_observed_contact_matches_a_scipy_reference():
    from scipy import ndimage

    from tactojax.mapping import observed_contact

    rng = np.random.default_rng(0)
    background = rng.uniform(0.3, 0.6, (30, 40, 3)).astype(np.float32)
    image = background + rng.normal(0, 0.01, background.shape).astype(np.float32)
    image[10:13, 5:8] += 0.3  # one clearly observed spot
    mask = rng.uniform(size=(30, 40)) > 0.3
    observed = observed_contact(jnp.asarray(image), jnp.asarray(background), jnp.asarray(mask), 0.5,
                                threshold=0.05, radius_mm=2.0)
    change = np.abs(ndimage.uniform_filter(image - background, size=(3, 3, 1), mode="constant")).max(-1)
    near = ndimage.maximum_filter(change > 0.05, size=9, mode="constant")  # 2 mm = 4 px each way
    np.testing.assert_array_equal(np.asarray(observed), mask & near)
    assert 0 < np.asarray(observed).sum() < mask.sum()


def _reduce_window_observed_contact(image, background, mask, mm_per_px, threshold, radius_mm):
    """``observed_contact`` as it was computed before issue 17: XLA's ``reduce_window``."""
    change = jax.lax.reduce_window(image - background, 0.0, jax.lax.add, (3, 3, 1), (1, 1, 1), "SAME") / 9.0
    strong = (jnp.max(jnp.abs(change), axis=-1) > threshold).astype(jnp.float32)
    size = 2 * int(round(radius_mm / mm_per_px)) + 1
    near = jax.lax.reduce_window(strong, 0.0, jax.lax.max, (size, 1), (1, 1), "SAME")
    near = jax.lax.reduce_window(near, 0.0, jax.lax.max, (1, size), (1, 1), "SAME") > 0.0
    return mask & near


@pytest.mark.parametrize("mm_per_px, radius_mm", [(0.2, 3.0), (0.5, 2.0), (0.1, 0.05)])
def test_observed_contact_equals_the_reduce_window_formulation(mm_per_px, radius_mm):
    from tactojax.mapping import observed_contact

    rng = np.random.default_rng(int(10 * radius_mm))
    shape = (3, 40, 64, 3)
    background = jnp.asarray(rng.uniform(0.3, 0.6, shape[1:]), jnp.float32)
    # Camera noise and a few single-pixel spots whose 3x3 means straddle the threshold.
    change = rng.normal(0, 0.01, shape)
    for index in range(shape[0]):
        rows, cols, channels = rng.integers(0, shape[1], 4), rng.integers(0, shape[2], 4), rng.integers(0, 3, 4)
        change[index, rows, cols, channels] += rng.uniform(0.2, 0.9, 4)
    images = jnp.clip(background + jnp.asarray(change, jnp.float32), 0.0, 1.0)
    masks = jnp.asarray(rng.uniform(size=shape[:3]) > 0.3)
    expected = jnp.stack([_reduce_window_observed_contact(i, background, m, mm_per_px, 0.05, radius_mm)
                          for i, m in zip(images, masks)])
    assert 0 < int(expected.sum()) < int(masks.sum())
    observe = functools.partial(observed_contact, mm_per_px=mm_per_px, threshold=0.05, radius_mm=radius_mm)
    np.testing.assert_array_equal(observe(images[0], background, masks[0]), expected[0])
    np.testing.assert_array_equal(jax.jit(jax.vmap(observe, in_axes=(0, None, 0)))(images, background, masks),
                                  expected)


def test_shape_fit_clouds_hold_the_refined_contact_of_the_map(cylinder_map):
    from tactojax.mapping import (depth_observed, fit_shape_to_clouds, fit_tactile_map, membrane_skirt,
                                  shape_fit_clouds)

    depth, contact = shape_fit_clouds(cylinder_map)
    plain_depth, plain_contact = shape_fit_clouds(cylinder_map, refine_contact=False)
    map_points, _ = stitched_point_cloud(cylinder_map)
    np.testing.assert_array_equal(plain_depth, map_points)
    np.testing.assert_array_equal(plain_contact, map_points)
    # As many points per imprint as the map samples, from the refined masks (pixel counts).
    mm_per_px = cylinder_map.mm_per_px
    masks_of = jax.jit(jax.vmap(lambda h, m: (m & ~membrane_skirt(h, mm_per_px), depth_observed(h, mm_per_px))))
    refined, reachable = (np.asarray(x) for x in masks_of(cylinder_map.heightmaps, cylinder_map.masks))
    observed = refined & reachable
    per_imprint = cylinder_map.points.shape[1]
    imprints = np.asarray(cylinder_map.imprint_valid)
    assert len(contact) == np.minimum(refined.reshape(len(refined), -1).sum(1), per_imprint)[imprints].sum()
    assert len(depth) == np.minimum(observed.reshape(len(observed), -1).sum(1), per_imprint)[imprints].sum()
    assert 0.5 * len(map_points) < len(depth) <= len(contact) <= len(map_points)
    # The skirt hangs off the object: the refined contact lies closer to the true surface.
    cylinder = get_object("cylinder")
    assert surface_distance(cylinder, contact)["p95"] < surface_distance(cylinder, map_points)["p95"]
    fit = fit_tactile_map(cylinder_map, "cylinder")
    assert bool(fit.converged)
    assert abs(float(fit.parameters["radius_mm"]) - 25.0) < 0.02 * 25.0
    # The same fit from the clouds drawn above (how a caller that also measures them avoids drawing twice).
    from_clouds = fit_shape_to_clouds(depth, contact, "cylinder")
    assert float(from_clouds.parameters["radius_mm"]) == float(fit.parameters["radius_mm"])
