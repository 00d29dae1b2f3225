"""The env batch split into ``env_shards`` shards, as data parallelism over devices.

Each shard rolls out ``num_envs / env_shards`` of a seed's environments and draws its share of every minibatch
(``inner_batch / env_shards`` generated and expert steps; a ``1 / env_shards`` share of each PPO minibatch) from
its own steps; the gradients of the discriminator, psi and PPO steps are averaged over the shards before the
optimizers use them (over the named axis ``AXIS``, as brax's PPO averages over devices with ``pmean``), as are
the return normaliser's batch moments, the advantage normalisation's and the logged metrics (gathered and
averaged in shard order: the same bits on any layout of the shards over devices and processes). Every shard thus
holds the same parameters after every step, and the run trains one policy on all of a seed's environments.

The shards are an axis of the algorithm, not of the hardware: ``AXIS`` is bound either by ``shard_map`` over a
mesh axis of that name (one shard per device, ``parallel.SeedChunk``) or, on one device, by ``jax.vmap`` with that
axis name (``train.make_train_fns``): both run the same arithmetic, up to the order of the averages' sums. With one
shard every function here is the identity and nothing is reduced: the one-device program is unchanged.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

AXIS = "envs"


def count(cfg) -> int:
    return cfg.env_shards


def local_envs(cfg) -> int:
    """The environments of one seed that one shard steps."""
    return cfg.num_envs // cfg.env_shards


def local_batch(cfg, n: int) -> int:
    """One shard's share of a minibatch of ``n`` steps."""
    return n // cfg.env_shards


def index(cfg):
    """This shard's index (0 with one shard)."""
    return 0 if cfg.env_shards == 1 else jax.lax.axis_index(AXIS)


def key(cfg, k):
    """``k`` made this shard's own (the shards sample different steps; ``k`` itself with one shard)."""
    return k if cfg.env_shards == 1 else jax.random.fold_in(k, jax.lax.axis_index(AXIS))


def mean(cfg, tree):
    """The mean over the shards of every leaf of ``tree`` (gradients, metrics): every shard's value gathered, then
    averaged in shard order, so that the result does not depend on how the shards lie on devices and processes
    (an all-reduce's summation order does: 2 processes x 2 devices differed from 4 devices of one process in the
    last bit)."""
    if cfg.env_shards == 1:
        return tree
    return jax.tree.map(lambda x: jax.lax.all_gather(x, AXIS).mean(0), tree)


def total(cfg, tree):
    """The sum over the shards of every leaf of ``tree`` (counts), in shard order as ``mean``."""
    if cfg.env_shards == 1:
        return tree
    return jax.tree.map(lambda x: jax.lax.all_gather(x, AXIS).sum(0), tree)


def moments(cfg, x):
    """Mean and variance of all shards' ``x`` together (each shard's ``x`` of the same size)."""
    if cfg.env_shards == 1:
        return x.mean(), x.var()
    m = mean(cfg, x.mean())
    return m, mean(cfg, jnp.mean((x - m) ** 2))
