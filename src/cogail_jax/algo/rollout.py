"""The rollout: ``num_envs`` environments stepped together for ``unroll_length`` steps in one ``lax.scan``.

Each episode has its own strategy code z, taken when it starts: the next cell of an n x n grid over
(-1, 1)^2 visited in cycle order, plus U[-noise, noise]. An env whose episode ends (success, failure or time
limit) restarts inside the scan with a fresh state and a new code. A time-out is recorded as a truncation
together with the episode's final observation, so that GAE can bootstrap it with the critic.
"""
from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from . import actions, shards
from .config import TrainConfig
from .networks import policy_input


class Carry(NamedTuple):
    """What a rollout continues from (one seed, batched over envs)."""

    env_state: Any  # batched brax State
    z: jax.Array  # (N, code_dim) each env's episode code
    hist: jax.Array  # (N, K + 1, obs_dim) raw observations s_{t-K..t}
    prev_ah: jax.Array  # (N, human_action_size) a^H_{t-1}
    code_counter: jax.Array  # int32: the next grid cell in cycle order


def code_grid(n: int) -> jnp.ndarray:
    """n x n grid of cell centres over (-1, 1)^2, row-major (the cycle order)."""
    c = jnp.linspace(-1 + 1 / n, 1 - 1 / n, n)
    return jnp.stack(jnp.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)


def new_codes(cfg: TrainConfig, counter, done, key, stride: int = 1):
    """Codes for the envs whose episode (re)starts (``done``, (N,) bool): the next grid cells in cycle order
    plus noise, clipped to [-1, 1] (zero for presets without a code). Returns ``(z, counter)``. ``stride``: every
    stride-th cell (an env shard's own cells, interleaved with the other shards')."""
    grid = code_grid(cfg.code_grid)
    if stride == 1:
        idx = counter + jnp.cumsum(done.astype(jnp.int32)) - 1
    else:
        idx = counter + stride * (jnp.cumsum(done.astype(jnp.int32)) - 1)
    noise = jax.random.uniform(key, (done.shape[0], cfg.code_dim), minval=-cfg.code_noise, maxval=cfg.code_noise)
    z = jnp.clip(grid[idx % grid.shape[0]] + noise, -1.0, 1.0)
    z = z if cfg.use_code else jnp.zeros_like(z)
    count = jnp.sum(done.astype(jnp.int32))
    return z, counter + (count if stride == 1 else stride * count)


def initial_carry(cfg: TrainConfig, env, key_env, key_z) -> Carry:
    """Fresh episodes in every env, with the first grid cells as their codes."""
    n = cfg.num_envs
    env_state = jax.vmap(env.reset)(jax.random.split(key_env, n))
    z, counter = new_codes(cfg, jnp.zeros((), jnp.int32), jnp.ones((n,), bool), key_z)
    return Carry(env_state, z, jnp.repeat(env_state.obs[:, None], cfg.history + 1, axis=1),
                 jnp.zeros((n, env.human_action_size)), counter)


def rollout(cfg: TrainConfig, env, actor, critic, params, norm, carry: Carry, key):
    """Step every env ``cfg.unroll_length`` times with the co-policy ``actor`` (sampled actions).

    Returns ``(carry, traj, last_value)``: ``traj`` holds (T, N) arrays of the step's inputs (obs, z, hist,
    prev_ah, first) and outputs (action, act = clipped action, logp, value, done, truncation, success,
    env_failed), and ``final_value``: the critic's value of the final observation of an episode the time limit
    ended (0 at other steps); ``last_value`` is the value of the state after the last step.

    With ``env_shards`` > 1 this is one shard's rollout (its ``carry`` holds its own envs; ``key`` its own): shard i
    of E takes the cycle's cells i, i + E, i + 2E, ... from the counter on, and the returned counter is advanced by
    every shard's new episodes (``shards.total``), the same on every shard."""
    n, k, ah, e = shards.local_envs(cfg), cfg.history, env.human_action_size, shards.count(cfg)
    spec = actions.spec_of(env)
    counter0 = carry.code_counter
    if e > 1:
        carry = carry._replace(code_counter=counter0 + shards.index(cfg))
    # One batch of fresh episodes per rollout, not per step: an env whose episode ends takes its fresh state
    # (for MJX tasks a reset costs a forward pass, so resetting every env every step doubled the step's cost).
    # An env that ends twice within one unroll restarts from the same initial state (with a new code).
    key, k_pool = jax.random.split(key)
    fresh = jax.vmap(env.reset)(jax.random.split(k_pool, n))
    fresh_hist = jnp.repeat(fresh.obs[:, None], k + 1, 1)

    def body(c: Carry, key):
        k_act, k_code = jax.random.split(key)
        obs_n = policy_input(norm, c.hist)
        mean, log_std = actor(params["actor"], obs_n, c.z)
        value = critic(params["critic"], obs_n, c.z)
        a, act = actions.sample(spec, mean, log_std, k_act)
        nxt = jax.vmap(env.step)(c.env_state, act)
        done = nxt.done > 0
        zero = jnp.zeros(done.shape)
        tr = {"obs": c.env_state.obs, "z": c.z, "hist": c.hist, "prev_ah": c.prev_ah,
              "first": c.env_state.info["t"] == 0, "action": a, "act": act,
              "logp": actions.log_prob(spec, mean, log_std, a), "value": value, "done": done.astype(jnp.float32),
              "truncation": nxt.info.get("truncation", zero) * done, "next_obs": nxt.obs,
              "success": nxt.metrics["success"] * done, "env_failed": nxt.info.get("failed", zero),
              "task_reward": nxt.reward}
        z_new, counter = new_codes(cfg, c.code_counter, done, k_code, stride=e)

        def pick(r, x):
            return jnp.where(done.reshape(done.shape + (1,) * (x.ndim - 1)), r, x)

        c = Carry(jax.tree.map(pick, fresh, nxt), pick(z_new, c.z),
                  pick(fresh_hist, jnp.concatenate([c.hist[:, 1:], nxt.obs[:, None]], 1)),
                  pick(jnp.zeros((n, ah)), act[:, :ah]), counter)
        return c, tr

    carry, traj = jax.lax.scan(body, carry, jax.random.split(key, cfg.unroll_length), unroll=cfg.scan_unroll)
    if e > 1:
        carry = carry._replace(code_counter=counter0 + shards.total(cfg, (carry.code_counter - counter0) // e))
    # the critic's value of a timed-out episode's last observation (the auto-reset replaced it in the carry)
    final_obs = policy_input(norm, jnp.stack([traj["obs"], traj.pop("next_obs")], -2))
    traj["final_value"] = jnp.where(traj["truncation"] > 0, critic(params["critic"], final_obs, traj["z"]), 0.0)
    last_value = critic(params["critic"], policy_input(norm, carry.hist), carry.z)
    return carry, traj, last_value
