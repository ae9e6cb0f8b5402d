"""Compact tactile maps (format version 2): the round trip keeps the imprints within float16's
bound, version-1 files still load, and an imprint takes at most 50 kB in memory."""

import json

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.io import (MAP_VERSION, CorruptMapError, compact_tactile_map, load_localization_map, load_tactile_map,
                         save_tactile_map, stored_surface, tactile_map_bytes, tactile_map_metadata,
                         update_tactile_map_metadata)
from tactojax.localize import LocalizationMap, SurfaceSettings, build_map_surface
from tactojax.mapping import TactileMap, pack_heightmaps, pixel_index_dtype, sample_contact_pixels
from tactojax.objects import NO_SYMMETRY, ObjectSymmetry

HEIGHT_PX, WIDTH_PX, MM_PER_PX, POINTS = 120, 160, 0.2, 1024
FLOAT16_RELATIVE = 2.0**-11  # float16 rounding, relative to the value


def _presses(count=3, seed=0):
    """(heightmaps float32, masks) of spherical presses at random places, with small positive
    noise off contact (as predicted heightmaps have)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[:HEIGHT_PX, :WIDTH_PX] * MM_PER_PX
    heightmaps = []
    for _ in range(count):
        centre = rng.uniform([6, 8], [18, 24])
        distance2 = (rows - centre[0]) ** 2 + (cols - centre[1]) ** 2
        heightmaps.append(np.clip(1.1 - distance2 / (2 * 12.0), 0, None) + rng.uniform(0, 0.05, rows.shape))
    heightmaps = np.stack(heightmaps).astype(np.float32)
    return heightmaps, heightmaps > 0.16


def _numpy_points(heightmap, pixels):
    """Points (x, y, -h) and normals at flat pixel indices: an independent numpy reference."""
    row, col = np.divmod(np.asarray(pixels, np.int64), WIDTH_PX)
    x = (col - (WIDTH_PX - 1) / 2) * MM_PER_PX
    y = (row - (HEIGHT_PX - 1) / 2) * MM_PER_PX
    dh_drow, dh_dcol = np.gradient(heightmap.astype(np.float64))
    normals = np.stack([-dh_dcol[row, col] / MM_PER_PX, -dh_drow[row, col] / MM_PER_PX, -np.ones(len(row))], -1)
    return np.stack([x, y, -heightmap[row, col]], -1), normals / np.linalg.norm(normals, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def tiny_map():
    heightmaps, masks = _presses()
    keys = jax.random.split(jax.random.key(0), len(heightmaps))
    pixels, valid = jax.vmap(sample_contact_pixels, in_axes=(0, 0, None))(keys, jnp.asarray(masks), POINTS)
    count = len(heightmaps)
    T = jaxlie.SE3.from_translation(jnp.asarray(np.random.default_rng(1).normal(0, 10, (count, 3)), jnp.float32))
    tactile_map = TactileMap(
        images=jnp.asarray(np.random.default_rng(2).integers(0, 256, (count, HEIGHT_PX, WIDTH_PX, 3), np.uint8)),
        packed_heightmaps=pack_heightmaps(heightmaps, masks),
        point_pixels=pixels.astype(pixel_index_dtype(HEIGHT_PX, WIDTH_PX)), valid=valid, T_object_sensor=T,
        openings=jnp.full(count, 20.0), features=jnp.ones((count, 8)), imprint_valid=valid.any(axis=1),
        object_id="spheres", mm_per_px=MM_PER_PX, sensor="gelslim")
    return tactile_map, heightmaps, masks


def _check_against_reference(loaded, heightmaps, masks):
    """The loaded map against the float32 originals: heights within float16's relative bound,
    masks exact, points and normals as numpy computes them from the originals."""
    decoded = np.asarray(loaded.heightmaps)
    assert np.all(np.abs(decoded - heightmaps) <= FLOAT16_RELATIVE * heightmaps + 1e-7)
    assert np.abs(decoded - heightmaps).max() <= 0.0006  # mm, on these 0-1.15 mm presses
    np.testing.assert_array_equal(np.asarray(loaded.masks), masks)
    points, normals, valid = (np.asarray(x) for x in (loaded.points, loaded.normals, loaded.valid))
    for k in range(len(heightmaps)):
        reference_points, reference_normals = _numpy_points(heightmaps[k], np.asarray(loaded.point_pixels[k]))
        np.testing.assert_allclose(points[k, :, :2], reference_points[:, :2], atol=1e-5)
        assert np.abs(points[k, :, 2] - reference_points[:, 2]).max() <= 0.0006
        angle = np.degrees(np.arccos(np.clip(np.sum(normals[k] * reference_normals, -1), -1, 1)))
        assert angle[valid[k]].max() < 0.5
        np.testing.assert_array_equal(valid[k], masks[k].reshape(-1)[np.asarray(loaded.point_pixels[k])])


def test_compact_round_trip_within_the_float16_bound(tiny_map, tmp_path):
    tactile_map, heightmaps, masks = tiny_map
    path = save_tactile_map(tmp_path / "map.npz", tactile_map, metadata={"note": "test"})
    assert tactile_map_metadata(path)["version"] == MAP_VERSION == 2
    loaded = load_tactile_map(path)
    assert loaded.images is None  # read only when asked for
    for name in ("packed_heightmaps", "point_pixels", "valid", "openings", "features", "imprint_valid"):
        np.testing.assert_array_equal(np.asarray(getattr(loaded, name)), np.asarray(getattr(tactile_map, name)))
        assert getattr(loaded, name).dtype == getattr(tactile_map, name).dtype
    np.testing.assert_array_equal(np.signbit(loaded.packed_heightmaps), np.signbit(tactile_map.packed_heightmaps))
    _check_against_reference(loaded, heightmaps, masks)
    np.testing.assert_array_equal(np.asarray(load_tactile_map(path, images=True).images), np.asarray(tactile_map.images))
    with pytest.raises(ValueError, match="stores no images"):
        loaded.stored_images()


def test_the_recorded_symmetry_round_trips_and_localization_reads_it(tiny_map, tmp_path):
    tactile_map, _, _ = tiny_map
    # "spheres" is no catalog object: without a recorded group the map has none.
    assert load_tactile_map(save_tactile_map(tmp_path / "none.npz", tactile_map)).object_symmetry == NO_SYMMETRY
    recorded = ObjectSymmetry(axis="y", flips=("z",), centre=(1.0, 2.0, 3.0), exact=False)
    loaded = load_tactile_map(save_tactile_map(tmp_path / "map.npz", tactile_map.replace(symmetry=recorded)))
    assert loaded.symmetry == loaded.object_symmetry == recorded
    view = LocalizationMap.from_tactile_map(loaded)
    np.testing.assert_allclose(view.symmetry_axis, [0.0, 1.0, 0.0])
    np.testing.assert_allclose(view.symmetry_centre, [1.0, 2.0, 3.0])
    assert view.symmetries.wxyz_xyz.shape == (2, 7) and view.symmetric  # the identity and the flip


def test_bytes_per_imprint_below_50_kB(tiny_map, tmp_path):
    tactile_map, _, _ = tiny_map
    path = save_tactile_map(tmp_path / "map.npz", tactile_map.replace(images=None))
    summary = tactile_map_bytes(path)
    count = summary["imprints"]
    loaded = sum(int(x.nbytes) for x in jax.tree.leaves(load_tactile_map(path)))
    assert summary["loaded_bytes"] == summary["memory_bytes"] == loaded
    assert loaded / count <= 50_000
    # the arrays: 38,400 (float16 heightmap) + 2,048 (uint16 pixels) + 1,024 (valid) + the rest
    assert summary["fields"]["packed_heightmaps"]["memory"] == count * HEIGHT_PX * WIDTH_PX * 2
    assert summary["file_bytes"] / count < 50_000


def _write_version_1(path, heightmaps, masks, pixels, valid, images, header_metadata):
    """A map file as version 1 wrote it (float32 heightmaps, bool masks, float32 points and
    normals from the heightmaps, images), with numpy alone."""
    points, normals = zip(*(_numpy_points(h, p) for h, p in zip(heightmaps, pixels)))
    count = len(heightmaps)
    header = {"format": "tactojax-tactile-map", "version": 1, "object_id": "spheres", "mm_per_px": MM_PER_PX,
              "sensor": "gelslim", "metadata": header_metadata}
    np.savez_compressed(path, header=np.array(json.dumps(header)), images=images, heightmaps=heightmaps,
                        masks=masks, points=np.stack(points).astype(np.float32),
                        normals=np.stack(normals).astype(np.float32), valid=valid,
                        T_object_sensor=np.tile(np.array([1, 0, 0, 0, 0, 0, 0], np.float32), (count, 1)),
                        openings=np.full(count, 20.0, np.float32), features=np.ones((count, 8), np.float32),
                        imprint_valid=valid.any(axis=1))


def test_a_version_1_map_loads_and_converts(tiny_map, tmp_path):
    tactile_map, heightmaps, masks = tiny_map
    pixels, valid, images = (np.asarray(x) for x in (tactile_map.point_pixels, tactile_map.valid, tactile_map.images))
    old = tmp_path / "old.npz"
    fit = {"temperature": 0.3, "appearance": 1.0, "fusion_exponent": 0.5, "encoder": "bundled:features-tactile"}
    _write_version_1(old, heightmaps, masks, pixels, valid, images, {"belief_calibration": fit, "seed": 3})
    loaded = load_tactile_map(old, images=True)
    np.testing.assert_array_equal(np.asarray(loaded.point_pixels), pixels)
    np.testing.assert_array_equal(np.asarray(loaded.images), images)
    _check_against_reference(loaded, heightmaps, masks)

    new = compact_tactile_map(old, tmp_path / "new.npz")  # features from the calibration's encoder: kept
    header = tactile_map_metadata(new)
    assert header["version"] == 2 and header["metadata"]["belief_calibration"] == fit and header["metadata"]["seed"] == 3
    converted = load_tactile_map(new, images=True)
    assert converted.images is None
    np.testing.assert_array_equal(np.asarray(converted.packed_heightmaps), np.asarray(loaded.packed_heightmaps))
    np.testing.assert_array_equal(np.asarray(converted.features), np.ones((len(heightmaps), 8)))
    assert tactile_map_bytes(new)["file_bytes"] < tactile_map_bytes(old)["file_bytes"] / 2


def test_version_1_points_off_the_pixel_grid_are_refused(tiny_map, tmp_path):
    from tactojax.io import CorruptMapError

    tactile_map, heightmaps, masks = tiny_map
    path = tmp_path / "old.npz"
    _write_version_1(path, heightmaps, masks, np.asarray(tactile_map.point_pixels), np.asarray(tactile_map.valid),
                     np.asarray(tactile_map.images), {})
    with np.load(path) as npz:
        arrays = dict(npz)
    arrays["points"][0, 0, 0] += 0.05  # a quarter pixel
    np.savez_compressed(path, **arrays)
    with pytest.raises(CorruptMapError, match="pixel grid"):
        load_tactile_map(path)


@pytest.mark.parametrize("version", [1, 2])
def test_a_metadata_update_leaves_every_array_and_the_version(tiny_map, tmp_path, version):
    """What ``calibrate-belief`` stores: the header changes, the arrays (images included) and the
    format version do not."""
    tactile_map, heightmaps, masks = tiny_map
    path = tmp_path / "map.npz"
    if version == 1:
        _write_version_1(path, heightmaps, masks, *(np.asarray(x) for x in (tactile_map.point_pixels, tactile_map.valid,
                                                                            tactile_map.images)), {"seed": 3})
    else:
        save_tactile_map(path, tactile_map, metadata={"seed": 3})
    with np.load(path) as before:
        arrays = {name: before[name] for name in before.files if name != "header"}
    fit = {"temperature": 0.1, "appearance": 5.0, "fusion_exponent": 0.5}
    assert update_tactile_map_metadata(path, {"seed": 3, "belief_calibration": fit}) == path
    header = tactile_map_metadata(path)
    assert header["version"] == version and header["metadata"] == {"seed": 3, "belief_calibration": fit}
    with np.load(path) as after:
        assert sorted(after.files) == sorted([*arrays, "header"]) and "images" in after.files
        for name, value in arrays.items():
            np.testing.assert_array_equal(after[name], value)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_the_stored_surface_is_the_one_localization_builds_and_is_read_instead(tiny_map, tmp_path, monkeypatch):
    tactile_map, _, _ = tiny_map
    path = save_tactile_map(tmp_path / "map.npz", tactile_map)
    built = build_map_surface(load_tactile_map(path))
    stored = stored_surface(path)
    for name in ("blocks", "block_index", "origin"):
        np.testing.assert_array_equal(np.asarray(getattr(stored, name)), np.asarray(getattr(built, name)))
    assert stored.pitch_mm == built.pitch_mm and stored.blocks.dtype == built.blocks.dtype
    assert stored_surface(path, SurfaceSettings(reach_mm=2.0)) is None  # other settings: build anew
    # Loading for localization reads it: building one would fail here.
    monkeypatch.setattr("tactojax.localize._map.build_map_surface", lambda *a, **k: pytest.fail("surface rebuilt"))
    view = load_localization_map(path)
    np.testing.assert_array_equal(np.asarray(view.surface.blocks), np.asarray(built.blocks))
    assert tactile_map_bytes(path)["surface_bytes"] == built.blocks.nbytes + built.block_index.nbytes


def test_a_map_without_a_stored_surface_builds_it_and_a_bad_one_is_refused(tiny_map, tmp_path):
    tactile_map, _, _ = tiny_map
    path = save_tactile_map(tmp_path / "map.npz", tactile_map, surface=False)
    assert stored_surface(path) is None and tactile_map_bytes(path)["surface_bytes"] == 0
    view = load_localization_map(path)
    np.testing.assert_array_equal(np.asarray(view.surface.blocks), np.asarray(build_map_surface(tactile_map).blocks))
    stored = save_tactile_map(tmp_path / "stored.npz", tactile_map)
    with np.load(stored) as npz:
        arrays = {name: npz[name] for name in npz.files}
    arrays["surface_block_index"] = arrays["surface_block_index"] + len(arrays["surface_blocks"])  # past the blocks
    np.savez_compressed(tmp_path / "bad.npz", **arrays)
    with pytest.raises(CorruptMapError, match="stored surface"):
        stored_surface(tmp_path / "bad.npz")
