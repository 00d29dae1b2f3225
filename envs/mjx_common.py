"""Shared MJX parts of the manipulation tasks (HR-Handover, HR-SeqManip).

Scene conventions
-----------------
* World frame: z up, table top is the plane z = 0. The "human" sits at -y and faces +y, the "robot"
  sits at +y and faces -y. Seen from the human, *left* is -x and *right* is +x.
* Each agent is a floating parallel gripper (no arm). Its body ``<name>`` hangs under a fixed base body
  ``<name>_base`` (whose pose is the agent's *base frame*) through 3 slide joints (x, y, z of the base
  frame) followed by 3 hinge joints (x, y, z, intrinsic: ``R = Rx(a) Ry(b) Rz(c)``), all about the tool
  centre point (TCP, the body origin, between the finger pads). At zero angles the fingers point down
  (-z) and close along the gripper's local x. Each joint has a ``position`` actuator; the gripper body
  and the fingers have ``gravcomp="1"``. The two finger slide joints are coupled by a joint equality
  and driven together by ONE position actuator on the fixed tendon ``<name>_grip`` (= the finger gap).
  Actuator order per gripper: x, y, z, rx, ry, rz, grip (:data:`N_GRIPPER_ACT` = 7).
* Collisions: every geom has contype = conaffinity = 0; only explicit ``<contact><pair>`` entries
  collide (fingers/palm vs. objects, objects vs. table). Grippers are kept off the furniture by joint
  limits, never by contacts. Grasp detection uses ``<contact>`` sensors (data="found") between each
  finger pad and each graspable geom.
* Physics: :data:`TIMESTEP` = 0.01 s, :data:`N_SUBSTEPS` = 2 substeps per env step (0.02 s) in a
  ``lax.scan``; Newton solver with :data:`ITERATIONS` = 2 iterations and :data:`LS_ITERATIONS` = 4
  line-search iterations; finger-pad pairs with :data:`FINGER_CONDIM` = 3 (no torsional friction); Euler
  integrator with ``eulerdamp`` disabled (actuator damping is explicit; the gains are stable at 10 ms).
  These are ~2.5x cheaper per env step on CPU than the earlier 4 x 5 ms / 4 / 8 / condim-4 settings
  with the same scripted-team results (``experiments/mjx_settings.py``); the old settings remain
  available through the env constructors (``n_substeps=4, timestep=0.005, iterations=4,
  ls_iterations=8, finger_condim=4``).

Actions (per agent, 7 numbers in [-1, 1])
-----------------------------------------
``(dx, dy, dz, drx, dry, drz, g)``: the first six *move the position-actuator targets* of the gripper
joints: ``POS_SCALE`` = 1 cm per unit per env step for translation (in the agent's base frame) and
``ROT_SCALE`` = 1 degree per unit per env step for each of the three hinge angles (the paper's
HR-Handover action space, no extra scaling). ``g`` is the absolute gripper command: -1 fully closed,
+1 fully open (paper convention); it sets the finger-gap target linearly in [0, ``MAX_GAP``]. Targets are
clipped to the joint ranges, so an agent can never push its target outside its workspace.

Observations helpers return the TCP pose in the agent's base frame (position + continuous 6D rotation:
the first two columns of the rotation matrix, Zhou et al. 2019) and object positions relative to the
TCP expressed in the base frame.

Grasping
--------
The default is an honest *friction* grasp: the bar is squeezed by the two box finger pads (position
actuator on the finger tendon, force limited), no welds. It is reliable in MJX with the settings
below (measured: the HR-Handover scripted team succeeded in all of >= 1000 episodes with the earlier
4 x 5 ms / condim-4 settings, and in all 64 + 128 episodes checked with the current ones), so no grasp
assist is compiled in. :func:`is_grasping` is the grasp detector: both finger pads touch the object
(contact sensors) *and* the gripper is commanded closed.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from .segment_sums import gathered_segment_sums

__all__ = [
    "N_GRIPPER_ACT", "N_SUBSTEPS", "TIMESTEP", "ITERATIONS", "LS_ITERATIONS", "FINGER_CONDIM",
    "POS_SCALE", "ROT_SCALE", "MAX_GAP",
    "GripperSpec", "gripper_body_xml", "gripper_actuator_xml", "gripper_tendon_xml",
    "gripper_equality_xml", "gripper_pairs_xml", "gripper_sensors_xml", "free_box_xml",
    "pair_xml", "camera_xml", "table_xml", "scene_xml", "build",
    "Gripper", "apply_gripper_action", "physics_step", "rot6d", "tcp_pos", "tcp_mat",
    "tcp_pose_base", "to_base", "finger_gap", "touching", "is_grasping", "body_pos",
    "body_mat", "make_data", "template_data", "quat_to_mat", "yaw_of", "wrap_angle", "FrameRenderer",
    "rot_x", "rot_y", "rot_z", "pose_mat", "euler_xyz", "grip_angles", "rot_toward", "angles_close", "bar_normal",
]

N_GRIPPER_ACT = 7
N_SUBSTEPS = 2                   # physics steps per env step (env step = N_SUBSTEPS * TIMESTEP = 0.02 s)
TIMESTEP = 0.01
ITERATIONS = 2                   # Newton solver iterations
LS_ITERATIONS = 4                # Newton line-search iterations
FINGER_CONDIM = 3                # finger pad vs. object/handle pairs: sliding friction only (no torsion)
POS_SCALE = 0.01                 # metres per action unit per env step
ROT_SCALE = float(np.deg2rad(1.0))  # radians per action unit per env step
MAX_GAP = 0.08                   # finger gap when fully open (m)
FINGER_HALF = (0.006, 0.012, 0.025)  # finger pad box half sizes (x: thickness, y: width, z: length)
FINGER_ZC = 0.01                 # finger pad centre height above the TCP (tips 1.5 cm below the TCP)
PALM_HALF = (0.058, 0.016, 0.01)
PALM_ZC = FINGER_ZC + FINGER_HALF[2] + PALM_HALF[2]


def _fmt(v: Sequence[float]) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


@dataclasses.dataclass(frozen=True)
class GripperSpec:
    """Static description of one floating gripper.

    ``lo``/``hi``: joint limits of (x, y, z, rx, ry, rz) in the base frame (metres, radians); the same
    limits are the position-actuator control ranges. ``base_pos``/``base_yaw``: the base frame (yaw in
    degrees about world z). ``init``: nominal starting joint values.
    """

    name: str
    base_pos: tuple[float, float, float]
    base_yaw: float
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    rgba: tuple[float, float, float, float] = (0.3, 0.5, 0.9, 1.0)
    kp_pos: float = 2000.0
    kv_pos: float = 65.0
    kp_rot: float = 20.0
    kv_rot: float = 0.6
    kp_grip: float = 300.0
    kv_grip: float = 8.0
    grip_force: float = 20.0
    finger_friction: float = 1.5


def gripper_body_xml(s: GripperSpec) -> str:
    """``<body>`` of one gripper (goes in ``<worldbody>``)."""
    n = s.name
    axes = ("1 0 0", "0 1 0", "0 0 1")
    joints = []
    for i, ax in enumerate(axes):
        joints.append(
            f'<joint name="{n}_{"xyz"[i]}" type="slide" axis="{ax}" range="{s.lo[i]:.6g} {s.hi[i]:.6g}" '
            f'armature="0.1"/>')
    for i, ax in enumerate(axes):
        joints.append(
            f'<joint name="{n}_r{"xyz"[i]}" type="hinge" axis="{ax}" range="{s.lo[3 + i]:.6g} {s.hi[3 + i]:.6g}" '
            f'armature="0.005"/>')
    fx, fy, fz = FINGER_HALF
    rgba = _fmt(s.rgba)
    dark = _fmt((0.15, 0.15, 0.15, 1.0))
    fingers = []
    for side, sign in (("fl", 1.0), ("fr", -1.0)):
        fingers.append(
            f'<body name="{n}_{side}" gravcomp="1">'
            f'<joint name="{n}_{side}" type="slide" axis="{sign:g} 0 0" range="0 {MAX_GAP / 2:.6g}" armature="0.1"/>'
            f'<geom name="{n}_{side}" type="box" size="{_fmt(FINGER_HALF)}" pos="{sign * fx:.6g} 0 {FINGER_ZC:.6g}" '
            f'mass="0.02" rgba="{dark}"/>'
            f'</body>')
    return (
        f'<body name="{n}_base" pos="{_fmt(s.base_pos)}" euler="0 0 {np.deg2rad(s.base_yaw):.12g}">'
        f'<body name="{n}" gravcomp="1">' + "".join(joints) +
        f'<site name="{n}_tcp" size="0.004" rgba="1 0 0 0.5"/>'
        f'<geom name="{n}_palm" type="box" size="{_fmt(PALM_HALF)}" pos="0 0 {PALM_ZC:.6g}" mass="0.3" rgba="{rgba}"/>'
        f'<geom name="{n}_wrist" type="cylinder" size="0.018 0.03" pos="0 0 {PALM_ZC + PALM_HALF[2] + 0.03:.6g}" '
        f'mass="0.1" rgba="{rgba}"/>' + "".join(fingers) + '</body></body>')


def gripper_actuator_xml(s: GripperSpec) -> str:
    """The 7 position actuators of one gripper, in the order x, y, z, rx, ry, rz, grip."""
    n = s.name
    out = []
    for i, j in enumerate(("x", "y", "z", "rx", "ry", "rz")):
        kp, kv = (s.kp_pos, s.kv_pos) if i < 3 else (s.kp_rot, s.kv_rot)
        frc = 60.0 if i < 3 else 3.0
        out.append(f'<position name="{n}_{j}" joint="{n}_{j}" kp="{kp:g}" kv="{kv:g}" '
                   f'ctrlrange="{s.lo[i]:.6g} {s.hi[i]:.6g}" forcerange="-{frc:g} {frc:g}"/>')
    out.append(f'<position name="{n}_grip" tendon="{n}_grip" kp="{s.kp_grip:g}" kv="{s.kv_grip:g}" '
               f'ctrlrange="0 {MAX_GAP:.6g}" forcerange="-{s.grip_force:g} {s.grip_force:g}"/>')
    return "".join(out)


def gripper_tendon_xml(s: GripperSpec) -> str:
    n = s.name
    return (f'<fixed name="{n}_grip"><joint joint="{n}_fl" coef="1"/><joint joint="{n}_fr" coef="1"/></fixed>')


def gripper_equality_xml(s: GripperSpec) -> str:
    n = s.name
    return f'<joint name="{n}_fingers" joint1="{n}_fr" joint2="{n}_fl" solref="0.01 1"/>'


def pair_xml(g1: str, g2: str, friction: float = 1.0, condim: int = 3, margin: float = 0.0,
             torsion: float = 0.005) -> str:
    return (f'<pair geom1="{g1}" geom2="{g2}" condim="{condim}" margin="{margin:g}" '
            f'friction="{friction:g} {friction:g} {torsion:g} 0.0001 0.0001" solref="0.01 1" solimp="0.95 0.99 0.001"/>')


def gripper_pairs_xml(s: GripperSpec, geom: str, palm: bool = True, finger_condim: int = FINGER_CONDIM) -> str:
    """Contact pairs between the gripper's finger pads (and palm) and ``geom``.

    ``finger_condim``: 3 (default, :data:`FINGER_CONDIM`) = sliding friction only; 4 adds torsional
    friction (coefficient 0.05) on the finger pads. The box-box pad contacts have several contact points,
    which already resist the bar pivoting between the pads.
    """
    n = s.name
    out = [pair_xml(f"{n}_fl", geom, s.finger_friction, condim=finger_condim, torsion=0.05),
           pair_xml(f"{n}_fr", geom, s.finger_friction, condim=finger_condim, torsion=0.05)]
    if palm:
        out.append(pair_xml(f"{n}_palm", geom, 0.5))
    return "".join(out)


def gripper_sensors_xml(s: GripperSpec, geom: str) -> str:
    """Two contact sensors (``data="found"``): finger pad fl / fr touching ``geom``."""
    n = s.name
    return "".join(f'<contact name="{n}_{f}_{geom}" geom1="{n}_{f}" geom2="{geom}" data="found" num="1"/>'
                   for f in ("fl", "fr"))


def free_box_xml(name: str, pos: Sequence[float], half: Sequence[float], mass: float,
                 rgba: Sequence[float] = (0.9, 0.5, 0.1, 1.0), yaw: float = 0.0) -> str:
    """A free-floating box body ``name`` with one geom ``name`` (radians yaw)."""
    return (f'<body name="{name}" pos="{_fmt(pos)}" euler="0 0 {yaw:.6g}"><freejoint name="{name}"/>'
            f'<geom name="{name}" type="box" size="{_fmt(half)}" mass="{mass:g}" rgba="{_fmt(rgba)}"/></body>')


def camera_xml(name: str, pos: Sequence[float], target: Sequence[float]) -> str:
    """A fixed camera at ``pos`` looking at ``target`` (z up)."""
    pos, target = np.asarray(pos, float), np.asarray(target, float)
    f = target - pos
    f /= np.linalg.norm(f)
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return f'<camera name="{name}" pos="{_fmt(pos)}" xyaxes="{_fmt(x)} {_fmt(y)}"/>'


def table_xml(half: Sequence[float] = (0.6, 0.6), height: float = 0.4) -> str:
    """Table top = collision plane ``table`` at z = 0 plus a visual slab and legs (no collisions)."""
    hx, hy = half
    legs = "".join(
        f'<geom type="box" size="0.02 0.02 {height / 2:g}" pos="{sx * (hx - 0.04):g} {sy * (hy - 0.04):g} {-height / 2 - 0.02:g}" '
        f'rgba="0.45 0.3 0.2 1"/>' for sx in (-1, 1) for sy in (-1, 1))
    return (f'<geom name="table" type="plane" size="{hx:g} {hy:g} 0.01" rgba="0.75 0.6 0.45 1"/>'
            f'<geom name="table_slab" type="box" size="{hx:g} {hy:g} 0.01" pos="0 0 -0.0105" rgba="0.6 0.45 0.3 1"/>'
            + legs)


def scene_xml(name: str, grippers: Sequence[GripperSpec], worldbody: str = "", contact: str = "",
              sensor: str = "", equality: str = "", tendon: str = "", actuator: str = "",
              iterations: int = ITERATIONS, ls_iterations: int = LS_ITERATIONS, impratio: float = 10.0,
              timestep: float = TIMESTEP) -> str:
    """Full MJCF: options, visual, table, the grippers, extra bodies and the explicit contact pairs.

    Extra actuators go *after* the gripper actuators, so ``ctrl[7*i : 7*i+7]`` belongs to gripper ``i``.
    """
    bodies = "".join(gripper_body_xml(g) for g in grippers)
    acts = "".join(gripper_actuator_xml(g) for g in grippers) + actuator
    tend = "".join(gripper_tendon_xml(g) for g in grippers) + tendon
    eq = "".join(gripper_equality_xml(g) for g in grippers) + equality
    return f"""<mujoco model="{name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep:g}" iterations="{iterations}" ls_iterations="{ls_iterations}" solver="Newton"
          integrator="Euler" cone="pyramidal" impratio="{impratio:g}">
    <flag eulerdamp="disable"/>
  </option>
  <default><geom contype="0" conaffinity="0" solref="0.01 1"/></default>
  <visual><global offwidth="640" offheight="480"/><quality shadowsize="1024"/>
    <headlight ambient="0.4 0.4 0.4" diffuse="0.6 0.6 0.6"/></visual>
  <worldbody>
    <light pos="0 0 1.5" dir="0 0 -1" directional="true"/>
    {camera_xml("side", (1.05, -0.75, 0.5), (0.0, 0.0, 0.15))}
    {camera_xml("front", (0.0, -1.05, 0.55), (0.0, 0.0, 0.12))}
    <camera name="top" pos="0 0 1.3" xyaxes="1 0 0 0 1 0"/>
    {table_xml()}
    {bodies}
    {worldbody}
  </worldbody>
  <tendon>{tend}</tendon>
  <equality>{eq}</equality>
  <actuator>{acts}</actuator>
  <contact>{contact}</contact>
  <sensor>{sensor}</sensor>
</mujoco>"""


def build(xml: str) -> tuple[mujoco.MjModel, mjx.Model]:
    """Compile an MJCF string into a MuJoCo model and its MJX model (on this process's first device: MJX's own
    default, ``jax.devices()[0]``, belongs to process 0 in a run over several processes)."""
    m = mujoco.MjModel.from_xml_string(xml)
    return m, mjx.put_model(m, device=jax.local_devices()[0])


def template_data(mx: mjx.Model) -> mjx.Data:
    """MJX's initial data of ``mx`` on this process's first device (see :func:`build`)."""
    return mjx.make_data(mx, device=jax.local_devices()[0])


# ----------------------------------------------------------------------------------------------------
# Runtime helpers (pure, jittable). ``Gripper`` holds static indices only.
# ----------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Gripper:
    """Static indices of one gripper inside a compiled model."""

    name: str
    act: int                    # first actuator index (7 consecutive)
    qpos: tuple[int, ...]       # qpos addresses of x, y, z, rx, ry, rz
    finger_qpos: tuple[int, int]
    body: int                   # gripper body id (its frame is the TCP)
    base_pos: np.ndarray        # (3,) base frame origin (world)
    base_mat: np.ndarray        # (3, 3) base frame rotation (world <- base)
    lo: np.ndarray              # (7,) ctrl lower bounds
    hi: np.ndarray              # (7,) ctrl upper bounds
    sensors: dict               # geom name -> (adr_fl, adr_fr) in sensordata

    @staticmethod
    def from_model(m: mujoco.MjModel, name: str, geoms: Sequence[str] = ()) -> "Gripper":
        jid = lambda j: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        qpos = tuple(int(m.jnt_qposadr[jid(f"{name}_{j}")]) for j in ("x", "y", "z", "rx", "ry", "rz"))
        fq = tuple(int(m.jnt_qposadr[jid(f"{name}_{f}")]) for f in ("fl", "fr"))
        act = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{name}_x")
        body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{name}_base")
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)
        sens = {}
        for g in geoms:
            adr = []
            for f in ("fl", "fr"):
                sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, f"{name}_{f}_{g}")
                adr.append(int(m.sensor_adr[sid]))
            sens[g] = tuple(adr)
        return Gripper(name=name, act=int(act), qpos=qpos, finger_qpos=fq, body=int(body),
                       base_pos=np.array(d.xpos[base]), base_mat=np.array(d.xmat[base]).reshape(3, 3),
                       lo=np.array(m.actuator_ctrlrange[act:act + N_GRIPPER_ACT, 0]),
                       hi=np.array(m.actuator_ctrlrange[act:act + N_GRIPPER_ACT, 1]), sensors=sens)

    def __hash__(self):  # static config for jit closures
        return hash((self.name, self.act, self.body))

    def __eq__(self, other):
        return isinstance(other, Gripper) and (self.name, self.act, self.body) == (other.name, other.act, other.body)


def apply_gripper_action(ctrl: jax.Array, action: jax.Array, g: Gripper,
                         pos_scale: float = POS_SCALE, rot_scale: float = ROT_SCALE) -> jax.Array:
    """New ``ctrl`` after one agent's 7-D action: delta on the 6 pose targets, absolute gripper."""
    a = jnp.clip(action, -1.0, 1.0)
    cur = ctrl[g.act:g.act + 6]
    scale = jnp.array([pos_scale] * 3 + [rot_scale] * 3)
    pose = jnp.clip(cur + a[:6] * scale, g.lo[:6], g.hi[:6])
    grip = (a[6] + 1.0) * 0.5 * MAX_GAP
    return ctrl.at[g.act:g.act + N_GRIPPER_ACT].set(jnp.concatenate([pose, grip[None]]))


def physics_step(mx: mjx.Model, d: mjx.Data, ctrl: jax.Array, n_substeps: int = N_SUBSTEPS) -> mjx.Data:
    """Set ``ctrl`` and advance ``n_substeps`` x ``mjx.step`` (lax.scan).

    Matrix products are traced at full float32 precision: on NVIDIA GPUs XLA otherwise runs float32 matmuls in
    TF32, and the Newton solver's Hessian / Cholesky in TF32 occasionally produced NaN states on the H200.
    MJX's sums over the kinematic tree are traced as gathers (``segment_sums``): as scatter-adds, deterministic
    GPU execution runs them as serial loops."""
    d = d.replace(ctrl=ctrl)
    forward = shared_forward(mx)

    def body(dd, _):  # mjx.step with the scene's Euler integrator (``scene_xml``)
        return mjx.euler(mx, forward(dd)), None

    with jax.default_matmul_precision("highest"), gathered_segment_sums():
        d, _ = jax.lax.scan(body, d, None, length=n_substeps)
    return d


_FORWARD: dict[int, tuple[mjx.Model, object]] = {}


def shared_forward(mx: mjx.Model):
    """``mjx.forward(mx, .)`` (tree sums as gathers) as one jitted function per model, shared by every program of
    the process: JAX traces it once per matmul precision and shape, where a plain call is traced again at every
    call site (a task's reset and step, in the training program, the evaluation's and the demonstrations'), each
    time under every vmap around it. XLA inlines it: the compiled programs compute the same numbers."""
    if id(mx) not in _FORWARD:
        def forward(d):
            with gathered_segment_sums():
                return mjx.forward(mx, d)

        _FORWARD[id(mx)] = (mx, jax.jit(forward))  # the model kept alive: its id is not reused
    return _FORWARD[id(mx)][1]


# Joint speeds (m/s or rad/s) above this are a diverging simulation, not motion: the grippers move at most
# 1 cm / 1 degree per 0.02 s control step and scripted or random-action episodes stay below ~25.
QVEL_LIMIT = 200.0


def guarded_physics_step(mx: mjx.Model, d: mjx.Data, ctrl: jax.Array,
                         n_substeps: int = N_SUBSTEPS) -> tuple[mjx.Data, jax.Array]:
    """``physics_step`` that never hands on a diverged state.

    If the new state has a non-finite or exploding (|qvel| > ``QVEL_LIMIT``) coordinate, the previous state
    (with the new ``ctrl``) is kept instead and ``failed`` is True; the env then ends the episode as a failure.
    Without this a single diverged env out of thousands turns every observation-normaliser statistic,
    discriminator input and gradient of the update into NaN."""
    nd = physics_step(mx, d, ctrl, n_substeps)
    ok = jnp.all(jnp.isfinite(nd.qpos)) & jnp.all(jnp.isfinite(nd.qvel)) & (jnp.max(jnp.abs(nd.qvel)) < QVEL_LIMIT)
    prev = d.replace(ctrl=ctrl)
    return jax.tree.map(lambda a, b: jnp.where(ok, a, b), nd, prev), ~ok


# mjx.Data fields that ``mjx.forward`` writes before it reads them (the constraint rows, contacts, mass matrix and
# its factor): a state with them zeroed steps to the same bits (tests/test_tasks.py). 52 % of a seqmanip env
# state's bytes; ``efc_type`` is set once, at ``make_data``, and kept.
RECOMPUTED = ("efc_J", "efc_D", "efc_aref", "efc_force", "efc_frictionloss", "efc_margin", "efc_pos", "contact", "M",
              "qLD")


def without_recomputed(d: mjx.Data) -> mjx.Data:
    """``d`` with the ``RECOMPUTED`` fields zeroed (those this MJX version has): what a checkpoint stores."""
    impl = getattr(d, "_impl", None)
    names = set(getattr(impl, "__dataclass_fields__", ()))
    zero = {f: jax.tree.map(jnp.zeros_like, getattr(impl, f)) for f in RECOMPUTED if f in names}
    return d.replace(_impl=impl.replace(**zero)) if zero else d


def make_data(m: mujoco.MjModel, mx: mjx.Model, qpos: jax.Array, ctrl: jax.Array, template: mjx.Data) -> mjx.Data:
    """A fresh ``mjx.Data`` at ``qpos`` (zero velocity) with ``ctrl``, after ``mjx.forward``."""
    d = template.replace(qpos=qpos, qvel=jnp.zeros_like(template.qvel), ctrl=ctrl)
    return shared_forward(mx)(d)


def rot6d(mat: jax.Array) -> jax.Array:
    """Continuous 6D rotation: first two columns of a (..., 3, 3) rotation matrix, flattened."""
    return jnp.concatenate([mat[..., :, 0], mat[..., :, 1]], axis=-1)


def body_pos(d: mjx.Data, body: int) -> jax.Array:
    return d.xpos[body]


def body_mat(d: mjx.Data, body: int) -> jax.Array:
    return d.xmat[body].reshape(3, 3)


def tcp_pos(d: mjx.Data, g: Gripper) -> jax.Array:
    """TCP position in the world frame."""
    return d.xpos[g.body]


def tcp_mat(d: mjx.Data, g: Gripper) -> jax.Array:
    return d.xmat[g.body].reshape(3, 3)


def to_base(p_world: jax.Array, g: Gripper) -> jax.Array:
    """A world point expressed in the gripper's base frame."""
    return jnp.asarray(g.base_mat.T) @ (p_world - jnp.asarray(g.base_pos))


def tcp_pose_base(d: mjx.Data, g: Gripper) -> jax.Array:
    """(9,) TCP position (3) and 6D rotation (6), both in the agent's base frame."""
    pos = to_base(tcp_pos(d, g), g)
    mat = jnp.asarray(g.base_mat.T) @ tcp_mat(d, g)
    return jnp.concatenate([pos, rot6d(mat)])


OBJECT_FEATURES = 17  # per agent: object_frame_features' length


def object_frame_features(d: mjx.Data, g: Gripper, p_obj: jax.Array, R_obj: jax.Array, half_len: float) -> jax.Array:
    """(17,) object-centric features of one agent and a bar-like object (long axis: the object's local y):
    the bar's two ends relative to the agent's TCP in the agent's base frame (the frame its actions move in;
    3 + 3), the yaw of the TCP relative to the bar, wrapped to [-pi/2, pi/2) (two-finger grippers and bars are
    symmetric under half a turn), and its magnitude (2), the TCP's position in the object's frame (3), and the
    bar's orientation in the TCP's frame (6D rotation of ``R_tcp^T R_obj``, of the two half-turn-equivalent
    frames of the bar the nearer one: how the gripper must still turn, about every axis, to hold it square; 6).
    They look the same wherever the object is and however it is turned, which is what a policy needs to grasp it
    there; the relative yaw is linear, not a point on a circle, so a larger turn than the demonstrations' reads
    as more of the same."""
    B = jnp.asarray(g.base_mat.T)
    tcp = tcp_pos(d, g)
    R_tcp = tcp_mat(d, g)
    axis = R_obj[:, 1] * half_len
    dyaw = wrap_angle(yaw_of(R_tcp) - yaw_of(R_obj), np.pi)
    rel = R_tcp.T @ R_obj
    rel = jnp.where(jnp.trace(rel) >= jnp.trace(rel @ rot_z(np.pi)), rel, rel @ rot_z(np.pi))
    return jnp.concatenate([B @ (p_obj + axis - tcp), B @ (p_obj - axis - tcp),
                            jnp.stack([dyaw, jnp.abs(dyaw)]), R_obj.T @ (tcp - p_obj), rot6d(rel)])


# ----------------------------------------------------------------------------------------------------
# Full 3D orientations (the scripted teams present and grasp objects turned about every axis)
# ----------------------------------------------------------------------------------------------------

def rot_x(a) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.array([[o, z, z], [z, c, -s], [z, s, c]])


def rot_y(a) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.array([[c, z, s], [z, o, z], [-s, z, c]])


def rot_z(a) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.array([[c, -s, z], [s, c, z], [z, z, o]])


def pose_mat(roll, pitch, yaw) -> jax.Array:
    """A bar's orientation (long axis: local y) from the angles a hand turns it by: ``Rz(yaw) Rx(pitch) Ry(roll)``
    -- yaw about the vertical, pitch tilting the long axis up or down, roll twisting the bar about its long axis."""
    return rot_z(yaw) @ rot_x(pitch) @ rot_y(roll)


def euler_xyz(R: jax.Array) -> jax.Array:
    """(a, b, c) with ``R = Rx(a) Ry(b) Rz(c)``: the gripper's hinge angles (rx, ry, rz) that give orientation ``R``
    in its base frame."""
    b = jnp.arcsin(jnp.clip(R[0, 2], -1.0, 1.0))
    a = jnp.arctan2(-R[1, 2], R[2, 2])
    c = jnp.arctan2(-R[0, 1], R[0, 0])
    return jnp.stack([a, b, c])


def grip_angles(R_world: jax.Array, g: Gripper) -> jax.Array:
    """The hinge targets (rx, ry, rz) that hold a bar of world orientation ``R_world`` square: the gripper's frame on
    the bar's, of the two half-turn-equivalent frames (about the bar's normal) the one with the smaller turn about the
    gripper's own vertical (within its +-1.6 rad joint range)."""
    Rb = jnp.asarray(g.base_mat.T) @ R_world
    e0, e1 = euler_xyz(Rb), euler_xyz(Rb @ rot_z(np.pi))
    return jnp.where(jnp.abs(e0[2]) <= jnp.abs(e1[2]), e0, e1)


def rot_toward(d: mjx.Data, g: Gripper, target: jax.Array, gain=0.25, vmax=0.9) -> jax.Array:
    """The three rotation actions that move the hinge targets (rx, ry, rz) towards ``target`` (proportional, each
    clipped to +-``vmax``)."""
    cur = d.ctrl[g.act + 3:g.act + 6]
    return jnp.clip(gain * (target - cur) / ROT_SCALE, -vmax, vmax)


def angles_close(d: mjx.Data, g: Gripper, target: jax.Array, tol: float = 0.05) -> jax.Array:
    """Whether every hinge target is within ``tol`` of ``target``."""
    return jnp.all(jnp.abs(d.ctrl[g.act + 3:g.act + 6] - target) < tol)


def bar_normal(R_obj: jax.Array) -> jax.Array:
    """The bar's local z axis, pointing up (the side a gripper comes from to grasp it)."""
    n = R_obj[:, 2]
    return jnp.where(n[2] >= 0, n, -n)


def finger_gap(d: mjx.Data, g: Gripper) -> jax.Array:
    """Distance between the finger pads (m)."""
    return d.qpos[g.finger_qpos[0]] + d.qpos[g.finger_qpos[1]]


def touching(d: mjx.Data, g: Gripper, geom: str) -> jax.Array:
    """Both finger pads are in contact with ``geom`` (contact sensors)."""
    a, b = g.sensors[geom]
    return (d.sensordata[a] > 0) & (d.sensordata[b] > 0)


def is_grasping(d: mjx.Data, g: Gripper, geom: str) -> jax.Array:
    """Grasp detector: both pads touch ``geom`` and the gripper is commanded to close past the gap."""
    commanded_closed = d.ctrl[g.act + 6] < finger_gap(d, g) - 0.002
    return touching(d, g, geom) & commanded_closed


def quat_to_mat(q: jax.Array) -> jax.Array:
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def yaw_of(mat: jax.Array) -> jax.Array:
    """Heading of a rotation's x axis in the xy plane."""
    return jnp.arctan2(mat[1, 0], mat[0, 0])


def wrap_angle(a: jax.Array, period: float = 2 * np.pi) -> jax.Array:
    """Wrap to [-period/2, period/2)."""
    return (a + period / 2) % period - period / 2


# ----------------------------------------------------------------------------------------------------
# Rendering (host side, numpy; not jitted)
# ----------------------------------------------------------------------------------------------------

class FrameRenderer:
    """Offscreen RGB frames of a model: ``FrameRenderer(m)(mj_data, width, height, camera)``.

    Uses ``mujoco.Renderer`` when MuJoCo can make its own context (``MUJOCO_GL`` = egl/osmesa when
    ``mujoco`` was imported, or a display). Otherwise (the usual headless case: ``mujoco`` imported
    before anybody set ``MUJOCO_GL``) it creates an EGL context by hand and renders with the low-level
    ``mjr_*`` API. Without any OpenGL it falls back to a top + side projection of the boxes drawn with numpy.
    """

    def __init__(self, m: mujoco.MjModel):
        self.m = m
        self._cache = None  # ((width, height), renderer, gl context or None)

    def __call__(self, d: mujoco.MjData, width: int = 320, height: int = 240, camera: str = "side") -> np.ndarray:
        try:
            rend, ctx = self._get(width, height)
        except Exception:  # no OpenGL at all
            return _render_boxes(self.m, d, width, height)
        if ctx is not None:
            ctx.make_current()
        rend.update_scene(d, camera=camera)
        return np.asarray(rend.render(), np.uint8)

    def _get(self, width: int, height: int):
        if self._cache is None or self._cache[0] != (width, height):
            if _default_gl_usable():
                rend, ctx = mujoco.Renderer(self.m, height, width), None
            else:
                from mujoco.egl import GLContext
                ctx = GLContext(width, height)
                ctx.make_current()
                rend = _LowLevelRenderer(self.m, width, height)
            self._cache = ((width, height), rend, ctx)
        return self._cache[1], self._cache[2]


def _default_gl_usable() -> bool:
    """Whether ``mujoco.Renderer`` can make its own context (EGL/OSMesa chosen, or a display present)."""
    import os
    from mujoco.rendering.classic import gl_context
    backend = getattr(gl_context, "_MUJOCO_GL", "")
    return backend in ("egl", "osmesa") or bool(os.environ.get("DISPLAY"))


class _LowLevelRenderer:
    """Minimal offscreen renderer on an already-current GL context."""

    def __init__(self, m: mujoco.MjModel, width: int, height: int):
        self.m, self.w, self.h = m, width, height
        self.scene = mujoco.MjvScene(m, maxgeom=1000)
        self.opt = mujoco.MjvOption()
        self.cam = mujoco.MjvCamera()
        self.con = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.con)
        self.rect = mujoco.MjrRect(0, 0, width, height)

    def update_scene(self, d: mujoco.MjData, camera: str):
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.cam.fixedcamid = mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        mujoco.mjv_updateScene(self.m, d, self.opt, None, self.cam, mujoco.mjtCatBit.mjCAT_ALL, self.scene)

    def render(self) -> np.ndarray:
        mujoco.mjr_render(self.rect, self.scene, self.con)
        img = np.empty((self.h, self.w, 3), np.uint8)
        mujoco.mjr_readPixels(img, None, self.rect, self.con)
        return img[::-1]


def _render_boxes(m: mujoco.MjModel, d: mujoco.MjData, width: int, height: int) -> np.ndarray:
    """Fallback without OpenGL: top (x-y) and side (y-z) projections of the bodies' box geoms, each box's projected
    bounding rectangle filled in its colour (lower boxes first), drawn with numpy in about a millisecond (so that
    `cogail play` and `cogail collect` keep their step rate on a machine without OpenGL)."""
    img = np.full((height, width, 3), 255, np.uint8)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    boxes = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX and m.geom_bodyid[g] != 0]
    pts = {g: d.geom_xpos[g] + (corners * m.geom_size[g]) @ d.geom_xmat[g].reshape(3, 3).T for g in boxes}
    half = width // 2
    # panel: (projected axes, limits, the axis drawn last-on-top)
    for p, ((i, j), (lo_i, hi_i), (lo_j, hi_j), depth) in enumerate((((0, 1), (-0.5, 0.5), (-0.5, 0.5), 2),
                                                                     ((1, 2), (-0.5, 0.5), (-0.05, 0.5), 0))):
        x0, w = p * half, half if p == 0 else width - half
        scale = min((w - 8) / (hi_i - lo_i), (height - 8) / (hi_j - lo_j))
        ox, oy = x0 + (w - scale * (hi_i - lo_i)) / 2, (height + scale * (hi_j - lo_j)) / 2
        img[int(oy - scale * (hi_j - lo_j)):int(oy) + 1, int(ox):int(ox + scale * (hi_i - lo_i)) + 1] = 240
        order = sorted(boxes, key=lambda g: pts[g][:, depth].max() * (1 if depth == 2 else -1))
        for g in order:
            lo, hi = pts[g][:, [i, j]].min(0), pts[g][:, [i, j]].max(0)
            c0, c1 = (int(np.clip(ox + scale * (v - lo_i), x0, x0 + w)) for v in (lo[0], hi[0]))
            r0, r1 = (int(np.clip(oy - scale * (v - lo_j), 0, height)) for v in (hi[1], lo[1]))
            img[r0:max(r1, r0 + 1), c0:max(c1, c0 + 1)] = (np.asarray(m.geom_rgba[g][:3]) * 255).astype(np.uint8)
    img[:, half - 1:half + 1] = 128
    return img
