"""A map built from the simulator's true heightmaps (no shape model): the touch prediction is
then compared with the simulator's touch at the true pose, the map's own errors aside."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.localize import LocalizationMap
from tactojax.mapping import TactileMap, sample_contact_points
from tactojax.simulate import MappingProtocol, simulate_grasps
from tactojax.simulate._protocols import mapping_plan


def truth_map(spec, obj, *, grid_mm: float = 10.0, points: int = 128) -> LocalizationMap:
    """The object's map from the mapping protocol's true heightmaps and poses (features: none)."""
    plan = mapping_plan(obj, MappingProtocol(grid_mm=grid_mm))
    result = simulate_grasps(jax.random.key(0), spec, obj, plan.T_world_object, plan.T_world_gripper)
    keep = np.flatnonzero(np.asarray(result.valid))
    imprint = jax.tree.map(lambda x: x[keep], result.imprint)
    T_object_sensor = jax.tree.map(lambda x: x[keep], plan.T_world_object).inverse() @ imprint.T_world_sensor
    keys = jax.random.split(jax.random.key(1), len(keep))
    sample = jax.vmap(sample_contact_points, in_axes=(0, 0, 0, None, None))
    point_array, normals, valid = sample(keys, imprint.heightmap, imprint.mask, spec.mm_per_px, points)
    tactile_map = TactileMap(
        images=jnp.zeros((len(keep), spec.height_px, spec.width_px, 3), jnp.uint8), heightmaps=imprint.heightmap,
        masks=imprint.mask, points=point_array, normals=normals, valid=valid,
        T_object_sensor=jaxlie.SE3(T_object_sensor.wxyz_xyz), openings=imprint.opening,
        features=jnp.zeros((len(keep), 4)), imprint_valid=valid.any(axis=1), object_id=obj.name,
        mm_per_px=spec.mm_per_px)
    return LocalizationMap.from_tactile_map(tactile_map)
