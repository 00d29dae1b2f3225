"""2D-Fetch-Quest's scripted human-human team (the env is :mod:`cogail_envs.fetchq.env`).

Each agent runs a phase program (per strategy: who fetches first, which room is whose): fetcher-first
DOOR, TREASURE, EXIT, HOLD(other button), DEST; helper-first HOLD(other button), DOOR, TREASURE, EXIT,
DEST. Within a strategy it varies speeds, curved legs, reaction delays after each phase, short pauses and
action noise; motion is low-pass filtered with a slow-down on arrival (minimum-jerk-like).

How the robot decides: it watches the human (:func:`read_strategy`). It compares the human's heading (its
last action) with the directions to the four strategies' first targets (a button or a door) and commits to a
strategy once the heading clearly points at its target (or the human stands at it); it may re-decide while
both agents are still in their first phase (a human who first heads elsewhere is followed), and until it
knows it waits still. A human partner in a human-human demonstration does not know the other's plan in
advance, and a robot learned from such demonstrations follows the person rather than a plan fixed at step 0
(the strategy drawn from ``mix`` is the human's; ``strategy[1]`` is what the robot has read so far). Its
TIMING reacts to the state: it waits at a door until the human opens it (``doors``) and holds a button until
the human is inside the room with the treasure. A robot that replays the demonstrators' timing fails when
the human is late.

Variations of the human (:mod:`cogail_envs.variations`; the robot is unchanged):

* slow / fast: the human's speed factor x0.6 / x1.4 (actions stay within [-1, 1]: fast saturates them);
* pauses: 2 stops of 20-40 steps, starting at a random step in [5, 130);
* detour: the first leg (which reveals the strategy) goes via a random waypoint in the open middle of the
  map, so does the leg to the destination; legs bend twice as much (other approach angles);
* noise: action noise std 0.25 instead of 0.05;
* change_of_mind: for 15-35 steps (or until it gets there) the human first heads for the first target of
  another strategy (another button or another room's door), then follows its own plan.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .env import BUTTON_R, BUTTONS, DESTS, DOOR_SPOTS, SPEED, TREASURES, _in_room
from ..registry import Team
from ..variations import CHANGE_OF_MIND, DETOUR, NOISE, VARIATION_SALT, pace_factor, pause_schedule, paused

# Scripted-team phases.
GOTO_DOOR, GOTO_TREASURE, EXIT_DOOR, HOLD_BUTTON, GOTO_DEST, DONE = range(6)

PACE = (0.6, 1.4)  # slow, fast
NUM_PAUSES, PAUSE_START, PAUSE_LEN = 2, (5, 130), (20, 41)
NOISE_STD, NOISY_STD = 0.05, 0.25
DECOY_STEPS = (15, 36)
WAYPOINT_BOXES = ((1.2, 2.2, 6.8, 5.0), (2.0, 2.0, 6.0, 4.5))  # x0, y0, x1, y1: first leg, destination leg
UNKNOWN = 0  # the robot's strategy before it has read the human's
# the robot commits when the human's heading points at one strategy's first target: cosine above WATCH_COS,
# WATCH_MARGIN above the runner-up, and the human moving (|last action| above WATCH_SPEED); or when the human
# stands within WATCH_AT of one (there its heading is jitter, which would otherwise flip the robot's choice
# after the human arrived, and leave a robot that chose wrong waiting for a human who waits for it)
WATCH_COS, WATCH_MARGIN, WATCH_SPEED, WATCH_AT = 0.93, 0.15, 0.2, 0.5


class TeamState(NamedTuple):
    strategy: jax.Array  # (2,) strategy each agent follows (the robot's: UNKNOWN until it has read the human's)
    phase: jax.Array  # (2,) int32
    delay: jax.Array  # (2,) int32 reaction-delay / pause countdown
    prev: jax.Array  # (2, 2) previous action (smoothing)
    speed: jax.Array  # (2,) per-episode speed factor
    curve: jax.Array  # (2,) lateral bias of the current leg
    # the human's variation (neutral values for the default team)
    pace: jax.Array  # () speed multiplier of the human
    noise: jax.Array  # (2,) action noise std
    curve_scale: jax.Array  # () multiplier of the human's leg bends
    pause_t: jax.Array  # (K,) int32 pause start steps
    pause_n: jax.Array  # (K,) int32 pause lengths (0: no pause)
    waypoint: jax.Array  # (2, 2) detour waypoints (first leg, destination leg)
    wp_on: jax.Array  # (2,) bool: waypoint still to visit
    decoy: jax.Array  # () int32 strategy whose first target the human heads for first
    decoy_n: jax.Array  # () int32 steps left of heading for it (0: none)
    watching: jax.Array  # () bool: the robot reads its strategy off the human (False: it keeps strategy[1])
    # co-play only (``robot_act``): the human's position the robot saw last step (the default team ignores it)
    seen: jax.Array = np.zeros((2,), np.float32)


def team_init(env, rng: jax.Array, mix: jax.Array, variation=0) -> tuple[TeamState, jax.Array]:
    ks = jax.random.split(rng, 4)
    strategy = jax.random.categorical(ks[0], jnp.log(jnp.asarray(mix) + 1e-12)) + 1
    v = jnp.asarray(variation, jnp.int32)
    kv = jax.random.split(jax.random.fold_in(rng, VARIATION_SALT), 5)
    pause_t, pause_n = pause_schedule(kv[0], v, NUM_PAUSES, PAUSE_START, PAUSE_LEN)
    boxes = jnp.asarray(WAYPOINT_BOXES)
    waypoint = jax.random.uniform(kv[1], (2, 2), minval=boxes[:, :2], maxval=boxes[:, 2:])
    decoy = (strategy - 1 + jax.random.randint(kv[2], (), 1, 4)) % 4 + 1
    decoy_n = jnp.where(v == CHANGE_OF_MIND, jax.random.randint(kv[3], (), *DECOY_STEPS), 0)
    ts = TeamState(
        strategy=jnp.stack([strategy, jnp.full_like(strategy, UNKNOWN)]).astype(jnp.int32),
        phase=jnp.zeros((2,), jnp.int32),
        delay=jax.random.randint(ks[1], (2,), 0, 6),
        prev=jnp.zeros((2, 2)),
        speed=jax.random.uniform(ks[2], (2,), minval=0.75, maxval=1.0),
        curve=jax.random.uniform(ks[3], (2,), minval=-0.5, maxval=0.5),
        pace=pace_factor(v, *PACE),
        noise=jnp.stack([jnp.where(v == NOISE, NOISY_STD, NOISE_STD), jnp.asarray(NOISE_STD)]).astype(jnp.float32),
        curve_scale=jnp.where(v == DETOUR, 2.0, 1.0).astype(jnp.float32),
        pause_t=pause_t,
        pause_n=pause_n,
        waypoint=waypoint,
        wp_on=jnp.full((2,), v == DETOUR),
        decoy=decoy.astype(jnp.int32),
        decoy_n=decoy_n.astype(jnp.int32),
        watching=jnp.array(True),
    )
    ts = ts._replace(curve=ts.curve.at[0].multiply(ts.curve_scale))
    return ts, strategy.astype(jnp.int32)


def plan(strategy: jax.Array, agent: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(own room, room of the button this agent holds, whether this agent fetches first)."""
    human_room = jnp.where(strategy <= 2, 0, 1)
    robot_first = (strategy == 1) | (strategy == 3)
    own = human_room if agent == 0 else 1 - human_room
    fetch_first = ~robot_first if agent == 0 else robot_first
    other = 1 - own
    return own, other, fetch_first


def first_target(strategy: jax.Array, agent: int) -> jax.Array:
    """Where an agent following ``strategy`` goes first: its room's door (fetcher) or the other button."""
    own, other, fetch_first = plan(strategy, agent)
    return jnp.where(fetch_first, jnp.asarray(DOOR_SPOTS)[own], jnp.asarray(BUTTONS)[other])


def read_strategy(ts: TeamState, ps: dict) -> jax.Array:
    """The robot's strategy after watching the human this step: the strategy whose first target the human
    stands at or its heading (its last action) clearly points at; it may (re)decide only while both agents are
    in their first phase, and otherwise keeps what it had (UNKNOWN until then)."""
    targets = jnp.stack([first_target(jnp.int32(s), 0) for s in range(1, 5)])  # (4, 2)
    v = ts.prev[0]
    d = targets - ps["pos"][0]
    dist, speed = jnp.linalg.norm(d, axis=-1), jnp.linalg.norm(v)
    cos = (d @ v) / (dist * speed + 1e-6)
    runner_up, top = jnp.sort(cos)[-2:]
    heading = (top > WATCH_COS) & (top - runner_up > WATCH_MARGIN) & (speed > WATCH_SPEED)
    at = jnp.min(dist) < WATCH_AT
    best = jnp.where(at, jnp.argmin(dist), jnp.argmax(cos)) + 1
    may = ts.watching & (ts.phase[0] == 0) & (ts.phase[1] == 0)
    return jnp.where(may & (at | heading), best, ts.strategy[1]).astype(jnp.int32)


def agent_target(ts: TeamState, ps: dict, i: int) -> tuple[jax.Array, jax.Array]:
    """Target point of agent i and whether its current phase is complete."""
    own, other, fetch_first = plan(ts.strategy[i], i)
    phase = ts.phase[i]
    pos = ps["pos"][i]
    partner = ps["pos"][1 - i]
    # phase program: fetcher-first: DOOR, TREASURE, EXIT, HOLD(other), DEST
    #                helper-first:  HOLD(other), DOOR, TREASURE, EXIT, DEST
    seq_first = jnp.array([GOTO_DOOR, GOTO_TREASURE, EXIT_DOOR, HOLD_BUTTON, GOTO_DEST, DONE])
    seq_help = jnp.array([HOLD_BUTTON, GOTO_DOOR, GOTO_TREASURE, EXIT_DOOR, GOTO_DEST, DONE])
    kind = jnp.where(fetch_first, seq_first[phase], seq_help[phase])
    dests = jnp.asarray(DESTS)
    dest = dests[jnp.argmin(jnp.linalg.norm(dests - pos, axis=-1))]
    target = jnp.select(
        [kind == GOTO_DOOR, kind == GOTO_TREASURE, kind == EXIT_DOOR, kind == HOLD_BUTTON],
        [jnp.asarray(DOOR_SPOTS)[own], jnp.asarray(TREASURES)[own], jnp.asarray(DOOR_SPOTS)[own],
         jnp.asarray(BUTTONS)[other]],
        dest,
    )
    dist = jnp.linalg.norm(target - pos)
    partner_in_other = jnp.where(other == 0, _in_room(partner, 0), _in_room(partner, 1))
    # a helper is done once the partner has its treasure (in the room with it, or gone already: a human who
    # paused on the button may see the partner only after it left the room)
    complete = jnp.select(
        [kind == GOTO_DOOR, kind == GOTO_TREASURE, kind == EXIT_DOOR, kind == HOLD_BUTTON],
        [(dist < 0.3) & (ps["doors"][own] > 0.5), ps["carry"][i] >= 0, dist < 0.35,
         (dist < BUTTON_R) & ((partner_in_other & (ps["carry"][1 - i] >= 0)) | (ps["carry"][1 - i] == other))],
        False,
    )
    return target, complete


def human_detour(ts: TeamState, pos: jax.Array, target: jax.Array, complete: jax.Array):
    """The human's variation of its target: a decoy (another strategy's first target) or a waypoint first.
    Returns (target, complete, decoy_n, wp_on) for this step."""
    first_leg = ts.phase[0] == 0
    decoy_pt = first_target(ts.decoy, 0)
    decoying = first_leg & (ts.decoy_n > 0)
    reached_decoy = jnp.linalg.norm(decoy_pt - pos) < 0.6
    leg = jnp.stack([first_leg, ts.phase[0] == GOTO_DEST])
    detouring = leg & ts.wp_on
    k = jnp.argmax(detouring)
    wp_active = jnp.any(detouring) & ~decoying
    wp = ts.waypoint[k]
    reached_wp = jnp.linalg.norm(wp - pos) < 0.4
    new_target = jnp.where(decoying, decoy_pt, jnp.where(wp_active, wp, target))
    new_complete = complete & ~decoying & ~wp_active
    decoy_n = jnp.where(decoying, jnp.where(reached_decoy, 0, ts.decoy_n - 1), ts.decoy_n)
    wp_on = jnp.where(wp_active & reached_wp, ts.wp_on.at[k].set(False), ts.wp_on)
    return new_target, new_complete, decoy_n, wp_on


def team_act(env, ts: TeamState, state, rng: jax.Array) -> tuple[TeamState, jax.Array]:
    ps = state.pipeline_state
    k_noise, k_delay, k_pause, k_curve = jax.random.split(rng, 4)
    stopped = paused(ts.pause_t, ts.pause_n, state.info["t"])  # the human's variation: a dead stop
    robot_strategy = read_strategy(ts, ps)
    unknown = robot_strategy == UNKNOWN
    # while unknown the robot's program runs on a placeholder strategy (1) and its outputs are discarded
    ts = ts._replace(strategy=ts.strategy.at[1].set(jnp.where(unknown, 1, robot_strategy)))
    actions, phases, delays, curves = [], [], [], []
    decoy_n, wp_on = ts.decoy_n, ts.wp_on
    for i in range(2):
        target, complete = agent_target(ts, ps, i)
        if i == 0:
            target, complete, decoy_n, wp_on = human_detour(ts, ps["pos"][0], target, complete)
        vec = target - ps["pos"][i]
        dist = jnp.linalg.norm(vec)
        direction = vec / (dist + 1e-6)
        perp = jnp.array([-direction[1], direction[0]])
        # curved legs: lateral bias that fades near the target
        bend = ts.curve[i] * jnp.clip(dist / 3.0, 0.0, 1.0)
        desired = direction + bend * perp
        desired = desired / (jnp.max(jnp.abs(desired)) + 1e-6)
        # minimum-jerk-like: slow down on arrival, low-pass the command
        speed = ts.speed[i] * ts.pace if i == 0 else ts.speed[i]
        gain = jnp.clip(dist / (SPEED * 3.0), 0.0, 1.0) * speed
        desired = desired * gain
        waiting = ts.delay[i] > 0
        desired = jnp.where(waiting, 0.0, desired)
        a = ts.prev[i] + 0.45 * (desired - ts.prev[i])
        a = a + ts.noise[i] * jax.random.normal(jax.random.fold_in(k_noise, i), (2,))
        a = jnp.clip(a, -1.0, 1.0)
        advance = complete & ~waiting
        new_phase = jnp.minimum(ts.phase[i] + advance.astype(jnp.int32), DONE)
        # reaction delay after each completed phase; occasional short pauses
        react = jax.random.randint(jax.random.fold_in(k_delay, i), (), 1, 7)
        pause = jax.random.bernoulli(jax.random.fold_in(k_pause, i), 0.01)
        plen = jax.random.randint(jax.random.fold_in(k_pause, 10 + i), (), 2, 6)
        delay = jnp.where(advance, react, jnp.where(waiting, ts.delay[i] - 1, jnp.where(pause, plen, 0)))
        curve = jnp.where(
            advance, jax.random.uniform(jax.random.fold_in(k_curve, i), (), minval=-0.5, maxval=0.5), ts.curve[i]
        )
        if i == 0:  # a stopped human stands still and its plan waits (the robot goes on reacting)
            curve = jnp.where(advance, curve * ts.curve_scale, curve)
            a = jnp.where(stopped, 0.0, a)
            new_phase = jnp.where(stopped, ts.phase[0], new_phase)
            delay = jnp.where(stopped, ts.delay[0], delay)
            curve = jnp.where(stopped, ts.curve[0], curve)
            decoy_n = jnp.where(stopped, ts.decoy_n, decoy_n)
            wp_on = jnp.where(stopped, ts.wp_on, wp_on)
        else:  # a robot that does not know the strategy yet stands still in its first phase
            a = jnp.where(unknown, 0.0, a)
            new_phase = jnp.where(unknown, 0, new_phase)
            delay = jnp.where(unknown, 0, delay)
            curve = jnp.where(unknown, ts.curve[1], curve)
        actions.append(a)
        phases.append(new_phase)
        delays.append(delay)
        curves.append(curve)
    prev = jnp.stack(actions)
    new_ts = ts._replace(strategy=ts.strategy.at[1].set(robot_strategy), phase=jnp.stack(phases),
                         delay=jnp.stack(delays).astype(jnp.int32), prev=prev, curve=jnp.stack(curves),
                         decoy_n=decoy_n.astype(jnp.int32), wp_on=wp_on)
    return new_ts, prev.reshape(-1)


def human_act(env, ts: TeamState, state, rng: jax.Array) -> tuple[TeamState, jax.Array]:
    """The scripted human alone (closed-loop co-play): its part of :func:`team_act`, which reads only the state
    (both positions, the doors, who carries what) and the human's own plan; the robot's entries of the returned
    team state are the scripted robot's bookkeeping, read by nobody."""
    ts, action = team_act(env, ts, state, rng)
    return ts, action[:2]


def robot_act(env, ts: TeamState, state, rng: jax.Array) -> tuple[TeamState, jax.Array]:
    """The scripted robot alone (closed-loop co-play), on observables only: the human's heading is its
    displacement since the last step (``seen``), not its last action, and the robot may (re)decide the strategy
    while its own first phase lasts and the human is neither in a room nor carrying a treasure (instead of the
    human's phase). The human's entries of ``ts`` are never read: they are replaced by what the robot sees."""
    ps = state.pipeline_state
    pos_h = ps["pos"][0]
    heading = jnp.where(state.info["t"] > 0, (pos_h - ts.seen) / SPEED, 0.0)
    busy = _in_room(pos_h, 0) | _in_room(pos_h, 1) | (ps["carry"][0] >= 0)
    view = ts._replace(prev=ts.prev.at[0].set(heading), phase=ts.phase.at[0].set(busy.astype(jnp.int32)),
                       watching=jnp.array(True))
    new, action = team_act(env, view, state, rng)
    out = ts._replace(**{f: getattr(ts, f).at[1].set(getattr(new, f)[1])
                         for f in ("strategy", "phase", "delay", "prev", "curve")}, seen=pos_h)
    return out, action[2:]


TEAM = Team(init=team_init, act=team_act, variations=True, partner_can_follow=False, human_act=human_act,
            robot_act=robot_act)
