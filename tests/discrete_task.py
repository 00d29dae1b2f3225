"""A tiny task with discrete actions, for the trainer's tests: two agents on a line of 9 cells, both starting in the
middle; each step an agent moves left, stays or moves right (3 choices, one-hot). The human walks to one end (its
strategy: 1 left, 2 right) and the robot must walk to the other; success when both stand at opposite ends. The robot
can only tell where to go from the human's first moves."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cogail_envs import Task, Team, register_task
from cogail_envs.base import CollabEnv, State

CELLS = 9
MID = CELLS // 2


class LineMeet(CollabEnv):
    name = "line_meet"
    human_action_size = 3
    robot_action_size = 3
    human_action_discrete = True
    robot_action_discrete = True
    init_size = 2
    strategy_names = ("human left", "human right")

    def __init__(self, max_episode_steps: int = 14):
        self.max_episode_steps = int(max_episode_steps)

    @property
    def observation_size(self) -> int:
        return 2

    def sample_init(self, rng):
        return jnp.full((2,), float(MID))

    def reset_from(self, init):
        pos = jnp.asarray(init, jnp.float32)
        zero = jnp.zeros(())
        return State({"pos": pos}, pos / (CELLS - 1), zero, zero, {"success": zero, "human_end": zero},
                     {"t": jnp.zeros((), jnp.int32), "truncation": zero})

    def step(self, state, action):
        move = jnp.stack([jnp.argmax(action[:3]), jnp.argmax(action[3:])]).astype(jnp.float32) - 1.0
        pos = jnp.clip(state.pipeline_state["pos"] + move, 0, CELLS - 1)
        apart = ((pos[0] == 0) & (pos[1] == CELLS - 1)) | ((pos[0] == CELLS - 1) & (pos[1] == 0))
        m = dict(state.metrics)
        m["success"] = jnp.maximum(m["success"], apart.astype(jnp.float32))
        m["human_end"] = jnp.where(apart, jnp.where(pos[0] == 0, 1.0, 2.0), m["human_end"])
        t = state.info["t"] + 1
        done, tr = self.time_limit(t, apart)
        return state.replace(pipeline_state={"pos": pos}, obs=pos / (CELLS - 1), reward=apart.astype(jnp.float32),
                             done=done, metrics=m, info=dict(state.info, t=t, truncation=tr))

    def classify_strategy(self, metrics):
        return jnp.where(metrics["success"] > 0, metrics["human_end"], 0).astype(jnp.int32)

    def render(self, state, width=90, height=10, camera=None):
        img = np.zeros((height, width, 3), np.uint8)
        pos = np.asarray(state.pipeline_state["pos"]).astype(int)
        w = width // CELLS
        img[:, pos[0] * w:(pos[0] + 1) * w, 0] = 255
        img[:, pos[1] * w:(pos[1] + 1) * w, 2] = 255
        return img


def _init(env, rng, mix, variation):
    strategy = jax.random.choice(rng, 2, p=mix) + 1
    return {"strategy": strategy}, strategy


def _act(env, ts, state, rng):
    pos = state.pipeline_state["pos"]
    goal_h = jnp.where(ts["strategy"] == 1, 0.0, CELLS - 1.0)
    k1, k2 = jax.random.split(rng)
    step_h = jnp.where(jax.random.uniform(k1) < 0.2, 0.0, jnp.sign(goal_h - pos[0]))  # a pause now and then
    shown = pos[0] != MID  # the robot waits until the human's move shows the strategy
    goal_r = jnp.where(pos[0] < MID, CELLS - 1.0, 0.0)
    step_r = jnp.where(shown, jnp.sign(goal_r - pos[1]), 0.0)
    one_hot = lambda s: jax.nn.one_hot((s + 1).astype(jnp.int32), 3)  # noqa: E731
    return ts, jnp.concatenate([one_hot(step_h), one_hot(step_r)])


TASK = register_task(Task(name="line_meet", env=LineMeet, team=Team(init=_init, act=_act),
                          splits={"train": 16, "validation": 8, "test": 8},
                          default_config=lambda: dict(disc_loss="bce")), replace=True)
