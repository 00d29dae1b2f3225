"""HR-SeqManip in MuJoCo MJX: put an object into a drawer, together (Co-GAIL paper, appendix).

Scene (world frame, z up, table top z = 0; see :mod:`mjx_common` for the gripper model)::

                     robot base (0, +0.40, 0.25), faces -y
                                   |
                      handle       |   +-----------------+
      left (-x)       (x = 0.14    | ==|  drawer (slides  |  cabinet  x in [0.20, 0.42]
                       closed)     |   |  along x, opens |           y in [-0.15, 0.15]
                                   |   |  towards -x)    |           top at z = 0.10-0.12
                                   |   +-----------------+
         [=bar=]  object on the counter in front of the human, lying along y at (-0.08, -0.22)
                                   |
                     human base (0, -0.40, 0.25), faces +y

* Object: a bar 3 x 14 x 3 cm, 80 g. The human grasps it 3.5 cm from its centre on its own side, the
  robot 3.5 cm from the centre on the other side. The robot's workspace (joint limits) stops at
  y = -0.10, so it can never reach the bar where it lies: only the human can pick it up.
* Drawer: a tray (floor + 4 walls; interior 18 x 24 x 6 cm, floor top at z = 0.03) on a slide joint
  (range 0..16 cm, damping 8 N s/m, no spring); at 0 it sits inside the cabinet. Its handle is a
  horizontal capsule (radius 1 cm, 12 cm long, along y) 6 cm in front of the drawer face at z = 0.06.
* Both grippers' TCPs are limited to x <= 0.15 (joint limits keep them out of the cabinet). Collisions
  are explicit pairs only: finger pads + palm vs. the object, finger pads vs. the handle, the object vs.
  the table, the drawer floor (friction), the drawer walls and the cabinet top (frictionless, they only
  need to stop the object; the cabinet top stops it from entering a closed drawer from above).
  60 contacts in all, Newton solver (2 iterations, 4 line-search iterations), 2 x 10 ms substeps,
  finger-pad pairs with condim 3 (see :mod:`mjx_common`; measured on CPU ~2.5x cheaper per env step than
  4 / 8 iterations, 4 x 5 ms and condim 4, with the same scripted-team results).

Action (14): ``concat(a_H, a_R)``, each ``(dx, dy, dz, drx, dry, drz, g)`` in [-1, 1]: 1 cm / 1 degree
per unit per step in the agent's base frame (the paper's HR-Handover scale, shared with
:mod:`handover`) and the absolute gripper command (-1 closed, +1 open).

Observation (43): human TCP pose in the human base frame (3 + 6D rotation), robot TCP pose in the robot
base frame (3 + 6), object position relative to each TCP (each in that agent's base frame, 3 + 3),
object orientation (6D, world), finger gaps / 8 cm (2), handle position relative to each TCP (each in
that agent's base frame, 3 + 3), drawer opening / 16 cm (1), flags: human grasps the object, robot
grasps the object, human grasps the handle, robot grasps the handle (4).

Rules:
* Grasping is an honest friction grasp of the bar (:func:`mjx_common.is_grasping`: both finger pads
  touch it, contact sensors, and the gripper is commanded closed); no weld, no grasp assist. Nobody
  holding the bar => it falls (plain physics).
* Drawer handle: no weld either. A gripper opens or closes the drawer by closing its fingers around the
  handle and moving along x: the finger pads push on the capsule (contact normal forces, so the pull
  needs no friction). "Grasps the handle" = :func:`mjx_common.is_grasping` on the handle.
* ``success`` (sticky metric; ``done`` on success or at ``max_episode_steps`` = 600): the object's
  centre is inside the drawer's box (drawer frame: between the walls, between floor and wall top), no
  finger pad touches it, it rests (speed < 5 cm/s) and the drawer is closed (opening < 1 cm).
* Strategy events (scalar metrics; 1 = human, 2 = robot, 3 = both at once, 0 = nobody/not yet):
  ``opened_by`` = who was last touching the handle when the opening last rose past 8 cm;
  ``placed_by`` = who last held the object alone (grasp) before it came to lie free inside the drawer;
  ``closed_by`` = who was last touching the handle when the drawer last closed; ``handover`` = 1 once the
  robot grasped the object while the human touched it; ``max_open`` = largest opening (m).
  :meth:`SeqManip.classify_strategy`: 1 "human-hands-over" if the episode succeeded with
  opened_by = human and placed_by = robot; 2 "robot-opens" if it succeeded with opened_by = robot and
  placed_by = human; otherwise 0.

Scripted human-human team (:meth:`SeqManip.team_init` / :meth:`SeqManip.team_act`, pure JAX, vmappable):
two phase machines (human ``H_*``, robot ``R_*``; successor tables ``NEXT_H`` / ``NEXT_R`` per
strategy). The strategy is drawn from ``mix``; within a strategy it varies the handover spot
(x in [-0.16, 0], y in [-0.07, 0], z in [0.14, 0.26]), the carry yaw, the waiting points, how far the
drawer is pulled (12.5-15.5 cm), where each hand grasps the handle, where and from how high the object
is dropped, speeds, acceleration limits, gains, start and reaction delays, a pause after lifting and
action noise. Motions are proportional control with velocity and acceleration limits (bell-shaped,
minimum-jerk-like speed profiles). Waiting phases are gated: their timer only runs while the awaited
condition holds (e.g. the drawer is open and held), so every hand-off has a reaction delay.

1. human-hands-over: the human picks the bar up and carries it out to the handover spot; once the human
   has come past the middle of the table towards it (TCP y > ``CUE_Y``) the robot reacts, grasps the
   bar's far end; the human lets go, backs off, grasps the handle and pulls the drawer open while the
   robot hovers with the bar; the robot lowers the bar over the drawer and drops it; the robot retreats
   and the human pushes the drawer shut.
2. robot-opens: the human picks the bar up and carries it to a waiting point near the drawer; once the
   human holds still there the robot reacts, grasps the handle and pulls the drawer open; the human lowers
   the bar over the drawer and drops it, then retreats; the robot pushes the drawer shut.

The robot's cues are things it can see in the state (where the human's hand is, whether it has
stopped), so a policy reading the state and the human's recent history can tell the two strategies apart
when it has to act. (Before the 5th session the robot started on the human's lift in strategy 1 and 20-60
steps after it in strategy 2: while the two humans' motions were still alike, the demonstrated robots
already did different things, and behaviour cloning averaged them.)

Measured (CPU, ``cogail_jax.demos.generate``, uniform mix, seeds 100-103, 4 x 256 episodes): 1024 of 1024
scripted episodes succeed and all are classified as their intended strategy; length 456.1 +- 35.7 steps
(370-548) for human-hands-over, 369.5 +- 28.3 (306-454) for robot-opens, 411.9 overall (paper: 404).
``python -m cogail_envs.seqmanip`` prints the MJCF.

Rendering uses :class:`mjx_common.FrameRenderer` (default camera ``drawer``: the drawer front seen from
the human's left).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import mjx_common as mc
from .base import CollabEnv, State

OBJ = "object"
OBJ_HALF = (0.015, 0.07, 0.015)
OBJ_MASS = 0.08
GRASP_OFF = 0.035
OBJ_START = (-0.08, -0.22)
HUMAN_BASE = (0.0, -0.40, 0.25)
ROBOT_BASE = (0.0, 0.40, 0.25)

X_FRONT = 0.20          # cabinet front face = drawer front face when closed (world x)
DR_DX, DR_DY = 0.09, 0.12   # drawer interior half sizes
WALL = 0.005            # wall half thickness
WALL_H = 0.06           # wall height above the drawer floor
FLOOR_Z = 0.03          # drawer floor top surface (world z)
TRAVEL = 0.16           # slide range
STANDOFF = 0.06         # handle axis distance in front of the drawer face
HANDLE_R = 0.01
HANDLE_HALF = 0.06
HANDLE_DZ = 0.03        # handle height above the floor surface
DRAWER_X0 = X_FRONT + 2 * WALL + DR_DX   # drawer body origin (closed), centre of the floor top surface
CAB_TOP_Z = 0.10

X_MAX = 0.15            # grippers' TCP x limit (keeps them out of the cabinet)

HUMAN = mc.GripperSpec("human", HUMAN_BASE, 0.0, (-0.35, -0.05, -0.234, -0.6, -0.6, -1.6),
                       (X_MAX, 0.55, 0.20, 0.6, 0.6, 1.6), rgba=(0.25, 0.55, 0.9, 1.0))
ROBOT = mc.GripperSpec("robot", ROBOT_BASE, 180.0, (-X_MAX, -0.05, -0.234, -0.6, -0.6, -1.6),
                       (0.35, 0.50, 0.20, 0.6, 0.6, 1.6), rgba=(0.9, 0.35, 0.3, 1.0))

DRAWER_GEOMS = ("drawer_floor", "drawer_front", "drawer_back", "drawer_left", "drawer_right")


# init vector: obj dx, obj dy, obj yaw, human start (3, base frame), robot start (3, base frame)
INIT_LO = np.array([-0.05, -0.015, -0.15, -0.03, -0.03, -0.03, -0.03, -0.03, -0.03], np.float32)
INIT_HI = -INIT_LO

OPEN_THRESH = 0.08      # opening (m) that counts as "the drawer was opened"
CLOSED_TOL = 0.01       # opening (m) below which the drawer counts as closed
REST_SPEED = 0.05       # object speed (m/s) below which it "rests"
DRAWER_OPEN_MIN = 0.10  # opening the scripted droppers wait for
CUE_Y = -0.13           # s1: the scripted robot starts once the human's TCP is past this y (spot side)
WALL_TOP = FLOOR_Z + WALL_H


def _rotz(yaw: jax.Array) -> jax.Array:
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.array([[c, -s, z], [s, c, z], [z, z, o]])


def _move(p_cmd, target, vel, vmax, amax, gain):
    """Velocity- and acceleration-limited proportional step (world frame, action units): bell-shaped,
    minimum-jerk-like speed profiles."""
    v_des = gain * (target - p_cmd) / mc.POS_SCALE
    n = jnp.linalg.norm(v_des)
    v_des = v_des * jnp.minimum(1.0, vmax / (n + 1e-9))
    dv = v_des - vel
    dn = jnp.linalg.norm(dv)
    return vel + dv * jnp.minimum(1.0, amax / (dn + 1e-9))


# ---------------------------------------------------------------------------------------------------
# Scripted team: phases. Human (H_*) and robot (R_*) phase machines; NEXT_* gives the successor of a
# completed phase per strategy (row 0: human-hands-over, row 1: robot-opens).
# ---------------------------------------------------------------------------------------------------
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


NEXT_H = _next_table(21, {(0, H_LET_GO): H_RETREAT, (1, H_LIFT): H_CARRY_WAIT, (1, H_LET_GO): H_RETREAT})
NEXT_R = _next_table(18, {(1, R_WAIT): R_TO_HANDLE, (0, R_RELEASE): R_RETREAT, (1, R_RELEASE): R_RETREAT})


class TeamState(NamedTuple):
    """Scripted human-human team (per episode); index 0 human, 1 robot where paired."""

    strategy: jax.Array   # (2,) int32 strategy each agent follows (1 human-hands-over, 2 robot-opens)
    spot: jax.Array       # (3,) object-centre target of the handover (strategy 1, world)
    wait_pt: jax.Array    # (2, 3) waiting points: human with the object (s2), robot with the object (s1)
    yaw: jax.Array        # () carry yaw of the human (rad)
    drop: jax.Array       # (4,) drop point: x past the drawer's front inner wall, y, release height, yaw
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


def _f(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def _box(half, pos, rgba: str, name: str = "") -> str:
    nm = f'name="{name}" ' if name else ""
    return f'<geom {nm}type="box" size="{_f(half)}" pos="{_f(pos)}" rgba="{rgba}"/>'


def seqmanip_xml(iterations: int = mc.ITERATIONS, ls_iterations: int = mc.LS_ITERATIONS,
                 side_walls: bool = True, finger_condim: int = mc.FINGER_CONDIM,
                 timestep: float = mc.TIMESTEP) -> str:
    """The HR-SeqManip MJCF (two grippers, the table, the cabinet with its drawer, the bar)."""
    wood, dark, metal = "0.55 0.38 0.22 1", "0.45 0.3 0.18 1", "0.7 0.7 0.72 1"
    ww, hz = WALL, WALL_H / 2
    face = DR_DX + 2 * ww  # drawer face (outer side of the front wall), behind the body origin
    # drawer body frame: origin at the centre of the floor's top surface
    dg = [
        _box((face, DR_DY + 2 * ww, ww), (0, 0, -ww), dark, "drawer_floor"),
        _box((ww, DR_DY + 2 * ww, hz), (-(DR_DX + ww), 0, hz), wood, "drawer_front"),
        _box((ww, DR_DY + 2 * ww, hz), (DR_DX + ww, 0, hz), wood, "drawer_back"),
        _box((DR_DX, ww, hz), (0, -(DR_DY + ww), hz), wood, "drawer_left"),
        _box((DR_DX, ww, hz), (0, DR_DY + ww, hz), wood, "drawer_right"),
        _box((ww, DR_DY + 0.025, 0.045), (-face - ww, 0, 0.035), wood, "drawer_panel"),  # visual front panel
    ] + [_box(((STANDOFF - 0.01) / 2, 0.006, 0.006), (-face - (STANDOFF + 0.01) / 2, sy * (HANDLE_HALF - 0.006),
                                                       HANDLE_DZ), metal) for sy in (-1, 1)]  # handle posts
    dg.append(f'<geom name="handle" type="capsule" size="{HANDLE_R:g} {HANDLE_HALF:g}" '
              f'pos="{-face - STANDOFF:g} 0 {HANDLE_DZ:g}" euler="1.5707963 0 0" rgba="0.75 0.75 0.78 1"/>')
    drawer = (f'<body name="drawer" pos="{DRAWER_X0:g} 0 {FLOOR_Z:g}">'
              f'<joint name="drawer" type="slide" axis="1 0 0" range="{-TRAVEL:g} 0" damping="8" armature="0.5"/>'
              f'<inertial pos="0 0 0.02" mass="1.0" diaginertia="0.01 0.01 0.01"/>' + "".join(dg) + '</body>')
    cx0, cx1 = X_FRONT, X_FRONT + 2 * DR_DX + 4 * ww + 0.02
    cy = DR_DY + 2 * ww + 0.02
    cxc, cxh = (cx0 + cx1) / 2, (cx1 - cx0) / 2
    cab = [
        _box((cxh, cy, 0.01), (cxc, 0, CAB_TOP_Z + 0.01), wood, "cab_top"),
        _box((cxh, cy, (FLOOR_Z - 2 * ww) / 2), (cxc, 0, (FLOOR_Z - 2 * ww) / 2), wood),  # visual from here on
        _box((0.01, cy, CAB_TOP_Z / 2), (cx1 - 0.01, 0, CAB_TOP_Z / 2), wood),
    ] + [_box((cxh, 0.01, CAB_TOP_Z / 2), (cxc, sy * (cy - 0.01), CAB_TOP_Z / 2), wood) for sy in (-1, 1)]
    obj = mc.free_box_xml(OBJ, (*OBJ_START, OBJ_HALF[2]), OBJ_HALF, OBJ_MASS, rgba=(0.95, 0.75, 0.1, 1.0))
    walls = DRAWER_GEOMS if side_walls else DRAWER_GEOMS[:3]
    fc = finger_condim
    contact = (mc.gripper_pairs_xml(HUMAN, OBJ, finger_condim=fc)
               + mc.gripper_pairs_xml(ROBOT, OBJ, finger_condim=fc)
               + mc.gripper_pairs_xml(HUMAN, "handle", palm=False, finger_condim=fc)
               + mc.gripper_pairs_xml(ROBOT, "handle", palm=False, finger_condim=fc)
               + mc.pair_xml(OBJ, "table", 0.8) + mc.pair_xml(OBJ, "drawer_floor", 0.8)
               # walls and the cabinet top only need to stop the object: frictionless (condim 1, fewer rows)
               + "".join(mc.pair_xml(OBJ, g, 0.0, condim=1) for g in walls[1:] + ("cab_top",)))
    sensor = "".join(mc.gripper_sensors_xml(g, geom) for g in (HUMAN, ROBOT) for geom in (OBJ, "handle"))
    cam = mc.camera_xml("drawer", (-0.45, -0.60, 0.50), (0.05, -0.03, 0.10))  # the task's default view
    world = cam + drawer + "".join(cab) + obj
    return mc.scene_xml("seqmanip", [HUMAN, ROBOT], worldbody=world, contact=contact, sensor=sensor,
                        iterations=iterations, ls_iterations=ls_iterations, timestep=timestep)


class SeqManip(mc.MjxSnapshots, CollabEnv):
    """HR-SeqManip with brax's ``Env`` API (``pipeline_state`` is ``mjx.Data``).

    ``iterations`` / ``ls_iterations``: Newton solver settings; ``n_substeps``: physics steps per env
    step; ``timestep``: physics timestep (s); ``side_walls=False`` drops the two drawer side walls' contact
    pairs (8 fewer contacts; the scripted team does not need them); ``finger_condim``: 3 (sliding only,
    default) or 4 (sliding + torsional friction) for the finger-pad pairs (object and handle). Defaults:
    :data:`mjx_common.ITERATIONS` / ``LS_ITERATIONS`` / ``N_SUBSTEPS`` / ``TIMESTEP`` / ``FINGER_CONDIM``
    (2 / 4 / 2 / 0.01 s / 3).
    """

    name = "seqmanip"
    human_action_size = 7
    robot_action_size = 7
    max_episode_steps = 600
    init_size = 9
    strategy_names = ("human-hands-over", "robot-opens")
    discriminator_loss = "lsgan"

    def __init__(self, max_episode_steps: int = 600, iterations: int = mc.ITERATIONS,
                 ls_iterations: int = mc.LS_ITERATIONS, n_substeps: int = mc.N_SUBSTEPS,
                 side_walls: bool = True, finger_condim: int = mc.FINGER_CONDIM,
                 timestep: float = mc.TIMESTEP):
        import mujoco
        from mujoco import mjx

        self.max_episode_steps = int(max_episode_steps)
        self.n_substeps = int(n_substeps)
        self.timestep = float(timestep)
        self.xml = seqmanip_xml(iterations, ls_iterations, side_walls, finger_condim, self.timestep)
        self.mj_model, self.mx = mc.build(self.xml)
        m = self.mj_model
        self.human = mc.Gripper.from_model(m, "human", [OBJ, "handle"])
        self.robot = mc.Gripper.from_model(m, "robot", [OBJ, "handle"])
        self.obj_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, OBJ)
        jnt = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, OBJ)
        self.obj_qpos, self.obj_dof = int(m.jnt_qposadr[jnt]), int(m.jnt_dofadr[jnt])
        self.drawer_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "drawer")
        self.drawer_qpos = int(m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "drawer")])
        self.handle_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "handle")
        self._template = mjx.make_data(self.mx)
        self._renderer = None

    @property
    def observation_size(self) -> int:
        return 43

    @property
    def dt(self) -> float:
        return self.timestep * self.n_substeps

    # ------------------------------------------------------------------ reset
    def sample_init(self, rng: jax.Array) -> jax.Array:
        return jax.random.uniform(rng, (self.init_size,), minval=INIT_LO, maxval=INIT_HI)

    def reset_from(self, init: jax.Array) -> State:
        init = jnp.asarray(init, jnp.float32)
        m = self.mj_model
        qpos = jnp.asarray(m.qpos0, jnp.float32)
        h, r = self.human, self.robot
        qpos = qpos.at[jnp.array(h.qpos[:3])].set(init[3:6]).at[jnp.array(r.qpos[:3])].set(init[6:9])
        qpos = qpos.at[jnp.array(h.finger_qpos + r.finger_qpos)].set(mc.MAX_GAP / 2)
        yaw = init[2]
        obj = jnp.array([OBJ_START[0] + init[0], OBJ_START[1] + init[1], OBJ_HALF[2],
                         jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
        qpos = qpos.at[self.obj_qpos:self.obj_qpos + 7].set(obj).at[self.drawer_qpos].set(0.0)
        ctrl = jnp.zeros((m.nu,), jnp.float32)
        for g in (h, r):
            ctrl = ctrl.at[jnp.array(g.act + np.arange(6))].set(qpos[jnp.array(g.qpos)])
            ctrl = ctrl.at[g.act + 6].set(mc.MAX_GAP)
        d = mc.make_data(m, self.mx, qpos, ctrl, self._template)
        zero = jnp.zeros(())
        info = {"t": jnp.zeros((), jnp.int32), "failed": zero, "human_grasp": zero, "robot_grasp": zero,
                "human_handle": zero, "robot_handle": zero, "obj_last": zero, "handle_last": zero,
                "opening": zero}
        metrics = {"success": zero, "handover": zero, "opened_by": zero, "placed_by": zero,
                   "closed_by": zero, "max_open": zero}
        return State(d, self._obs(d, info), zero, zero, metrics, info)

    # ------------------------------------------------------------------ geometry
    def _obj_pos(self, d) -> jax.Array:
        return d.xpos[self.obj_body]

    def _obj_mat(self, d) -> jax.Array:
        return d.xmat[self.obj_body].reshape(3, 3)

    def _handle_pos(self, d) -> jax.Array:
        return d.geom_xpos[self.handle_geom]

    def _opening(self, d) -> jax.Array:
        """How far the drawer is pulled out (m, 0 = closed)."""
        return -d.qpos[self.drawer_qpos]

    def _inside(self, d) -> jax.Array:
        """Object centre inside the drawer's box (drawer frame: floor to wall top, between the walls)."""
        rel = self._obj_pos(d) - d.xpos[self.drawer_body]
        return (jnp.abs(rel[0]) < DR_DX) & (jnp.abs(rel[1]) < DR_DY) & (rel[2] > 0.0) & (rel[2] < WALL_H)

    @staticmethod
    def _any_touch(d, g: mc.Gripper, geom: str) -> jax.Array:
        a, b = g.sensors[geom]
        return (d.sensordata[a] > 0) | (d.sensordata[b] > 0)

    # ------------------------------------------------------------------ observation
    def _obs(self, d, info: dict) -> jax.Array:
        h, r = self.human, self.robot
        p, hp = self._obj_pos(d), self._handle_pos(d)
        rel = lambda q, g: jnp.asarray(g.base_mat.T) @ (q - mc.tcp_pos(d, g))
        return jnp.concatenate([
            mc.tcp_pose_base(d, h), mc.tcp_pose_base(d, r), rel(p, h), rel(p, r), mc.rot6d(self._obj_mat(d)),
            jnp.stack([mc.finger_gap(d, h), mc.finger_gap(d, r)]) / mc.MAX_GAP,
            rel(hp, h), rel(hp, r), (self._opening(d) / TRAVEL)[None],
            jnp.stack([info["human_grasp"], info["robot_grasp"], info["human_handle"], info["robot_handle"]]),
        ]).astype(jnp.float32)

    # ------------------------------------------------------------------ step
    def step(self, state: State, action: jax.Array) -> State:
        h, r = self.human, self.robot
        info = state.info
        a_h, a_r = self.split_action(jnp.asarray(action, jnp.float32))
        d = state.pipeline_state
        ctrl = mc.apply_gripper_action(d.ctrl, a_h, h)
        ctrl = mc.apply_gripper_action(ctrl, a_r, r)
        d, failed = mc.guarded_physics_step(self.mx, d, ctrl, self.n_substeps)

        h_grasp, r_grasp = mc.is_grasping(d, h, OBJ), mc.is_grasping(d, r, OBJ)
        h_touch, r_touch = self._any_touch(d, h, OBJ), self._any_touch(d, r, OBJ)
        h_handle, r_handle = mc.is_grasping(d, h, "handle"), mc.is_grasping(d, r, "handle")
        h_th, r_th = self._any_touch(d, h, "handle"), self._any_touch(d, r, "handle")
        opening, prev_open = self._opening(d), info["opening"]
        free = ~h_touch & ~r_touch
        inside = self._inside(d)
        speed = jnp.linalg.norm(d.qvel[self.obj_dof:self.obj_dof + 3])

        sole = lambda a, b: jnp.where(a & ~b, 1.0, jnp.where(b & ~a, 2.0, jnp.where(a & b, 3.0, 0.0)))
        g_sole = sole(h_grasp, r_grasp)
        obj_last = jnp.where((g_sole == 1) | (g_sole == 2), g_sole, info["obj_last"])
        t_sole = sole(h_th, r_th)
        handle_last = jnp.where(t_sole > 0, t_sole, info["handle_last"])

        m = dict(state.metrics)
        m["handover"] = jnp.maximum(m["handover"], (r_grasp & h_touch).astype(jnp.float32))
        m["opened_by"] = jnp.where((opening > OPEN_THRESH) & (prev_open <= OPEN_THRESH), handle_last, m["opened_by"])
        m["closed_by"] = jnp.where((opening < CLOSED_TOL) & (prev_open >= CLOSED_TOL), handle_last, m["closed_by"])
        m["placed_by"] = jnp.where(inside & free, obj_last, m["placed_by"])
        m["max_open"] = jnp.maximum(m["max_open"], opening)
        succ = (inside & free & (opening < CLOSED_TOL) & (speed < REST_SPEED)).astype(jnp.float32)
        m["success"] = jnp.maximum(m["success"], succ)
        t = info["t"] + 1
        done = ((m["success"] > 0) | (t >= self.max_episode_steps) | failed).astype(jnp.float32)
        f = lambda x: x.astype(jnp.float32)
        info = dict(info, t=t, failed=f(failed), human_grasp=f(h_grasp), robot_grasp=f(r_grasp),
                    human_handle=f(h_handle),
                    robot_handle=f(r_handle), obj_last=obj_last, handle_last=handle_last, opening=opening)
        return state.replace(pipeline_state=d, obs=self._obs(d, info), reward=succ, done=done,
                             metrics=m, info=info)

    # ------------------------------------------------------------------ strategies
    def classify_strategy(self, metrics: dict[str, jax.Array]) -> jax.Array:
        ok = metrics["success"] > 0
        s1 = (metrics["opened_by"] == 1) & (metrics["placed_by"] == 2)
        s2 = (metrics["opened_by"] == 2) & (metrics["placed_by"] == 1)
        return jnp.where(ok & s1, 1, jnp.where(ok & s2, 2, 0)).astype(jnp.int32)

    # ------------------------------------------------------------------ scripted team
    def team_init(self, rng: jax.Array, mix: jax.Array) -> tuple[TeamState, jax.Array]:
        ks = jax.random.split(rng, 20)
        u = lambda k, lo, hi, shape=(): jax.random.uniform(k, shape, minval=jnp.asarray(lo, jnp.float32),
                                                           maxval=jnp.asarray(hi, jnp.float32))
        strategy = (jax.random.categorical(ks[0], jnp.log(jnp.asarray(mix, jnp.float32) + 1e-12)) + 1).astype(jnp.int32)
        ts = TeamState(
            strategy=jnp.stack([strategy, strategy]),
            spot=u(ks[1], [-0.16, -0.07, 0.14], [0.0, 0.0, 0.26], (3,)),
            wait_pt=jnp.stack([u(ks[2], [-0.06, -0.21, 0.18], [0.04, -0.15, 0.25], (3,)),
                               u(ks[3], [0.04, 0.13, 0.24], [0.10, 0.17, 0.29], (3,))]),
            yaw=u(ks[4], -0.3, 0.3),
            drop=u(ks[5], [0.035, -0.03, 0.01, -0.1], [0.05, 0.03, 0.03, 0.1], (4,)),
            open_amt=u(ks[6], 0.125, 0.155),
            handle_y=jnp.stack([u(ks[7], -0.04, -0.005), u(ks[8], 0.005, 0.04)]),
            vmax=u(ks[9], 0.45, 0.85, (2,)),
            amax=u(ks[10], 0.06, 0.12, (2,)),
            gain=u(ks[11], 0.12, 0.22, (2,)),
            # robot: reaction delay once its cue holds (s1 the human carrying past CUE_Y, s2 the human at
            # its waiting point)
            delay=jax.random.randint(ks[12], (2,), jnp.array([2, 3]), jnp.array([15, 12])),
            react=jax.random.randint(ks[13], (2,), 2, 10),
            lift=u(ks[14], 0.04, 0.09),
            pause=jax.random.randint(ks[15], (), 0, 12),
            retreat=jnp.stack([jnp.array([0.0, -0.10, 0.08]) + u(ks[16], -0.03, 0.03, (3,)),
                               jnp.array([0.0, 0.10, 0.08]) + u(ks[17], -0.03, 0.03, (3,))]),
            noise=u(ks[18], 0.02, 0.08, (2,)),
            phase=jnp.zeros((2,), jnp.int32),
            timer=jnp.zeros((2,), jnp.int32),
            vel=jnp.zeros((2, 3)),
            anchor=jnp.zeros((2, 3)),
        )
        return ts, strategy

    def _world_ctrl(self, d, g: mc.Gripper) -> jax.Array:
        """The gripper's position target (world)."""
        return jnp.asarray(g.base_pos) + jnp.asarray(g.base_mat) @ d.ctrl[g.act:g.act + 3]

    @staticmethod
    def _select(ph, table: dict, default):
        keys = list(table)
        return jnp.select([ph == k for k in keys], [jnp.asarray(table[k]) for k in keys], default)

    def team_act(self, ts: TeamState, state: State, rng: jax.Array) -> tuple[TeamState, jax.Array]:
        d = state.pipeline_state
        h, r = self.human, self.robot
        p_obj, R_obj = self._obj_pos(d), self._obj_mat(d)
        obj_yaw = mc.wrap_angle(mc.yaw_of(R_obj), np.pi)  # the bar is symmetric under 180 deg
        handle = self._handle_pos(d)
        opening = self._opening(d)
        tcp = jnp.stack([mc.tcp_pos(d, h), mc.tcp_pos(d, r)])
        yaw = jnp.stack([d.ctrl[h.act + 5], d.ctrl[r.act + 5]])  # (robot: its own base frame)
        h_grasp, r_grasp = mc.is_grasping(d, h, OBJ), mc.is_grasping(d, r, OBJ)
        h_handle, r_handle = mc.is_grasping(d, h, "handle"), mc.is_grasping(d, r, "handle")
        h_touch, r_touch = self._any_touch(d, h, OBJ), self._any_touch(d, r, OBJ)
        gap_open = jnp.stack([mc.finger_gap(d, h), mc.finger_gap(d, r)]) > 0.036
        placed = self._inside(d) & ~h_touch & ~r_touch
        ph, pr = ts.phase[0], ts.phase[1]
        th, tr = ts.timer[0], ts.timer[1]
        s_h, s_r = ts.strategy[0] - 1, ts.strategy[1] - 1
        up = lambda z: jnp.array([0.0, 0.0, z])
        near = lambda i, tgt, tol: jnp.linalg.norm(tcp[i] - tgt) < tol
        yaw_ok = lambda i, tgt: jnp.abs(mc.wrap_angle(yaw[i] - tgt, np.pi)) < 0.05
        # drop point: object centre above the open drawer, TCP keeps its current offset to the object
        front_inner = d.xpos[self.drawer_body][0] - DR_DX
        drop_c = jnp.stack([front_inner + ts.drop[0], ts.drop[1], WALL_TOP + OBJ_HALF[2] + ts.drop[2]])
        drop_tcp = [drop_c + (tcp[i] - p_obj) for i in (0, 1)]
        handle_pt = [handle + jnp.array([0.0, ts.handle_y[i], 0.0]) for i in (0, 1)]
        pull = [ts.anchor[i] - jnp.array([ts.open_amt, 0.0, 0.0]) for i in (0, 1)]
        closed_x = handle[0] + opening + 0.008  # handle x of the closed drawer (+ a little push)
        push = [ts.anchor[i].at[0].set(closed_x) for i in (0, 1)]

        # ---------------- human
        g_h = p_obj + R_obj @ jnp.array([0.0, -GRASP_OFF, 0.0])
        g_h = g_h.at[2].set(jnp.maximum(g_h[2], 0.018))
        spot_h = ts.spot + _rotz(ts.yaw) @ jnp.array([0.0, -GRASP_OFF, 0.0])
        hold_h = ts.anchor[0]
        retreat_h = ts.anchor[0] + ts.retreat[0]
        target_h = self._select(ph, {
            H_WAIT: self._world_ctrl(d, h), H_REACH: g_h + up(0.07), H_DESCEND: g_h, H_CLOSE: hold_h,
            H_LIFT: ts.anchor[0] + up(ts.lift), H_CARRY: spot_h, H_OFFER: spot_h,
            H_BACKOFF: ts.anchor[0] + jnp.array([0.0, -0.06, 0.03]), H_TO_HANDLE: handle_pt[0] + up(0.07),
            H_DESC_HANDLE: handle_pt[0], H_GRIP_HANDLE: hold_h, H_PULL: pull[0], H_HOLD_OPEN: hold_h,
            H_PUSH: push[0], H_LET_GO: hold_h, H_CARRY_WAIT: ts.wait_pt[0], H_WAIT_OPEN: ts.wait_pt[0],
            H_ABOVE_DROP: drop_tcp[0] + up(0.06), H_LOWER: drop_tcp[0], H_RELEASE: hold_h}, retreat_h)
        yawt_h = self._select(ph, {
            H_REACH: obj_yaw, H_DESCEND: obj_yaw, H_CLOSE: obj_yaw, H_LIFT: ts.yaw, H_CARRY: ts.yaw,
            H_OFFER: ts.yaw, H_TO_HANDLE: 0.0, H_DESC_HANDLE: 0.0, H_GRIP_HANDLE: 0.0, H_PULL: 0.0,
            H_HOLD_OPEN: 0.0, H_PUSH: 0.0, H_CARRY_WAIT: ts.yaw, H_WAIT_OPEN: ts.yaw,
            H_ABOVE_DROP: ts.drop[3], H_LOWER: ts.drop[3]}, yaw[0])
        offer_release = (ph == H_OFFER) & (th >= ts.react[0])
        grip_h = jnp.where(((ph >= H_CLOSE) & (ph <= H_OFFER) & ~offer_release)
                           | ((ph >= H_GRIP_HANDLE) & (ph <= H_PUSH))
                           | ((ph >= H_CARRY_WAIT) & (ph <= H_LOWER)), -1.0, 1.0)
        gate_h = self._select(ph, {
            H_OFFER: r_grasp,
            H_HOLD_OPEN: placed & (pr == R_RETREAT),
            H_WAIT_OPEN: (opening >= DRAWER_OPEN_MIN) & (pr == R_HOLD_OPEN)}, True)
        adv_h = self._select(ph, {
            H_WAIT: th >= ts.delay[0],
            H_REACH: near(0, g_h + up(0.07), 0.012) & yaw_ok(0, obj_yaw),
            H_DESCEND: near(0, g_h, 0.006),
            H_CLOSE: h_grasp & (th >= 5),
            H_LIFT: near(0, ts.anchor[0] + up(ts.lift), 0.012) & (th >= ts.pause),
            H_CARRY: near(0, spot_h, 0.008) & yaw_ok(0, ts.yaw),
            H_OFFER: offer_release & gap_open[0],
            H_BACKOFF: near(0, ts.anchor[0] + jnp.array([0.0, -0.06, 0.03]), 0.02),
            H_TO_HANDLE: near(0, handle_pt[0] + up(0.07), 0.012) & yaw_ok(0, 0.0),
            H_DESC_HANDLE: near(0, handle_pt[0], 0.006),
            H_GRIP_HANDLE: h_handle & (th >= 4),
            H_PULL: near(0, pull[0], 0.01) | (opening >= ts.open_amt),
            H_HOLD_OPEN: th >= ts.react[0],
            H_PUSH: (opening < 0.004) & (th >= 5),
            H_LET_GO: gap_open[0] & (th >= 3),
            H_CARRY_WAIT: near(0, ts.wait_pt[0], 0.012) & yaw_ok(0, ts.yaw),
            H_WAIT_OPEN: th >= ts.react[0],
            H_ABOVE_DROP: near(0, drop_tcp[0] + up(0.06), 0.012) & yaw_ok(0, ts.drop[3]),
            H_LOWER: near(0, drop_tcp[0], 0.008),
            H_RELEASE: gap_open[0] & (th >= 3)}, False)
        carrying_h = ((ph >= H_LIFT) & (ph <= H_OFFER)) | ((ph >= H_CARRY_WAIT) & (ph <= H_LOWER))
        regrasp_h = ((ph == H_CLOSE) & (th > 25)) | (carrying_h & ~h_grasp & (p_obj[2] < 0.03))
        rehandle_h = (ph == H_GRIP_HANDLE) & (th > 25)
        new_ph = jnp.where(adv_h, jnp.asarray(NEXT_H)[s_h, ph], ph)
        new_ph = jnp.where(regrasp_h, H_REACH, jnp.where(rehandle_h, H_TO_HANDLE, new_ph))

        # ---------------- robot
        g_r = p_obj + R_obj @ jnp.array([0.0, GRASP_OFF, 0.0])
        hold_r = ts.anchor[1]
        retreat_r = ts.anchor[1] + ts.retreat[1]
        lift_r = ts.anchor[1] + jnp.array([0.0, 0.06, 0.06])
        target_r = self._select(pr, {
            R_WAIT: self._world_ctrl(d, r), R_APPROACH: g_r + up(0.07), R_DESCEND: g_r, R_CLOSE: hold_r,
            R_LIFT: lift_r, R_HOVER: ts.wait_pt[1], R_WAIT_OPEN: ts.wait_pt[1],
            R_ABOVE_DROP: drop_tcp[1] + up(0.06), R_LOWER: drop_tcp[1], R_RELEASE: hold_r,
            R_TO_HANDLE: handle_pt[1] + up(0.07), R_DESC_HANDLE: handle_pt[1], R_GRIP_HANDLE: hold_r,
            R_PULL: pull[1], R_HOLD_OPEN: hold_r, R_PUSH: push[1], R_LET_GO: hold_r}, retreat_r)
        yawt_r = self._select(pr, {
            R_APPROACH: obj_yaw, R_DESCEND: obj_yaw, R_CLOSE: obj_yaw, R_ABOVE_DROP: ts.drop[3],
            R_LOWER: ts.drop[3], R_TO_HANDLE: 0.0, R_DESC_HANDLE: 0.0, R_GRIP_HANDLE: 0.0, R_PULL: 0.0,
            R_HOLD_OPEN: 0.0, R_PUSH: 0.0}, jnp.nan)
        grip_r = jnp.where(((pr >= R_CLOSE) & (pr <= R_LOWER)) | ((pr >= R_GRIP_HANDLE) & (pr <= R_PUSH)), -1.0, 1.0)
        gate_r = self._select(pr, {
            # the robot reacts to what it can see (so a policy reading the state can tell the strategies
            # apart when the robot has to act): s1, the human carrying the bar has come past the middle
            # towards it; s2, the human holds the bar still at its waiting point by the drawer
            R_WAIT: jnp.where(s_r == 0, (ph >= H_CARRY) & (ph <= H_OFFER) & (tcp[0, 1] > CUE_Y),
                              (ph == H_WAIT_OPEN) | ((ph == H_CARRY_WAIT) & near(0, ts.wait_pt[0], 0.03))),
            R_WAIT_OPEN: (opening >= DRAWER_OPEN_MIN) & (ph == H_HOLD_OPEN),
            R_HOLD_OPEN: placed & (ph == H_RETREAT)}, True)
        adv_r = self._select(pr, {
            R_WAIT: tr >= ts.delay[1],
            R_APPROACH: (ph == H_OFFER) & near(1, g_r + up(0.07), 0.012) & yaw_ok(1, obj_yaw),
            R_DESCEND: near(1, g_r, 0.006),
            R_CLOSE: r_grasp & (ph >= H_BACKOFF) & ~h_touch & (tr >= 4),
            R_LIFT: near(1, lift_r, 0.015),
            R_HOVER: near(1, ts.wait_pt[1], 0.012),
            R_WAIT_OPEN: tr >= ts.react[1],
            R_ABOVE_DROP: near(1, drop_tcp[1] + up(0.06), 0.012) & yaw_ok(1, ts.drop[3]),
            R_LOWER: near(1, drop_tcp[1], 0.008),
            R_RELEASE: gap_open[1] & (tr >= 3),
            R_TO_HANDLE: near(1, handle_pt[1] + up(0.07), 0.012) & yaw_ok(1, 0.0),
            R_DESC_HANDLE: near(1, handle_pt[1], 0.006),
            R_GRIP_HANDLE: r_handle & (tr >= 4),
            R_PULL: near(1, pull[1], 0.01) | (opening >= ts.open_amt),
            R_HOLD_OPEN: tr >= ts.react[1],
            R_PUSH: (opening < 0.004) & (tr >= 5),
            R_LET_GO: gap_open[1] & (tr >= 3)}, False)
        regrasp_r = (pr == R_CLOSE) & (tr > 40) & ~r_grasp
        rehandle_r = (pr == R_GRIP_HANDLE) & (tr > 25)
        new_pr = jnp.where(adv_r, jnp.asarray(NEXT_R)[s_r, pr], pr)
        new_pr = jnp.where(regrasp_r, R_APPROACH, jnp.where(rehandle_r, R_TO_HANDLE, new_pr))

        # ---------------- actions
        k1, _ = jax.random.split(rng)
        vel_h = _move(self._world_ctrl(d, h), target_h, ts.vel[0], ts.vmax[0], ts.amax[0], ts.gain[0])
        vel_r = _move(self._world_ctrl(d, r), target_r, ts.vel[1], ts.vmax[1], ts.amax[1], ts.gain[1])
        vel_h = jnp.where(ph == H_WAIT, 0.0, vel_h)
        vel_r = jnp.where(pr == R_WAIT, 0.0, vel_r)
        noise = jax.random.normal(k1, (2, 6)) * ts.noise[:, None] * jnp.array([1.0, 1, 1, 0.3, 0.3, 0.3])
        yawt_r = jnp.where(jnp.isnan(yawt_r), yaw[1], mc.wrap_angle(yawt_r, np.pi))
        a_h = jnp.concatenate([jnp.asarray(h.base_mat.T) @ vel_h, self._rot_action(d, h, yawt_h)]) + noise[0]
        a_r = jnp.concatenate([jnp.asarray(r.base_mat.T) @ vel_r, self._rot_action(d, r, yawt_r)]) + noise[1]
        action = jnp.clip(jnp.concatenate([a_h, grip_h[None], a_r, grip_r[None]]), -1.0, 1.0)

        new_phase = jnp.stack([new_ph, new_pr]).astype(jnp.int32)
        changed = new_phase != ts.phase
        counted = jnp.where(jnp.stack([gate_h, gate_r]), ts.timer + 1, 0)
        timer = jnp.where(changed, 0, counted).astype(jnp.int32)
        anchor = jnp.where(changed[:, None], tcp, ts.anchor)
        ts = ts._replace(phase=new_phase, timer=timer, vel=jnp.stack([vel_h, vel_r]), anchor=anchor)
        return ts, action

    @staticmethod
    def _rot_action(d, g: mc.Gripper, yaw_target, gain=0.25, vmax=0.9):
        cur = d.ctrl[g.act + 3:g.act + 6]
        tgt = jnp.stack([0.0, 0.0, yaw_target])
        return jnp.clip(gain * (tgt - cur) / mc.ROT_SCALE, -vmax, vmax)

    # ------------------------------------------------------------------ rendering
    def render(self, state: State, width: int = 320, height: int = 240, camera: str = "drawer") -> np.ndarray:
        """RGB frame (height, width, 3) uint8 of one unbatched state (cameras: drawer, front, side, top)."""
        from mujoco import mjx

        if self._renderer is None:
            self._renderer = mc.FrameRenderer(self.mj_model)
        d = mjx.get_data(self.mj_model, jax.device_get(state.pipeline_state))
        return self._renderer(d, width, height, camera)


if __name__ == "__main__":  # print the scene, e.g. to open it in MuJoCo's viewer
    print(seqmanip_xml())
