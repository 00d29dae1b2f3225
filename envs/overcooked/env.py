"""Overcooked-AI (Carroll et al., NeurIPS 2019) as a collaboration task, on JaxMARL's v1 ``Overcooked`` (pure JAX).

Two cooks share a kitchen (:mod:`.kitchen`: five layouts). A soup is three onions put into a pot; it cooks for 20
steps, is ladled onto a plate and served at a serving spot (20 points). The game's dynamics are JaxMARL's,
unchanged: this class wraps its ``step_env`` (no auto-reset) and reads the events it needs off the states.

Seats: each episode seats the human as one of the two players, the robot as the other (the init vector's last
entry, ``seat``: the human's player, 0 or 1; ``sample_init`` draws it, so the robot learns and is judged in both
seats, as the field's agents are). ``State.info["seat"]`` holds it. Each agent has 6 discrete actions: 0 up, 1 down, 2 right, 3 left, 4 stay, 5 interact (y points down); ``step`` takes
``concat(a_H, a_R)`` as two one-hot vectors (12 floats) and acts on the argmax of each half; a half of zeros (no
choice: a replayed recording that has ended, or a file's padding) is stay.

Observation: the human's JaxMARL observation (that of the human's player), an (H, W, 26) grid of feature planes
(``obs_grid``; the human's planes first, then the robot's, then the kitchen's, pots and items, and the last-40-steps
urgency plane), flattened to float32; ``obs[seat_view]`` is the robot's. Reward: JaxMARL's, 20 per delivered soup (shared). Episodes last ``max_episode_steps``
(400); nothing ends them earlier, so every end is a truncation.

Metrics (float32, counted over the episode): ``soups`` (deliveries), ``success`` (1 once a soup was delivered),
and each agent's share of the work, ``_h`` for the human and ``_r`` for the robot:

* ``onions_h/_r``  onions put into a pot;
* ``plates_h/_r``  plates picked up (from the pile or a counter);
* ``dished_h/_r``  ready soups ladled from a pot onto a plate;
* ``served_h/_r``  soups delivered.

Strategy (:meth:`Overcooked.classify_strategy`): the division of labour between cooking (putting onions in) and
serving (ladling a soup and carrying it out). With the human's shares ``cook_h = onions_h / (onions_h + onions_r)``
and ``serve_h = (dished_h + served_h) / (dished_h + dished_r + served_h + served_r)`` (1/2 where neither did it),
a job is an agent's when its share is at least 2/3 (:data:`SHARE`), and::

    0  none                          no soup delivered
    1  human cooks, robot serves     cook_h >= 2/3 and serve_h <= 1/3
    2  robot cooks, human serves     cook_h <= 1/3 and serve_h >= 2/3
    3  shared                        anything else: at least one job done by both (shares in (1/3, 2/3))
    4  human cooks and serves        cook_h >= 2/3 and serve_h >= 2/3 (the robot fetches, e.g. forced coordination)
    5  robot cooks and serves        cook_h <= 1/3 and serve_h <= 1/3

Start (``sample_init``): the agents on the trials' start cells (:data:`~.kitchen.TRIAL_STARTS`; ``start="jaxmarl"``:
JaxMARL's layout start cells instead), facing random directions as JaxMARL's reset draws them, empty hands, pots and
counters. ``reset_from(init)`` starts from any game state (:mod:`.kitchen` has the init vector's layout).
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..base import CollabEnv, State
from . import features
from . import kitchen as kt

NUM_ACTIONS = 6
ACTION_NAMES = ("up", "down", "right", "left", "stay", "interact")
STAY, INTERACT = 4, 5
OBS_CHANNELS = 26
STARTS = ("trials", "jaxmarl")
DELIVERY_REWARD = 20.0  # JaxMARL's reward per delivered soup
SHARE = 2.0 / 3.0  # the share of a job that makes it an agent's (classify_strategy; _owner's arithmetic)
METRICS = ("success", "soups", "onions_h", "onions_r", "plates_h", "plates_r", "dished_h", "dished_r",
           "served_h", "served_r")


class Overcooked(CollabEnv):
    """Overcooked-AI on JaxMARL, with brax's ``Env`` API (see the module docstring)."""

    human_action_size = NUM_ACTIONS
    robot_action_size = NUM_ACTIONS
    human_action_discrete = True
    robot_action_discrete = True
    score_metric = "soups"
    strategy_names = ("human cooks, robot serves", "robot cooks, human serves", "shared", "human cooks and serves",
                      "robot cooks and serves")

    def __init__(self, kitchen: str = "cramped_room", max_episode_steps: int = 400, start: str = "trials"):
        if start not in STARTS:
            raise ValueError(f"unknown start {start!r}: choose one of {', '.join(STARTS)}")
        self.kitchen = kitchen
        self.geometry = kt.kitchen_geometry(kitchen)  # raises for an unknown kitchen
        self.max_episode_steps = int(max_episode_steps)
        self.start = start
        self.name = "overcooked" if kitchen == "cramped_room" else f"overcooked_{kitchen}"
        # the dynamics (JaxMARL v1), the observation and init layouts and the start (version fingerprint)
        self.spec_tag = f"overcooked-v1-seats-{kitchen}" + ("" if start == "trials" else f"-{start}")
        self.init_size = self.geometry.init_size + 1  # the game state, then the human's seat
        self.obs_grid = (self.geometry.height, self.geometry.width, OBS_CHANNELS)
        # the state as player 1 sees it: JaxMARL puts an agent's own planes first (position 0, orientations 2-5) and
        # its partner's next (1, 6-9); the kitchen's planes are the same for both
        channels = np.array([1, 0, 6, 7, 8, 9, 2, 3, 4, 5, *range(10, OBS_CHANNELS)])
        self.seat_view = tuple(int(i) for i in np.arange(self.observation_size).reshape(self.obs_grid)[..., channels]
                               .reshape(-1))
        self._game = kt.jaxmarl_game(kitchen, self.max_episode_steps)
        self.person_features = features.make_featurize(self.geometry.cells)  # what the field's BC models read

    @property
    def observation_size(self) -> int:
        return int(np.prod(self.obs_grid))

    # ------------------------------------------------------------------ dynamics
    def sample_init(self, rng: jax.Array) -> jax.Array:
        """The task's start (module docstring): fixed cells, empty hands, pots and counters; random facings."""
        cells = self.geometry.start if self.start == "trials" else self.geometry.jaxmarl_start
        k_dir, k_seat = jax.random.split(rng)
        game = kt.start_init(self.geometry, jax.random.randint(k_dir, (2,), 0, 4), cells)
        return jnp.concatenate([game, jax.random.randint(k_seat, (1,), 0, 2).astype(jnp.float32)])

    def seat_init(self, init: jax.Array, seat) -> jax.Array:
        """``init`` with the human seated as player ``seat`` (0 or 1)."""
        return jnp.asarray(init).at[-1].set(jnp.asarray(seat, jnp.float32))

    def reset_from(self, init: jax.Array) -> State:
        init = jnp.asarray(init, jnp.float32)
        ps = kt.state_from_init(self.geometry, init[:-1])
        seat = init[-1].astype(jnp.int32)
        zero = jnp.zeros((), jnp.float32)
        metrics = {k: zero for k in METRICS}
        info = {"t": jnp.zeros((), jnp.int32), "truncation": zero, "seat": seat}
        return State(ps, self._obs(self._game.get_obs(ps), seat), zero, zero, metrics, info)

    def encode(self, state: State) -> jax.Array:
        """The init vector of a state (``reset_from(encode(s))`` restores the game state of ``s``)."""
        return jnp.concatenate([kt.init_from_state(self.geometry, state.pipeline_state),
                                state.info["seat"].astype(jnp.float32)[None]])

    def _obs(self, obs: dict, seat) -> jax.Array:
        """The human's observation: that of the human's player."""
        return jnp.where(seat == 0, obs["agent_0"], obs["agent_1"]).astype(jnp.float32).reshape(-1)

    def step(self, state: State, action: jax.Array) -> State:
        ps, seat = state.pipeline_state, state.info["seat"]
        halves = jnp.asarray(action).reshape(2, NUM_ACTIONS)
        hr = jnp.where(jnp.any(halves != 0, axis=-1), jnp.argmax(halves, axis=-1), STAY)  # human, robot
        hr = hr.astype(jnp.int32)
        acts = jnp.where(seat == 0, hr, hr[::-1])  # by player
        obs, nps, rewards, _, _ = self._game.step_env(jax.random.PRNGKey(0), ps, {"agent_0": acts[0],
                                                                                  "agent_1": acts[1]})
        before, after = ps.agent_inv, nps.agent_inv
        ahead = (ps.agent_pos.astype(jnp.int32) + ps.agent_dir.astype(jnp.int32))  # the cell each agent faces
        facing = jnp.asarray(self.geometry.cells)[ahead[:, 1], ahead[:, 0]]
        events = {
            "onions": (before == kt.ONION) & (after == kt.EMPTY) & (facing == kt.POT_CELL),
            "plates": (before == kt.EMPTY) & (after == kt.PLATE),
            "dished": (before == kt.PLATE) & (after == kt.DISH) & (facing == kt.POT_CELL),
            "served": (before == kt.DISH) & (after == kt.EMPTY) & (facing == kt.GOAL_CELL),
        }
        m = dict(state.metrics)
        for name, happened in events.items():
            happened = happened.astype(jnp.float32)  # by player: the human's is the seat's
            m[f"{name}_h"] = m[f"{name}_h"] + happened[seat]
            m[f"{name}_r"] = m[f"{name}_r"] + happened[1 - seat]
        m["soups"] = m["soups"] + jnp.sum(events["served"].astype(jnp.float32))
        m["success"] = (m["soups"] > 0).astype(jnp.float32)
        t = state.info["t"] + 1
        done, truncation = self.time_limit(t, jnp.zeros((), bool))
        info = dict(state.info, t=t, truncation=truncation)
        reward = jnp.asarray(rewards["agent_0"], jnp.float32)
        obs = self._obs(obs, seat)
        return state.replace(pipeline_state=nps, obs=obs, reward=reward, done=done, metrics=m, info=info)

    # ------------------------------------------------------------------ strategies
    def classify_strategy(self, metrics: dict[str, jax.Array]) -> jax.Array:
        cook = _owner(metrics["onions_h"], metrics["onions_r"])
        serve = _owner(metrics["dished_h"] + metrics["served_h"], metrics["dished_r"] + metrics["served_r"])
        sid = jnp.select([(cook == 1) & (serve == 2), (cook == 2) & (serve == 1), (cook == 1) & (serve == 1),
                          (cook == 2) & (serve == 2)], [1, 2, 4, 5], 3)
        return jnp.where(metrics["success"] > 0, sid, 0).astype(jnp.int32)

    # ------------------------------------------------------------------ rendering
    def render(self, state: State, width: int = 320, height: int = 240, camera: str | None = None) -> np.ndarray:
        """An RGB frame (height, width, 3) of the kitchen (one view: ``camera`` is ignored)."""
        from .render import render_frame

        init = np.asarray(jax.device_get(self.encode(state)))
        game, seat = init[:-1].copy(), int(round(float(init[-1])))
        if seat == 1:  # the human drawn as the first player (orange)
            sl = self.geometry.init_slices()
            for name in ("dir", "held"):
                game[sl[name]] = game[sl[name]][::-1]
            game[0:4] = np.concatenate([game[2:4], game[0:2]])
        return render_frame(self.geometry, game, width, height)

    def human_position(self, state: State) -> jax.Array:
        """The human's cell (x, y), y down."""
        return state.pipeline_state.agent_pos[state.info["seat"]].astype(jnp.float32)


def _owner(human: jax.Array, robot: jax.Array) -> jax.Array:
    """Whose job it is from how often each did it: 1 the human's (share >= 2/3), 2 the robot's (human's share
    <= 1/3), 0 both's (in between, or neither did it). Exact for counts: ``3 h >= 2 (h + r)``."""
    total = human + robot
    mine = (3 * human >= 2 * total) & (total > 0)
    theirs = (3 * robot >= 2 * total) & (total > 0)
    return jnp.where(mine, 1, jnp.where(theirs, 2, 0))


def one_hot_actions(ids: Any) -> np.ndarray:
    """One-hot float32 vectors (..., 6) of action ids."""
    return np.eye(NUM_ACTIONS, dtype=np.float32)[np.asarray(ids, np.int64)]
