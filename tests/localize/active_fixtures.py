"""A map built from the simulator's true heightmaps (no shape model): the touch prediction is
then compared with the simulator's touch at the true pose, the map's own errors aside."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.localize import LocalizationMap
from tactojax.mapping import TactileMap, pack_heightmaps, sample_contact_pixels
from tactojax.simulate import MappingProtocol, simulate_grasps
from tactojax.simulate._protocols import mapping_plan


_MAPS = {}


def truth_map(spec, obj, *, grid_mm: float = 10.0, points: int = 128) -> LocalizationMap:
    """The object's map from the mapping protocol's true heightmaps and poses (features: none),
    every imprint also placed by each of the object's symmetries (so that the map is exactly as
    symmetric as the object), built once per process and object."""
    key = (spec.height_px, spec.width_px, obj.name, grid_mm, points)
    if key not in _MAPS:
        _MAPS[key] = _build(spec, obj, grid_mm, points)
    return _MAPS[key]


def _build(spec, obj, grid_mm, points):
    plan = mapping_plan(obj, MappingProtocol(grid_mm=grid_mm))
    result = simulate_grasps(jax.random.key(0), spec, obj, plan.T_world_object, plan.T_world_gripper)
    keep = np.flatnonzero(np.asarray(result.valid))
    imprint = jax.tree.map(lambda x: x[keep], result.imprint)
    T_object_sensor = jax.tree.map(lambda x: x[keep], plan.T_world_object).inverse() @ imprint.T_world_sensor
    keys = jax.random.split(jax.random.key(1), len(keep))
    pixels, valid = jax.vmap(sample_contact_pixels, in_axes=(0, 0, None))(keys, imprint.mask, points)
    symmetries = obj.symmetry.transforms()
    copies = len(symmetries.wxyz_xyz)
    T_object_sensor = jaxlie.SE3(jax.vmap(lambda S: (S @ T_object_sensor).wxyz_xyz)(symmetries).reshape(-1, 7))
    keep = np.tile(keep, copies)
    imprint, pixels, valid = jax.tree.map(lambda x: jnp.concatenate([x] * copies), (imprint, pixels, valid))
    tactile_map = TactileMap(
        images=jnp.zeros((len(keep), spec.height_px, spec.width_px, 3), jnp.uint8),
        packed_heightmaps=pack_heightmaps(imprint.heightmap, imprint.mask), point_pixels=pixels, valid=valid,
        T_object_sensor=jaxlie.SE3(T_object_sensor.wxyz_xyz), openings=imprint.opening,
        features=jnp.zeros((len(keep), 4)), imprint_valid=valid.any(axis=1), object_id=obj.name,
        mm_per_px=spec.mm_per_px)
    return LocalizationMap.from_tactile_map(tactile_map)
