"""Robot actions in the object's frame (``TrainConfig.action_frame``, ``algo.frames``): one action means the same move
relative to the bar however the bar is posed, the env takes it turned into the robot's base frame, and the
demonstrations' actions are turned the other way for training."""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import cogail_envs
from cogail_envs import mjx_common as mc

from cogail_jax.algo import frames
from cogail_jax.algo.config import ConfigError, TrainConfig


@pytest.fixture(scope="module")
def env():
    return cogail_envs.make_env("handover")


def _obs(env, roll, pitch, yaw):
    """An observation whose bar has orientation ``pose_mat(roll, pitch, yaw)`` (all the frame reads)."""
    return jnp.zeros(env.observation_size).at[24:30].set(mc.rot6d(mc.pose_mat(roll, pitch, yaw)))


def test_object_frame_actions_move_relative_to_the_bar(env):
    """Along the bar's long axis and along its normal, however the bar is turned (yaw beyond the training range,
    tilted, twisted), are the same two object-frame actions; the bar turned by half a turn gives the same frame; the
    env's action and the object-frame one map onto each other."""
    B = np.asarray(env.robot.base_mat).T
    for pose in [(0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.4, -0.3, -0.9), (-0.4, 0.4, 0.2)]:
        obs = _obs(env, *pose)
        R_obj = np.asarray(mc.pose_mat(*pose))
        along = np.asarray(frames.to_env(env, obs, jnp.array([0.0, 0.5, 0, 0, 0, 0, 1.0])))
        assert abs(abs(along[:3] @ (B @ R_obj[:, 1])) - 0.5) < 1e-5 and along[6] == 1.0, pose
        down = np.asarray(frames.to_env(env, obs, jnp.array([0.0, 0, -0.5, 0, 0, 0, 0])))
        np.testing.assert_allclose(down[:3], -0.5 * B @ mc.bar_normal(jnp.asarray(R_obj)), atol=1e-5)
        turned = obs.at[24:30].set(mc.rot6d(jnp.asarray(R_obj) @ mc.rot_z(np.pi)))  # the same bar, half a turn
        np.testing.assert_allclose(np.asarray(env.robot_action_frame(obs)), np.asarray(env.robot_action_frame(turned)),
                                   atol=1e-5)
        a = jnp.array([0.3, -0.2, 0.1, 0.2, -0.1, 0.05, -1.0])
        np.testing.assert_allclose(np.asarray(frames.to_env(env, obs, frames.to_policy(env, obs, a))), a, atol=1e-5)


def test_the_wrapper_turns_only_the_robots_action_and_the_demonstrations_the_other_way(env):
    """The wrapped env's ``step`` passes the human's action on as it is and the robot's turned into its base frame;
    the training arrays' robot actions are turned back row by row (padding rows stay zero), so the scripted robot's
    recorded action, turned and then taken by the wrapper, is the action the env recorded."""
    taken = []

    class Fake:
        name, human_action_size, robot_action_size = "fake", 7, 7
        robot_action_frame = staticmethod(env.robot_action_frame)

        def step(self, state, action):
            taken.append(np.asarray(action))
            return state

    class S:
        obs = _obs(env, 0.2, 0.1, 0.8)

    w = frames.ObjectFrameActions(Fake())
    a_h, a_r = np.linspace(-0.6, 0.6, 7), np.array([0.0, 0.4, 0.0, 0.0, 0.0, 0.3, -1.0])
    w.step(S(), jnp.concatenate([jnp.asarray(a_h), frames.to_policy(env, S.obs, a_r)]))
    np.testing.assert_allclose(taken[0][:7], a_h, atol=1e-6)
    np.testing.assert_allclose(taken[0][7:], a_r, atol=1e-5)
    obs = np.stack([np.asarray(S.obs), np.asarray(_obs(env, 0.0, 0.0, -0.5)), np.zeros(env.observation_size)])
    expert = {"obs": obs, "ar": np.stack([a_r, a_r, np.zeros(7)]).astype(np.float32), "count": np.int32(2)}
    out = frames.expert_to_policy(expert, env)
    for i in range(2):
        np.testing.assert_allclose(out["ar"][i], np.asarray(frames.to_policy(env, jnp.asarray(obs[i]), a_r)), atol=1e-5)
    assert not out["ar"][2].any() and not np.array_equal(out["ar"][0], out["ar"][1])
    assert frames.wrap(TrainConfig(task="handover"), env) is env  # the default: the task's own actions


def test_an_action_frame_the_task_cannot_give_is_one_sentence():
    with pytest.raises(ConfigError, match="action_frame must be base or object"):
        TrainConfig(task="handover", action_frame="world").validate()
    with pytest.raises(frames.ActionFrameError, match="fetchq has no object frame .* --set action_frame=base$"):
        frames.wrap(TrainConfig(task="fetchq", action_frame="object"), cogail_envs.make_env("fetchq"))
