"""Table-Carry: two agents carry a long table through a door (2D, pure JAX).

The map is 8 x 8 (x right, y up). A wall runs across it at y = 4 with one door opening, x in [3.3, 4.7].
The table is a rigid bar of length 2: the human holds end 0, the robot end 1. The table is longer than the
door is wide, so it passes only when it is held roughly along the door's direction (within ~35 degrees of
vertical, when carried straight). Start: the table lies below the wall, roughly horizontal (within 25
degrees), its centre in [3, 5] x [1.6, 2.2], the human's end to the left or to the right. Goal: both ends in
the goal zone above the wall, x in [2.5, 5.5], y in [5, 7.9].

Layout::

    +--------------------------------+ y = 8
    |        +------------+          |
    |        | goal zone  |          |   x in [2.5, 5.5], y in [5, 7.9]
    |        +------------+          |
    |=============    ===============| y = 4, door x in [3.3, 4.7]
    |                                |
    |        H ========== R          |   start: centre in [3, 5] x [1.6, 2.2], tilt within 25 degrees
    +--------------------------------+ y = 0

Two strategies: which end goes through the door first.
  1: human-leads: the human turns its end up towards the door and walks through first, the robot follows;
  2: robot-leads: the human turns its end down and pushes from behind, the robot's end goes through first.
At reset nothing tells the strategy (the start pose does not depend on it): only the human's first motion
(its end going up or down) reveals it. ``State.metrics["first"]`` records whose end crossed the wall first
(1 human, 2 robot).

Dynamics: action ``concat(a_H, a_R)``, each (dx, dy) in [-1, 1]; an agent moves its end by
``SPEED * clip(a, -1, 1)`` (SPEED = 0.1 map units). The table then keeps its centre and its length is
restored along its new direction. A move that leaves the map, or that would put the table through the wall
outside the door (the table's crossing of the wall line, and each end's path across it, must lie in the
door, x in [3.4, 4.6]: the door less the table's half-width), is replaced by the first valid of: both agents'
moves along y only, along x only, the human's move alone, the robot's move alone, no move.
``State.metrics["blocked"]`` counts the steps whose full move was refused.

Observation (6): human end xy / 8, robot end xy / 8, the table's unit direction from the robot's end to the
human's. No clock.
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from cogail_envs.base import CollabEnv, State

MAP = 8.0
SPEED = 0.1
LENGTH = 2.0  # the table
WALL_Y = 4.0
DOOR = (3.3, 4.7)  # the opening in the wall
PASS = (3.4, 4.6)  # where the table may cross the wall line: the door less the table's half-width
MARGIN = 0.1  # the ends stay this far inside the map
GOAL = np.array([2.5, 5.0, 5.5, 7.9], np.float32)  # x0, y0, x1, y1
START_CENTRE = np.array([[3.0, 1.6], [5.0, 2.2]], np.float32)
START_TILT = 25.0  # degrees from horizontal


def project(h: jax.Array, r: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Restore the table's length about its centre, along its current direction (batched over leading axes)."""
    c = 0.5 * (h + r)
    d = h - r
    u = d / jnp.maximum(jnp.linalg.norm(d, axis=-1, keepdims=True), 1e-6)
    return c + 0.5 * LENGTH * u, c - 0.5 * LENGTH * u


def _crosses_in_door(p: jax.Array, q: jax.Array) -> jax.Array:
    """Whether the segment p-q, if it meets the wall line, meets it within the passable part of the door."""
    sp, sq = p[..., 1] - WALL_Y, q[..., 1] - WALL_Y
    meets = sp * sq <= 0.0
    denom = sp - sq
    safe = jnp.where(jnp.abs(denom) > 1e-6, denom, 1.0)
    x = p[..., 0] + (q[..., 0] - p[..., 0]) * sp / safe
    inside = (x >= PASS[0]) & (x <= PASS[1]) & (jnp.abs(denom) > 1e-6)
    return ~meets | inside


def valid(h0: jax.Array, r0: jax.Array, h: jax.Array, r: jax.Array) -> jax.Array:
    """Whether the table may move from (h0, r0) to (h, r): inside the map, and through the wall only by the door
    (the table's crossing of the wall line and each end's path across it). Batched over leading axes."""
    ends = jnp.stack([h, r], axis=-2)
    inside = jnp.all((ends >= MARGIN) & (ends <= MAP - MARGIN), axis=(-2, -1))
    return inside & _crosses_in_door(h, r) & _crosses_in_door(h0, h) & _crosses_in_door(r0, r)


# the moves tried in turn, as masks of (human dx, dy, robot dx, dy): the full move, both along y, both along x,
# the human's alone, the robot's alone, none (always valid: the start is, and only valid moves are taken)
_FALLBACKS = np.array([[1, 1, 1, 1], [0, 1, 0, 1], [1, 0, 1, 0], [1, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 0]],
                      np.float32)


def move(h: jax.Array, r: jax.Array, dh: jax.Array, dr: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The table after the agents move its ends by dh, dr: the first valid of the full move, the moves along y,
    along x, the human's alone, the robot's alone, none. Returns (h, r, whether the full move was refused)."""
    delta = _FALLBACKS * jnp.concatenate([dh, dr])[None]  # (6, 4)
    ph, pr = project(h[None] + delta[:, :2], r[None] + delta[:, 2:])
    ok = valid(h[None], r[None], ph, pr).at[-1].set(True)
    k = jnp.argmax(ok)
    return ph[k], pr[k], ~ok[0]


def in_goal(p: jax.Array) -> jax.Array:
    return (p[0] >= GOAL[0]) & (p[0] <= GOAL[2]) & (p[1] >= GOAL[1]) & (p[1] <= GOAL[3])


class TableCarry(CollabEnv):
    """Table-Carry with brax's ``Env`` API (see the module docstring)."""

    name = "table_carry"
    human_action_size = 2
    robot_action_size = 2
    max_episode_steps = 200
    init_size = 4  # human end xy, robot end xy
    strategy_names = ("human-leads", "robot-leads")
    # the observation layout and the scripted team (part of the version fingerprint of generated demonstrations)
    spec_tag = "table-carry-v1"

    def __init__(self, max_episode_steps: int = 200):
        self.max_episode_steps = int(max_episode_steps)

    @property
    def observation_size(self) -> int:
        return 6

    # ------------------------------------------------------------------ dynamics
    def sample_init(self, rng: jax.Array) -> jax.Array:
        k1, k2, k3 = jax.random.split(rng, 3)
        c = jax.random.uniform(k1, (2,), minval=START_CENTRE[0], maxval=START_CENTRE[1])
        tilt = jnp.deg2rad(jax.random.uniform(k2, (), minval=-START_TILT, maxval=START_TILT))
        side = jnp.where(jax.random.bernoulli(k3), 1.0, -1.0)  # the human's end right (+1) or left (-1)
        half = 0.5 * LENGTH * side * jnp.array([jnp.cos(tilt), jnp.sin(tilt)])
        return jnp.concatenate([c + half, c - half]).astype(jnp.float32)

    def reset_from(self, init: jax.Array) -> State:
        init = jnp.asarray(init, jnp.float32)
        pipeline = {"pos": init.reshape(2, 2)}
        zero = jnp.zeros((), jnp.float32)
        metrics = {
            "success": zero,
            "first": zero,  # whose end crossed the wall first: 0 none yet, 1 human, 2 robot
            "blocked": zero,  # steps whose full move was refused
        }
        info = {"t": jnp.zeros((), jnp.int32), "truncation": zero}
        return State(pipeline, self._obs(pipeline), zero, zero, metrics, info)

    def _obs(self, ps: dict) -> jax.Array:
        h, r = ps["pos"][0], ps["pos"][1]
        u = (h - r) / jnp.maximum(jnp.linalg.norm(h - r), 1e-6)
        return jnp.concatenate([h / MAP, r / MAP, u]).astype(jnp.float32)

    def step(self, state: State, action: jax.Array) -> State:
        pos = state.pipeline_state["pos"]
        a = jnp.clip(action, -1.0, 1.0).reshape(2, 2) * SPEED
        h, r, refused = move(pos[0], pos[1], a[0], a[1])
        m = dict(state.metrics)
        above = jnp.stack([h[1] > WALL_Y, r[1] > WALL_Y])
        first = jnp.where(above[0], 1.0, jnp.where(above[1], 2.0, 0.0))
        m["first"] = jnp.where(m["first"] == 0, first, m["first"]).astype(jnp.float32)
        m["blocked"] = (m["blocked"] + refused).astype(jnp.float32)
        success = (in_goal(h) & in_goal(r)).astype(jnp.float32)
        m["success"] = jnp.maximum(m["success"], success)
        t = state.info["t"] + 1
        done, truncation = self.time_limit(t, m["success"] > 0)
        ps = {"pos": jnp.stack([h, r])}
        info = dict(state.info, t=t, truncation=truncation)
        return state.replace(pipeline_state=ps, obs=self._obs(ps), reward=success, done=done, metrics=m, info=info)

    # ------------------------------------------------------------------ strategies
    def classify_strategy(self, metrics: dict[str, jax.Array]) -> jax.Array:
        ok = (metrics["success"] > 0) & (metrics["first"] > 0)
        return jnp.where(ok, metrics["first"], 0).astype(jnp.int32)

    # ------------------------------------------------------------------ rendering
    def render(self, state: State, width: int = 256, height: int | None = None, camera: str | None = None) -> np.ndarray:
        """An RGB frame of the map, ``width`` pixels square (one view: ``height`` and ``camera`` are ignored)."""
        return render_frame(jax.device_get(state.pipeline_state), width)

    def human_position(self, state: State) -> jax.Array:
        """The human's end of the table in map units (x, y)."""
        return state.pipeline_state["pos"][0]


def render_frame(ps: dict[str, Any], size: int = 256) -> np.ndarray:
    """An RGB frame (size, size, 3) of one table_carry state (numpy; not jitted)."""
    from PIL import Image, ImageDraw

    s = size / MAP
    img = Image.new("RGB", (size, size), (245, 245, 240))
    d = ImageDraw.Draw(img)

    def xy(p):  # map -> pixel (y up)
        return float(p[0]) * s, size - float(p[1]) * s

    a, b = xy((GOAL[0], GOAL[3])), xy((GOAL[2], GOAL[1]))
    d.rectangle([a[0], a[1], b[0], b[1]], fill=(225, 240, 225), outline=(60, 150, 70), width=2)
    wall = max(2, int(0.2 * s))
    d.line([xy((0.0, WALL_Y)), xy((DOOR[0], WALL_Y))], fill=(70, 70, 70), width=wall)
    d.line([xy((DOOR[1], WALL_Y)), xy((MAP, WALL_Y))], fill=(70, 70, 70), width=wall)
    pos = np.asarray(ps["pos"])
    d.line([xy(pos[0]), xy(pos[1])], fill=(150, 100, 50), width=max(2, int(0.22 * s)))

    def disc(p, r, fill, outline):
        cx, cy = xy(p)
        d.ellipse([cx - r * s, cy - r * s, cx + r * s, cy + r * s], fill=fill, outline=outline, width=2)

    disc(pos[0], 0.25, (240, 120, 40), (90, 40, 0))  # human: orange
    disc(pos[1], 0.25, (40, 160, 230), (0, 50, 90))  # robot: blue
    return np.asarray(img)
