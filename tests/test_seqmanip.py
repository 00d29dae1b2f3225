"""HR-SeqManip (MJX) on CPU, tiny sizes: one jitted, vmapped rollout of 8 episodes serves most tests."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cogail_envs import mjx_common as mc
from cogail_envs import get_task
from cogail_envs.seqmanip.env import CUE_Y, TRAVEL, SeqManip
from cogail_envs.seqmanip.team import H_CARRY_WAIT, H_WAIT_OPEN, R_WAIT

TEAM = get_task("seqmanip").team

REPEATS = 3  # scripted episodes per strategy
RELEASE_AT = 300  # step at which the "drop" episode opens the human's gripper


@pytest.fixture(scope="module")
def env():
    return SeqManip()


@pytest.fixture(scope="module")
def jitted(env):
    """``reset_from`` and ``step`` jitted once for the whole module (an MJX compile costs ~30 s on CPU)."""
    return jax.jit(env.reset_from), jax.jit(env.step)


@pytest.fixture(scope="module")
def rollout(env):
    """8 episodes in one call: 3 scripted per strategy, one where nobody acts (all-zero actions), and one
    "robot-opens" episode with an idle robot where the human's gripper is forced open at RELEASE_AT.

    Returns the intended strategy, final metrics (frozen at the step that ended the episode), the label,
    per-step traces, and the reset parameters with the first observation.
    """
    T = env.max_episode_steps

    def one(rng, mix, human_on, robot_on, release_at):
        k0, k1, k2 = jax.random.split(rng, 3)
        init = env.sample_init(k0)
        state = env.reset_from(init)
        ts, sid = TEAM.init(env, k1, mix)

        def body(carry, key):
            state, ts, finished, metrics = carry
            ts, a = TEAM.act(env, ts, state, key)
            a = a.at[:7].multiply(human_on).at[7:].multiply(robot_on)  # idle agent: all-zero action
            a = a.at[6].set(jnp.where(state.info["t"] >= release_at, 1.0, a[6]))  # forced human release
            nxt = env.step(state, a)
            new_state = jax.tree.map(lambda o, n: jnp.where(finished, o, n), state, nxt)
            new_metrics = jax.tree.map(lambda o, n: jnp.where(finished, o, n), metrics, nxt.metrics)
            trace = dict(z=env._obj_pos(nxt.pipeline_state)[2], success=nxt.metrics["success"],
                         done=nxt.done, finished=finished, phase_h=ts.phase[0], phase_r=ts.phase[1],
                         human_y=mc.tcp_pos(state.pipeline_state, env.human)[1],
                         opening=env._opening(nxt.pipeline_state),
                         wait=env.replay_hold(state, a[:7])[0], r_grasp=state.info["robot_grasp"])
            return (new_state, ts, finished | (nxt.done > 0), new_metrics), trace

        carry = (state, ts, jnp.array(False), state.metrics)
        (_, _, _, metrics), trace = jax.lax.scan(body, carry, jax.random.split(k2, T))
        return sid, metrics, env.classify_strategy(metrics), trace, (init, state.obs)

    n_team = 2 * REPEATS
    mix = np.zeros((n_team + 2, 2), np.float32)
    mix[np.arange(n_team), np.repeat(np.arange(2), REPEATS)] = 1.0
    mix[n_team:, 1] = 1.0
    human_on = np.array([1.0] * n_team + [0.0, 1.0], np.float32)
    robot_on = np.array([1.0] * n_team + [0.0, 0.0], np.float32)
    release = np.array([10**6] * (n_team + 1) + [RELEASE_AT], np.int32)
    rngs = jax.random.split(jax.random.PRNGKey(11), n_team + 2)
    out = jax.jit(jax.vmap(one))(rngs, jnp.asarray(mix), jnp.asarray(human_on), jnp.asarray(robot_on),
                                 jnp.asarray(release))
    return jax.device_get(out)




def test_reset_from_reproduces_the_start(env, jitted, rollout):
    init, obs0 = rollout[-1]
    assert init.shape == (8, env.init_size)
    s = jitted[0](init[0])  # outside the rollout's jit, unbatched
    np.testing.assert_allclose(np.asarray(s.obs), obs0[0], atol=1e-5)
    assert not np.allclose(obs0[0], obs0[1])  # the init vector matters


def test_scripted_team_succeeds_with_each_strategy(rollout):
    sid, metrics, cls, trace, _ = rollout
    n = 2 * REPEATS
    np.testing.assert_array_equal(sid[:n], np.repeat([1, 2], REPEATS))
    assert np.all(metrics["success"][:n] == 1.0)
    np.testing.assert_array_equal(cls[:n], sid[:n])
    # who opened / put the object in / closed: human = 1, robot = 2
    np.testing.assert_array_equal(metrics["opened_by"][:n], sid[:n])
    np.testing.assert_array_equal(metrics["closed_by"][:n], sid[:n])
    np.testing.assert_array_equal(metrics["placed_by"][:n], 3 - sid[:n])
    np.testing.assert_array_equal(metrics["handover"][:n], (sid[:n] == 1).astype(np.float32))
    assert np.all(metrics["max_open"][:n] > 0.1)
    length = (~trace["finished"][:n]).sum(1)
    assert np.all((length > 250) & (length < 600))
    assert np.all(trace["opening"][:n].max(1) <= TRAVEL + 1e-3)


def test_scripted_robot_waits_for_a_cue_it_can_see(rollout):
    """The scripted robot leaves its waiting phase only once the strategy shows in the state: human-hands-over,
    the human's hand (carrying the bar) is past CUE_Y towards the robot; robot-opens, the human has reached
    its waiting point by the drawer. A robot that moved on the human's lift would fail this."""
    sid, _, _, trace, _ = rollout
    for i in range(2 * REPEATS):
        start = int(np.argmax(trace["phase_r"][i] != R_WAIT))
        assert start > 0, "the robot never left its waiting phase"
        if sid[i] == 1:
            assert trace["human_y"][i, start] > CUE_Y
            assert np.all(trace["human_y"][i, :start - 20] < CUE_Y + 0.02)  # it did wait for the human
        else:
            assert trace["phase_h"][i, start] in (H_CARRY_WAIT, H_WAIT_OPEN)
            assert trace["human_y"][i, start] < CUE_Y - 0.01  # the human stays on its side


def test_nothing_done_never_succeeds(rollout):
    _, metrics, cls, trace, _ = rollout
    i = 2 * REPEATS
    assert trace["success"][i].max() == 0.0 and cls[i] == 0
    assert trace["done"][i, -1] == 1.0 and trace["done"][i, :-1].max() == 0.0  # time limit only
    assert trace["opening"][i].max() < 1e-3 and abs(trace["z"][i, -1] - 0.015) < 2e-3


def test_idle_robot_never_succeeds(rollout):
    _, metrics, cls, trace, _ = rollout
    i = -1
    assert trace["success"][i].max() == 0.0 and cls[i] == 0
    assert trace["done"][i, -1] == 1.0 and trace["done"][i, :-1].max() == 0.0
    assert trace["opening"][i].max() < 1e-3  # nobody opened the drawer


def test_object_falls_when_released(rollout):
    _, _, _, trace, _ = rollout
    z = trace["z"][-1]
    assert trace["phase_h"][-1, RELEASE_AT - 1] == H_WAIT_OPEN  # holding it up, waiting for the drawer
    assert z[RELEASE_AT - 1] > 0.10
    assert z[-1] < 0.02  # on the table


def test_classify_strategy(env):
    m = {"success": jnp.array([1.0, 1.0, 1.0, 0.0, 1.0]),
         "opened_by": jnp.array([1.0, 2.0, 1.0, 1.0, 3.0]),
         "placed_by": jnp.array([2.0, 1.0, 1.0, 2.0, 2.0])}
    np.testing.assert_array_equal(np.asarray(env.classify_strategy(m)), [1, 2, 0, 0, 0])






def test_a_patient_human_holds_on_at_a_handover_only(rollout, env):
    """``replay_hold``: the human waits instead of opening its gripper only while it holds the object out and the
    robot does not hold it: never in the scripted team's episodes before the robot grasps, never when it drops the
    object into the drawer (robot-opens), and at a forced release away from the drawer with nobody taking it."""
    sid, _, _, trace, _ = rollout
    n = 2 * REPEATS
    wait, grasped = trace["wait"], np.maximum.accumulate(trace["r_grasp"] > 0, axis=1)
    assert env.has_patient_replay
    assert not (wait[:n] & ~grasped[:n]).any()
    assert not wait[:n][np.asarray(sid[:n]) == 2].any()  # robot-opens: the human's release is the drop
    assert wait[-1, RELEASE_AT] and not wait[-1, :RELEASE_AT].any()


def test_the_dropper_turns_the_bar_back_only_beyond_what_the_drawer_takes():
    from types import SimpleNamespace

    from cogail_envs.seqmanip.team import DROP_FITS, _drop_yaw

    ts = SimpleNamespace(drop=jnp.array([0.05, 0.0, 0.02, 0.1]))  # this episode's bound: DROP_FITS + 0.05
    bound = DROP_FITS + 0.05
    held = jnp.array([0.2, -0.3, 0.9, -1.0, np.pi - 0.1])  # the last: the same bar, half a turn round
    got = np.asarray(jax.vmap(lambda y: _drop_yaw({"yaw": jnp.stack([y, y])}, ts, 1))(held))
    np.testing.assert_allclose(got[:, 2], [0.2, -0.3, bound, -bound, -0.1], atol=1e-6)
    assert not got[:, :2].any()  # and levelled: a tilted or twisted bar is dropped flat
    # an env's own bound (a training split's team that turns every bar back further) is the droppers' bound
    got = np.asarray(jax.vmap(lambda y: _drop_yaw({"yaw": jnp.stack([y, y]), "drop_fits": 0.1}, ts, 0))(held))
    np.testing.assert_allclose(got[:, 2], [0.15, -0.15, 0.15, -0.15, -0.1], atol=1e-6)


def test_an_env_s_drop_bound_reaches_the_team_and_names_its_own_data():
    import cogail_envs
    from cogail_envs.seqmanip import team

    plain, bound = cogail_envs.make_env("seqmanip"), cogail_envs.make_env("seqmanip", drop_yaw_bound=0.1)
    assert plain.drop_yaw_bound is None and bound.drop_yaw_bound == 0.1
    assert plain.version != bound.version  # a split made with it is another dataset
    for env, want in ((plain, team.DROP_FITS), (bound, 0.1)):
        seen = []  # what the team's context reads, traced only (running MJX's reset eagerly takes half a minute)

        def context(key, env=env, seen=seen):
            ts, _ = team.team_init(env, key, env.uniform_mix(), 0)
            seen.append(team._context(env, ts, env.reset_from(env.sample_init(key)))["drop_fits"])
            return key

        jax.eval_shape(context, jax.random.PRNGKey(0))
        assert seen == [want]
