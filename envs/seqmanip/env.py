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

Observation (77): human TCP pose in the human base frame (3 + 6D rotation), robot TCP pose in the robot
base frame (3 + 6), object position relative to each TCP (each in that agent's base frame, 3 + 3),
object orientation (6D, world), finger gaps / 8 cm (2), handle position relative to each TCP (each in
that agent's base frame, 3 + 3), drawer opening / 16 cm (1), flags: human grasps the object, robot
grasps the object, human grasps the handle, robot grasps the handle (4); then the object-centric features of
the human and of the robot (17 each, :func:`mjx_common.object_frame_features`: the bar's ends in the agent's
base frame relative to its TCP, the TCP's yaw relative to the bar, the TCP in the bar's frame, the bar's
orientation in the TCP's frame), the observation
indices :attr:`SeqManip.object_frame_dims` (a config's ``obs_frame`` chooses whether
they or the absolute orientations are read).

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

Scripted human-human team (:mod:`cogail_envs.seqmanip.team`,
pure JAX, vmappable): 1. human-hands-over: the human carries the bar out to a
handover spot, the robot takes it, the human opens the drawer, the robot drops the bar in, the human closes
it; 2. robot-opens: the human carries the bar to a waiting point by the drawer, the robot opens the drawer,
the human drops the bar in, the robot closes it. The robot's cues are things it can see in the state (where
the human's hand is, whether it has stopped). Details, and the variations of the human, in that module.

Measured (CPU, ``cogail_jax.demos.generate``, uniform mix, seeds 100-103, 4 x 256 episodes): 1024 of 1024
scripted episodes succeed and all are classified as their intended strategy; length 456.1 +- 35.7 steps
(370-548) for human-hands-over, 369.5 +- 28.3 (306-454) for robot-opens, 411.9 overall (paper: 404).
``python -m cogail_envs.seqmanip`` prints the MJCF.

Rendering uses :class:`mjx_common.FrameRenderer` (default camera ``drawer``: the drawer front seen from
the human's left).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import mjx_common as mc
from ..base import CollabEnv, State

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


# init vector: obj dx, obj dy, obj yaw, human start (3, base frame), robot start (3, base frame), robot start yaw.
# The robot's start: within 3 cm of its home pose, not turned; the constructor's ``robot_start_yaw`` /
# ``robot_start_z`` widen its yaw and height (the task's training split is made so: ``TASK.train_env``).
INIT_LO = np.array([-0.05, -0.015, -0.15, -0.03, -0.03, -0.03, -0.03, -0.03, -0.03, 0.0], np.float32)
INIT_HI = -INIT_LO

OPEN_THRESH = 0.08      # opening (m) that counts as "the drawer was opened"
CLOSED_TOL = 0.01       # opening (m) below which the drawer counts as closed
REST_SPEED = 0.05       # object speed (m/s) below which it "rests"
DRAWER_OPEN_MIN = 0.10  # opening the scripted droppers wait for
CUE_Y = -0.13           # s1: the scripted robot starts once the human's TCP is past this y (spot side)
HANDOVER_X_MAX = 0.075  # the patient human's handovers: object x below this (handover spots x <= 0.02; the drop into
                        # the open drawer is at x >= 0.085)
WALL_TOP = FLOOR_Z + WALL_H


def _f(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def _box(half, pos, rgba: str, name: str = "") -> str:
    nm = f'name="{name}" ' if name else ""
    return f'<geom {nm}type="box" size="{_f(half)}" pos="{_f(pos)}" rgba="{rgba}"/>'


def seqmanip_xml() -> str:
    """The HR-SeqManip MJCF (two grippers, the table, the cabinet with its drawer, the bar), with
    :mod:`mjx_common`'s solver settings."""
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
    contact = (mc.gripper_pairs_xml(HUMAN, OBJ) + mc.gripper_pairs_xml(ROBOT, OBJ)
               + mc.gripper_pairs_xml(HUMAN, "handle", palm=False)
               + mc.gripper_pairs_xml(ROBOT, "handle", palm=False)
               + mc.pair_xml(OBJ, "table", 0.8) + mc.pair_xml(OBJ, "drawer_floor", 0.8)
               # walls and the cabinet top only need to stop the object: frictionless (condim 1, fewer rows)
               + "".join(mc.pair_xml(OBJ, g, 0.0, condim=1) for g in DRAWER_GEOMS[1:] + ("cab_top",)))
    sensor = "".join(mc.gripper_sensors_xml(g, geom) for g in (HUMAN, ROBOT) for geom in (OBJ, "handle"))
    cam = mc.camera_xml("drawer", (-0.45, -0.60, 0.50), (0.05, -0.03, 0.10))  # the task's default view
    world = cam + drawer + "".join(cab) + obj
    return mc.scene_xml("seqmanip", [HUMAN, ROBOT], worldbody=world, contact=contact, sensor=sensor)


class SeqManip(CollabEnv):
    """HR-SeqManip with brax's ``Env`` API (``pipeline_state`` is ``mjx.Data``).

    Physics: :mod:`mjx_common`'s Newton solver settings, substeps, timestep and finger-pad contacts (object and
    handle): ``ITERATIONS`` / ``LS_ITERATIONS`` / ``N_SUBSTEPS`` / ``TIMESTEP`` / ``FINGER_CONDIM`` (2 / 4 / 2 /
    0.01 s / 3).
    """

    name = "seqmanip"
    human_action_size = 7
    robot_action_size = 7
    max_episode_steps = 600
    init_size = 10
    strategy_names = ("human-hands-over", "robot-opens")

    def __init__(self, max_episode_steps: int = 600, robot_start_yaw: float = 0.0, robot_start_z: float = 0.03,
                 drop_yaw_bound: float | None = None):
        import mujoco
        from mujoco import mjx

        self.max_episode_steps = int(max_episode_steps)
        self.init_lo = INIT_LO.copy()
        self.init_lo[8], self.init_lo[9] = -float(robot_start_z), -float(robot_start_yaw)
        if (float(robot_start_yaw), float(robot_start_z)) != (0.0, 0.03):  # another start: another dataset version
            self.spec_tag = f"{type(self).spec_tag}-robot-start-{float(robot_start_yaw):g}-{float(robot_start_z):g}"
        # the scripted droppers' yaw bound (rad, about the vertical): None, what the drawer takes (``team.DROP_FITS``);
        # less makes the team turn every bar back further before it drops it (e.g. in a training split)
        self.drop_yaw_bound = None if drop_yaw_bound is None else float(drop_yaw_bound)
        if self.drop_yaw_bound is not None:
            self.spec_tag = f"{self.spec_tag}-drop-yaw-bound-{self.drop_yaw_bound:g}"
        self.n_substeps, self.timestep = mc.N_SUBSTEPS, mc.TIMESTEP
        self.xml = seqmanip_xml()
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
        self._template = mc.template_data(self.mx)
        self._renderer = None

    # the observation layout and the team's pose ranges (part of the version fingerprint of generated data)
    spec_tag = "obs77-object-frame-rot-poses6dof-prompt-start10-drop-fits-04-early-0.04"
    object_frame_dims = tuple(range(43, 77))
    orientation_dims = (*range(3, 9), *range(12, 18), *range(24, 30))  # the TCPs' and the bar's 6D rotations

    @property
    def observation_size(self) -> int:
        return 77

    @property
    def dt(self) -> float:
        return self.timestep * self.n_substeps

    # ------------------------------------------------------------------ reset
    def sample_init(self, rng: jax.Array) -> jax.Array:
        return jax.random.uniform(rng, (self.init_size,), minval=self.init_lo, maxval=-self.init_lo)

    def reset_from(self, init: jax.Array) -> State:
        init = jnp.asarray(init, jnp.float32)
        m = self.mj_model
        qpos = jnp.asarray(m.qpos0, jnp.float32)
        h, r = self.human, self.robot
        qpos = qpos.at[jnp.array(h.qpos[:3])].set(init[3:6]).at[jnp.array(r.qpos[:3])].set(init[6:9])
        qpos = qpos.at[r.qpos[5]].set(init[9])
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
        info = {"t": jnp.zeros((), jnp.int32), "truncation": zero, "failed": zero, "human_grasp": zero,
                "robot_grasp": zero, "human_handle": zero, "robot_handle": zero, "obj_last": zero,
                "handle_last": zero, "opening": zero}
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
        p, hp, R = self._obj_pos(d), self._handle_pos(d), self._obj_mat(d)
        rel = lambda q, g: jnp.asarray(g.base_mat.T) @ (q - mc.tcp_pos(d, g))
        return jnp.concatenate([
            mc.tcp_pose_base(d, h), mc.tcp_pose_base(d, r), rel(p, h), rel(p, r), mc.rot6d(R),
            jnp.stack([mc.finger_gap(d, h), mc.finger_gap(d, r)]) / mc.MAX_GAP,
            rel(hp, h), rel(hp, r), (self._opening(d) / TRAVEL)[None],
            jnp.stack([info["human_grasp"], info["robot_grasp"], info["human_handle"], info["robot_handle"]]),
            mc.object_frame_features(d, h, p, R, OBJ_HALF[1]), mc.object_frame_features(d, r, p, R, OBJ_HALF[1]),
        ]).astype(jnp.float32)

    def replay_hold(self, state: State, a_h: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The patient human, at a handover only: while it holds the object out (not over the drawer) and the
        robot does not hold it, it does not open its gripper -- the recorded human opens when its own partner had
        taken it -- but holds still, gripper closed. (It does not wait for the drawer: a recorded drop goes ahead
        whether the drawer is open or not.)"""
        info = state.info
        out = self._obj_pos(state.pipeline_state)[0] < HANDOVER_X_MAX
        wait = (a_h[6] > -0.5) & (info["human_grasp"] > 0) & (info["robot_grasp"] == 0) & out
        return wait, jnp.zeros_like(a_h).at[6].set(-1.0)

    # ------------------------------------------------------------------ step
    def checkpoint_state(self, state: State) -> State:
        return state.replace(pipeline_state=mc.without_recomputed(state.pipeline_state))

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
        done, truncation = self.time_limit(t, (m["success"] > 0) | failed)
        f = lambda x: x.astype(jnp.float32)
        info = dict(info, t=t, truncation=truncation, failed=f(failed), human_grasp=f(h_grasp), robot_grasp=f(r_grasp),
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

    def human_position(self, state: State) -> jax.Array:
        """The human's TCP in the world frame (metres)."""
        return mc.tcp_pos(state.pipeline_state, self.human)

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
