"""Beliefs along the touches of test episodes: the one compiled belief program behind the
new-grasps evaluation, the belief's calibration and identification.

An episode of G grasps with F fingers becomes one *touch sequence*: its touches in order
(grasp 0's fingers, grasp 1's, ...), each with its sensor pose (the kinematics), fused into one
belief; then, optionally, every later grasp's first finger *alone*, each after a reset to the
empty belief (a single touch, as a robot also meets it; grasp 0's first touch alone is the
sequence's first belief). :func:`episode_beliefs` runs the belief update along every episode's
sequence, one update per step in a ``lax.scan``, and returns the belief after every step.

The callers observe those beliefs in programs of their own (errors, calibration records,
log-evidence), which compile in a fraction of the update's time: the update itself compiles
once per map shape and settings, however many of them ask.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float
from tqdm.auto import tqdm

from tactojax import _struct as struct
from tactojax.localize._belief import BeliefSettings, PoseBelief, empty_belief, update_belief
from tactojax.localize._compile import top_level_jit
from tactojax.localize._map import LocalizationMap, Touch
from tactojax.localize._sharded import batch_mesh, in_batches, over_batch, run_sharded


@struct.dataclass
class TestEpisodes:
    """E episodes of G grasps with F fingers each, as localization reads them."""

    heightmaps: Float[Array, "E G F H W"]
    """Predicted heightmaps, mm."""
    masks: Bool[Array, "E G F H W"]
    """Predicted (observed) contact masks."""
    features: Float[Array, "E G F D"]
    """Retrieval features."""
    openings: Float[Array, "E G"]
    """Gripper openings, mm."""
    T_object_sensor: jaxlie.SE3
    """(E, G, F) true sensor poses in the object (map) frame: the truth, and the kinematics
    (only their relative poses within an episode reach the localizer)."""
    cloud_mean: Float[Array, "E G F 3"]
    """Mean of every touch's true contact cloud, sensor frame, mm (the error metric)."""
    cloud_covariance: Float[Array, "E G F 3 3"]
    """Its covariance, mm^2."""

    def sensor_touches(self) -> TestEpisodes:
        """Every grasp's sensor-finger touch (finger 0) as an episode of its own: (E * G, 1, 1) episodes."""
        def alone(x):
            return x[:, :, :1].reshape(-1, 1, 1, *x.shape[3:])

        return TestEpisodes(heightmaps=alone(self.heightmaps), masks=alone(self.masks), features=alone(self.features),
                            openings=self.openings.reshape(-1, 1),
                            T_object_sensor=jax.tree.map(alone, self.T_object_sensor),
                            cloud_mean=alone(self.cloud_mean), cloud_covariance=alone(self.cloud_covariance))


def episode_touch(episode: TestEpisodes, g, finger: int) -> Touch:
    """Grasp ``g``'s touch of finger ``finger`` in one episode."""
    return Touch(heightmap=episode.heightmaps[g, finger], mask=episode.masks[g, finger],
                 feature=episode.features[g, finger], opening=episode.openings[g])


def sequence_order(grasps: int, fingers: int, alone: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An episode's touch sequence (N = G * F, plus G - 1 with ``alone``): (N,) the grasp and
    (N,) the finger of every step, and (N,) whether the belief starts afresh there."""
    grasp = np.repeat(np.arange(grasps), fingers)
    finger = np.tile(np.arange(fingers), grasps)
    reset = np.arange(grasps * fingers) == 0
    if alone:
        grasp = np.concatenate([grasp, np.arange(1, grasps)])
        finger = np.concatenate([finger, np.zeros(grasps - 1, int)])
        reset = np.concatenate([reset, np.ones(grasps - 1, bool)])
    return grasp, finger, reset


def fused_steps(grasps: int, fingers: int) -> np.ndarray:
    """(G,) the step of a touch sequence after which the first g + 1 grasps are fused."""
    return np.arange(grasps) * fingers + fingers - 1


def alone_steps(grasps: int, fingers: int) -> np.ndarray:
    """(G,) the step of a touch sequence (with ``alone``) whose belief holds grasp g's first
    finger alone (grasp 0's: the sequence's first step)."""
    return np.concatenate([[0], grasps * fingers + np.arange(grasps - 1)]).astype(int)


def sequence_touches(grasps: int, fingers: int, alone: bool) -> np.ndarray:
    """(N, G * F) which of an episode's touches (grasp-major) every step's belief holds."""
    grasp, finger, reset = sequence_order(grasps, fingers, alone)
    holds = np.zeros((len(grasp), grasps * fingers), bool)
    for step, (g, f) in enumerate(zip(grasp, finger)):
        if not reset[step]:
            holds[step] = holds[step - 1]
        holds[step, g * fingers + f] = True
    return holds


def beliefs_along(view: LocalizationMap, episode: TestEpisodes, fingers: int, alone: bool,
                  settings: BeliefSettings) -> PoseBelief:
    """(N,) the belief after every step of one episode's touch sequence (:func:`sequence_order`),
    each touch at its sensor pose in the object frame (the kinematics). Pure; the callers jit it."""
    grasp, finger, reset = sequence_order(episode.openings.shape[0], fingers, alone)
    empty = empty_belief(view, settings)

    def step(belief, item):
        g, f, restart = item
        belief = jax.tree.map(lambda e, b: jnp.where(restart, e, b), empty, belief)
        T_touch = jax.tree.map(lambda x: x[g, f], episode.T_object_sensor)
        belief = update_belief(view, belief, episode_touch(episode, g, f), T_touch, settings)
        return belief, belief

    _, beliefs = jax.lax.scan(step, empty, (jnp.asarray(grasp), jnp.asarray(finger), jnp.asarray(reset)))
    return beliefs


@functools.partial(top_level_jit, static_argnames=("fingers", "alone", "settings", "batch_size", "mesh"))
def _episode_beliefs(view: LocalizationMap, episodes: TestEpisodes, fingers: int, alone: bool,
                     settings: BeliefSettings, batch_size: int, mesh) -> PoseBelief:
    def local(view, episodes):
        return in_batches(lambda episode: beliefs_along(view, episode, fingers, alone, settings), episodes,
                          batch_size)

    return over_batch(local, mesh)(view, episodes)


def episode_beliefs(
    view: LocalizationMap,
    episodes: TestEpisodes,
    *,
    fingers: int,
    alone: bool = False,
    settings: BeliefSettings = BeliefSettings(),
    devices=None,
    batch_size: int = 1,
    progress: bool = False,
) -> PoseBelief:
    """The belief after every step of every episode's touch sequence (:func:`sequence_order`).

    One compiled program for a map shape, settings, sequence and batch size: the episodes are
    sharded over ``devices`` (a mesh with one ``batch`` axis), each device fusing ``batch_size``
    episodes at once (vmapped; 1: one at a time, the reference results).

    Args:
        view: the object's map (its calibration and symmetries are used).
        episodes: E test episodes of G grasps (F >= ``fingers``).
        fingers: fingers fused per grasp.
        alone: also every later grasp's first finger alone.
        settings: belief parameters.
        devices: the devices the episodes are sharded over (default: every local device).
        batch_size: episodes a device fuses at once.
        progress: a progress bar (per chunk of episodes).

    Returns:
        (E, N) beliefs, as numpy arrays.
    """
    if fingers < 1 or episodes.heightmaps.shape[2] < fingers:
        raise ValueError(f"{fingers} fingers asked, and the episodes have {episodes.heightmaps.shape[2]}")
    mesh = batch_mesh(devices)
    count = episodes.openings.shape[0]
    batch_size = min(batch_size, count)
    program = functools.partial(_episode_beliefs, fingers=fingers, alone=alone, settings=settings,
                                batch_size=batch_size, mesh=mesh)
    with tqdm(total=count, desc=f"beliefs ({fingers} finger{'s' * (fingers > 1)})", unit="episode",
              disable=not progress) as bar:
        return run_sharded(program, view, episodes, mesh=mesh, bar=bar,
                           per_device=batch_size)
