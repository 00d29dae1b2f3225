"""HR-SeqManip's scripted human-human team (the env is :mod:`cogail_envs.seqmanip`).

Two phase machines (human ``H_*``, robot ``R_*``; successor tables ``NEXT_H`` / ``NEXT_R`` per strategy).
The strategy is drawn from ``mix``; within a strategy the team varies the handover spot, the orientation at which
the human carries and holds the bar (roll, pitch and yaw), the waiting points, the drop place (ranges below), how far the drawer is pulled
(12.5-15.5 cm), where each hand grasps the handle, where and from how high the object is dropped, speeds,
acceleration limits, gains, start and reaction delays, a pause after lifting and action noise. Motions are
proportional control with velocity and acceleration limits (bell-shaped, minimum-jerk-like speed
profiles). Waiting phases are gated: their timer only runs while the awaited condition holds (e.g. the
drawer is open and held), so every hand-off has a reaction delay. In the training split's episodes
(``variations.PROMPT_ROBOT``) the robot is the most prompt of the team's draws (top speed, acceleration and gain,
the shortest start and reaction delays, and it starts towards the drop as soon as the human grasps the handle,
lowering the bar once the drawer is open and held), so that the learned robot does not keep the person waiting.
The training split is also made in the task's training env (``TASK.train_env``): the robot's gripper starts turned
by up to +-1.0 rad and up to 8 cm above or below its home height (everywhere else within 3 cm of home, not turned).

1. human-hands-over: the human picks the bar up and carries it out to the handover spot; once the human
   has come past the middle of the table towards it (TCP y > ``CUE_Y``) the robot reacts, grasps the
   bar's far end; the human lets go, backs off, grasps the handle and pulls the drawer open while the
   robot hovers with the bar; the robot lowers the bar over the drawer and drops it; the robot retreats
   and the human pushes the drawer shut.
2. robot-opens: the human picks the bar up and carries it to a waiting point near the drawer; once the
   human holds still there the robot reacts, grasps the handle and pulls the drawer open; the human lowers
   the bar over the drawer and drops it, then retreats; the robot pushes the drawer shut.

How the robot decides: it takes the strategy from the team's shared plan (``strategy``), but every step of
its TIMING waits on the state and on the human: it starts when the human carrying the bar has come past
the middle of the table (s1) or holds the bar still at its waiting point by the drawer (s2); it grasps the
bar once the human offers it, closes once the human has let go, drops once the drawer is open and held,
and closes the drawer once the bar lies in it and the human has retreated. A human who is late, pauses or
first heads elsewhere is waited for.

Poses and places (the ranges a person plausibly uses and both grippers reach and grasp; the robot grasps the bar
however it is offered, aligning its gripper with the bar about all three axes, and either dropper levels the bar
before the drop, as a person putting it away would). The bar's orientation while the human carries, offers or holds
it is ``Rz(yaw) Rx(pitch) Ry(roll)`` (:func:`mjx_common.pose_mat`: yaw about the vertical, pitch tilting its long axis,
roll twisting it about its long axis); the places are the handover spot (bar centre, strategy 1), the human's waiting
point with the bar (its TCP, strategy 2) and the drop (the bar's centre over the open drawer, either strategy); m,
world:

==========  ===================================================  ===============================================
axis        training range                                       held-out slice (``pose_heldout_<axis>``)
==========  ===================================================  ===============================================
roll        ``|roll| <= 0.3`` (17 degrees)                        ``0.3 < |roll| <= 0.45`` (26 degrees)
pitch       ``|pitch| <= 0.3``                                    ``0.3 < |pitch| <= 0.45``
yaw         ``|yaw| <= 0.7`` (40 degrees)                         ``0.7 < |yaw| <= 1.05`` (the outer third of +-60)
x           spot [-0.20, 0.02]; waiting point [-0.09, 0.04]       spot [-0.25, -0.20) or (0.02, 0.05]; waiting
                                                                 point [-0.13, -0.09) or (0.04, 0.07]
y           spot [-0.08, 0.01]; waiting point [-0.23, -0.14]      spot (0.01, 0.04]; waiting point [-0.27, -0.23)
z           spot [0.12, 0.26]; waiting point [0.18, 0.25]         spot (0.26, 0.31]; waiting point (0.25, 0.30]
place       the drop: 4.7-5.5 cm past the drawer's front inner    5.5-6.5 cm past it, or 3-4.5 cm to the side
            wall, within 3 cm of its middle sideways             (either side), at even odds
==========  ===================================================  ===============================================

The slices end where the task does: the spot's y band lies towards the robot only and the waiting point's towards
the human only (the robot starts on a human past the middle of the table, ``CUE_Y``, for a handover and short of it
for the drawer), the spot's x stays short of the drawer, and the drop's bands end where the bar still clears the
drawer's walls and the cabinet's front. Every default, training, validation and test episode lies in the training
ranges; an episode drawn with ``variation | pose_slice(axis)`` has that axis in its slice and every other in range,
one drawn with ``variation | POSE_HELDOUT`` alone one of the seven axes (drawn) in its slice.

The drop (either agent): the bar's centre 4.7-5.5 cm past the drawer's front inner wall (in the place slice 5.5-6.5),
within 3 cm of the drawer's middle sideways (in the place slice 3-4.5 cm to one side), 1-3 cm above the walls. A
bar turned by at most 0.35-0.45 rad (the episode's bound) fits the drawer there, so the dropper turns the bar only as
far as it must: a bar held within the bound is dropped as it is held, one turned further is turned back to the bound
first, and a tilted or twisted bar is levelled, as a person putting it away would.

Variations of the human (:mod:`cogail_envs.variations`; the robot is unchanged):

* slow / fast: the human's speed, acceleration and gain limits x0.7 / x1.4 (speed capped at 1 action unit;
  slow is 0.7, not 0.6, so that slowed episodes still end within the 600-step limit);
* pauses: 2 dead stops of 20-40 steps starting at a random step in [15, 380) (phase and timers frozen);
* detour: the reach comes in from the side (a waypoint 8-15 cm left or right of, and 5-10 cm higher than,
  the point above the bar) and the carry goes via a waypoint 6-12 cm to the side of the straight path and
  3-8 cm up;
* noise: action noise std x3 (0.06-0.24 instead of 0.02-0.08);
* change_of_mind: after lifting the bar, the human first carries it towards the other strategy's first
  sub-goal (s1: the waiting point by the drawer; s2: the handover spot) and holds it there (35-60 steps
  in all), then to its own.

With ``variation | FOLLOWING_PARTNER`` the robot does not read the plan under change_of_mind: it takes the
strategy the human's first leg suggests (its cue: the human with the bar past the middle of the table, or
holding it by the drawer) and starts on it; when the human turns to its own strategy the robot lets go of what
it holds, stops, and starts over on the human's strategy from its waiting phase (a robot recovering from a
wrong guess, for the training sets).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import mjx_common as mc
from .env import CUE_Y, DR_DX, DRAWER_OPEN_MIN, GRASP_OFF, OBJ, OBJ_HALF, WALL_TOP
from ..registry import Team
from ..variations import (CHANGE_OF_MIND, DETOUR, NOISE, VARIATION_SALT, band_draw, following, held_axes,
                          human_variation, pace_factor, pause_schedule, paused, prompt, slice_draw)

(H_WAIT, H_REACH, H_DESCEND, H_CLOSE, H_LIFT,
 H_CARRY, H_OFFER, H_BACKOFF, H_TO_HANDLE, H_DESC_HANDLE, H_GRIP_HANDLE, H_PULL, H_HOLD_OPEN, H_PUSH,
 H_LET_GO,
 H_CARRY_WAIT, H_WAIT_OPEN, H_ABOVE_DROP, H_LOWER, H_RELEASE,
 H_RETREAT) = range(21)
(R_WAIT,
 R_APPROACH, R_DESCEND, R_CLOSE, R_LIFT, R_HOVER, R_WAIT_OPEN, R_ABOVE_DROP, R_LOWER, R_RELEASE,
 R_TO_HANDLE, R_DESC_HANDLE, R_GRIP_HANDLE, R_PULL, R_HOLD_OPEN, R_PUSH, R_LET_GO,
 R_RETREAT) = range(18)


def _next_table(n: int, edits: dict) -> np.ndarray:
    t = np.tile(np.minimum(np.arange(n) + 1, n - 1), (2, 1)).astype(np.int32)
    for (s, p), q in edits.items():
        t[s, p] = q
    return t


# successor of a completed phase per strategy (row 0: human-hands-over, row 1: robot-opens)
NEXT_H = _next_table(21, {(0, H_LET_GO): H_RETREAT, (1, H_LIFT): H_CARRY_WAIT, (1, H_LET_GO): H_RETREAT})
NEXT_R = _next_table(18, {(1, R_WAIT): R_TO_HANDLE, (0, R_RELEASE): R_RETREAT, (1, R_RELEASE): R_RETREAT})

PACE = (0.7, 1.4)
NUM_PAUSES, PAUSE_START, PAUSE_LEN = 2, (15, 380), (20, 41)
NOISE_FACTOR = 3.0
DECOY_STEPS = (35, 61)
YAW_RANGE, YAW_HELD = (0.0, 0.7), (0.7, 1.05)   # |yaw| of the held bar: training range, held-out slice
TILT_RANGE, TILT_HELD = (0.0, 0.3), (0.3, 0.45)  # |pitch| and |roll| of the held bar (rad)
SPOT_LO, SPOT_HI, SPOT_Z_HELD = (-0.20, -0.08, 0.12), (0.02, 0.01, 0.26), (0.26, 0.31)
SPOT_X_HELD, SPOT_Y_HELD = ((-0.25, -0.20), (0.02, 0.05)), (None, (0.01, 0.04))  # (below, above) bands
WAIT_LO, WAIT_HI, WAIT_Z_HELD = (-0.09, -0.23, 0.18), (0.04, -0.14, 0.25), (0.25, 0.30)
WAIT_X_HELD, WAIT_Y_HELD = ((-0.13, -0.09), (0.04, 0.07)), ((-0.27, -0.23), None)
DROP_LO, DROP_HI = (0.047, -0.03, 0.01, -0.1), (0.055, 0.03, 0.03, 0.1)  # drop x past the wall, y, height; yaw bound
DROP_X_HELD, DROP_Y_HELD = (0.055, 0.065), (0.03, 0.045)  # the place slice: further in, or (|y|) to the side
SLICES = ("roll", "pitch", "yaw", "x", "y", "z", "place")  # the team's held-out slices (variations.POSE_AXES)
POSE_SALT = 4_242
# what the co-play agents see of each other (``human_act`` / ``robot_act``): the bar lifted (its centre this
# high, the human grasping it), held still (moving less than STILL_SPEED per step for STILL_STEPS steps), the
# human's TCP this high when it waits with the bar by the drawer (strategy 2; the lift stays below), and an agent
# gone from the bar once its TCP is this far from it (gripper open, not touching)
LIFTED_SEEN, STILL_SPEED, STILL_STEPS, WAIT_Z, AWAY = 0.03, 0.001, 6, 0.16, 0.06
# the drop: a bar turned by at most this much (rad, about the vertical; plus half the episode's ``drop[3]``) fits the
# open drawer at the drop point, so the dropper turns a bar only as far as it must (none within the bound)
DROP_FITS = 0.4
# the training split's prompt robot starts towards the drop once the human grasps the handle and the drawer is open by
# this much (m), and lowers the bar once it is open and held as every robot does (the others start then)
EARLY_OPEN = 0.04


def _rotz(yaw: jax.Array) -> jax.Array:
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.array([[c, -s, z], [s, c, z], [z, z, o]])


def move(p_cmd, target, vel, vmax, amax, gain):
    """Velocity- and acceleration-limited proportional step (world frame, action units): bell-shaped,
    minimum-jerk-like speed profiles."""
    v_des = gain * (target - p_cmd) / mc.POS_SCALE
    n = jnp.linalg.norm(v_des)
    v_des = v_des * jnp.minimum(1.0, vmax / (n + 1e-9))
    dv = v_des - vel
    dn = jnp.linalg.norm(dv)
    return vel + dv * jnp.minimum(1.0, amax / (dn + 1e-9))


def rot_action(d, g: mc.Gripper, target, gain=0.25, vmax=0.9):
    """Rotation actions towards the hinge targets ``target`` (rx, ry, rz)."""
    return mc.rot_toward(d, g, target, gain, vmax)


def presented(ts: TeamState) -> jax.Array:
    """The orientation (world) the human carries, offers and holds the bar at."""
    return mc.pose_mat(ts.roll, ts.pitch, ts.yaw)


def _flat(yaw) -> jax.Array:
    """Hinge targets of a level gripper turned by ``yaw`` about the vertical."""
    return jnp.stack([jnp.zeros_like(yaw), jnp.zeros_like(yaw), yaw])


def world_ctrl(d, g: mc.Gripper) -> jax.Array:
    """The gripper's position target (world)."""
    return jnp.asarray(g.base_pos) + jnp.asarray(g.base_mat) @ d.ctrl[g.act:g.act + 3]


def _select(ph, table: dict, default):
    keys = list(table)
    return jnp.select([ph == k for k in keys], [jnp.asarray(table[k]) for k in keys], default)


class TeamState(NamedTuple):
    """Scripted human-human team (per episode); index 0 human, 1 robot where paired."""

    strategy: jax.Array   # (2,) int32 strategy each agent follows (1 human-hands-over, 2 robot-opens)
    spot: jax.Array       # (3,) object-centre target of the handover (strategy 1, world)
    wait_pt: jax.Array    # (2, 3) waiting points: human with the object (s2), robot with the object (s1)
    yaw: jax.Array        # () the carried bar's yaw (rad)
    drop: jax.Array       # (4,) drop point: x past the drawer's front inner wall, y, release height; its yaw bound
    open_amt: jax.Array   # () how far the opener pulls the drawer (m)
    handle_y: jax.Array   # (2,) where each agent grasps the handle (y offset from its centre)
    vmax: jax.Array       # (2,) speed limits (action units)
    amax: jax.Array       # (2,) acceleration limits (action units / step)
    gain: jax.Array       # (2,) proportional gains
    delay: jax.Array      # (2,) int32 start delays
    react: jax.Array      # (2,) int32 reaction delays (hand-offs, waiting for the partner)
    lift: jax.Array       # () lift height after grasping (m)
    pause: jax.Array      # () int32 pause after lifting
    retreat: jax.Array    # (2, 3) retreat offsets (world)
    noise: jax.Array      # (2,) action noise std
    phase: jax.Array      # (2,) int32
    timer: jax.Array      # (2,) int32 steps in the current phase (gated phases: steps the gate held)
    vel: jax.Array        # (2, 3) previous translational command (world, action units)
    anchor: jax.Array     # (2, 3) TCP position when the current phase began (world)
    # the human's variation (neutral values for the default team)
    rot_gain: jax.Array   # () the human's rotation gain multiplier
    pause_t: jax.Array    # (K,) int32 pause start steps
    pause_n: jax.Array    # (K,) int32 pause lengths (0: no pause)
    wp_off: jax.Array     # (2, 3) detour offsets: reach (from the point above the bar), carry (from the midpoint)
    wp_on: jax.Array      # (2,) bool: waypoint still to visit (reach, carry)
    decoy_n: jax.Array    # () int32 steps left of carrying towards the other strategy's target (0: none)
    follows: jax.Array    # () bool: the robot takes the strategy the human's moves suggest (FOLLOWING_PARTNER)
    # co-play only (``robot_act``; the default team ignores them): the bar's position the robot saw last step, for
    # how many steps it has seen the bar held still, and the strategy it has read off the human (0: none yet)
    seen: jax.Array = np.zeros((3,), np.float32)
    still: jax.Array = np.zeros((), np.int32)
    guess: jax.Array = np.zeros((), np.int32)
    early: jax.Array = np.zeros((), bool)  # the robot starts towards the drop as the drawer is being opened
    pitch: jax.Array = np.zeros((), np.float32)  # the bar as the human carries and holds it: its long axis tilted up or down (rad)
    roll: jax.Array = np.zeros((), np.float32)  # and twisted about its long axis (rad)


def team_init(env, rng: jax.Array, mix: jax.Array, variation=0) -> tuple[TeamState, jax.Array]:
    ks = jax.random.split(rng, 20)
    u = lambda k, lo, hi, shape=(): jax.random.uniform(k, shape, minval=jnp.asarray(lo, jnp.float32),  # noqa: E731
                                                       maxval=jnp.asarray(hi, jnp.float32))
    strategy = (jax.random.categorical(ks[0], jnp.log(jnp.asarray(mix, jnp.float32) + 1e-12)) + 1).astype(jnp.int32)
    v = human_variation(variation)
    kp = jax.random.split(jax.random.fold_in(rng, POSE_SALT), 12)
    held = held_axes(kp[0], variation, SLICES)
    spot = u(ks[1], SPOT_LO, SPOT_HI, (3,))
    spot = spot.at[0].set(band_draw(kp[3], held["x"], (SPOT_LO[0], SPOT_HI[0]), *SPOT_X_HELD))
    spot = spot.at[1].set(band_draw(kp[4], held["y"], (SPOT_LO[1], SPOT_HI[1]), *SPOT_Y_HELD))
    spot = spot.at[2].set(slice_draw(kp[1], held["z"], (SPOT_LO[2], SPOT_HI[2]), SPOT_Z_HELD))
    wait_h = u(ks[2], WAIT_LO, WAIT_HI, (3,))
    wait_h = wait_h.at[0].set(band_draw(kp[5], held["x"], (WAIT_LO[0], WAIT_HI[0]), *WAIT_X_HELD))
    wait_h = wait_h.at[1].set(band_draw(kp[6], held["y"], (WAIT_LO[1], WAIT_HI[1]), *WAIT_Y_HELD))
    wait_h = wait_h.at[2].set(slice_draw(kp[2], held["z"], (WAIT_LO[2], WAIT_HI[2]), WAIT_Z_HELD))
    drop = u(ks[5], DROP_LO, DROP_HI, (4,))
    side = jax.random.bernoulli(kp[7], 0.5)  # the place slice: further in, or to the side
    drop = drop.at[0].set(jnp.where(held["place"] & side, u(kp[8], *DROP_X_HELD), drop[0]))
    drop = drop.at[1].set(jnp.where(held["place"] & ~side, slice_draw(kp[9], True, (0.0, 0.0), DROP_Y_HELD,
                                                                         symmetric=True), drop[1]))
    kv = jax.random.split(jax.random.fold_in(rng, VARIATION_SALT), 8)
    pace = pace_factor(v, *PACE)
    pause_t, pause_n = pause_schedule(kv[0], v, NUM_PAUSES, PAUSE_START, PAUSE_LEN)
    side = jnp.where(jax.random.bernoulli(kv[1], 0.5, (2,)), 1.0, -1.0)
    wp_off = jnp.stack([
        jnp.stack([side[0] * u(kv[2], 0.08, 0.15), u(kv[3], -0.03, 0.03), u(kv[4], 0.05, 0.10)]),
        jnp.stack([side[1] * u(kv[5], 0.06, 0.12), jnp.zeros(()), u(kv[6], 0.03, 0.08)]),
    ])
    decoy_n = jnp.where(v == CHANGE_OF_MIND, jax.random.randint(kv[7], (), *DECOY_STEPS), 0)
    vmax, amax, gain = u(ks[9], 0.45, 0.85, (2,)), u(ks[10], 0.06, 0.12, (2,)), u(ks[11], 0.12, 0.22, (2,))
    noise = u(ks[18], 0.02, 0.08, (2,))
    delay = jax.random.randint(ks[12], (2,), jnp.array([2, 3]), jnp.array([15, 12]))
    react = jax.random.randint(ks[13], (2,), 2, 10)
    fast = prompt(variation)  # the training split's robot: the top of its ranges, its shortest reactions
    vmax, amax, gain = (jnp.where(fast, x.at[1].set(top), x) for x, top in ((vmax, 0.85), (amax, 0.12), (gain, 0.22)))
    delay, react = jnp.where(fast, delay.at[1].set(3), delay), jnp.where(fast, react.at[1].set(2), react)
    follows = following(variation) & (v == CHANGE_OF_MIND)
    ts = TeamState(
        strategy=jnp.stack([strategy, jnp.where(follows, 3 - strategy, strategy)]),
        spot=spot,
        wait_pt=jnp.stack([wait_h,
                           u(ks[3], [0.04, 0.13, 0.24], [0.10, 0.17, 0.29], (3,))]),
        yaw=slice_draw(ks[4], held["yaw"], (-YAW_RANGE[1], YAW_RANGE[1]), YAW_HELD, symmetric=True),
        pitch=slice_draw(kp[10], held["pitch"], (-TILT_RANGE[1], TILT_RANGE[1]), TILT_HELD, symmetric=True),
        roll=slice_draw(kp[11], held["roll"], (-TILT_RANGE[1], TILT_RANGE[1]), TILT_HELD, symmetric=True),
        drop=drop,
        open_amt=u(ks[6], 0.125, 0.155),
        handle_y=jnp.stack([u(ks[7], -0.04, -0.005), u(ks[8], 0.005, 0.04)]),
        vmax=vmax.at[0].set(jnp.minimum(vmax[0] * pace, 1.0)),
        amax=amax.at[0].multiply(pace),
        gain=gain.at[0].multiply(pace),
        # robot: reaction delay once its cue holds (s1 the human carrying past CUE_Y, s2 the human at
        # its waiting point)
        delay=delay,
        react=react,
        lift=u(ks[14], 0.04, 0.09),
        pause=jax.random.randint(ks[15], (), 0, 12),
        retreat=jnp.stack([jnp.array([0.0, -0.10, 0.08]) + u(ks[16], -0.03, 0.03, (3,)),
                           jnp.array([0.0, 0.10, 0.08]) + u(ks[17], -0.03, 0.03, (3,))]),
        noise=noise.at[0].multiply(jnp.where(v == NOISE, NOISE_FACTOR, 1.0)),
        phase=jnp.zeros((2,), jnp.int32),
        timer=jnp.zeros((2,), jnp.int32),
        vel=jnp.zeros((2, 3)),
        anchor=jnp.zeros((2, 3)),
        rot_gain=pace,
        pause_t=pause_t,
        pause_n=pause_n,
        wp_off=wp_off,
        wp_on=jnp.full((2,), v == DETOUR),
        decoy_n=decoy_n.astype(jnp.int32),
        follows=follows,
        early=fast,
    )
    return ts, strategy


def _context(env, ts: TeamState, state) -> dict:
    """What both scripted agents look at this step, and the targets they share."""
    d = state.pipeline_state
    h, r = env.human, env.robot
    p_obj, R_obj = env._obj_pos(d), env._obj_mat(d)
    handle = env._handle_pos(d)
    opening = env._opening(d)
    tcp = jnp.stack([mc.tcp_pos(d, h), mc.tcp_pos(d, r)])
    h_touch, r_touch = env._any_touch(d, h, OBJ), env._any_touch(d, r, OBJ)
    # drop point: object centre above the open drawer, TCP keeps its current offset to the object
    front_inner = d.xpos[env.drawer_body][0] - DR_DX
    drop_c = jnp.stack([front_inner + ts.drop[0], ts.drop[1], WALL_TOP + OBJ_HALF[2] + ts.drop[2]])
    closed_x = handle[0] + opening + 0.008  # handle x of the closed drawer (+ a little push)
    return dict(
        d=d, p_obj=p_obj, R_obj=R_obj, normal=mc.bar_normal(R_obj), grip_r=mc.grip_angles(R_obj, r),
        obj_yaw=mc.wrap_angle(mc.yaw_of(R_obj), np.pi),  # the bar is symmetric under 180 deg
        handle=handle, opening=opening, tcp=tcp,
        yaw=jnp.stack([d.ctrl[h.act + 5], d.ctrl[r.act + 5]]),  # (robot: its own base frame)
        ang=jnp.stack([d.ctrl[h.act + 3:h.act + 6], d.ctrl[r.act + 3:r.act + 6]]),  # every hinge target
        h_grasp=mc.is_grasping(d, h, OBJ), r_grasp=mc.is_grasping(d, r, OBJ),
        h_handle=mc.is_grasping(d, h, "handle"), r_handle=mc.is_grasping(d, r, "handle"),
        h_touch=h_touch, r_touch=r_touch,
        gap_open=jnp.stack([mc.finger_gap(d, h), mc.finger_gap(d, r)]) > 0.036,
        placed=env._inside(d) & ~h_touch & ~r_touch,
        drop_fits=DROP_FITS if getattr(env, "drop_yaw_bound", None) is None else env.drop_yaw_bound,
        drop_tcp=[drop_c + (tcp[i] - p_obj) for i in (0, 1)],
        handle_pt=[handle + jnp.array([0.0, ts.handle_y[i], 0.0]) for i in (0, 1)],
        pull=[ts.anchor[i] - jnp.array([ts.open_amt, 0.0, 0.0]) for i in (0, 1)],
        push=[ts.anchor[i].at[0].set(closed_x) for i in (0, 1)],
    )


def _up(z):
    return jnp.array([0.0, 0.0, z])


def _near(c, i, tgt, tol):
    return jnp.linalg.norm(c["tcp"][i] - tgt) < tol


def _drop_yaw(c, ts: TeamState, i):
    """The hinge targets agent ``i`` drops the bar at: level, its own yaw turned back within the bound the drawer
    takes (``c["drop_fits"]``, the env's ``drop_yaw_bound`` where it sets one)."""
    bound = c.get("drop_fits", DROP_FITS) + 0.5 * ts.drop[3]
    return _flat(jnp.clip(mc.wrap_angle(c["yaw"][i], np.pi), -bound, bound))


def _yaw_ok(c, i, tgt):
    """Every hinge target of agent ``i`` within 0.05 rad of ``tgt`` (rx, ry, rz)."""
    return jnp.all(jnp.abs(c["ang"][i] - tgt) < 0.05)


def _human(env, ts: TeamState, c: dict, coplay: bool = False):
    """The human's phase machine: (target, yaw target, gripper, gate, new phase, wp_on, decoy_n). ``coplay``: it
    sees the robot's state instead of its phase (the robot gone from the bar; the robot holding the handle)."""
    d, h = c["d"], env.human
    ph, pr, th = ts.phase[0], ts.phase[1], ts.timer[0]
    s_h = ts.strategy[0] - 1
    obj_yaw, drop_tcp, handle_pt = c["obj_yaw"], c["drop_tcp"], c["handle_pt"]
    g_h = c["p_obj"] + c["R_obj"] @ jnp.array([0.0, -GRASP_OFF, 0.0])
    g_h = g_h.at[2].set(jnp.maximum(g_h[2], 0.018))
    R_show = presented(ts)
    show = mc.grip_angles(R_show, h)
    flat, level = _flat(obj_yaw), _flat(jnp.zeros(()))
    spot_h = ts.spot + R_show @ jnp.array([0.0, -GRASP_OFF, 0.0])
    hold_h = ts.anchor[0]
    retreat_h = ts.anchor[0] + ts.retreat[0]
    target = _select(ph, {
        H_WAIT: world_ctrl(d, h), H_REACH: g_h + _up(0.07), H_DESCEND: g_h, H_CLOSE: hold_h,
        H_LIFT: ts.anchor[0] + _up(ts.lift), H_CARRY: spot_h, H_OFFER: spot_h,
        H_BACKOFF: ts.anchor[0] + jnp.array([0.0, -0.06, 0.03]), H_TO_HANDLE: handle_pt[0] + _up(0.07),
        H_DESC_HANDLE: handle_pt[0], H_GRIP_HANDLE: hold_h, H_PULL: c["pull"][0], H_HOLD_OPEN: hold_h,
        H_PUSH: c["push"][0], H_LET_GO: hold_h, H_CARRY_WAIT: ts.wait_pt[0], H_WAIT_OPEN: ts.wait_pt[0],
        H_ABOVE_DROP: drop_tcp[0] + _up(0.06), H_LOWER: drop_tcp[0], H_RELEASE: hold_h}, retreat_h)
    yawt = _select(ph, {
        H_REACH: flat, H_DESCEND: flat, H_CLOSE: flat, H_LIFT: show, H_CARRY: show,
        H_OFFER: show, H_TO_HANDLE: level, H_DESC_HANDLE: level, H_GRIP_HANDLE: level, H_PULL: level,
        H_HOLD_OPEN: level, H_PUSH: level, H_CARRY_WAIT: show, H_WAIT_OPEN: show,
        H_ABOVE_DROP: _drop_yaw(c, ts, 0), H_LOWER: _drop_yaw(c, ts, 0)}, c["ang"][0])
    offer_release = (ph == H_OFFER) & (th >= ts.react[0])
    grip = jnp.where(((ph >= H_CLOSE) & (ph <= H_OFFER) & ~offer_release)
                     | ((ph >= H_GRIP_HANDLE) & (ph <= H_PUSH))
                     | ((ph >= H_CARRY_WAIT) & (ph <= H_LOWER)), -1.0, 1.0)
    if coplay:
        robot_gone = c["gap_open"][1] & ~c["r_touch"] & (jnp.linalg.norm(c["tcp"][1] - c["p_obj"]) > AWAY)
        robot_holds_open = c["r_handle"]
    else:
        robot_gone, robot_holds_open = pr == R_RETREAT, pr == R_HOLD_OPEN
    gate = _select(ph, {
        H_OFFER: c["r_grasp"],
        H_HOLD_OPEN: c["placed"] & robot_gone,
        H_WAIT_OPEN: (c["opening"] >= DRAWER_OPEN_MIN) & robot_holds_open}, True)
    near = lambda tgt, tol: _near(c, 0, tgt, tol)  # noqa: E731
    adv = _select(ph, {
        H_WAIT: th >= ts.delay[0],
        H_REACH: near(g_h + _up(0.07), 0.012) & _yaw_ok(c, 0, flat),
        H_DESCEND: near(g_h, 0.006),
        H_CLOSE: c["h_grasp"] & (th >= 5),
        H_LIFT: near(ts.anchor[0] + _up(ts.lift), 0.012) & (th >= ts.pause),
        H_CARRY: near(spot_h, 0.008) & _yaw_ok(c, 0, show),
        H_OFFER: offer_release & c["gap_open"][0],
        H_BACKOFF: near(ts.anchor[0] + jnp.array([0.0, -0.06, 0.03]), 0.02),
        H_TO_HANDLE: near(handle_pt[0] + _up(0.07), 0.012) & _yaw_ok(c, 0, level),
        H_DESC_HANDLE: near(handle_pt[0], 0.006),
        H_GRIP_HANDLE: c["h_handle"] & (th >= 4),
        H_PULL: near(c["pull"][0], 0.01) | (c["opening"] >= ts.open_amt),
        H_HOLD_OPEN: th >= ts.react[0],
        H_PUSH: (c["opening"] < 0.004) & (th >= 5),
        H_LET_GO: c["gap_open"][0] & (th >= 3),
        H_CARRY_WAIT: near(ts.wait_pt[0], 0.012) & _yaw_ok(c, 0, show),
        H_WAIT_OPEN: th >= ts.react[0],
        H_ABOVE_DROP: near(drop_tcp[0] + _up(0.06), 0.012) & _yaw_ok(c, 0, _drop_yaw(c, ts, 0)),
        H_LOWER: near(drop_tcp[0], 0.008),
        H_RELEASE: c["gap_open"][0] & (th >= 3)}, False)
    target, adv, wp_on, decoy_n = _human_variation(ts, c, target, adv, g_h, spot_h)
    carrying = ((ph >= H_LIFT) & (ph <= H_OFFER)) | ((ph >= H_CARRY_WAIT) & (ph <= H_LOWER))
    regrasp = ((ph == H_CLOSE) & (th > 25)) | (carrying & ~c["h_grasp"] & (c["p_obj"][2] < 0.03))
    rehandle = (ph == H_GRIP_HANDLE) & (th > 25)
    new_ph = jnp.where(adv, jnp.asarray(NEXT_H)[s_h, ph], ph)
    new_ph = jnp.where(regrasp, H_REACH, jnp.where(rehandle, H_TO_HANDLE, new_ph))
    return target, yawt, grip, gate, new_ph, wp_on, decoy_n


def _human_variation(ts: TeamState, c: dict, target, adv, g_h, spot_h):
    """The human's path variations: the other strategy's first sub-goal first (change of mind: s1 carries
    towards the waiting point by the drawer, s2 towards the handover spot), waypoints (detour)."""
    ph = ts.phase[0]
    carry_leg = (ph == H_CARRY) | (ph == H_CARRY_WAIT)
    decoying = carry_leg & (ts.decoy_n > 0)
    decoy_pt = jnp.where(ph == H_CARRY, ts.wait_pt[0], spot_h)
    wps = jnp.stack([g_h + _up(0.07) + ts.wp_off[0], 0.5 * (ts.anchor[0] + target) + ts.wp_off[1]])
    leg = jnp.stack([ph == H_REACH, carry_leg]) & ts.wp_on & ~decoying
    k = jnp.argmax(leg)
    wp_active = jnp.any(leg)
    new_target = jnp.where(decoying, decoy_pt, jnp.where(wp_active, wps[k], target))
    adv = adv & ~decoying & ~wp_active
    decoy_n = jnp.where(decoying, ts.decoy_n - 1, ts.decoy_n)  # there (or on its way) for decoy_n steps
    wp_on = jnp.where(wp_active & _near(c, 0, wps[k], 0.02), ts.wp_on.at[k].set(False), ts.wp_on)
    return new_target, adv, wp_on, decoy_n


def _robot(env, ts: TeamState, c: dict, seen: dict | None = None):
    """The robot's phase machine: (target, yaw target or NaN (keep), gripper, gate, new phase). ``seen``: what the
    co-play robot sees of the human instead of its phase (:func:`robot_act`)."""
    d, r = c["d"], env.robot
    ph, pr, tr = ts.phase[0], ts.phase[1], ts.timer[1]
    s_r = ts.strategy[1] - 1
    grip_a, drop_tcp, handle_pt, tcp = c["grip_r"], c["drop_tcp"], c["handle_pt"], c["tcp"]
    level = _flat(jnp.zeros(()))
    g_r = c["p_obj"] + c["R_obj"] @ jnp.array([0.0, GRASP_OFF, 0.0])
    over_r = g_r + 0.07 * c["normal"]  # over the bar along its normal: the gripper comes square to a tilted bar
    hold_r = ts.anchor[1]
    retreat_r = ts.anchor[1] + ts.retreat[1]
    lift_r = ts.anchor[1] + jnp.array([0.0, 0.06, 0.06])
    target = _select(pr, {
        R_WAIT: world_ctrl(d, r), R_APPROACH: over_r, R_DESCEND: g_r, R_CLOSE: hold_r,
        R_LIFT: lift_r, R_HOVER: ts.wait_pt[1], R_WAIT_OPEN: ts.wait_pt[1],
        R_ABOVE_DROP: drop_tcp[1] + _up(0.06), R_LOWER: drop_tcp[1], R_RELEASE: hold_r,
        R_TO_HANDLE: handle_pt[1] + _up(0.07), R_DESC_HANDLE: handle_pt[1], R_GRIP_HANDLE: hold_r,
        R_PULL: c["pull"][1], R_HOLD_OPEN: hold_r, R_PUSH: c["push"][1], R_LET_GO: hold_r}, retreat_r)
    keep = jnp.full((3,), jnp.nan)
    yawt = _select(pr, {
        R_APPROACH: grip_a, R_DESCEND: grip_a, R_CLOSE: grip_a, R_ABOVE_DROP: _drop_yaw(c, ts, 1),
        R_LOWER: _drop_yaw(c, ts, 1), R_TO_HANDLE: level, R_DESC_HANDLE: level, R_GRIP_HANDLE: level, R_PULL: level,
        R_HOLD_OPEN: level, R_PUSH: level}, keep)
    grip = jnp.where(((pr >= R_CLOSE) & (pr <= R_LOWER)) | ((pr >= R_GRIP_HANDLE) & (pr <= R_PUSH)), -1.0, 1.0)
    near = lambda tgt, tol: _near(c, 1, tgt, tol)  # noqa: E731
    near_h = lambda tgt, tol: _near(c, 0, tgt, tol)  # noqa: E731
    # a following robot takes the human's first leg of a change of mind for what it looks like
    if seen is None:  # the team's robot sees the human's phase
        decoy = ts.follows & ((ph == H_CARRY) | (ph == H_CARRY_WAIT)) & (ts.decoy_n > 0)
        # the robot reacts to what it can see (so a policy reading the state can tell the strategies
        # apart when the robot has to act): s1, the human carrying the bar has come past the middle
        # towards it; s2, the human holds the bar still at its waiting point by the drawer
        start = jnp.where(s_r == 0, (((ph >= H_CARRY) & (ph <= H_OFFER)) | decoy) & (tcp[0, 1] > CUE_Y),
                          (ph == H_WAIT_OPEN) | (((ph == H_CARRY_WAIT) | decoy) & near_h(ts.wait_pt[0], 0.03)))
        holds_open, gone, offers, let_go = ph == H_HOLD_OPEN, ph == H_RETREAT, ph == H_OFFER, ph >= H_BACKOFF
    else:
        start, holds_open, gone, offers, let_go = (seen[k] for k in ("start", "holds_open", "gone", "offers",
                                                                     "let_go"))
    open_held = (c["opening"] >= DRAWER_OPEN_MIN) & holds_open
    early = ts.early & (seen is None)
    opening = c["h_handle"] & (c["opening"] >= EARLY_OPEN)
    gate = _select(pr, {
        R_WAIT: start,
        R_WAIT_OPEN: jnp.where(early, opening | open_held, open_held),
        R_HOLD_OPEN: c["placed"] & gone}, True)
    adv = _select(pr, {
        R_WAIT: tr >= ts.delay[1],
        R_APPROACH: offers & near(over_r, 0.012) & _yaw_ok(c, 1, grip_a),
        R_DESCEND: near(g_r, 0.006),
        R_CLOSE: c["r_grasp"] & let_go & ~c["h_touch"] & (tr >= 4),
        R_LIFT: near(lift_r, 0.015),
        R_HOVER: near(ts.wait_pt[1], 0.012),
        R_WAIT_OPEN: tr >= ts.react[1],
        R_ABOVE_DROP: near(drop_tcp[1] + _up(0.06), 0.012) & _yaw_ok(c, 1, _drop_yaw(c, ts, 1))
        & (open_held | ~early),
        R_LOWER: near(drop_tcp[1], 0.008),
        R_RELEASE: c["gap_open"][1] & (tr >= 3),
        R_TO_HANDLE: near(handle_pt[1] + _up(0.07), 0.012) & _yaw_ok(c, 1, level),
        R_DESC_HANDLE: near(handle_pt[1], 0.006),
        R_GRIP_HANDLE: c["r_handle"] & (tr >= 4),
        R_PULL: near(c["pull"][1], 0.01) | (c["opening"] >= ts.open_amt),
        R_HOLD_OPEN: tr >= ts.react[1],
        R_PUSH: (c["opening"] < 0.004) & (tr >= 5),
        R_LET_GO: c["gap_open"][1] & (tr >= 3)}, False)
    regrasp = (pr == R_CLOSE) & (tr > 40) & ~c["r_grasp"]
    rehandle = (pr == R_GRIP_HANDLE) & (tr > 25)
    new_pr = jnp.where(adv, jnp.asarray(NEXT_R)[s_r, pr], pr)
    new_pr = jnp.where(regrasp, R_APPROACH, jnp.where(rehandle, R_TO_HANDLE, new_pr))
    return target, yawt, grip, gate, new_pr


def team_act(env, ts: TeamState, state, rng: jax.Array, coplay: bool = False,
             seen: dict | None = None) -> tuple[TeamState, jax.Array]:
    """Both agents' step. ``coplay``: the human sees the robot's state instead of its phase (:func:`human_act`);
    ``seen``: the co-play robot's view of the human (:func:`robot_act`)."""
    d = state.pipeline_state
    h, r = env.human, env.robot
    c = _context(env, ts, state)
    target_h, yawt_h, grip_h, gate_h, new_ph, wp_on, decoy_n = _human(env, ts, c, coplay)
    target_r, yawt_r, grip_r, gate_r, new_pr = _robot(env, ts, c, seen)
    ph, pr = ts.phase[0], ts.phase[1]

    # ---------------- actions
    k1, _ = jax.random.split(rng)
    vel_h = move(world_ctrl(d, h), target_h, ts.vel[0], ts.vmax[0], ts.amax[0], ts.gain[0])
    vel_r = move(world_ctrl(d, r), target_r, ts.vel[1], ts.vmax[1], ts.amax[1], ts.gain[1])
    vel_h = jnp.where(ph == H_WAIT, 0.0, vel_h)
    vel_r = jnp.where(pr == R_WAIT, 0.0, vel_r)
    noise = jax.random.normal(k1, (2, 6)) * ts.noise[:, None] * jnp.array([1.0, 1, 1, 0.3, 0.3, 0.3])
    yawt_r = jnp.where(jnp.isnan(yawt_r), c["ang"][1], yawt_r)
    a_h = jnp.concatenate([jnp.asarray(h.base_mat.T) @ vel_h,
                           rot_action(d, h, yawt_h, 0.25 * ts.rot_gain, jnp.minimum(0.9 * ts.rot_gain, 1.0))]) + noise[0]
    a_r = jnp.concatenate([jnp.asarray(r.base_mat.T) @ vel_r, rot_action(d, r, yawt_r)]) + noise[1]
    # the human's variation: a dead stop (no motion, gripper as it was, its plan and timers frozen)
    stopped = paused(ts.pause_t, ts.pause_n, state.info["t"])
    a_h = jnp.where(stopped, 0.0, a_h)
    vel_h = jnp.where(stopped, 0.0, vel_h)
    new_ph = jnp.where(stopped, ph, new_ph)
    wp_on = jnp.where(stopped, ts.wp_on, wp_on)
    decoy_n = jnp.where(stopped, ts.decoy_n, decoy_n)
    action = jnp.clip(jnp.concatenate([a_h, grip_h[None], a_r, grip_r[None]]), -1.0, 1.0)

    # a following robot's switch: the human turns from its first leg to its own strategy
    switch = ts.follows & (ts.strategy[1] != ts.strategy[0]) & (ts.decoy_n > 0) & (decoy_n == 0)
    new_pr = jnp.where(switch, R_WAIT, new_pr)
    strategy = ts.strategy.at[1].set(jnp.where(switch, ts.strategy[0], ts.strategy[1]))

    new_phase = jnp.stack([new_ph, new_pr]).astype(jnp.int32)
    changed = (new_phase != ts.phase) | jnp.stack([False, switch])
    counted = jnp.where(jnp.stack([gate_h, gate_r]), ts.timer + 1, 0)
    counted = counted.at[0].set(jnp.where(stopped, ts.timer[0], counted[0]))
    timer = jnp.where(changed, 0, counted).astype(jnp.int32)
    anchor = jnp.where(changed[:, None], c["tcp"], ts.anchor)
    ts = ts._replace(phase=new_phase, timer=timer, vel=jnp.stack([vel_h, vel_r]), anchor=anchor, wp_on=wp_on,
                     decoy_n=decoy_n, strategy=strategy)
    return ts, action


def human_act(env, ts: TeamState, state, rng: jax.Array) -> tuple[TeamState, jax.Array]:
    """The scripted human alone (closed-loop co-play): its part of :func:`team_act` with the gates that read the
    robot's phase replaced by what a person sees: the bar dropped into the drawer and the robot gone from it (gripper
    open, not touching it, its TCP ``AWAY`` from it) before it shuts the drawer; the drawer open with the robot
    holding the handle before it drops the bar. The robot's entries of the returned team state are the scripted
    robot's bookkeeping, read by nobody."""
    ts, action = team_act(env, ts, state, rng, coplay=True)
    return ts, action[:env.human_action_size]


# the robot's phases in which it holds nothing yet and may still change its mind about the strategy
_UNCOMMITTED = (R_WAIT, R_APPROACH, R_DESCEND, R_TO_HANDLE, R_DESC_HANDLE)


def robot_act(env, ts: TeamState, state, rng: jax.Array) -> tuple[TeamState, jax.Array]:
    """The scripted robot alone (closed-loop co-play), on observables only. It reads the strategy off the human's
    moves (``guess``), as the following robot of the training sets does: strategy 1 once the human with the bar
    lifted has come past the middle of the table (TCP y > ``CUE_Y``), strategy 2 once the human holds the bar
    still, high (TCP z > ``WAIT_Z``), on its own side; while it holds nothing yet a new reading makes it start over
    from its waiting phase. Instead of the human's phase it sees the bar offered (held still past the middle), the
    human's hand off the bar, the human holding the drawer's handle, and the human gone from the bar. The human's
    entries of ``ts`` and the team's plan (``strategy``) are never read."""
    c = _context(env, ts, state)
    p_obj, tcp_h = c["p_obj"], c["tcp"][0]
    still = jnp.where((state.info["t"] > 0) & (jnp.linalg.norm(p_obj - ts.seen) < STILL_SPEED), ts.still + 1, 0)
    lifted = c["h_grasp"] & (p_obj[2] > LIFTED_SEEN)
    held_still = lifted & (still >= STILL_STEPS)
    cue1 = lifted & (tcp_h[1] > CUE_Y)
    cue2 = held_still & (tcp_h[1] <= CUE_Y) & (tcp_h[2] > WAIT_Z)
    pr = ts.phase[1]
    free = jnp.any(jnp.stack([pr == p for p in _UNCOMMITTED]))
    guess = jnp.where(free & cue1, 1, jnp.where(free & cue2, 2, ts.guess)).astype(jnp.int32)
    seen = dict(start=jnp.where(guess == 1, cue1, cue2) & (guess > 0),
                offers=held_still & (tcp_h[1] > CUE_Y),
                let_go=c["gap_open"][0] & ~c["h_touch"],
                holds_open=c["h_handle"],
                gone=c["gap_open"][0] & ~c["h_touch"] & ~c["h_handle"] & (jnp.linalg.norm(tcp_h - p_obj) > AWAY))
    view = ts._replace(strategy=ts.strategy.at[1].set(jnp.maximum(guess, 1)), follows=jnp.array(False))
    new, action = team_act(env, view, state, rng, seen=seen)
    switch = (ts.guess > 0) & (guess != ts.guess)  # a new reading: let go, start over from the waiting phase
    phase = jnp.where(switch, R_WAIT, new.phase[1])
    timer = jnp.where(switch, 0, new.timer[1])
    anchor = jnp.where(switch, c["tcp"][1], new.anchor[1])
    out = ts._replace(phase=ts.phase.at[1].set(phase), timer=ts.timer.at[1].set(timer),
                      vel=ts.vel.at[1].set(new.vel[1]), anchor=ts.anchor.at[1].set(anchor),
                      seen=p_obj.astype(jnp.float32), still=still.astype(jnp.int32), guess=guess)
    a_r = action[env.human_action_size:]
    return out, jnp.where(switch, a_r.at[-1].set(1.0), a_r)


TEAM = Team(init=team_init, act=team_act, variations=True, partner_can_follow=True, human_act=human_act,
            robot_act=robot_act, held_out=True, held_out_slices=SLICES, prompt_robot=True)
