"""The symmetry-aware error over a continuous symmetry: each sampled copy turned to its closest
about the axis in closed form equals a brute-force search over the turn, for one touch and for a
fused set of touches."""

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize._evaluate import closest_turn_about_axis, cloud_moments, moment_rmse, pose_errors
from tactojax.localize._new_grasps import _errors

AXIS, CENTRE = jnp.array([0.0, 1.0, 0.0]), jnp.array([1.0, 2.0, 3.0])


def _turn(angle):
    """Object-frame turns by ``angle`` (any shape, rad) about AXIS through CENTRE."""
    rotation = jaxlie.SO3.exp(jnp.asarray(angle)[..., None] * AXIS)
    return jaxlie.SE3.from_rotation_and_translation(rotation, CENTRE - rotation @ CENTRE)


def _clouds(count, seed=0):
    rng = np.random.default_rng(seed)
    points = [jnp.asarray(rng.normal(0, 4, (150, 3)) + [0, 0, 40.0], jnp.float32) for _ in range(count)]
    return [cloud_moments(p, jnp.ones(len(p), bool)) for p in points], points


def _brute_force(moments, T_true, T_estimate):
    """min over turns of the fused RMSE (mean of the touches' squared RMSE): a 0.1-degree search
    over the whole circle, then 0.001 degrees about its best (numpy)."""
    def fused(angles):
        turned = _turn(jnp.asarray(angles))
        return sum(np.asarray(moment_rmse(m, c, jaxlie.SE3(T_true.wxyz_xyz[t]),
                                          turned @ jaxlie.SE3(T_estimate.wxyz_xyz[t]))) ** 2
                   for t, (m, c) in enumerate(moments)) / len(moments)

    coarse = np.deg2rad(np.arange(-180.0, 180.0, 0.1))
    start = coarse[np.argmin(fused(coarse))]
    fine = start + np.deg2rad(np.arange(-0.2, 0.2, 0.001))
    return float(np.sqrt(np.min(fused(fine))))


@pytest.mark.parametrize("angle_deg", [0.7, 41.0, -133.0])
def test_one_touch_equals_a_search_over_the_turn(angle_deg):
    (moments,), (points,) = _clouds(1)
    T_true = jaxlie.SE3.exp(jnp.array([10.0, 20.0, 5.0, 0.3, -0.2, 0.5]))
    T_estimate = _turn(np.deg2rad(angle_deg)) @ T_true @ jaxlie.SE3.exp(jnp.array([0.3, -0.2, 0.1, 0.01, 0.0, -0.01]))
    copies = _turn(jnp.arange(180) * np.deg2rad(2.0))  # the catalog's 2-degree sampling
    exact = pose_errors(points, jnp.ones(len(points), bool), T_true, T_estimate, copies, AXIS, CENTRE)
    sampled = pose_errors(points, jnp.ones(len(points), bool), T_true, T_estimate, copies)
    reference = _brute_force([moments], jaxlie.SE3(T_true.wxyz_xyz[None]), jaxlie.SE3(T_estimate.wxyz_xyz[None]))
    assert float(exact["symmetric_rmse"]) == pytest.approx(reference, abs=2e-3)
    assert float(exact["symmetric_rmse"]) <= float(sampled["symmetric_rmse"]) + 1e-5


def test_fused_touches_share_one_turn():
    moments, _ = _clouds(3, seed=1)
    rng = np.random.default_rng(2)
    T_true = jaxlie.SE3.exp(jnp.asarray(rng.normal(0, [20, 20, 20, 0.5, 0.5, 0.5], (3, 6)), jnp.float32))
    T_estimate = _turn(1.1) @ T_true @ jaxlie.SE3.exp(jnp.asarray(rng.normal(0, [0.3] * 3 + [0.01] * 3, (3, 6)),
                                                                   jnp.float32))
    mean, covariance = (jnp.stack(x) for x in zip(*moments))
    valid = jnp.ones(3, bool)
    copies = _turn(jnp.arange(180) * np.deg2rad(2.0))
    _, symmetric, _, _ = _errors(T_true, T_estimate, mean, covariance, valid, copies, AXIS, CENTRE)
    assert float(symmetric) == pytest.approx(_brute_force(moments, T_true, T_estimate), abs=2e-3)
    # A touch that does not count (padding) changes nothing.
    padded = [jnp.concatenate([x, x[:1]]) for x in (mean, covariance)]
    T_pad = [jaxlie.SE3(jnp.concatenate([T.wxyz_xyz, T.wxyz_xyz[:1] * 0 + jnp.array([1.0, 0, 0, 0, 9, 9, 9])]))
             for T in (T_true, T_estimate)]
    _, again, _, _ = _errors(*T_pad, *padded, jnp.array([True, True, True, False]), copies, AXIS, CENTRE)
    assert float(again) == pytest.approx(float(symmetric), abs=1e-5)


def test_no_axis_turns_nothing():
    moments, _ = _clouds(1)
    mean, covariance = (jnp.stack(x) for x in zip(*moments))
    T = jaxlie.SE3.exp(jnp.array([[1.0, 2.0, 3.0, 0.1, 0.2, 0.3]]))
    turn = closest_turn_about_axis(mean, covariance, jnp.ones(1, bool), T, _turn(0.5) @ T, jnp.zeros(3), CENTRE)
    np.testing.assert_allclose(np.asarray(turn.wxyz_xyz), np.asarray(jaxlie.SE3.identity().wxyz_xyz), atol=1e-6)


def test_belief_distances_take_the_copies_and_the_closest_turn(bumps_view, belief_settings):
    """The belief's distances up to symmetry (its modes, P(within 2 mm)) from the copies that no
    turn reaches plus the closed-form turn equal a search over every copy and turn."""
    from tactojax.localize._belief import empty_belief, hypothesis_distances, reference_cloud
    from tactojax.objects import ObjectSymmetry

    copies = ObjectSymmetry(axis="y", flips=("z",), centre=tuple(np.asarray(CENTRE))).copies()
    assert copies.wxyz_xyz.shape == (2, 7)
    view = bumps_view.replace(symmetries=copies, symmetry_axis=AXIS, symmetry_centre=CENTRE)
    belief = empty_belief(view, belief_settings)
    rng = np.random.default_rng(3)
    contact = belief.evidence.contact.at[0].set(jnp.asarray(rng.normal(0, 4, belief.evidence.contact.shape[1:])
                                                            + [0, 0, 40.0], jnp.float32))
    evidence = belief.evidence.replace(contact=contact, contact_valid=belief.evidence.contact_valid.at[0].set(True))
    T_reference = jaxlie.SE3.exp(jnp.array([10.0, 20.0, 5.0, 0.3, -0.2, 0.5]))
    M = belief.log_weights.shape[0]
    turns = _turn(jnp.asarray(rng.uniform(-np.pi, np.pi, M), jnp.float32))
    copy = jaxlie.SE3(copies.wxyz_xyz[rng.integers(0, 2, M)])
    noise = jaxlie.SE3.exp(jnp.asarray(rng.normal(0, [1.0] * 3 + [0.03] * 3, (M, 6)), jnp.float32))
    hypotheses = turns @ copy @ T_reference @ noise
    belief = belief.replace(evidence=evidence, touch_valid=belief.touch_valid.at[0].set(True),
                            T_object_reference=hypotheses)
    distances = np.asarray(hypothesis_distances(belief, T_reference, symmetric=True))
    moments = [cloud_moments(*reference_cloud(belief))]
    for m in range(M):
        T_m = jaxlie.SE3(hypotheses.wxyz_xyz[m:m + 1])
        reference = min(_brute_force(moments, T_m, jaxlie.SE3((jaxlie.SE3(copies.wxyz_xyz[c]) @ T_reference).wxyz_xyz[None]))
                        for c in range(2))
        assert distances[m] == pytest.approx(reference, abs=2e-3)
    plain = np.asarray(hypothesis_distances(belief, T_reference))
    assert np.all(distances <= plain + 1e-5) and np.any(distances < plain - 1.0)


_NESTED_COPIES = """
import jax, jax.numpy as jnp, jaxlie, numpy as np
from tactojax.localize._evaluate import closest_copy_square, cloud_moments

rng = np.random.default_rng(5)
poses = lambda n: jaxlie.SE3.exp(jnp.asarray(rng.normal(0, 1, (n, 6)), jnp.float32))
copies, hypotheses = poses(2), poses(2 * 8).wxyz_xyz.reshape(2, 8, 7)
mean, covariance = (x[None] for x in cloud_moments(jnp.asarray(rng.normal(0, 4, (50, 3)), jnp.float32),
                                                   jnp.ones(50, bool)))
one = lambda T: jaxlie.SE3(jnp.reshape(T, (1, 7)))

def square(T_true, T_estimate, axis):
    return closest_copy_square(mean, covariance, jnp.ones(1, bool), one(T_true), one(T_estimate), copies, axis,
                               jnp.array([1.0, 2.0, 3.0]))

for axis in (jnp.zeros(3), jnp.array([0.0, 1.0, 0.0])):
    nested = jax.vmap(lambda H: jax.vmap(lambda start: jax.vmap(lambda h: square(h, start, axis))(H))(H))
    got = np.asarray(jax.jit(nested)(hypotheses))  # (beliefs, starts, hypotheses)
    for b, i, j in [(0, 0, 1), (1, 3, 7), (1, 6, 2)]:
        want = float(jax.jit(square)(hypotheses[b, j], hypotheses[b, i], axis))
        assert abs(got[b, i, j] - want) <= 1e-3 + 1e-4 * want, (got[b, i, j], want)
print("ok")
"""


def test_copies_nested_in_vmaps_compile_with_the_default_emitters():
    """The closest of two symmetric copies, vmapped over beliefs and, within each, over the poses
    measured from and the hypotheses (as the new-grasps evaluation's credible sets run it), equals
    one pair of poses at a time, compiled as a user's process compiles it. A vmap over the copies
    inside crashed XLA's default CPU fusion emitters (jaxlib 0.10.2); the suite compiles with the
    older ones (conftest), so this runs in a fresh process without them."""
    import os
    import subprocess
    import sys

    flags = [f for f in os.environ.get("XLA_FLAGS", "").split()
             if not f.startswith(("--xla_cpu_use_fusion_emitters", "--xla_backend_optimization_level"))]
    run = subprocess.run([sys.executable, "-c", _NESTED_COPIES], capture_output=True, text=True, timeout=600,
                         env={**os.environ, "XLA_FLAGS": " ".join(flags), "JAX_PLATFORMS": "cpu"})
    assert run.returncode == 0 and run.stdout.strip() == "ok", (run.returncode, run.stderr[-2000:])
