"""HR-Handover (MJX) on CPU, tiny sizes: one jitted, vmapped rollout of 10 episodes serves most tests."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cogail_envs import mjx_common as mc
from cogail_envs import get_task
from cogail_envs.handover.env import Handover
from cogail_envs.handover.team import H_HOLD, TILT_RANGE
from cogail_envs.variations import pose_slice

TEAM = get_task("handover").team

REPEATS = 2  # scripted episodes per region
RELEASE_AT = 200  # step at which the "drop" episode opens the human's gripper


@pytest.fixture(scope="module")
def env():
    return Handover()


@pytest.fixture(scope="module")
def rollout(env):
    """10 episodes in one call: 2 scripted per region, 2 scripted with the bar presented twisted (roll) and tilted
    (pitch) beyond the training range (the held-out slices), then 2 with an idle robot (one drops the bar).

    Returns final metrics (frozen at the step that ended the episode) and per-step traces.
    """
    T = env.max_episode_steps

    def one(rng, mix, robot_on, release_at, variation):
        k0, k1, k2 = jax.random.split(rng, 3)
        state = env.reset(k0)
        ts, sid = TEAM.init(env, k1, mix, variation)

        def body(carry, key):
            state, ts, finished, metrics = carry
            ts, a = TEAM.act(env, ts, state, key)
            a = a.at[7:].multiply(robot_on)  # idle robot: all-zero action
            a = a.at[6].set(jnp.where(state.info["t"] >= release_at, 1.0, a[6]))  # forced human release
            nxt = env.step(state, a)
            new_state = jax.tree.map(lambda o, n: jnp.where(finished, o, n), state, nxt)
            new_metrics = jax.tree.map(lambda o, n: jnp.where(finished, o, n), metrics, nxt.metrics)
            trace = dict(z=env._obj_pos(nxt.pipeline_state)[2], success=nxt.metrics["success"],
                         done=nxt.done, finished=finished, phase_h=ts.phase[0],
                         wait=env.replay_hold(state, a[:7])[0], r_grasp=state.info["robot_grasp"],
                         tilt=jnp.arccos(mc.bar_normal(env._obj_mat(nxt.pipeline_state))[2]))
            return (new_state, ts, finished | (nxt.done > 0), new_metrics), trace

        carry = (state, ts, jnp.array(False), state.metrics)
        (_, _, _, metrics), trace = jax.lax.scan(body, carry, jax.random.split(k2, T))
        return sid, metrics, env.classify_strategy(metrics), trace

    n_team = 3 * REPEATS
    mix = np.zeros((n_team + 4, 3), np.float32)
    mix[np.arange(n_team), np.repeat(np.arange(3), REPEATS)] = 1.0
    mix[n_team:] = 1.0 / 3
    robot_on = np.array([1.0] * (n_team + 2) + [0.0, 0.0], np.float32)
    release = np.array([10**6] * (n_team + 3) + [RELEASE_AT], np.int32)
    variation = np.array([0] * n_team + [pose_slice("roll"), pose_slice("pitch"), 0, 0], np.int32)
    rngs = jax.random.split(jax.random.PRNGKey(7), n_team + 4)
    out = jax.jit(jax.vmap(one))(rngs, jnp.asarray(mix), jnp.asarray(robot_on), jnp.asarray(release),
                                 jnp.asarray(variation))
    return jax.device_get(out)


@pytest.fixture(scope="module")
def first(env):
    """One jitted call: reset(rng); three single steps (one compiled step, ``lax.map`` over the inputs): from
    the reset state with an out-of-range action, from it with zero action, and from it with the bar thrown at
    1e4 m/s (a diverging simulation). (The eager MJX reset and a separately jitted step the divergence test once
    used cost ~75 s on CPU; the time limit is the env contract's, tests/test_tasks.py.)"""

    def f(rng):
        s0 = env.reset(rng)
        d = s0.pipeline_state
        bad = s0.replace(pipeline_state=d.replace(qvel=d.qvel.at[:].set(1e4)))
        states = jax.tree.map(lambda *x: jnp.stack(x), s0, s0, bad)
        zero = jnp.zeros(env.action_size)
        actions = jnp.stack([zero.at[0].set(5.0), zero, zero])  # 5.0: clipped to 1 cm
        steps = jax.lax.map(lambda sa: env.step(*sa), (states, actions))
        s1, ok, diverged = (jax.tree.map(lambda x, i=i: x[i], steps) for i in range(3))
        return s0, s1, ok, diverged

    return jax.device_get(jax.jit(f)(jax.random.PRNGKey(3)))


def test_reset_step_shapes(env, first):
    s, s2 = first[:2]
    assert env.action_size == 14 and env.human_action_size == env.robot_action_size == 7
    assert s.obs.shape == (env.observation_size,) and s.obs.dtype == np.float32
    assert set(s.metrics) >= {"success", "handover", "handover_x", "handover_y", "handover_z"}
    assert s2.obs.shape == s.obs.shape and np.shape(s2.reward) == () and np.shape(s2.done) == ()
    assert int(s2.info["t"]) == 1 and float(s2.done) == 0.0
    moved = float(s2.pipeline_state.ctrl[0] - s.pipeline_state.ctrl[0])
    assert abs(moved - mc.POS_SCALE) < 1e-6
    assert np.all(np.isfinite(s2.obs))




def test_scripted_team_succeeds_in_each_region(rollout):
    sid, metrics, cls, trace = rollout
    n = 3 * REPEATS
    np.testing.assert_array_equal(sid[:n], np.repeat([1, 2, 3], REPEATS))
    assert np.all(metrics["success"][:n] == 1.0)
    assert np.all(metrics["handover"][:n] == 1.0)
    np.testing.assert_array_equal(cls[:n], sid[:n])
    length = (~trace["finished"][:n]).sum(1)
    assert np.all((length > 100) & (length < 300))


def test_scripted_robot_takes_a_bar_twisted_or_tilted_beyond_the_training_range(rollout):
    """The held-out roll and pitch slices: the human presents the bar turned about a horizontal axis by more than
    any training episode, and the scripted robot, aligning its gripper with the bar about all three axes, takes it
    (a robot that turned only about the vertical would close its fingers on the bar's edges)."""
    sid, metrics, cls, trace = rollout
    n = 3 * REPEATS
    for i in (n, n + 1):
        held = trace["tilt"][i][~trace["finished"][i]]
        assert held.max() > TILT_RANGE[1] + 0.01, i  # presented beyond the range
        assert metrics["success"][i] == 1.0 and cls[i] == sid[i], i


def test_object_falls_when_released_in_the_air(rollout):
    _, metrics, cls, trace = rollout
    z = trace["z"][-1]
    assert trace["phase_h"][-1, RELEASE_AT - 1] == H_HOLD  # the human was holding it still at the spot
    assert z[RELEASE_AT - 1] > 0.10
    assert z[-1] < 0.02  # on the table
    assert metrics["success"][-1] == 0.0 and cls[-1] == 0


def test_idle_robot_never_succeeds(rollout, env):
    _, metrics, cls, trace = rollout
    for i in (-2, -1):
        assert trace["success"][i].max() == 0.0
        assert cls[i] == 0
        assert trace["done"][i, -1] == 1.0 and trace["done"][i, :-1].max() == 0.0  # time limit only
    assert trace["z"][-2, -1] > 0.10  # the human still holds the bar out, waiting


def test_classify_strategy_thresholds(env):
    m = {k: jnp.zeros(4) for k in ("handover_y", "handover_z")}
    m["handover_x"] = jnp.array([-0.2, 0.0, 0.2, 0.2])
    m["success"] = jnp.array([1.0, 1.0, 1.0, 0.0])
    m["handover"] = jnp.ones(4)
    np.testing.assert_array_equal(np.asarray(env.classify_strategy(m)), [1, 2, 3, 0])




def test_diverged_physics_step_ends_the_episode_with_finite_state(env, first):
    """A step whose simulation diverges (here: the bar thrown at 1e4 m/s) keeps the previous state, reports
    ``failed`` and ends the episode, so no NaN or exploding observation reaches the trainer."""
    s, ok, nxt = first[0], first[2], first[3]  # the steps from reset with zero action, and with the bar thrown
    assert float(ok.info["failed"]) == 0.0 and float(ok.done) == 0.0
    assert float(nxt.info["failed"]) == 1.0 and float(nxt.done) == 1.0
    assert float(nxt.info["truncation"]) == 0.0  # a failure, not a time limit: the trainer does not bootstrap it
    assert np.all(np.isfinite(np.asarray(nxt.obs)))
    np.testing.assert_array_equal(np.asarray(nxt.pipeline_state.qpos), np.asarray(s.pipeline_state.qpos))


def test_a_patient_human_holds_on_until_the_robot_has_the_bar(rollout, env):
    """``replay_hold``: a replayed human about to open its gripper while it holds the bar that the robot has not
    taken waits instead (still, gripper closed); the scripted team's human never waits before the robot grasps."""
    _, _, _, trace = rollout
    assert env.has_patient_replay
    wait, grasped = trace["wait"], np.maximum.accumulate(trace["r_grasp"] > 0, axis=1)
    assert wait[-1, RELEASE_AT] and not wait[-1, :RELEASE_AT].any()  # the forced release with nobody taking the bar
    assert not (wait[: 3 * REPEATS] & ~grasped[: 3 * REPEATS]).any()
    hold, a_wait = env.replay_hold(jax.tree.map(lambda x: x, env.reset(jax.random.PRNGKey(0))), jnp.ones(7))
    assert not bool(hold) and float(a_wait[6]) == -1.0 and not np.asarray(a_wait[:6]).any()
