"""The live Localizer against the same touch run stage by stage through the public API."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax._compilation import CompilationCounter
from tactojax.features import encode_image, encode_images
from tactojax.io import load_encoder
from tactojax.localize import Localizer, MapLibrary, Query, identify, localize
from tactojax.mapping import observed_contact
from tactojax.shape import predict


@pytest.fixture(scope="module")
def live(cylinder_map, gum_box_map, lookup_model, tiny_encoder_path):
    encoder = load_encoder(tiny_encoder_path)
    maps = [m.with_features(encode_images(encoder, m.images)) for m in (cylinder_map, gum_box_map)]
    return Localizer(maps, lookup_model, encoder, method="cti-icp-2"), maps, encoder


def stage_by_stage(maps, model, encoder, image, opening):
    pixels = jnp.asarray(image, jnp.float32) / 255.0
    heightmap, mask = predict(model, pixels)
    mask = observed_contact(pixels, model.background, mask, model.mm_per_px)
    feature = encode_image(encoder, image)
    chosen, _ = identify(MapLibrary.from_maps(maps), feature, jnp.float32(opening))
    query = Query(heightmap=heightmap, mask=mask, feature=feature, opening=jnp.float32(opening))
    return int(chosen), localize(jax.random.key(0), maps[int(chosen)], query, method="cti-icp-2")


def test_live_localizer_matches_the_stage_by_stage_pipeline(live, lookup_model):
    localizer, maps, encoder = live
    for tactile_map in maps:
        for index in np.flatnonzero(np.asarray(tactile_map.imprint_valid))[:3]:
            image, opening = np.asarray(tactile_map.images[index]), float(tactile_map.openings[index])
            estimate = localizer(image, opening)
            chosen, reference = stage_by_stage(maps, lookup_model, encoder, image, opening)
            assert estimate.object_id == maps[chosen].object_id
            np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz),
                                       np.asarray(reference.T_object_sensor.wxyz_xyz), atol=2e-3)
            assert estimate.converged == (bool(reference.converged) and estimate.contact)
            assert 0.0 <= estimate.confidence <= 1.0 and estimate.latency_s > 0.0


def test_live_localizer_never_recompiles_and_rejects_bad_frames(live, cylinder_map):
    localizer, _, _ = live
    image = np.asarray(cylinder_map.images[0])
    with CompilationCounter() as compiles:
        for opening in (30.0, 31.5, 60.0):
            localizer(image, opening)
    assert compiles.messages == []
    assert localizer.kernels > 0  # one compiled program per touch, its kernels counted
    with pytest.raises(ValueError, match="uint8 RGB frames"):
        localizer(image[:-1], 30.0)
    with pytest.raises(ValueError, match="uint8 RGB frames"):
        localizer(image.astype(np.float32), 30.0)
    with pytest.raises(ValueError, match="opening"):
        localizer(image, float("nan"))


def test_a_frame_without_contact_has_no_estimate(live, lookup_model):
    localizer, _, _ = live
    background = np.round(np.asarray(lookup_model.background) * 255).astype(np.uint8)
    for frame in (background, np.zeros_like(background)):  # nothing touching; a black frame
        estimate = localizer(frame, 40.0)
        assert not estimate.contact and estimate.T_object_sensor is None and estimate.object_id is None
        assert estimate.confidence == 0.0 and not estimate.converged and estimate.latency_s > 0
        assert estimate.as_dict()["T_object_sensor_wxyz_xyz"] is None
