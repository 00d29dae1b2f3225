"""Scripted human-human demonstrations: the task's team rolled out vmapped in one jitted call."""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np



class Episodes(NamedTuple):
    """Padded batch of episodes: arrays have a leading (num,) axis, time axis of length max_episode_steps."""

    obs: np.ndarray  # (N, T, obs_dim): observation before each step
    actions_human: np.ndarray  # (N, T, human_action_size)
    actions_robot: np.ndarray  # (N, T, robot_action_size)
    length: np.ndarray  # (N,) number of valid steps (the step that ended the episode included)
    strategy: np.ndarray  # (N,) intended strategy id (1..S)
    executed: np.ndarray  # (N,) classify_strategy of the executed episode (0 = none)
    success: np.ndarray  # (N,)
    init: np.ndarray  # (N, init_size) reset parameters (reset_from reproduces the start)
    final_metrics: dict  # name -> (N,) metrics at the episode's last step


def resolve_mix(env, mix) -> jnp.ndarray:
    """A mixture given as a name (uniform, or one of the task's ``Task.mixtures``), a sequence of weights or None ->
    normalised weights."""
    from cogail_envs import get_task

    if mix is None or mix == "uniform":
        return env.uniform_mix()
    if isinstance(mix, str):
        named = get_task(env.name).mixtures
        if mix not in named:
            raise ValueError(f"unknown mixture {mix!r} for {env.name}: use {', '.join(['uniform', *named])} or "
                             "comma-separated weights")
        mix = named[mix]
    w = jnp.asarray(mix, jnp.float32)
    if w.shape != (env.num_strategies,) or not bool(jnp.all(w >= 0)) or float(w.sum()) <= 0:
        raise ValueError(
            f"a mixture for {env.name} needs {env.num_strategies} non-negative weights, got {list(np.asarray(w))}"
        )
    return w / w.sum()


def team_rollout_fn(env, num: int, robot_strategy: int | None = None):
    """Jitted ``f(rng, mix) -> dict of arrays`` rolling out ``num`` scripted episodes in parallel.

    ``robot_strategy`` (tests only) makes the robot follow a fixed strategy whatever the human does.
    """
    from cogail_envs import team_of

    T = env.max_episode_steps
    team = team_of(env)

    def one(rng, mix):
        k_init, k_team, k_run = jax.random.split(rng, 3)
        init = env.sample_init(k_init)
        state = env.reset_from(init)
        ts, strategy = team.init(env, k_team, mix)
        if robot_strategy is not None:
            ts = ts._replace(strategy=ts.strategy.at[1].set(robot_strategy))
            if "watching" in ts._fields:  # a robot that reads the strategy off the human stops doing so
                ts = ts._replace(watching=jnp.array(False))

        def body(carry, key):
            state, ts, finished, last_metrics = carry
            ts, action = team.act(env, ts, state, key)
            nxt = env.step(state, action)
            out = (state.obs, action, finished)
            ended = nxt.done > 0
            # freeze the state once the episode ended (no auto-reset in demonstrations)
            new_state = jax.tree.map(lambda a, b: jnp.where(finished, a, b), state, nxt)
            new_metrics = jax.tree.map(lambda a, b: jnp.where(finished, a, b), last_metrics, nxt.metrics)
            return (new_state, ts, finished | ended, new_metrics), out

        carry = (state, ts, jnp.array(False), state.metrics)
        (state, ts, _, metrics), (obs, act, fin) = jax.lax.scan(body, carry, jax.random.split(k_run, T))
        length = jnp.sum(~fin).astype(jnp.int32)
        a_h, a_r = env.split_action(act)
        return dict(obs=obs, actions_human=a_h, actions_robot=a_r, length=length, strategy=strategy,
                    executed=env.classify_strategy(metrics), success=metrics["success"], init=init,
                    final_metrics=metrics)

    @jax.jit
    def run(rng, mix):
        return jax.vmap(one, in_axes=(0, None))(jax.random.split(rng, num), mix)

    return run


def generate(env, num: int, mix=None, seed: int = 0, robot_strategy: int | None = None) -> Episodes:
    """Generate ``num`` scripted human-human episodes (all in one jitted, vmapped call)."""
    w = resolve_mix(env, mix)
    out = jax.device_get(team_rollout_fn(env, num, robot_strategy)(jax.random.PRNGKey(seed), w))
    return Episodes(**{k: (np.asarray(v) if k != "final_metrics" else v) for k, v in out.items()})


def select(episodes: Episodes, keep: np.ndarray) -> Episodes:
    """The episodes where ``keep`` (a boolean (N,) mask) holds."""
    return Episodes(*[v[keep] if isinstance(v, np.ndarray) else
                      ({k: np.asarray(x)[keep] for k, x in v.items()} if isinstance(v, dict) else v)
                      for v in episodes])
