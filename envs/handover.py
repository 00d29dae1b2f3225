"""HR-Handover in MuJoCo MJX: a "human" gripper fetches a bar and hands it to a "robot" gripper.

Scene (world frame, z up, table top z = 0; see :mod:`mjx_common` for the gripper model)::

          robot base (0, +0.40, 0.25), faces -y
                 |
      left (-x)  |  right (+x)        <- seen from the human
     ------------+------------  handover band: object centre y in [-0.06, 0.05], z in [0.12, 0.32]
                 |
           [=====bar=====]         bar 3 x 20 x 3 cm, 80 g, lying along y at (x0, -0.21, 0.015)
                 |
          human base (0, -0.40, 0.25), faces +y

The human grasps the bar 4.5 cm from its centre on its own side, the robot 4.5 cm from the centre on the
other side (TCPs 9 cm apart while both hold it). The robot's workspace (joint limits) stops at y = -0.05,
so it can never reach the bar where it lies: the bar must be handed over.

Action (14): ``concat(a_H, a_R)``, each ``(dx, dy, dz, drx, dry, drz, g)`` in [-1, 1]: 1 cm / 1 degree
per unit per step in the agent's base frame (the paper's scale; a scripted demo lasts ~211 steps) and
the absolute gripper command (-1 closed, +1 open). See :mod:`mjx_common` for details.

Observation (35): human TCP pose in the human base frame (3 + 6D rotation), robot TCP pose in the robot
base frame (3 + 6), bar position relative to each TCP (each in that agent's base frame, 3 + 3), bar
orientation (6D, world), finger gaps / 8 cm (2), flags: human grasps, robot grasps, human released (3).

Rules:
* ``grasp`` (per agent): both finger pads touch the bar (contact sensors) and the gripper is commanded
  closed (:func:`mjx_common.is_grasping`). Nobody holding the bar => it falls (plain physics).
* Auto-release (paper appendix: "after the robot holds the object, the gripper of the human agent will
  automatically open"): once the robot has grasped the lifted bar for ``RELEASE_AFTER`` consecutive
  steps, the human's gripper command is overridden to "open" for the rest of the episode
  (``auto_release=True`` by default; flag ``released`` in the observation).
* ``success``: the robot grasps the bar, the human's fingers no longer touch it, the bar is off the
  table (z > 5 cm) and the two TCPs are more than 10 cm apart (paper: robot holds the object and the end
  effectors are > 10 cm apart). Sticky metric; ``done`` on success or at ``max_episode_steps``.
* Strategy event: ``handover_x/y/z`` = bar centre (world) at the first step where the robot grasps the
  lifted bar (z > 5 cm; out of the robot's reach unless the human holds it up), ``handover`` = 1 once
  recorded. :meth:`classify_strategy`:
  1 (left) if x < -``X_SPLIT``, 3 (right) if x > ``X_SPLIT``, else 2 (middle); 0 unless the episode
  succeeded through a handover.

The scripted human-human team (:meth:`Handover.team_init` / :meth:`Handover.team_act`) draws the region
from ``mix`` and then a continuous spot inside it (regions are separated by 5 cm gaps around the
classification thresholds so every demo is labelled by its drawn region), a carry yaw, speeds,
reaction delays, pauses and action noise; motions are proportional control with velocity and
acceleration limits (smooth, minimum-jerk-like bell-shaped speed profiles).

Rendering uses ``mujoco.Renderer`` (EGL offscreen works on headless CPU machines; if ``MUJOCO_GL`` was
not set before ``mujoco`` was imported, an EGL context is created by hand); if no OpenGL is available it
falls back to a matplotlib top + side projection of the geoms.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from . import mjx_common as mc
from .base import CollabEnv, State

OBJ = "object"
OBJ_HALF = (0.015, 0.10, 0.015)
OBJ_MASS = 0.08
GRASP_OFF = 0.045          # grasp points along the bar's local y (human -, robot +)
OBJ_START = (0.0, -0.21)   # nominal bar centre (x, y) on the table
HUMAN_BASE = (0.0, -0.40, 0.25)
ROBOT_BASE = (0.0, 0.40, 0.25)
X_SPLIT = 0.095            # |x| threshold between middle and left/right handovers
REGIONS_X = np.array([[-0.28, -0.12], [-0.07, 0.07], [0.12, 0.28]], np.float32)  # left, middle, right
SPOT_Y = (-0.06, 0.05)
SPOT_Z = (0.12, 0.32)
RELEASE_AFTER = 3          # robot-grasp steps before the human's gripper auto-opens
SUCCESS_DIST = 0.10
LIFTED_Z = 0.05
# init vector: obj dx, obj dy, obj yaw, human start (3, base frame), robot start (3, base frame)
INIT_LO = np.array([-0.05, -0.015, -0.15, -0.03, -0.03, -0.03, -0.03, -0.03, -0.03], np.float32)
INIT_HI = -INIT_LO

HUMAN = mc.GripperSpec("human", HUMAN_BASE, 0.0, (-0.35, -0.05, -0.234, -0.6, -0.6, -1.6),
                       (0.35, 0.50, 0.20, 0.6, 0.6, 1.6), rgba=(0.25, 0.55, 0.9, 1.0))
ROBOT = mc.GripperSpec("robot", ROBOT_BASE, 180.0, (-0.35, -0.05, -0.234, -0.6, -0.6, -1.6),
                       (0.35, 0.45, 0.20, 0.6, 0.6, 1.6), rgba=(0.9, 0.35, 0.3, 1.0))


def handover_xml(iterations: int = mc.ITERATIONS, ls_iterations: int = mc.LS_ITERATIONS,
                 finger_condim: int = mc.FINGER_CONDIM, timestep: float = mc.TIMESTEP) -> str:
    """The HR-Handover MJCF (two grippers, a table and the bar)."""
    obj = mc.free_box_xml(OBJ, (*OBJ_START, OBJ_HALF[2]), OBJ_HALF, OBJ_MASS, rgba=(0.95, 0.75, 0.1, 1.0))
    contact = (mc.gripper_pairs_xml(HUMAN, OBJ, finger_condim=finger_condim)
               + mc.gripper_pairs_xml(ROBOT, OBJ, finger_condim=finger_condim)
               + mc.pair_xml(OBJ, "table", 0.8))
    sensor = mc.gripper_sensors_xml(HUMAN, OBJ) + mc.gripper_sensors_xml(ROBOT, OBJ)
    return mc.scene_xml("handover", [HUMAN, ROBOT], worldbody=obj, contact=contact, sensor=sensor,
                        iterations=iterations, ls_iterations=ls_iterations, timestep=timestep)


def _rotz(yaw: jax.Array) -> jax.Array:
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.array([[c, -s, z], [s, c, z], [z, z, o]])


class TeamState(NamedTuple):
    """Scripted human-human team (per episode; index 0 human, 1 robot where paired)."""

    strategy: jax.Array   # (2,) int32 region 1..3 (same for both; the robot itself is reactive)
    spot: jax.Array       # (3,) bar-centre target of the handover (world)
    yaw: jax.Array        # () carry yaw of the human (rad)
    vmax: jax.Array       # (2,) speed limits (action units)
    amax: jax.Array       # (2,) acceleration limits (action units / step)
    gain: jax.Array       # (2,) proportional gains
    delay: jax.Array      # (2,) int32 start reaction delays
    lift: jax.Array       # () lift height after grasping (m)
    pause: jax.Array      # () int32 pause after lifting
    release: jax.Array    # () int32 human reaction to the robot's grasp (own release)
    retreat: jax.Array    # (2, 3) retreat offsets (world)
    noise: jax.Array      # (2,) action noise std
    phase: jax.Array      # (2,) int32
    timer: jax.Array      # (2,) int32 steps spent in the current phase
    vel: jax.Array        # (2, 3) previous translational command (world, action units)
    anchor: jax.Array     # (2, 3) phase anchor point (world)


# human phases
H_WAIT, H_REACH, H_DESCEND, H_CLOSE, H_LIFT, H_CARRY, H_HOLD, H_RETREAT = range(8)
# robot phases
R_WAIT, R_STAGE, R_OVER, R_DESCEND, R_CLOSE, R_RETREAT = range(6)


class Handover(mc.MjxSnapshots, CollabEnv):
    """HR-Handover with brax's ``Env`` API (``pipeline_state`` is ``mjx.Data``).

    ``iterations`` / ``ls_iterations``: Newton solver settings; ``n_substeps``: physics steps per env step;
    ``timestep``: physics timestep (s); ``finger_condim``: 3 (sliding friction only) or 4 (plus torsional
    friction) for the finger-pad pairs. Defaults: :data:`mjx_common.ITERATIONS` / ``LS_ITERATIONS`` /
    ``N_SUBSTEPS`` / ``TIMESTEP`` / ``FINGER_CONDIM`` (2 / 4 / 2 / 0.01 s / 3; the settings before were
    4 / 8 / 4 / 0.005 s / 4, ~2.5-3x more expensive on CPU with the same scripted-team results).
    """

    name = "handover"
    human_action_size = 7
    robot_action_size = 7
    max_episode_steps = 300
    init_size = 9
    strategy_names = ("left", "middle", "right")
    discriminator_loss = "lsgan"

    def __init__(self, max_episode_steps: int = 300, auto_release: bool = True,
                 iterations: int = mc.ITERATIONS, ls_iterations: int = mc.LS_ITERATIONS,
                 n_substeps: int = mc.N_SUBSTEPS, finger_condim: int = mc.FINGER_CONDIM,
                 timestep: float = mc.TIMESTEP):
        self.max_episode_steps = int(max_episode_steps)
        self.auto_release = bool(auto_release)
        self.n_substeps = int(n_substeps)
        self.timestep = float(timestep)
        self.xml = handover_xml(iterations, ls_iterations, finger_condim, self.timestep)
        self.mj_model, self.mx = mc.build(self.xml)
        m = self.mj_model
        self.human = mc.Gripper.from_model(m, "human", [OBJ])
        self.robot = mc.Gripper.from_model(m, "robot", [OBJ])
        self.obj_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, OBJ)
        self.obj_qpos = int(m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, OBJ)])
        self._template = mc.mjx.make_data(self.mx)
        self._frames = mc.FrameRenderer(self.mj_model)

    @property
    def observation_size(self) -> int:
        return 35

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
        open_q = mc.MAX_GAP / 2
        qpos = qpos.at[jnp.array(h.qpos[:3])].set(init[3:6]).at[jnp.array(r.qpos[:3])].set(init[6:9])
        qpos = qpos.at[jnp.array(h.finger_qpos + r.finger_qpos)].set(open_q)
        yaw = init[2]
        obj = jnp.array([OBJ_START[0] + init[0], OBJ_START[1] + init[1], OBJ_HALF[2],
                         jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
        qpos = qpos.at[self.obj_qpos:self.obj_qpos + 7].set(obj)
        ctrl = jnp.zeros((m.nu,), jnp.float32)
        for g in (h, r):
            ctrl = ctrl.at[jnp.array(g.act + np.arange(6))].set(qpos[jnp.array(g.qpos)])
            ctrl = ctrl.at[g.act + 6].set(mc.MAX_GAP)
        d = mc.make_data(m, self.mx, qpos, ctrl, self._template)
        zero = jnp.zeros(())
        info = {"t": jnp.zeros((), jnp.int32), "failed": zero, "released": zero,
                "hold": jnp.zeros((), jnp.int32), "human_grasp": zero, "robot_grasp": zero}
        metrics = {"success": zero, "handover": zero, "handover_x": zero, "handover_y": zero,
                   "handover_z": zero}
        return State(d, self._obs(d, info), zero, zero, metrics, info)

    # ------------------------------------------------------------------ observation
    def _obj_pos(self, d) -> jax.Array:
        return d.xpos[self.obj_body]

    def _obj_mat(self, d) -> jax.Array:
        return d.xmat[self.obj_body].reshape(3, 3)

    def _obs(self, d, info: dict) -> jax.Array:
        h, r = self.human, self.robot
        p = self._obj_pos(d)
        rel = [jnp.asarray(g.base_mat.T) @ (p - mc.tcp_pos(d, g)) for g in (h, r)]
        return jnp.concatenate([
            mc.tcp_pose_base(d, h), mc.tcp_pose_base(d, r), rel[0], rel[1], mc.rot6d(self._obj_mat(d)),
            jnp.stack([mc.finger_gap(d, h), mc.finger_gap(d, r)]) / mc.MAX_GAP,
            jnp.stack([info["human_grasp"], info["robot_grasp"], info["released"]]),
        ]).astype(jnp.float32)

    # ------------------------------------------------------------------ step
    def step(self, state: State, action: jax.Array) -> State:
        h, r = self.human, self.robot
        info = state.info
        a_h, a_r = self.split_action(jnp.asarray(action, jnp.float32))
        if self.auto_release:
            a_h = a_h.at[6].set(jnp.where(info["released"] > 0, 1.0, a_h[6]))
        d = state.pipeline_state
        ctrl = mc.apply_gripper_action(d.ctrl, a_h, h)
        ctrl = mc.apply_gripper_action(ctrl, a_r, r)
        d, failed = mc.guarded_physics_step(self.mx, d, ctrl, self.n_substeps)

        p = self._obj_pos(d)
        h_touch = mc.touching(d, h, OBJ)
        h_grasp = mc.is_grasping(d, h, OBJ)
        r_grasp = mc.is_grasping(d, r, OBJ)
        lifted = p[2] > LIFTED_Z
        hold = jnp.where(r_grasp & lifted, info["hold"] + 1, 0)
        released = jnp.where(hold >= RELEASE_AFTER, 1.0, info["released"]) if self.auto_release else info["released"]

        m = dict(state.metrics)
        first = r_grasp & lifted & (m["handover"] == 0)
        m["handover"] = jnp.where(first, 1.0, m["handover"])
        for i, k in enumerate(("handover_x", "handover_y", "handover_z")):
            m[k] = jnp.where(first, p[i], m[k])
        dist = jnp.linalg.norm(mc.tcp_pos(d, h) - mc.tcp_pos(d, r))
        succ = (r_grasp & ~h_touch & lifted & (dist > SUCCESS_DIST)).astype(jnp.float32)
        m["success"] = jnp.maximum(m["success"], succ)
        t = info["t"] + 1
        done = ((m["success"] > 0) | (t >= self.max_episode_steps) | failed).astype(jnp.float32)
        info = dict(info, t=t, failed=failed.astype(jnp.float32), released=released,
                    hold=hold.astype(jnp.int32), human_grasp=h_grasp.astype(jnp.float32), robot_grasp=r_grasp.astype(jnp.float32))
        return state.replace(pipeline_state=d, obs=self._obs(d, info), reward=succ, done=done,
                             metrics=m, info=info)

    # ------------------------------------------------------------------ strategies
    def classify_strategy(self, metrics: dict[str, jax.Array]) -> jax.Array:
        x = metrics["handover_x"]
        sid = jnp.where(x < -X_SPLIT, 1, jnp.where(x > X_SPLIT, 3, 2))
        ok = (metrics["success"] > 0) & (metrics["handover"] > 0)
        return jnp.where(ok, sid, 0).astype(jnp.int32)

    # ------------------------------------------------------------------ scripted team
    def team_init(self, rng: jax.Array, mix: jax.Array) -> tuple[TeamState, jax.Array]:
        ks = jax.random.split(rng, 14)
        u = lambda k, lo, hi, shape=(): jax.random.uniform(k, shape, minval=lo, maxval=hi)
        strategy = jax.random.categorical(ks[0], jnp.log(jnp.asarray(mix, jnp.float32) + 1e-12)).astype(jnp.int32) + 1
        lo, hi = jnp.asarray(REGIONS_X)[strategy - 1]
        spot = jnp.stack([u(ks[1], lo, hi), u(ks[2], *SPOT_Y), u(ks[3], *SPOT_Z)])
        ts = TeamState(
            strategy=jnp.stack([strategy, strategy]),
            spot=spot,
            yaw=u(ks[4], -0.35, 0.35),
            vmax=u(ks[5], 0.5, 0.9, (2,)),
            amax=u(ks[6], 0.06, 0.12, (2,)),
            gain=u(ks[7], 0.12, 0.22, (2,)),
            delay=jax.random.randint(ks[8], (2,), jnp.array([2, 4]), jnp.array([15, 25])),
            lift=u(ks[9], 0.04, 0.09),
            pause=jax.random.randint(ks[10], (), 0, 12),
            release=jax.random.randint(ks[11], (), 2, 7),
            retreat=jnp.stack([
                jnp.array([0.0, -0.12, 0.03]) + u(ks[12], -0.03, 0.03, (3,)),
                jnp.array([0.0, 0.13, 0.03]) + u(ks[13], -0.03, 0.03, (3,)),
            ]),
            noise=u(jax.random.fold_in(rng, 99), 0.02, 0.08, (2,)),
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
    def _move(p_cmd, target, vel, vmax, amax, gain):
        """Velocity-limited, acceleration-limited proportional step (world frame, action units)."""
        v_des = gain * (target - p_cmd) / mc.POS_SCALE
        n = jnp.linalg.norm(v_des)
        v_des = v_des * jnp.minimum(1.0, vmax / (n + 1e-9))
        dv = v_des - vel
        dn = jnp.linalg.norm(dv)
        return vel + dv * jnp.minimum(1.0, amax / (dn + 1e-9))

    def _rot_action(self, d, g: mc.Gripper, yaw_target, gain=0.25, vmax=0.9):
        cur = d.ctrl[g.act + 3:g.act + 6]
        tgt = jnp.stack([0.0, 0.0, yaw_target])
        return jnp.clip(gain * (tgt - cur) / mc.ROT_SCALE, -vmax, vmax)

    def team_act(self, ts: TeamState, state: State, rng: jax.Array) -> tuple[TeamState, jax.Array]:
        d = state.pipeline_state
        info = state.info
        h, r = self.human, self.robot
        p_obj = self._obj_pos(d)
        R_obj = self._obj_mat(d)
        obj_yaw = mc.wrap_angle(mc.yaw_of(R_obj), np.pi)  # bar is symmetric under 180 deg
        grasp_h = p_obj + R_obj @ jnp.array([0.0, -GRASP_OFF, 0.0])
        grasp_r = p_obj + R_obj @ jnp.array([0.0, GRASP_OFF, 0.0])
        grasp_h = grasp_h.at[2].set(jnp.maximum(grasp_h[2], 0.018))
        tcp_h, tcp_r = mc.tcp_pos(d, h), mc.tcp_pos(d, r)
        yaw_h = d.ctrl[h.act + 5]
        yaw_r = d.ctrl[r.act + 5]
        h_grasp = mc.is_grasping(d, h, OBJ)
        r_grasp = mc.is_grasping(d, r, OBJ)
        h_open = mc.finger_gap(d, h) > 0.036
        released = info["released"] > 0
        near = lambda a, b, tol: jnp.linalg.norm(a - b) < tol

        # ---------------- human
        ph, th = ts.phase[0], ts.timer[0]
        above_h = grasp_h + jnp.array([0.0, 0.0, 0.07])
        carry_h = ts.spot + _rotz(ts.yaw) @ jnp.array([0.0, -GRASP_OFF, 0.0])
        lift_h = ts.anchor[0] + jnp.array([0.0, 0.0, ts.lift])
        retreat_h = ts.anchor[0] + ts.retreat[0]
        hold_pos = ts.anchor[0]
        target_h = jnp.select(
            [ph == H_WAIT, ph == H_REACH, ph == H_DESCEND, ph == H_CLOSE, ph == H_LIFT, ph == H_CARRY, ph == H_HOLD],
            [self._world_ctrl(d, h), above_h, grasp_h, hold_pos, lift_h, carry_h, carry_h], retreat_h)
        yawt_h = jnp.select([ph <= H_CLOSE, ph <= H_HOLD], [obj_yaw, ts.yaw], yaw_h)
        yawt_h = jnp.where(ph == H_WAIT, yaw_h, yawt_h)
        own_release = (ph == H_HOLD) & r_grasp & (th >= ts.release)
        grip_h = jnp.where((ph >= H_CLOSE) & (ph <= H_HOLD) & ~released & ~own_release, -1.0, 1.0)
        adv_h = jnp.select(
            [ph == H_WAIT, ph == H_REACH, ph == H_DESCEND, ph == H_CLOSE, ph == H_LIFT, ph == H_CARRY,
             ph == H_HOLD],
            [th >= ts.delay[0],
             near(tcp_h, above_h, 0.012) & (jnp.abs(yaw_h - obj_yaw) < 0.05),
             near(tcp_h, grasp_h, 0.006),
             h_grasp & (th >= 5),
             near(tcp_h, lift_h, 0.012) & (th >= ts.pause),
             near(tcp_h, carry_h, 0.008) & (jnp.abs(yaw_h - ts.yaw) < 0.05),
             (released | own_release) & h_open],
            False)
        regrasp_h = ((ph == H_CLOSE) & (th > 25)) | ((ph == H_LIFT) | (ph == H_CARRY)) & ~h_grasp & (p_obj[2] < 0.03)
        new_ph = jnp.where(regrasp_h, H_REACH, ph + adv_h.astype(jnp.int32))
        anchor_h = jnp.where(adv_h & ((ph == H_DESCEND) | (ph == H_CLOSE) | (ph == H_HOLD)), tcp_h, ts.anchor[0])
        anchor_h = jnp.where(adv_h & (ph == H_DESCEND), grasp_h, anchor_h)

        # ---------------- robot: stage behind the bar's far end and above it, move over it once the
        # human holds still, descend, close, wait for the human to let go, retreat
        pr, tr = ts.phase[1], ts.timer[1]
        above_r = grasp_r + jnp.array([0.0, 0.0, 0.07])
        stage_r = grasp_r + R_obj @ jnp.array([0.0, 0.09, 0.0]) + jnp.array([0.0, 0.0, 0.08])
        retreat_r = ts.anchor[1] + ts.retreat[1]
        target_r = jnp.select(
            [pr == R_WAIT, pr == R_STAGE, pr == R_OVER, pr == R_DESCEND, pr == R_CLOSE],
            [self._world_ctrl(d, r), stage_r, above_r, grasp_r, ts.anchor[1]], retreat_r)
        yawt_r = jnp.where((pr == R_WAIT) | (pr == R_RETREAT), yaw_r, obj_yaw)
        grip_r = jnp.where(pr >= R_CLOSE, -1.0, 1.0)
        human_gone = (ph >= H_RETREAT) | (released & h_open)
        adv_r = jnp.select(
            [pr == R_WAIT, pr == R_STAGE, pr == R_OVER, pr == R_DESCEND, pr == R_CLOSE],
            [(ph >= H_LIFT) & (tr >= ts.delay[1]),
             (ph >= H_HOLD) & near(tcp_r, stage_r, 0.015),
             near(tcp_r, above_r, 0.01) & (jnp.abs(yaw_r - obj_yaw) < 0.05),
             near(tcp_r, grasp_r, 0.006),
             r_grasp & human_gone & (tr >= 4)],
            False)
        regrasp_r = (pr == R_CLOSE) & (tr > 40) & ~r_grasp
        new_pr = jnp.where(regrasp_r, R_STAGE, pr + adv_r.astype(jnp.int32))
        anchor_r = jnp.where(adv_r & ((pr == R_DESCEND) | (pr == R_CLOSE)), tcp_r, ts.anchor[1])
        # robot wait timer only starts once the human carries
        tr_next = jnp.where((pr == R_WAIT) & (ph < H_LIFT), 0, tr + 1)

        # ---------------- actions
        k1, k2 = jax.random.split(rng)
        vel_h = self._move(self._world_ctrl(d, h), target_h, ts.vel[0], ts.vmax[0], ts.amax[0], ts.gain[0])
        vel_r = self._move(self._world_ctrl(d, r), target_r, ts.vel[1], ts.vmax[1], ts.amax[1], ts.gain[1])
        vel_h = jnp.where(ph == H_WAIT, 0.0, vel_h)
        vel_r = jnp.where(pr == R_WAIT, 0.0, vel_r)
        noise = jax.random.normal(k1, (2, 6)) * ts.noise[:, None] * jnp.array([1.0, 1, 1, 0.3, 0.3, 0.3])
        a_h = jnp.concatenate([jnp.asarray(h.base_mat.T) @ vel_h, self._rot_action(d, h, yawt_h)]) + noise[0]
        a_r = jnp.concatenate([jnp.asarray(r.base_mat.T) @ vel_r,
                               self._rot_action(d, r, mc.wrap_angle(yawt_r, np.pi))]) + noise[1]
        action = jnp.clip(jnp.concatenate([a_h, grip_h[None], a_r, grip_r[None]]), -1.0, 1.0)

        new_phase = jnp.stack([new_ph, new_pr]).astype(jnp.int32)
        timer = jnp.where(new_phase != ts.phase, 0, jnp.stack([th + 1, tr_next])).astype(jnp.int32)
        ts = ts._replace(phase=new_phase, timer=timer, vel=jnp.stack([vel_h, vel_r]),
                         anchor=jnp.stack([anchor_h, anchor_r]))
        return ts, action

    # ------------------------------------------------------------------ rendering
    def render(self, state: State, width: int = 320, height: int = 240, camera: str = "side") -> np.ndarray:
        """RGB frame (height, width, 3) uint8 of one unbatched state (cameras: side, front, top)."""
        d = mc.mjx.get_data(self.mj_model, jax.device_get(state.pipeline_state))
        return self._frames(d, width, height, camera)


if __name__ == "__main__":  # print the scene, e.g. to open it in MuJoCo's viewer
    print(handover_xml())
