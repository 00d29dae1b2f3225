"""Robot actions in the object's frame (``TrainConfig.action_frame = "object"``; our addition, off by default).

The MJX tasks' robot moves its gripper by deltas in its own base frame: the same reach for a bar turned another way
is another action, so a policy that learned the demonstrations' poses must also learn every pose's actions. With
``action_frame = "object"`` the co-policy's robot action ``(dx, dy, dz, drx, dry, drz, g)`` is read in the frame of
the object (the env's ``robot_action_frame(obs)``: a rotation, object frame -> the robot's base frame, from the
observation alone): its translation and its rotation rates are both turned by it before the env takes them, and the
gripper command is left as it is. "Move along the bar, come down onto it, turn about its long axis" is then one
action however the bar is turned. The demonstrations' robot actions are turned the other way once, when the training
arrays are made (:func:`expert_to_policy`), so every loss (BC, L_a, the discriminator's expert pairs) compares actions
in the same frame; the env wrapper (:class:`ObjectFrameActions`) turns the policy's actions at every step of training
rollouts, replay, co-play, play and video alike. The data files keep the env's own actions.

A frame change is exact (the rotation is orthonormal) except where a turned action leaves the [-1, 1] box: the env
clips it (the scripted robot's translations, at most 0.9 long, never do; its rotation rates, each up to 0.9, rarely).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

ACTION_FRAMES = ("base", "object")


class ActionFrameError(ValueError):
    """An ``action_frame`` the task cannot give; the message names it and the fix."""


def supports(env) -> bool:
    """Whether ``env`` can read its robot's actions in the object's frame (``robot_action_frame``, a 7-dim robot
    action: three translations, three rotation rates, the gripper)."""
    return callable(getattr(env, "robot_action_frame", None)) and int(env.robot_action_size) == 7


def check(cfg, env) -> None:
    if cfg.action_frame == "object" and not supports(env):
        raise ActionFrameError(f"task {env.name} has no object frame for its robot's actions: train it with "
                               "--set action_frame=base")


def _turn(R, a, inverse: bool):
    """``a`` (..., 7) with its translation and rotation parts turned by ``R`` (..., 3, 3) (``inverse``: by R^T)."""
    eq = "...ji,...j->...i" if inverse else "...ij,...j->...i"
    return jnp.concatenate([jnp.einsum(eq, R, a[..., 0:3]), jnp.einsum(eq, R, a[..., 3:6]), a[..., 6:]], -1)


def to_env(env, obs, a_r):
    """The env's robot action for the policy's object-frame action ``a_r`` at observation ``obs`` (clipped)."""
    return jnp.clip(_turn(env.robot_action_frame(obs), a_r, False), -1.0, 1.0)


def to_policy(env, obs, a_r):
    """The object-frame action of the env's robot action ``a_r`` at observation ``obs``."""
    return _turn(env.robot_action_frame(obs), a_r, True)


def expert_to_policy(expert: dict, env) -> dict:
    """The training arrays (``train.expert_arrays``) with the robot's actions in the object's frame (rows past
    ``count`` stay zero)."""
    n = int(expert["count"])
    ar = np.array(expert["ar"], np.float32, copy=True)
    if n:
        ar[:n] = np.asarray(jax.jit(lambda o, a: to_policy(env, o, a))(jnp.asarray(expert["obs"][:n]),
                                                                        jnp.asarray(ar[:n])))
    return {**expert, "ar": ar}


class ObjectFrameActions:
    """``env`` whose ``step`` takes the robot's part of the action in the object's frame (:func:`to_env`, at the
    state's observation); everything else is the env's own (``version`` too: the data files are the env's)."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def step(self, state, action):
        Ah = self.env.human_action_size
        a_r = to_env(self.env, state.obs, action[..., Ah:])
        return self.env.step(state, jnp.concatenate([action[..., :Ah], a_r], -1))

    def policy_robot_action(self, obs, a_r):
        """A robot action in the env's frame (e.g. the scripted robot's) as this env's ``step`` takes it."""
        return to_policy(self.env, obs, a_r)


def wrap(cfg, env):
    """``env`` as ``cfg``'s policy acts in it (``action_frame``)."""
    check(cfg, env)
    return ObjectFrameActions(env) if cfg.action_frame == "object" else env


__all__ = ["ACTION_FRAMES", "ActionFrameError", "supports", "check", "to_env", "to_policy", "expert_to_policy",
           "ObjectFrameActions", "wrap"]
