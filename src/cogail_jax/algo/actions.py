"""The co-policy's action distribution, per agent: a Gaussian over a box in [-1, 1]^n, or a categorical over n
discrete choices (a task says which with ``human_action_discrete`` / ``robot_action_discrete``).

The actor's output ``mean`` has one entry per action dimension either way: for a continuous agent its Gaussian
mean (the std from ``log_std``), for a discrete agent the logits of its choices. A discrete action travels as a
one-hot vector everywhere (the env's ``step``, demonstration files, the discriminator's input, psi's previous human
action), so the rest of the trainer handles both kinds alike. Where every agent is continuous these functions are
exactly the Gaussian ones (the same operations, hence the same bits as before discrete actions existed).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .networks import gaussian_entropy, gaussian_log_prob


class ActionSpec(NamedTuple):
    """The action vector's two parts, ``concat(a_H, a_R)``: their sizes and whether each is discrete."""

    human_size: int
    robot_size: int
    human_discrete: bool = False
    robot_discrete: bool = False

    @property
    def continuous(self) -> bool:
        return not (self.human_discrete or self.robot_discrete)

    @property
    def segments(self) -> tuple[tuple[int, int, bool], ...]:
        """``(start, size, discrete)`` of each agent's part."""
        return ((0, self.human_size, self.human_discrete), (self.human_size, self.robot_size, self.robot_discrete))


def spec_of(env) -> ActionSpec:
    return ActionSpec(int(env.human_action_size), int(env.robot_action_size),
                      bool(getattr(env, "human_action_discrete", False)), bool(getattr(env, "robot_action_discrete", False)))


def _split(spec: ActionSpec, x):
    return [(x[..., s:s + n], d) for s, n, d in spec.segments]


def sample(spec: ActionSpec, mean, log_std, key):
    """A sampled action ``a`` (what the log-probability is of) and the executed one (the Gaussian part clipped to
    [-1, 1]; a discrete part is its one-hot sample either way)."""
    noise = jax.random.normal(key, mean.shape)
    a = mean + jnp.exp(log_std) * noise
    if spec.continuous:
        return a, jnp.clip(a, -1.0, 1.0)
    parts = []
    for i, (s, n, d) in enumerate(spec.segments):
        if d:
            choice = jax.random.categorical(jax.random.fold_in(key, i + 1), mean[..., s:s + n])
            parts.append(jax.nn.one_hot(choice, n, dtype=mean.dtype))
        else:
            parts.append(a[..., s:s + n])
    a = jnp.concatenate(parts, -1)
    return a, clip_continuous(spec, a)


def clip_continuous(spec: ActionSpec, a):
    """``a`` with its continuous parts clipped to [-1, 1] (a one-hot part is left as it is)."""
    if spec.continuous:
        return jnp.clip(a, -1.0, 1.0)
    return jnp.concatenate([x if d else jnp.clip(x, -1.0, 1.0) for x, d in _split(spec, a)], -1)


def log_prob(spec: ActionSpec, mean, log_std, a):
    """log pi(a): the Gaussian's over continuous parts plus the categorical's of each discrete part's one-hot ``a``."""
    if spec.continuous:
        return gaussian_log_prob(mean, log_std, a)
    total = 0.0
    for (s, n, d) in spec.segments:
        if d:
            total = total + jnp.sum(a[..., s:s + n] * jax.nn.log_softmax(mean[..., s:s + n]), -1)
        else:
            total = total + gaussian_log_prob(mean[..., s:s + n], log_std[..., s:s + n], a[..., s:s + n])
    return total


def entropy(spec: ActionSpec, mean, log_std):
    if spec.continuous:
        return gaussian_entropy(log_std)
    total = 0.0
    for (s, n, d) in spec.segments:
        if d:
            logp = jax.nn.log_softmax(mean[..., s:s + n])
            total = total + -jnp.sum(jnp.exp(logp) * logp, -1)
        else:
            total = total + gaussian_entropy(log_std[..., s:s + n])
    return total


def mode(spec: ActionSpec, mean):
    """The deterministic action: the Gaussian mean clipped to [-1, 1]; a discrete part's most likely choice, one-hot."""
    if spec.continuous:
        return jnp.clip(mean, -1.0, 1.0)
    return jnp.concatenate([jax.nn.one_hot(jnp.argmax(x, -1), x.shape[-1], dtype=x.dtype) if d
                            else jnp.clip(x, -1.0, 1.0) for x, d in _split(spec, mean)], -1)


def act(spec: ActionSpec, mean, key):
    """The action evaluation takes: a continuous part's clipped mean (deterministic, the paper's protocol), a
    discrete part's choice drawn from its categorical with ``key`` (a discrete policy's argmax is not the policy it
    was trained as: in Overcooked two argmax agents block each other for good, and the field's agents sample)."""
    if spec.continuous:
        return mode(spec, mean)
    parts = []
    for i, (s, n, d) in enumerate(spec.segments):
        x = mean[..., s:s + n]
        parts.append(agent_act(d, x, jax.random.fold_in(key, i)))
    return jnp.concatenate(parts, -1)


def agent_act(discrete: bool, mean, key):
    """One agent's part of :func:`act`."""
    if discrete:
        return jax.nn.one_hot(jax.random.categorical(key, mean), mean.shape[-1], dtype=mean.dtype)
    return jnp.clip(mean, -1.0, 1.0)


def agent_mode(discrete: bool, mean):
    """One agent's deterministic action from its part of the actor's output."""
    if discrete:
        return jax.nn.one_hot(jnp.argmax(mean, -1), mean.shape[-1], dtype=mean.dtype)
    return jnp.clip(mean, -1.0, 1.0)


def agent_expected(discrete: bool, mean):
    """One agent's expected action, differentiable: the Gaussian mean, or the categorical's probabilities (the
    expected one-hot vector). L_z feeds it to psi as the previous human action."""
    return jax.nn.softmax(mean, -1) if discrete else mean


def agent_error(discrete: bool, mean, target):
    """The per-step fitting error of one agent's output against expert actions ``target``: the squared error of a
    Gaussian mean (the paper's |pi - a|), or the cross-entropy -log pi(a) of a categorical (the negative
    log-likelihood of the expert's choice). Shape: the leading axes."""
    if discrete:
        return -jnp.sum(target * jax.nn.log_softmax(mean, -1), -1)
    return jnp.sum((mean - target) ** 2, -1)


def joint_error(spec: ActionSpec, mean, target):
    """``agent_error`` summed over both agents' parts of ``mean`` and ``target`` (both full action vectors)."""
    if spec.continuous:
        return jnp.sum((mean - target) ** 2, -1)
    return sum(agent_error(d, mean[..., s:s + n], target[..., s:s + n]) for s, n, d in spec.segments)


__all__ = ["ActionSpec", "spec_of", "sample", "clip_continuous", "log_prob", "entropy", "mode", "act", "agent_act",
           "agent_mode",
           "agent_expected", "agent_error", "joint_error"]
