"""Retrieval (CTI): cosine similarities and the opening filter against a numpy brute force."""

import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.localize._retrieval import closest_imprints, cosine_similarities


def _brute_force(features, openings, valid, query, opening, n, threshold, exclude):
    similarity = features @ query / (np.linalg.norm(features, axis=1) * np.linalg.norm(query))
    eligible = [k for k in range(len(features))
                if valid[k] and abs(openings[k] - opening) < threshold and k != exclude]
    ranked = sorted(eligible, key=lambda k: -similarity[k])[:n]
    return ranked, similarity


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("exclude", [-1, 3])
def test_closest_imprints_match_brute_force(seed, exclude):
    rng = np.random.default_rng(seed)
    features = rng.normal(size=(30, 7)).astype(np.float32)
    openings = rng.uniform(10, 20, 30).astype(np.float32)
    valid = rng.uniform(size=30) > 0.2
    query, opening = rng.normal(size=7).astype(np.float32), np.float32(15.0)
    expected, similarity = _brute_force(features, openings, valid, query, opening, 5, 2.0, exclude)
    indices, similarities, ok = closest_imprints(features, openings, valid, query, opening, 5, exclude=exclude)
    count = len(expected)
    assert np.asarray(ok).tolist() == [True] * count + [False] * (5 - count)
    assert np.asarray(indices)[:count].tolist() == expected
    np.testing.assert_allclose(np.asarray(similarities)[:count], similarity[expected], rtol=1e-5, atol=1e-6)


def test_opening_filter_and_exclude_leave_too_few():
    features = np.eye(4, dtype=np.float32)
    openings = np.array([10.0, 11.9, 12.1, 30.0], np.float32)
    indices, _, ok = closest_imprints(features, openings, np.ones(4, bool), features[1], 10.0, 3, exclude=0)
    # Only imprint 1 is within 2 mm once imprint 0 is left out.
    assert np.asarray(ok).tolist() == [True, False, False] and int(indices[0]) == 1
    # No filter: every other imprint is eligible.
    _, _, ok = closest_imprints(features, openings, np.ones(4, bool), features[1], 10.0, 3,
                                max_opening_difference_mm=np.inf, exclude=0)
    assert np.asarray(ok).all()


def test_cosine_similarity_of_zero_vectors_is_zero_not_nan():
    similarities = cosine_similarities(jnp.zeros((3, 4)), jnp.ones(4))
    assert np.all(np.asarray(similarities) == 0.0)


def test_a_map_smaller_than_n_pads_with_invalid_entries():
    features = np.eye(3, dtype=np.float32)
    indices, _, ok = closest_imprints(features, np.full(3, 10.0, np.float32), np.ones(3, bool), features[2], 10.0, 5)
    assert indices.shape == (5,) and np.asarray(ok).tolist() == [True] * 3 + [False] * 2
    assert int(indices[0]) == 2 and sorted(np.asarray(indices)[:3].tolist()) == [0, 1, 2]
