"""Small synthetic tactile maps: analytic surfaces seen by a downward-looking sensor.

The sensor frame's z axis points down onto a surface z = f(x, y) of the object frame, so pixel
(x, y) sees the object point above (x, -y) (turned by the imprint's yaw) and the indentation
is h = f - t_z wherever positive (a rigid press to the plane z = t_z). Every imprint of a map
sees the same object regions in contact, so their heightmaps agree exactly where they overlap.
"""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.geometry import pixel_grid
from tactojax.localize import BeliefSettings, LocalizationMap
from tactojax.localize._candidates import CandidateGrid
from tactojax.localize._surface import SurfaceSettings, build_map_surface
from tactojax.mapping import TactileMap, pack_heightmaps, sample_contact_pixels

HEIGHT_PX, WIDTH_PX, MM_PER_PX = 24, 32, 0.5
PRESS_PLANE_MM = 0.2


def bumps(x, y):
    """A surface with features in every direction (all six pose dimensions are observable)."""
    return (1.2 * np.sin(x / 3.5) * np.cos(y / 4.5) + 0.8 * np.exp(-((x - 3.0) ** 2 + (y + 2.0) ** 2) / 8.0)
            + 0.6 * np.exp(-((x + 5.0) ** 2 + (y - 4.0) ** 2) / 5.0))


def ridges(x, y):
    """Another object: parallel ridges, for identification."""
    return 1.0 + 0.9 * np.cos((x + 0.4 * y) / 1.8)


def sensor_pose(x, y, yaw_deg=0.0, z=PRESS_PLANE_MM):
    """Sensor looking down (its z = object -z) at (x, y), turned by yaw about the object z."""
    yaw = np.deg2rad(yaw_deg)
    rotation = jaxlie.SO3.from_z_radians(yaw) @ jaxlie.SO3.from_x_radians(np.pi)
    return jaxlie.SE3.from_rotation_and_translation(rotation, jnp.array([x, y, z], jnp.float32))


def render(surface, T_object_sensor):
    """(heightmap, mask) of one press (numpy, float32)."""
    xy = np.asarray(pixel_grid(HEIGHT_PX, WIDTH_PX, MM_PER_PX), np.float64)
    p_sensor = np.concatenate([xy, np.zeros((HEIGHT_PX, WIDTH_PX, 1))], axis=-1)
    matrix = np.asarray(T_object_sensor.as_matrix(), np.float64)
    p_object = p_sensor @ matrix[:3, :3].T + matrix[:3, 3]
    height = np.clip(surface(p_object[..., 0], p_object[..., 1]) - matrix[2, 3], 0.0, None)
    return height.astype(np.float32), height > 0.02


def make_map(surface, poses, object_id="synthetic", points=128, features=None):
    """A TactileMap of presses at ``poses`` (list of SE3); features: the stand-in below."""
    heightmaps, masks = zip(*(render(surface, T) for T in poses))
    heightmaps, masks = jnp.asarray(np.stack(heightmaps)), jnp.asarray(np.stack(masks))
    keys = jax.random.split(jax.random.key(0), len(poses))
    pixels, valid = jax.vmap(sample_contact_pixels, in_axes=(0, 0, None))(keys, masks, points)
    T = jaxlie.SE3(jnp.stack([p.wxyz_xyz for p in poses]))
    tactile_map = TactileMap(
        images=jnp.zeros((len(poses), HEIGHT_PX, WIDTH_PX, 3), jnp.uint8),
        packed_heightmaps=pack_heightmaps(heightmaps, masks), point_pixels=pixels, valid=valid, T_object_sensor=T,
        openings=jnp.full(len(poses), 20.0), features=jnp.zeros((len(poses), 0)),
        imprint_valid=valid.any(axis=1), object_id=object_id, mm_per_px=MM_PER_PX)
    return tactile_map.with_features(standin_features(heightmaps, masks) if features is None else features)


def standin_features(heightmaps, masks):
    """Mean-removed, L2-normalised 6 x 8 block means of the masked heightmaps."""
    x = np.asarray(heightmaps) * np.asarray(masks)
    x = x.reshape(len(x), 6, HEIGHT_PX // 6, 8, WIDTH_PX // 8).mean((2, 4)).reshape(len(x), -1)
    x = x - x.mean(1, keepdims=True)
    return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)


GRID = [(x, y) for y in (-6.0, -3.0, 0.0, 3.0, 6.0) for x in (-8.0, -4.0, 0.0, 4.0, 8.0)]


@pytest.fixture(scope="session")
def bumps_map():
    """25 presses on a 4 x 3 mm grid over the bumps surface (16 x 12 mm field of view)."""
    return make_map(bumps, [sensor_pose(x, y) for x, y in GRID], "bumps")


@pytest.fixture(scope="session")
def ridges_map():
    return make_map(ridges, [sensor_pose(x, y, 10.0) for x, y in GRID], "ridges")


SURFACE = SurfaceSettings(pitch_mm=0.25, reach_mm=1.0, margin_mm=2.0, min_depth_mm=0.0)
"""The synthetic maps' surface grid (finer than the catalog's: their presses are 0.5 mm/px;
their heightmaps are exact renders, without a gel skirt to leave out)."""


@pytest.fixture(scope="session")
def belief_settings():
    """A small belief (few sources, offsets and hypotheses): every test that runs the belief
    shares these settings, so that each map compiles the update once."""
    return BeliefSettings(sources=4, grid=CandidateGrid(shift_mm=1.5, shift_steps=1, turn_deg=5.0, turn_steps=1),
                          new_hypotheses=6, registered_sources=2, registration_union=3, hypotheses=8, refine=4,
                          max_touches=2)


@pytest.fixture(scope="session")
def synthetic_views(bumps_map, ridges_map):
    """The bumps and ridges maps as localization reads them (surfaces built once per session),
    with the same shapes: the ridges' surface on the bumps' grid, both holding as many stored
    blocks, so that everything compiled for one serves the other."""
    bumps = LocalizationMap.from_tactile_map(bumps_map, surface=SURFACE)
    ridges = LocalizationMap.from_tactile_map(ridges_map, surface=SURFACE)
    ridges = ridges.replace(surface=build_map_surface(ridges_map, SURFACE, grid_like=bumps.surface))
    blocks = max(bumps.surface.blocks.shape[0], ridges.surface.blocks.shape[0])
    return tuple(view.replace(surface=view.surface.padded_to(view.surface.block_index.shape, blocks))
                 for view in (bumps, ridges))


@pytest.fixture(scope="session")
def bumps_view(synthetic_views):
    """The bumps map as localization reads it (:func:`synthetic_views`)."""
    return synthetic_views[0]


@pytest.fixture(scope="session")
def ridges_view(synthetic_views):
    """The ridges map as localization reads it, with the bumps' shapes (:func:`synthetic_views`)."""
    return synthetic_views[1]


EPISODE_PLACES = [[(-2.0, 1.0, 0.0), (3.0, -2.5, 5.0)], [(1.5, -1.0, -4.0), (-4.5, 2.5, 3.0)]]
"""Two episodes of two grasps (x, y, yaw) on the bumps, between the map's presses."""


@pytest.fixture(scope="session")
def bumps_episodes():
    """New grasps on the bumps: :data:`EPISODE_PLACES` as :class:`~tactojax.localize.evaluation.TestEpisodes`
    of one finger (true contact clouds from the rendered heightmaps)."""
    from tactojax.localize.evaluation import TestEpisodes

    touches, poses, means, covariances = [], [], [], []
    for episode in EPISODE_PLACES:
        for x, y, yaw in episode:
            T = sensor_pose(x, y, yaw)
            one = touch(bumps, T)
            xy = np.asarray(pixel_grid(*one.heightmap.shape, MM_PER_PX))[np.asarray(one.mask)]
            cloud = np.concatenate([xy, -np.asarray(one.heightmap)[np.asarray(one.mask)][:, None]], axis=1)
            touches.append(one)
            poses.append(T.wxyz_xyz)
            means.append(cloud.mean(0))
            covariances.append(np.cov(cloud.T, bias=True))
    shape = (len(EPISODE_PLACES), len(EPISODE_PLACES[0]), 1)
    stack = lambda values: jnp.asarray(np.stack(values)).reshape(*shape, *np.shape(values[0]))  # noqa: E731
    return TestEpisodes(
        heightmaps=stack([t.heightmap for t in touches]), masks=stack([t.mask for t in touches]),
        features=stack([t.feature for t in touches]), openings=jnp.full(shape[:2], 20.0),
        T_object_sensor=jaxlie.SE3(stack(poses)), cloud_mean=stack(means), cloud_covariance=stack(covariances))


@pytest.fixture(scope="session")
def synthetic():
    """The helpers above (test modules cannot import a conftest)."""
    import types

    return types.SimpleNamespace(bumps=bumps, ridges=ridges, render=render, sensor_pose=sensor_pose,
                                 make_map=make_map, grid=GRID, surface=SURFACE, touch=touch)


def touch(surface, T_object_sensor, opening=20.0):
    """The :class:`~tactojax.localize.Touch` of a press at ``T_object_sensor`` (its feature the
    stand-in's, as a one-imprint map computes it)."""
    from tactojax.localize import Touch

    heightmap, mask = render(surface, T_object_sensor)
    feature = standin_features(heightmap[None], mask[None])[0]
    return Touch(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=jnp.asarray(feature, jnp.float32),
                 opening=jnp.float32(opening))


@pytest.fixture(scope="session")
def live_tracker(cylinder_map, gum_box_map, lookup_model, tiny_encoder_path, belief_settings):
    """A :class:`~tactojax.localize.Tracker` over the cylinder and the gum box (features from the
    tiny encoder), with the small belief; its ``localizer`` serves the live localizer's tests
    (one set of compilations for both)."""
    from tactojax.features import encode_images
    from tactojax.io import load_encoder
    from tactojax.localize import Tracker

    encoder = load_encoder(tiny_encoder_path)
    maps = [m.with_features(encode_images(encoder, m.images)) for m in (cylinder_map, gum_box_map)]
    return Tracker(maps, lookup_model, encoder, settings=belief_settings), maps, encoder


@pytest.fixture(scope="session")
def grasp_frames():
    """``frames(tactile_map, index, T_world_object)``: imprint ``index`` of a map as a live frame
    (image, opening, T_world_gripper) for an object at ``T_world_object``, and its true sensor
    pose in the object frame."""
    from tactojax.geometry import gripper_pose

    def frames(tactile_map, index, T_world_object):
        T_object_sensor = jaxlie.SE3(tactile_map.T_object_sensor.wxyz_xyz[index])
        opening = float(tactile_map.openings[index])
        T_world_gripper = gripper_pose(T_world_object @ T_object_sensor, jnp.float32(opening))
        return np.asarray(tactile_map.images[index]), opening, T_world_gripper, T_object_sensor

    return frames
