"""Table-Carry's scripted human-human team (the env is :mod:`.env`).

The human follows a three-phase plan for the strategy drawn from ``mix``. Its end is its own to steer:

* TURN: turn the table upright where it stands, its own end up (human-leads) or down (robot-leads): the
  target is 1 above (or below) the table's starting centre, moved halfway towards the door's x;
* ALIGN: bring the table under the door, upright: the leading end at (4 + dx, 3.35) (dx a small per-episode
  offset); the phase ends once the human is there and the table is within ~7 degrees of vertical;
* THROUGH: carry it up through the door until the leading end is at (4 + dx', 7.3) (the episode ends on
  success, once both ends are in the goal zone).

The robot does not know the plan. It watches the human's end: it accumulates the end's vertical motion since
the start and, once that exceeds 0.25 map units, reads the strategy off its sign (up: human-leads, down:
robot-leads); until then it holds its end still. After a reaction delay it keeps its end one table length
below (human-leads) or above (robot-leads) the human's end: it moves with the human's motion (the human's
last action, which it feels through the table) plus a correction towards that point, and it keeps its end
below the wall unless the table is upright in front of the door.

Variety within a strategy: speeds, a lateral bend of the human's first two legs, the door offsets, reaction delays after
each phase and before the robot's first move, short pauses, action noise; commands are low-pass filtered and
slow down on arrival. ``variation`` is ignored (the team has no varied humans).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from cogail_envs.registry import Team

from .env import LENGTH, SPEED, WALL_Y

TURN, ALIGN, THROUGH = range(3)
UNKNOWN = 0
DOOR_X = 4.0
ALIGN_Y, GOAL_Y = 3.35, 7.3  # the leading end's targets
READ_AT = 0.25  # vertical motion of the human's end after which the robot reads the strategy
UPRIGHT = 0.12  # |x component| of the table's direction below which ALIGN is done
ROBOT_GAIN = 0.3
NOISE_STD = (0.05, 0.03)


class TeamState(NamedTuple):
    strategy: jax.Array  # (2,) int32: the human's plan; what the robot has read (UNKNOWN until it has)
    phase: jax.Array  # () int32: the human's phase
    delay: jax.Array  # (2,) int32: reaction-delay / pause countdown
    prev: jax.Array  # (2, 2) previous actions (smoothing; the robot feels the human's)
    speed: jax.Array  # (2,) per-episode speed factor
    curve: jax.Array  # () lateral bend of the human's current leg
    offset: jax.Array  # (2,) x offsets from the door's centre: ALIGN, THROUGH
    anchor: jax.Array  # (2,) the table's centre at the start (set at t = 0)
    h_prev: jax.Array  # (2,) the human's end at the previous step (what the robot saw)
    watched: jax.Array  # () the human end's vertical motion since the start, as the robot saw it


def team_init(env, rng: jax.Array, mix: jax.Array, variation=0) -> tuple[TeamState, jax.Array]:
    ks = jax.random.split(rng, 5)
    strategy = (jax.random.categorical(ks[0], jnp.log(jnp.asarray(mix) + 1e-12)) + 1).astype(jnp.int32)
    ts = TeamState(
        strategy=jnp.stack([strategy, jnp.int32(UNKNOWN)]),
        phase=jnp.int32(TURN),
        delay=jax.random.randint(ks[1], (2,), 0, 5).astype(jnp.int32),
        prev=jnp.zeros((2, 2), jnp.float32),
        speed=jax.random.uniform(ks[2], (2,), minval=jnp.array([0.65, 0.9]), maxval=jnp.array([0.9, 1.0])),
        curve=jax.random.uniform(ks[3], (), minval=-0.4, maxval=0.4),
        offset=jax.random.uniform(ks[4], (2,), minval=jnp.array([-0.12, -0.3]), maxval=jnp.array([0.12, 0.3])),
        anchor=jnp.zeros((2,), jnp.float32),
        h_prev=jnp.zeros((2,), jnp.float32),
        watched=jnp.zeros((), jnp.float32),
    )
    return ts, strategy


def human_target(ts: TeamState, h: jax.Array, u: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The human's target for its end, and whether its current phase is done."""
    lead = jnp.where(ts.strategy[0] == 1, 1.0, -1.0)  # +1: the human's end leads
    back = jnp.where(lead > 0, 0.0, LENGTH)  # the human's end is this far below the leading end
    turn = jnp.array([ts.anchor[0] + 0.5 * (DOOR_X - ts.anchor[0]), ts.anchor[1] + lead * 0.5 * LENGTH])
    align = jnp.array([DOOR_X + ts.offset[0], ALIGN_Y - back])
    through = jnp.array([DOOR_X + ts.offset[1], GOAL_Y - back])
    target = jnp.select([ts.phase == TURN, ts.phase == ALIGN], [turn, align], through)
    dist = jnp.linalg.norm(target - h)
    done = jnp.select([ts.phase == TURN, ts.phase == ALIGN], [dist < 0.3, (dist < 0.2) & (jnp.abs(u[0]) < UPRIGHT)],
                      False)
    return target, done


def team_act(env, ts: TeamState, state, rng: jax.Array) -> tuple[TeamState, jax.Array]:
    pos = state.pipeline_state["pos"]
    h, r = pos[0], pos[1]
    u = (h - r) / jnp.maximum(jnp.linalg.norm(h - r), 1e-6)
    start = state.info["t"] == 0
    ts = ts._replace(anchor=jnp.where(start, 0.5 * (h + r), ts.anchor), h_prev=jnp.where(start, h, ts.h_prev))
    k_noise, k_delay, k_pause, k_curve = jax.random.split(rng, 4)

    # ---- the human: its plan's current target
    target, done = human_target(ts, h, u)
    vec = target - h
    dist = jnp.linalg.norm(vec)
    direction = vec / (dist + 1e-6)
    perp = jnp.array([-direction[1], direction[0]])
    # a bend that fades near the target; none through the door (a bent carry jams the table at the door's side)
    bend = jnp.where(ts.phase == THROUGH, 0.0, ts.curve * jnp.clip(dist / 2.0, 0.0, 1.0))
    desired = direction + bend * perp
    desired = desired / (jnp.max(jnp.abs(desired)) + 1e-6)
    desired = desired * jnp.clip(dist / (3.0 * SPEED), 0.0, 1.0) * ts.speed[0]  # slow down on arrival
    waiting = ts.delay[0] > 0
    desired = jnp.where(waiting, 0.0, desired)
    a_h = ts.prev[0] + 0.45 * (desired - ts.prev[0])
    a_h = jnp.clip(a_h + NOISE_STD[0] * jax.random.normal(jax.random.fold_in(k_noise, 0), (2,)), -1.0, 1.0)
    advance = done & ~waiting
    phase = jnp.minimum(ts.phase + advance.astype(jnp.int32), THROUGH)
    react = jax.random.randint(jax.random.fold_in(k_delay, 0), (), 1, 7)
    pause = jax.random.bernoulli(k_pause, 0.01)
    plen = jax.random.randint(jax.random.fold_in(k_pause, 1), (), 2, 6)
    delay_h = jnp.where(advance, react, jnp.where(waiting, ts.delay[0] - 1, jnp.where(pause, plen, 0)))
    curve = jnp.where(advance, jax.random.uniform(k_curve, (), minval=-0.4, maxval=0.4), ts.curve)

    # ---- the robot: reads the strategy off the human's end, then keeps its end a table length behind/ahead
    watched = ts.watched + (h - ts.h_prev)[1]
    unknown = ts.strategy[1] == UNKNOWN
    read = unknown & (jnp.abs(watched) > READ_AT)
    robot_strategy = jnp.where(read, jnp.where(watched > 0, 1, 2), ts.strategy[1]).astype(jnp.int32)
    knows = robot_strategy != UNKNOWN
    lead = jnp.where(robot_strategy == 1, 1.0, -1.0)
    goal = h - LENGTH * lead * jnp.array([0.0, 1.0])
    at_door = (jnp.abs(u[0]) < 0.25) & (jnp.abs(r[0] - DOOR_X) < 0.45)
    goal = goal.at[1].set(jnp.where(at_door | (r[1] > WALL_Y), goal[1], jnp.minimum(goal[1], WALL_Y - 0.3)))
    desired_r = ts.prev[0] + ROBOT_GAIN * (goal - r) / SPEED
    desired_r = jnp.clip(desired_r, -1.0, 1.0) * ts.speed[1]
    robot_waits = ts.delay[1] > 0
    moving = knows & ~robot_waits
    desired_r = jnp.where(moving, desired_r, 0.0)
    a_r = ts.prev[1] + 0.5 * (desired_r - ts.prev[1])
    a_r = a_r + NOISE_STD[1] * jax.random.normal(jax.random.fold_in(k_noise, 1), (2,))
    a_r = jnp.clip(jnp.where(moving, a_r, 0.0), -1.0, 1.0)
    # the robot's delay counts down only once it knows (its reaction to what it read)
    delay_r = jnp.where(read, jax.random.randint(jax.random.fold_in(k_delay, 1), (), 2, 8),
                        jnp.where(knows & robot_waits, ts.delay[1] - 1, jnp.where(knows, 0, ts.delay[1])))

    prev = jnp.stack([a_h, a_r]).astype(jnp.float32)
    new_ts = ts._replace(strategy=jnp.stack([ts.strategy[0], robot_strategy]), phase=phase.astype(jnp.int32),
                         delay=jnp.stack([delay_h, delay_r]).astype(jnp.int32), prev=prev,
                         curve=curve.astype(jnp.float32), h_prev=h, watched=watched.astype(jnp.float32))
    return new_ts, prev.reshape(-1)


TEAM = Team(init=team_init, act=team_act, variations=False)
