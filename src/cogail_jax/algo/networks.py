"""The networks of the paper's appendix (flax.linen): co-policy actor and critic, psi, discriminator."""
from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


class MLP(nn.Module):
    hidden: Sequence[int]
    out: int
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x):
        act = {"tanh": nn.tanh, "relu": nn.relu}[self.activation]
        for h in self.hidden:
            x = act(nn.Dense(h)(x))
        return nn.Dense(self.out)(x)


class Actor(nn.Module):
    """Co-policy pi_co(a_H, a_R | s, z): 4 x 128 MLP -> per action dimension a Gaussian mean (state-independent log
    std) or, for a discrete agent, a logit of its choices (``actions``)."""

    action_size: int
    init_log_std: float = -0.5
    human_size: int = 0  # > 0: separate human and robot towers (``separate_towers``; BC-GAIL freezes the human one)

    @nn.compact
    def __call__(self, obs, z):
        x = jnp.concatenate([obs, z], -1)
        if self.human_size:
            mean = jnp.concatenate([MLP((128,) * 4, self.human_size, name="human")(x),
                                    MLP((128,) * 4, self.action_size - self.human_size, name="robot")(x)], -1)
        else:
            mean = MLP((128,) * 4, self.action_size)(x)
        log_std = self.param("log_std", nn.initializers.constant(self.init_log_std), (self.action_size,))
        return mean, jnp.broadcast_to(log_std, mean.shape)


class Critic(nn.Module):
    """Value V(s, z): 4 x 128 MLP -> 1."""

    @nn.compact
    def __call__(self, obs, z):
        return MLP((128,) * 4, 1)(jnp.concatenate([obs, z], -1))[..., 0]


class Psi(nn.Module):
    """Strategy recognition psi(z | s_{t-K..t}, a^H_{t-1}): 2-layer MLP -> code_dim, tanh."""

    code_dim: int = 2

    @nn.compact
    def __call__(self, h):
        return nn.tanh(MLP((128,), self.code_dim)(h))


class Discriminator(nn.Module):
    """D(s, a_H, a_R): (64, 64, 1); tanh on the output for LSGAN (targets +-1), raw logit for BCE."""

    squash: bool = True

    @nn.compact
    def __call__(self, x):
        d = MLP((64, 64), 1)(x)[..., 0]
        return jnp.tanh(d) if self.squash else d


def disc_kind(cfg, env) -> str:
    """The discriminator's loss: the config's, or with "auto" the task's (its ``default_config()``, else lsgan)."""
    from .config import task_default

    return task_default(cfg.task, "disc_loss", "lsgan") if cfg.disc_loss == "auto" else cfg.disc_loss


def make_networks(cfg, env) -> dict[str, nn.Module]:
    """The four networks of a run (BC-GAIL's actor has separate human and robot towers)."""
    return {
        "actor": Actor(env.action_size, cfg.init_log_std, env.human_action_size if cfg.two_towers else 0),
        "critic": Critic(),
        "psi": Psi(cfg.code_dim),
        "disc": Discriminator(squash=disc_kind(cfg, env) == "lsgan"),
    }


def normalize(norm: dict, x):
    """Observations standardised by the demonstrations' mean and std."""
    return (x - norm["mean"]) / norm["std"]


MOTION_CLIP = 5.0


def policy_input(norm: dict, hist, back: int = 0):
    """What the actor, the critic and the discriminator read (the last beside the actions) at the step ``back``
    steps before the last of ``hist`` (..., K + 1, D raw observations, the last the current one): the normalised
    observation and, where the normaliser has ``motion_std`` (config ``motion``), its change since the step before
    in units of the demonstrations' per-step change, clipped to +-``MOTION_CLIP`` (a history starts as copies of the
    first observation: no change; a feature that jumps, a flag or a wrapped angle, or a policy's wild step, stays in
    range)."""
    t = hist.shape[-2] - 1 - back
    x = normalize(norm, hist[..., t, :])
    if "motion_std" not in norm:
        return x
    change = (hist[..., t, :] - hist[..., max(t - 1, 0), :]) / norm["motion_std"]
    return jnp.concatenate([x, jnp.clip(change, -MOTION_CLIP, MOTION_CLIP)], -1)


def history_input(norm: dict, hist):
    """psi's history input: (..., K+1, D) raw observations -> (..., (K+1) D) normalised."""
    h = normalize(norm, hist)
    return h.reshape(*h.shape[:-2], h.shape[-2] * h.shape[-1])


def gaussian_log_prob(mean, log_std, x):
    var = jnp.exp(2 * log_std)
    return jnp.sum(-0.5 * ((x - mean) ** 2) / var - log_std - 0.5 * jnp.log(2 * jnp.pi), axis=-1)


def gaussian_entropy(log_std):
    return jnp.sum(log_std + 0.5 * jnp.log(2 * jnp.pi * jnp.e), axis=-1)


__all__ = ["Actor", "Critic", "Psi", "Discriminator", "make_networks", "disc_kind", "normalize", "policy_input",
           "history_input", "gaussian_log_prob", "gaussian_entropy", "jax"]
