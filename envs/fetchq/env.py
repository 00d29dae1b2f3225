"""2D-Fetch-Quest: a pure-JAX two-agent collaboration game (Co-GAIL paper, appendix).

The map is 8 x 8. Two locked rooms sit in the top corners, each holding a treasure. Each room has a
button outside it (below the room, towards the map's side); a room's door is open while an agent stands
on its button, and only then can an agent enter the room. The button is too far from the room for one
agent to hold it and walk in, so a room can only be entered when the collaborator holds its button.
Win: both agents hold a treasure and stand in a destination zone (bottom corners; each agent goes to the
one closest to it).

Layout (x right, y up)::

    +--------+--------------+--------+
    | L room |              | R room |   rooms: [0, 2.5] x [5.5, 8] and [5.5, 8] x [5.5, 8]
    |   T  door           door  T    |   doors face the centre (waiting spots at (3.0, 6.75), (5.0, 6.75))
    +--------+              +--------+
      (B_L)                      (B_R)     buttons at (0.9, 3.8) and (7.1, 3.8)
          start band: x in [3, 5], y in [0.8, 1.8]
     [D]                            [D]    destinations at (1, 1) and (7, 1), radius 0.7

Four strategies (paper appendix): who is helped first x which room each agent takes.
  1: human's room is L, the human helps the robot first (human holds B_R, robot fetches in R first)
  2: human's room is L, the human is helped first (robot holds B_L, human fetches in L first)
  3: human's room is R, the human helps the robot first (human holds B_L, robot fetches in L first)
  4: human's room is R, the human is helped first (robot holds B_R, human fetches in R first)
At reset nothing tells the strategy (start positions are drawn from one band): only the human's motion
reveals it, so a robot that ignores the human fails three episodes in four.

Action: ``concat(a_H, a_R)``, each (dx, dy) in [-1, 1]; an agent moves ``SPEED * clip(a, -1, 1)`` per
step (SPEED = 0.23 map units, so a scripted demonstration lasts ~145 steps).

Observation (12): human xy, robot xy, left treasure xy, right treasure xy (all / 8), left door open,
right door open, human carries, robot carries. A carried treasure moves with its carrier. As in the paper's
state, no clock: a policy that saw the time step could follow the demonstrators' timing instead of the person.
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..base import CollabEnv, State

MAP = 8.0
SPEED = 0.23
AGENT_R = 0.15
ROOMS = np.array([[0.0, 5.5, 2.5, 8.0], [5.5, 5.5, 8.0, 8.0]], np.float32)  # x0, y0, x1, y1
TREASURES = np.array([[1.1, 7.0], [6.9, 7.0]], np.float32)
DOOR_SPAN = (6.25, 7.25)  # y-extent of each door
DOOR_SPOTS = np.array([[3.0, 6.75], [5.0, 6.75]], np.float32)
BUTTONS = np.array([[0.9, 3.8], [7.1, 3.8]], np.float32)
DESTS = np.array([[1.0, 1.0], [7.0, 1.0]], np.float32)
BUTTON_R = 0.45
PICK_R = 0.5
DEST_R = 0.7
START_BAND = np.array([[3.0, 0.8], [5.0, 1.8]], np.float32)

def _in_room(p: jax.Array, room: int) -> jax.Array:
    r = ROOMS[room]
    return (p[0] > r[0]) & (p[0] < r[2]) & (p[1] > r[1]) & (p[1] < r[3])


def _at_door(p: jax.Array, room: int) -> jax.Array:
    """Whether p stands in front of the room's door (the room's wall that faces the map's centre)."""
    wall = ROOMS[room, 2] if room == 0 else ROOMS[room, 0]
    side = (p[0] >= wall) if room == 0 else (p[0] <= wall)
    return side & (p[1] >= DOOR_SPAN[0] - 0.25) & (p[1] <= DOOR_SPAN[1] + 0.25)


def _move(p: jax.Array, delta: jax.Array, doors: jax.Array) -> jax.Array:
    """Move p by delta. Rooms are entered only through their door, and only while it is open; walls stop
    the agent (it slides along them). Leaving a room is always possible."""

    def valid(q):
        ok = jnp.array(True)
        for room in range(2):
            entering = _in_room(q, room) & ~_in_room(p, room)
            ok = ok & ~(entering & ~((doors[room] > 0.5) & _at_door(p, room)))
        return ok

    lo, hi = AGENT_R, MAP - AGENT_R
    full = jnp.clip(p + delta, lo, hi)
    xonly = jnp.clip(p + delta * jnp.array([1.0, 0.0]), lo, hi)
    yonly = jnp.clip(p + delta * jnp.array([0.0, 1.0]), lo, hi)
    return jnp.where(valid(full), full, jnp.where(valid(xonly), xonly, jnp.where(valid(yonly), yonly, p)))


class FetchQuest(CollabEnv):
    """2D-Fetch-Quest with brax's ``Env`` API."""

    name = "fetchq"
    human_action_size = 2
    robot_action_size = 2
    max_episode_steps = 300
    init_size = 4
    strategy_names = ("human-helps-first/left", "human-first/left", "human-helps-first/right", "human-first/right")
    # the observation layout and the scripted team's behaviour (part of the version fingerprint of generated
    # demonstrations: cached ones made under another layout or by another team are regenerated)
    spec_tag = "obs12-watching-team"

    def __init__(self, max_episode_steps: int = 300):
        self.max_episode_steps = int(max_episode_steps)

    @property
    def observation_size(self) -> int:
        return 12

    # ------------------------------------------------------------------ dynamics
    def sample_init(self, rng: jax.Array) -> jax.Array:
        k1, k2 = jax.random.split(rng)
        lo, hi = START_BAND
        a = jax.random.uniform(k1, (2,), minval=lo, maxval=hi)
        # second agent at least 0.6 away from the first, same band
        off = jax.random.uniform(k2, (2,), minval=jnp.array([0.6, -0.5]), maxval=jnp.array([1.4, 0.5]))
        sign = jnp.where(a[0] > 4.0, -1.0, 1.0)
        b = jnp.clip(a + off * jnp.array([sign, 1.0]), lo, hi)
        swap = jax.random.bernoulli(k2)
        h, r = jnp.where(swap, b, a), jnp.where(swap, a, b)
        return jnp.concatenate([h, r])

    def reset_from(self, init: jax.Array) -> State:
        init = jnp.asarray(init, jnp.float32)
        pipeline = {
            "pos": init.reshape(2, 2),
            "treasure": jnp.asarray(TREASURES),
            "carry": jnp.full((2,), -1, jnp.int32),  # room index of the treasure each agent carries
            "doors": jnp.zeros((2,), jnp.float32),
        }
        pipeline["doors"] = self._doors(pipeline["pos"])
        zero = jnp.zeros(())
        metrics = {
            "success": zero,
            "human_room": zero,  # 0 none, 1 left, 2 right: room of the human's treasure
            "robot_room": zero,
            "first": zero,  # 0 none, 1 human picked a treasure first, 2 robot first
            "human_pressed": zero,  # 0 none, else 1 + room of the first button the human held
            "robot_pressed": zero,
        }
        info = {"t": jnp.zeros((), jnp.int32), "truncation": zero}
        obs = self._obs(pipeline)
        return State(pipeline, obs, zero, zero, metrics, info)

    def _doors(self, pos: jax.Array) -> jax.Array:
        d = jnp.linalg.norm(pos[:, None, :] - BUTTONS[None], axis=-1)  # (agent, button)
        return jnp.any(d < BUTTON_R, axis=0).astype(jnp.float32)

    def _obs(self, ps: dict) -> jax.Array:
        return jnp.concatenate(
            [
                ps["pos"].reshape(-1) / MAP,
                ps["treasure"].reshape(-1) / MAP,
                ps["doors"],
                (ps["carry"] >= 0).astype(jnp.float32),
            ]
        )

    def step(self, state: State, action: jax.Array) -> State:
        ps = state.pipeline_state
        a = jnp.clip(action, -1.0, 1.0).reshape(2, 2) * SPEED
        doors = ps["doors"]
        pos = jnp.stack([_move(ps["pos"][i], a[i], doors) for i in range(2)])
        carry = ps["carry"]
        treasure = ps["treasure"]
        m = dict(state.metrics)
        # pick up: an agent inside room k near its (untaken) treasure, carrying nothing
        taken = jnp.stack([jnp.any(carry == k) for k in range(2)])
        for i in range(2):
            for k in range(2):
                near = jnp.linalg.norm(pos[i] - treasure[k]) < PICK_R
                pick = (carry[i] < 0) & ~taken[k] & near & _in_room(pos[i], k)
                carry = carry.at[i].set(jnp.where(pick, k, carry[i]))
                taken = taken.at[k].set(taken[k] | pick)
                m["first"] = jnp.where(pick & (m["first"] == 0), i + 1.0, m["first"])
        m["human_room"] = jnp.where(carry[0] >= 0, carry[0] + 1.0, 0.0).astype(jnp.float32)  # not weak-typed
        m["robot_room"] = jnp.where(carry[1] >= 0, carry[1] + 1.0, 0.0).astype(jnp.float32)
        for k in range(2):
            treasure = treasure.at[k].set(
                jnp.where(carry[0] == k, pos[0], jnp.where(carry[1] == k, pos[1], treasure[k]))
            )
        new_doors = self._doors(pos)
        # who pressed which button first (strategy events)
        dist_b = jnp.linalg.norm(pos[:, None, :] - BUTTONS[None], axis=-1) < BUTTON_R  # (agent, button)
        for i, key in ((0, "human_pressed"), (1, "robot_pressed")):
            pressed = jnp.where(dist_b[i, 0], 1.0, jnp.where(dist_b[i, 1], 2.0, 0.0))
            m[key] = jnp.where(m[key] == 0, pressed, m[key])
        in_dest = jnp.any(jnp.linalg.norm(pos[:, None, :] - DESTS[None], axis=-1) < DEST_R, axis=1)
        success = jnp.all(in_dest & (carry >= 0)).astype(jnp.float32)
        m["success"] = jnp.maximum(m["success"], success)
        t = state.info["t"] + 1
        done, truncation = self.time_limit(t, m["success"] > 0)
        new_ps = {"pos": pos, "treasure": treasure, "carry": carry, "doors": new_doors}
        info = dict(state.info, t=t, truncation=truncation)
        return state.replace(
            pipeline_state=new_ps, obs=self._obs(new_ps), reward=success, done=done, metrics=m, info=info
        )

    # ------------------------------------------------------------------ strategies
    def classify_strategy(self, metrics: dict[str, jax.Array]) -> jax.Array:
        hr, rr, first = metrics["human_room"], metrics["robot_room"], metrics["first"]
        ok = (metrics["success"] > 0) & (hr > 0) & (rr > 0) & (hr != rr) & (first > 0)
        sid = jnp.where(hr == 1, 0, 2) + jnp.where(first == 2, 1, 2)
        return jnp.where(ok, sid, 0).astype(jnp.int32)

    # ------------------------------------------------------------------ rendering
    def render(self, state: State, width: int = 256, height: int | None = None, camera: str | None = None) -> np.ndarray:
        """An RGB frame of the map, ``width`` pixels square (one view: ``height`` and ``camera`` are ignored)."""
        return render_frame(jax.device_get(state.pipeline_state), width)

    def human_position(self, state: State) -> jax.Array:
        """The human agent's position in map units (x, y)."""
        return state.pipeline_state["pos"][0]


def render_frame(ps: dict[str, Any], size: int = 256) -> np.ndarray:
    """An RGB frame (size, size, 3) of one fetchq state (numpy; not jitted)."""
    from PIL import Image, ImageDraw

    s = size / MAP
    img = Image.new("RGB", (size, size), (245, 245, 240))
    d = ImageDraw.Draw(img)

    def xy(p):  # map -> pixel (y up)
        return float(p[0]) * s, size - float(p[1]) * s

    def disc(p, r, fill, outline=None):
        cx, cy = xy(p)
        d.ellipse([cx - r * s, cy - r * s, cx + r * s, cy + r * s], fill=fill, outline=outline, width=2)

    doors = np.asarray(ps["doors"])
    for k, (x0, y0, x1, y1) in enumerate(ROOMS):
        a, b = xy((x0, y1)), xy((x1, y0))
        d.rectangle([a[0], a[1], b[0], b[1]], fill=(215, 215, 225), outline=(60, 60, 60), width=3)
        wall_x = x1 if k == 0 else x0
        top, bot = xy((wall_x, DOOR_SPAN[1])), xy((wall_x, DOOR_SPAN[0]))
        d.line([top, bot], fill=(40, 180, 60) if doors[k] > 0.5 else (200, 40, 40), width=6)
    for k, b in enumerate(BUTTONS):
        disc(b, BUTTON_R, (250, 220, 60) if doors[k] > 0.5 else (190, 170, 60), (80, 80, 0))
    for p in DESTS:
        cx, cy = xy(p)
        r = DEST_R * s
        d.rectangle([cx - r, cy - r, cx + r, cy + r], outline=(40, 90, 200), width=3)
    for p in np.asarray(ps["treasure"]):
        cx, cy = xy(p)
        r = 0.22 * s
        d.polygon([(cx, cy - r), (cx + r, cy), (cx, cy + r), (cx - r, cy)], fill=(255, 190, 0), outline=(120, 80, 0))
    pos = np.asarray(ps["pos"])
    disc(pos[0], 0.28, (240, 120, 40), (90, 40, 0))  # human: orange
    disc(pos[1], 0.28, (40, 160, 230), (0, 50, 90))  # robot: blue
    return np.asarray(img)

