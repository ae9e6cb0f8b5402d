"""Slip sequences: per-frame limits of the walk, and every simulated frame a touch."""

import jax
import jaxlie
import numpy as np
import pytest

from tactojax.objects import get_object
from tactojax.simulate import SlipProtocol, SlipWalk, simulate_protocol, slip_offsets


def test_slip_stays_within_its_limits_per_frame_and_overall():
    protocol = SlipProtocol(frames=300, max_step_mm=0.5, max_step_deg=1.0, max_offset_mm=6.0, max_turn_deg=10.0)
    offsets = slip_offsets(jax.random.key(3), protocol)
    step = np.diff(offsets, axis=0)
    assert offsets.shape == (300, 3) and np.all(offsets[0] == 0)
    assert np.linalg.norm(step[:, :2], axis=1).max() <= 0.5 + 1e-9
    assert np.degrees(np.abs(step[:, 2])).max() <= 1.0 + 1e-9
    assert np.abs(offsets[:, :2]).max() <= 6.0 + 1e-9 and np.degrees(np.abs(offsets[:, 2])).max() <= 10.0 + 1e-9
    assert np.linalg.norm(step[:, :2], axis=1).mean() > 0.1  # it does move


def test_a_bounce_reverses_the_slip():
    walk = SlipWalk(jax.random.key(0), SlipProtocol(frames=50))
    ahead = walk.propose(4)
    walk.take(2, bounce=True)
    np.testing.assert_allclose(walk.offsets[-1], ahead[1])
    back = walk.propose(1)[0] - walk.offsets[-1]
    assert np.dot(back[:2], (ahead[2] - ahead[1])[:2]) < 0  # heading back the way it came
    with pytest.raises(ValueError, match="smoothness"):
        SlipWalk(jax.random.key(0), SlipProtocol(smoothness=1.0))


def test_slip_sequences_are_consecutive_touches(small_spec):
    protocol = SlipProtocol(sequences=2, frames=6, turns_deg=(0.0,))
    records = list(simulate_protocol(jax.random.key(1), small_spec, get_object("gum_box"), protocol,
                                     batch_size=4, progress=False))
    assert [int(r["sequence"][0]) for r in records] == [0, 1]
    for r in records:
        assert r["frame"].tolist() == list(range(6)) and r["mask"].any(axis=(1, 2)).all()
        T = jaxlie.SE3(np.asarray(r["T_world_gripper"]))
        # In the start gripper's frame, the slip is in the finger plane (x, z): at most 0.5 mm a frame.
        local = np.asarray((jaxlie.SE3(np.asarray(r["T_world_gripper"][:1])).inverse() @ T).translation())
        assert np.linalg.norm(np.diff(local[:, [0, 2]], axis=0), axis=1).max() <= 0.5 + 1e-3
