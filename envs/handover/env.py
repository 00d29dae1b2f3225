"""HR-Handover in MuJoCo MJX: a "human" gripper fetches a bar and hands it to a "robot" gripper.

Scene (world frame, z up, table top z = 0; see :mod:`mjx_common` for the gripper model)::

          robot base (0, +0.40, 0.25), faces -y
                 |
      left (-x)  |  right (+x)        <- seen from the human
     ------------+------------  handover band: object centre y in [-0.06, 0.05], z in [0.10, 0.35]
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

Observation (69): human TCP pose in the human base frame (3 + 6D rotation), robot TCP pose in the robot
base frame (3 + 6), bar position relative to each TCP (each in that agent's base frame, 3 + 3), bar
orientation (6D, world), finger gaps / 8 cm (2), flags: human grasps, robot grasps, human released (3);
then the object-centric features of the human and of the robot (17 each, :func:`mjx_common.object_frame_features`:
the bar's ends in the agent's base frame relative to its TCP, the TCP's yaw relative to the bar, the TCP in the
bar's frame, the bar's orientation in the TCP's frame), the observation indices :attr:`Handover.object_frame_dims` (a config's ``obs_frame``
chooses whether they or the absolute orientations are read).

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

The scripted human-human team (:mod:`cogail_envs.handover.team`)
draws the region from ``mix`` and then a continuous spot inside it, the bar's
orientation at the handover (roll, pitch and yaw), speeds, reaction delays, pauses and action noise (see that module, and its variations of the human).

Rendering uses ``mujoco.Renderer`` (EGL offscreen works on headless CPU machines; if ``MUJOCO_GL`` was
not set before ``mujoco`` was imported, an EGL context is created by hand); if no OpenGL is available it
falls back to a top + side projection of the geoms drawn with numpy.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from .. import mjx_common as mc
from ..base import CollabEnv, State

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
RELEASE_AFTER = 3          # robot-grasp steps before the human's gripper auto-opens
SUCCESS_DIST = 0.10
LIFTED_Z = 0.05
# init vector: obj dx, obj dy, obj yaw, human start (3, base frame), robot start (3, base frame), robot start yaw.
# The robot's start: within 3 cm of its home pose, not turned; the constructor's ``robot_start_yaw`` /
# ``robot_start_z`` widen its yaw and height (the task's training split is made so: ``TASK.train_env``).
INIT_LO = np.array([-0.05, -0.015, -0.15, -0.03, -0.03, -0.03, -0.03, -0.03, -0.03, 0.0], np.float32)
INIT_HI = -INIT_LO

HUMAN = mc.GripperSpec("human", HUMAN_BASE, 0.0, (-0.35, -0.05, -0.234, -0.6, -0.6, -1.6),
                       (0.35, 0.50, 0.20, 0.6, 0.6, 1.6), rgba=(0.25, 0.55, 0.9, 1.0))
ROBOT = mc.GripperSpec("robot", ROBOT_BASE, 180.0, (-0.35, -0.05, -0.234, -0.6, -0.6, -1.6),
                       (0.35, 0.45, 0.20, 0.6, 0.6, 1.6), rgba=(0.9, 0.35, 0.3, 1.0))


def handover_xml() -> str:
    """The HR-Handover MJCF (two grippers, a table and the bar), with :mod:`mjx_common`'s solver settings."""
    obj = mc.free_box_xml(OBJ, (*OBJ_START, OBJ_HALF[2]), OBJ_HALF, OBJ_MASS, rgba=(0.95, 0.75, 0.1, 1.0))
    contact = (mc.gripper_pairs_xml(HUMAN, OBJ) + mc.gripper_pairs_xml(ROBOT, OBJ)
               + mc.pair_xml(OBJ, "table", 0.8))
    sensor = mc.gripper_sensors_xml(HUMAN, OBJ) + mc.gripper_sensors_xml(ROBOT, OBJ)
    return mc.scene_xml("handover", [HUMAN, ROBOT], worldbody=obj, contact=contact, sensor=sensor)


class Handover(CollabEnv):
    """HR-Handover with brax's ``Env`` API (``pipeline_state`` is ``mjx.Data``).

    Physics: :mod:`mjx_common`'s Newton solver settings, substeps, timestep and finger-pad contacts
    (``ITERATIONS`` / ``LS_ITERATIONS`` / ``N_SUBSTEPS`` / ``TIMESTEP`` / ``FINGER_CONDIM``: 2 / 4 / 2 / 0.01 s / 3; the
    settings before were 4 / 8 / 4 / 0.005 s / 4, ~2.5-3x more expensive with the same scripted-team results).
    """

    name = "handover"
    human_action_size = 7
    robot_action_size = 7
    max_episode_steps = 300
    init_size = 10
    strategy_names = ("left", "middle", "right")

    def __init__(self, max_episode_steps: int = 300, auto_release: bool = True, robot_start_yaw: float = 0.0,
                 robot_start_z: float = 0.03):
        self.max_episode_steps = int(max_episode_steps)
        self.init_lo = INIT_LO.copy()
        self.init_lo[8], self.init_lo[9] = -float(robot_start_z), -float(robot_start_yaw)
        if (float(robot_start_yaw), float(robot_start_z)) != (0.0, 0.03):  # another start: another dataset version
            self.spec_tag = f"{type(self).spec_tag}-robot-start-{float(robot_start_yaw):g}-{float(robot_start_z):g}"
        self.auto_release = bool(auto_release)
        self.n_substeps, self.timestep = mc.N_SUBSTEPS, mc.TIMESTEP
        self.xml = handover_xml()
        self.mj_model, self.mx = mc.build(self.xml)
        m = self.mj_model
        self.human = mc.Gripper.from_model(m, "human", [OBJ])
        self.robot = mc.Gripper.from_model(m, "robot", [OBJ])
        self.obj_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, OBJ)
        self.obj_qpos = int(m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, OBJ)])
        self._template = mc.template_data(self.mx)
        self._frames = mc.FrameRenderer(self.mj_model)

    # the observation layout and the team's pose ranges (part of the version fingerprint of generated data)
    spec_tag = "obs69-object-frame-rot-poses6dof-prompt-start10"
    object_frame_dims = tuple(range(35, 69))
    orientation_dims = (*range(3, 9), *range(12, 18), *range(24, 30))  # the TCPs' and the bar's 6D rotations

    @property
    def observation_size(self) -> int:
        return 69

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
        open_q = mc.MAX_GAP / 2
        qpos = qpos.at[jnp.array(h.qpos[:3])].set(init[3:6]).at[jnp.array(r.qpos[:3])].set(init[6:9])
        qpos = qpos.at[r.qpos[5]].set(init[9])
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
        info = {"t": jnp.zeros((), jnp.int32), "truncation": zero, "failed": zero, "released": zero,
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
        p, R = self._obj_pos(d), self._obj_mat(d)
        rel = [jnp.asarray(g.base_mat.T) @ (p - mc.tcp_pos(d, g)) for g in (h, r)]
        return jnp.concatenate([
            mc.tcp_pose_base(d, h), mc.tcp_pose_base(d, r), rel[0], rel[1], mc.rot6d(R),
            jnp.stack([mc.finger_gap(d, h), mc.finger_gap(d, r)]) / mc.MAX_GAP,
            jnp.stack([info["human_grasp"], info["robot_grasp"], info["released"]]),
            mc.object_frame_features(d, h, p, R, OBJ_HALF[1]), mc.object_frame_features(d, r, p, R, OBJ_HALF[1]),
        ]).astype(jnp.float32)

    def replay_hold(self, state: State, a_h: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The patient human: while it holds the bar that the robot has not taken yet (the auto-release has not
        fired), it does not open its gripper -- the recorded human opens at the time its own partner had taken the
        bar, and a recording that has ended (zero actions) opens it too; it holds still, gripper closed, instead."""
        opens = a_h[6] > -0.5
        wait = opens & (state.info["human_grasp"] > 0) & (state.info["released"] == 0)
        return wait, jnp.zeros_like(a_h).at[6].set(-1.0)

    # ------------------------------------------------------------------ step
    def checkpoint_state(self, state: State) -> State:
        return state.replace(pipeline_state=mc.without_recomputed(state.pipeline_state))

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
        done, truncation = self.time_limit(t, (m["success"] > 0) | failed)
        info = dict(info, t=t, truncation=truncation, failed=failed.astype(jnp.float32), released=released,
                    hold=hold.astype(jnp.int32), human_grasp=h_grasp.astype(jnp.float32), robot_grasp=r_grasp.astype(jnp.float32))
        return state.replace(pipeline_state=d, obs=self._obs(d, info), reward=succ, done=done,
                             metrics=m, info=info)

    # ------------------------------------------------------------------ strategies
    def classify_strategy(self, metrics: dict[str, jax.Array]) -> jax.Array:
        x = metrics["handover_x"]
        sid = jnp.where(x < -X_SPLIT, 1, jnp.where(x > X_SPLIT, 3, 2))
        ok = (metrics["success"] > 0) & (metrics["handover"] > 0)
        return jnp.where(ok, sid, 0).astype(jnp.int32)

    def human_position(self, state: State) -> jax.Array:
        """The human's TCP in the world frame (metres)."""
        return mc.tcp_pos(state.pipeline_state, self.human)

    # ------------------------------------------------------------------ rendering
    def render(self, state: State, width: int = 320, height: int = 240, camera: str = "side") -> np.ndarray:
        """RGB frame (height, width, 3) uint8 of one unbatched state (cameras: side, front, top)."""
        d = mc.mjx.get_data(self.mj_model, jax.device_get(state.pipeline_state))
        return self._frames(d, width, height, camera)



if __name__ == "__main__":  # print the scene, e.g. to open it in MuJoCo's viewer
    print(handover_xml())
