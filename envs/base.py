"""The contract every cogail task implements (on top of brax's ``Env``).

A task is a ``brax.envs.base.Env`` whose action is ``concat(a_H, a_R)`` and whose observation is the
shared state ``s``. On top of brax's API a task exposes what the trainer, the demonstrators and the
evaluation need:

* ``human_action_size`` / ``robot_action_size`` -- the split of the action vector.
* ``human_action_discrete`` / ``robot_action_discrete`` -- each agent's action space: False (default) a box in
  [-1, 1]^size; True ``size`` discrete choices, given to ``step`` as a one-hot vector (the env acts on its argmax;
  demonstration files store the one-hot vectors, and the co-policy has a categorical head for that agent).
* ``score_metric`` (optional) -- the name of a ``State.metrics`` entry that counts what an episode achieved (e.g.
  soups served); evaluation reports its mean beside the success rate.
* ``max_episode_steps`` -- the time limit; ``step`` sets ``done`` on success, on failure or at the limit,
  and ``info["truncation"]`` (brax's convention) to 1.0 when the limit ended the episode without success or
  failure: a time-out is not a terminal state, and the trainer bootstraps it with the critic.
* ``init_size`` and ``reset_from(init)`` -- reset to a given initial condition (replay evaluation starts a
  held-out demonstration's episode exactly where the demonstration started); ``reset(rng)`` samples an
  ``init`` with ``sample_init`` and calls ``reset_from``.
* ``strategy_names`` -- the paper's strategy labels; ids are 1..len(strategy_names), 0 means "none".
* ``classify_strategy(metrics)`` -- label an executed episode from ``State.metrics`` at its last step
  (jittable, returns an int32; 0 when the episode did not succeed or fits no strategy).
* ``render(state, width, height, camera=None) -> np.ndarray`` -- an RGB frame (H, W, 3) uint8 of one
  (unbatched) state.
* ``human_position(state)`` (optional) -- where the human agent is (shown by ``cogail play``).

The scripted human-human team is not part of the env: it is the task's ``Team``
(:mod:`cogail_envs.registry`), which reads the env's state as a person at the table would.
* ``replay_hold(state, a_h) -> (wait, a_wait)`` (optional; default: never waits) -- the patient human of the
  replay protocol: whether a replayed human about to take its recorded action ``a_h`` waits instead, because that
  action would let go of something its partner has not taken yet, and what it does while it waits.

``State.metrics`` holds at least ``success`` (float 0/1, sticky within an episode) and the task's
strategy events. ``State.info`` holds at least ``t`` (int32 step counter) and ``truncation`` (float 0/1).
"""
from __future__ import annotations

import contextlib
import io
from typing import Sequence

import jax
import jax.numpy as jnp

with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints "Failed to import warp" (optional backend)
    import mujoco.mjx  # noqa: F401
    from brax.envs.base import Env, State

__all__ = ["CollabEnv", "State", "jitted"]


def jitted(env: Env, name: str):
    """``jax.jit(getattr(env, name))`` (e.g. ``step``, ``reset_from``), made once per env object and method: the
    callers that step an env from the host (the collection table, its scripted players, ``cogail play``) share one
    trace and compilation, where separate ``jax.jit`` wrappers of the same method trace and compile it each."""
    fns = env.__dict__.setdefault("_jitted_fns", {})
    if name not in fns:
        fns[name] = jax.jit(getattr(env, name))
    return fns[name]


class CollabEnv(Env):
    """Base class: brax ``Env`` plus the collaboration-task extras listed in the module docstring."""

    name: str = ""
    human_action_size: int = 0
    robot_action_size: int = 0
    human_action_discrete: bool = False
    robot_action_discrete: bool = False
    score_metric: str = ""
    max_episode_steps: int = 0
    init_size: int = 0
    strategy_names: Sequence[str] = ()
    # observation indices of object-centric features (the object's pose in each agent's frame and the reverse), and
    # of the absolute orientations (the agents' and the object's rotations in base or world frames): a run's
    # ``obs_frame`` chooses which of the two its networks read (algo.config)
    # the observation as the agent in the other seat sees it, ``obs[..., seat_view]`` (a permutation of its indices
    # that swaps the agents' own features): a task that has it can seat the robot in either place, and its people's
    # recordings train BC models of both players (the field's protocol, cogail_jax.eval.field)
    seat_view: Sequence[int] = ()
    # ``person_features(obs) -> (F,)``: hand-made features of an observation that the field's behaviour clones of
    # people read instead of the observation itself (cogail_jax.eval.field); None: they read the observation
    person_features = None
    object_frame_dims: Sequence[int] = ()
    orientation_dims: Sequence[int] = ()

    @property
    def action_size(self) -> int:
        return self.human_action_size + self.robot_action_size

    @property
    def backend(self) -> str:
        return "jax"

    @property
    def num_strategies(self) -> int:
        return len(self.strategy_names)

    def sample_init(self, rng: jax.Array) -> jax.Array:
        raise NotImplementedError

    def reset(self, rng: jax.Array) -> State:
        return self.reset_from(self.sample_init(rng))

    def reset_from(self, init: jax.Array) -> State:
        raise NotImplementedError

    def classify_strategy(self, metrics: dict[str, jax.Array]) -> jax.Array:
        raise NotImplementedError

    def render(self, state: State, width: int = 320, height: int = 240, camera: str | None = None):
        raise NotImplementedError

    def checkpoint_state(self, state: State) -> State:
        """The state as a checkpoint stores it: fields the next step recomputes before reading them may be zeroed
        (smaller checkpoints), as long as stepping it gives the same bits (the env contract's test checks it).
        This default keeps everything."""
        return state

    def human_position(self, state: State) -> jax.Array:
        """Where the human agent is (any units; ``cogail play`` shows it); empty where the task does not say."""
        return jnp.zeros((0,))

    def time_limit(self, t: jax.Array, terminal: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(done, truncation)`` (float32) for a step that reached step count ``t`` with ``terminal`` (bool:
        success or failure): the episode ends at a terminal state or at the time limit, and the time limit
        alone is a truncation."""
        limit = t >= self.max_episode_steps
        return (terminal | limit).astype(jnp.float32), (limit & ~terminal).astype(jnp.float32)

    @property
    def version(self) -> str:
        """A fingerprint of the task's dynamics and observation layout (MJCF, substeps, ``spec_tag``), stored in
        generated demonstration files: cached default demonstrations made under other physics (or, through
        ``spec_tag``, another observation layout or scripted team) are regenerated."""
        import hashlib

        parts = (self.name, getattr(self, "xml", ""), getattr(self, "n_substeps", ""), self.max_episode_steps)
        fingerprint = "|".join(str(p) for p in parts)
        if getattr(self, "spec_tag", ""):
            fingerprint += f"|{self.spec_tag}"
        return hashlib.sha1(fingerprint.encode()).hexdigest()[:12]

    def replay_hold(self, state: State, a_h: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Whether a patient replayed human waits instead of taking its recorded action ``a_h``, and its action
        while it waits (see the module docstring). This default never waits."""
        return jnp.zeros((), bool), a_h

    @property
    def has_patient_replay(self) -> bool:
        """Whether the task defines a patient human (``replay_hold``)."""
        return type(self).replay_hold is not CollabEnv.replay_hold

    def split_action(self, action: jax.Array) -> tuple[jax.Array, jax.Array]:
        return action[..., : self.human_action_size], action[..., self.human_action_size :]

    def uniform_mix(self) -> jax.Array:
        return jnp.full((self.num_strategies,), 1.0 / self.num_strategies)
