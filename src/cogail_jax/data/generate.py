"""Scripted episodes of a task's team: ONE compiled generator per task makes every set (the default splits,
the varied humans, the twins of the blind-robot figures).

The generator (:func:`generator_fn`) rolls out ``batch`` episodes, one per key, vmapped -- or re-simulates
recorded ones open-loop from their start, to validate them -- in one jitted program whose shapes depend only on
the task and the batch size (``generator_batch``: 512 episodes on an accelerator, 8 on a CPU), never on how
many episodes a set needs. Sets are made by calling it on chunks of their episodes' keys (several sets' episodes
share a chunk, the last one padded: ``run_requests``), so the task's sets share one compilation, kept in the
persistent compilation cache.

An episode is a function of its key alone: the default splits use ``jax.random.split(PRNGKey(seed), num)``, the
varied humans ``fold_in(PRNGKey(seed), index)``, as they always did, so the batching does not change them.
"""
from __future__ import annotations

import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

BATCH_ENV = "COGAIL_GEN_BATCH"


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
            f"a mixture for {env.name} needs {env.num_strategies} non-negative weights, e.g. "
            f"{','.join(['1'] * env.num_strategies)}, got "
            f"{','.join(f'{x:g}' for x in np.asarray(mix, float).ravel().tolist())}"
        )
    return w / w.sum()


def generator_batch(batch: int | None = None) -> int:
    """Episodes per generator call: ``batch`` if given, else $COGAIL_GEN_BATCH, else 512 on an accelerator and 8
    on a CPU (where a small program compiles and runs faster than a wide one)."""
    if batch:
        return int(batch)
    if os.environ.get(BATCH_ENV):
        return int(os.environ[BATCH_ENV])
    return 8 if jax.default_backend() == "cpu" else 512


def episode_one(env, key, mix, variation, resalt, robot_strategy, replay, rec_h, rec_r):
    """One scripted episode from ``key``: the team's human (``variation``: 0 none, i the i-th of
    ``cogail_envs.variations.VARIATIONS``) and robot (``robot_strategy`` > 0, tests only: it follows that strategy
    whatever the human does); ``resalt`` > 0 re-draws the per-step randomness (same start, strategy and
    episode-level draws; ``robot_strategy`` applies to team states with a ``strategy`` field of both agents'
    ids). The state freezes once the episode ends (no auto-reset in demonstrations).

    ``replay``: both agents' recorded actions ``rec_h`` / ``rec_r`` (T, A) are stepped instead, open-loop from the
    same start (the key's): the re-simulation that validates a recording, by the same compiled step."""
    from cogail_envs import team_of

    team = team_of(env)
    k_init, k_team, k_run = jax.random.split(key, 3)
    k_run = jnp.where(resalt > 0, jax.random.fold_in(k_run, resalt), k_run)
    init = env.sample_init(k_init)
    state = env.reset_from(init)
    ts, strategy = team.init(env, k_team, mix, variation)
    fields = getattr(ts, "_fields", ())  # a team state with the agents' strategies (the built-in teams')
    if "strategy" in fields:
        fixed = robot_strategy > 0
        ts = ts._replace(strategy=jnp.where(fixed, ts.strategy.at[1].set(robot_strategy), ts.strategy))
        if "watching" in fields:  # a robot that reads the strategy off the human stops doing so
            ts = ts._replace(watching=jnp.where(fixed, False, ts.watching))
    recorded = jnp.concatenate([rec_h, rec_r], -1)

    def body(carry, x):
        k, rec = x
        state, ts, finished, metrics = carry
        ts, action = team.act(env, ts, state, k)
        action = jnp.where(replay, rec, action)
        nxt = env.step(state, action)
        new_state = jax.tree.map(lambda a, b: jnp.where(finished, a, b), state, nxt)
        new_metrics = jax.tree.map(lambda a, b: jnp.where(finished, a, b), metrics, nxt.metrics)
        return (new_state, ts, finished | (nxt.done > 0), new_metrics), (state.obs, action, finished)

    carry = (state, ts, jnp.array(False), state.metrics)
    keys = jax.random.split(k_run, env.max_episode_steps)
    (_, _, _, metrics), (obs, act, fin) = jax.lax.scan(body, carry, (keys, recorded))
    a_h, a_r = env.split_action(act)
    return dict(obs=obs, actions_human=a_h, actions_robot=a_r, length=jnp.sum(~fin).astype(jnp.int32),
                strategy=strategy, executed=env.classify_strategy(metrics), success=metrics["success"], init=init,
                final_metrics=metrics)


def replay_one(env, init, a_h, a_r):
    """Both agents' recorded actions replayed open-loop from ``reset_from(init)``: success, executed strategy and
    length (for recordings made elsewhere: the blind-robot figures)."""
    state = env.reset_from(init)

    def body(carry, a):
        state, finished, metrics = carry
        nxt = env.step(state, a)
        new_state = jax.tree.map(lambda o, n: jnp.where(finished, o, n), state, nxt)
        new_metrics = jax.tree.map(lambda o, n: jnp.where(finished, o, n), metrics, nxt.metrics)
        return (new_state, finished | (nxt.done > 0), new_metrics), finished

    carry = (state, jnp.array(False), state.metrics)
    (_, _, metrics), fin = jax.lax.scan(body, carry, jnp.concatenate([a_h, a_r], -1))
    return dict(success=metrics["success"], executed=env.classify_strategy(metrics),
                length=jnp.sum(~fin).astype(jnp.int32))


def _cached(env, kind: str, batch: int, build):
    """One jitted program per (env object, kind, batch size)."""
    cache = env.__dict__.setdefault("_generator_fns", {})
    if (kind, batch) not in cache:
        cache[(kind, batch)] = build()
    return cache[(kind, batch)]


def generator_fn(env, batch: int | None = None):
    """The task's generator: jitted ``f(keys (B, 2), mix (B, S), variation (B,), resalt (B,), robot_strategy (B,),
    replay, rec_h (B, T, Ah), rec_r (B, T, Ar)) -> dict`` of B episodes (``episode_one``'s fields). Every argument
    is data, so one compilation serves every set of the task, and episodes of several sets share a call."""
    batch = generator_batch(batch)
    run = jax.vmap(episode_one, in_axes=(None, 0, 0, 0, 0, 0, None, 0, 0))
    return _cached(env, "generator", batch, lambda: jax.jit(lambda *a: run(env, *a)))


def replay_fn(env, batch: int | None = None):
    """Jitted ``f(init (B, I), actions_human (B, T, Ah), actions_robot (B, T, Ar)) -> dict`` (``replay_one``)."""
    return _cached(env, "replay", generator_batch(batch),
                   lambda: jax.jit(jax.vmap(lambda i, h, r: replay_one(env, i, h, r))))


def chunks(n: int, batch: int):
    """Index arrays of length ``batch`` covering range(n) (the last one padded by repeating index 0): each chunk's
    real indices and its padded ones."""
    for s in range(0, n, batch):
        idx = np.arange(s, min(s + batch, n))
        yield idx, np.concatenate([idx, np.zeros(batch - len(idx), idx.dtype)])


class Request(NamedTuple):
    """Episodes to make: one per key (N, 2), with the mixture's weights and the human's variation, re-salt and the
    robot's fixed strategy (``episode_one``); ``validate``: re-simulate each and return ``valid_success`` /
    ``valid_executed``."""

    keys: np.ndarray
    mix: np.ndarray
    variation: int = 0
    resalt: int = 0
    robot_strategy: int = 0
    validate: bool = False


def _host(tree):
    return jax.tree.map(np.asarray, jax.device_get(tree))


def _call_all(env, f, batch: int, args: dict, replay: bool, rec: tuple | None) -> dict:
    """``f`` over every episode of ``args`` (arrays with a leading (N,) axis) in chunks of ``batch``: the outputs,
    concatenated (numpy)."""
    n = len(args["keys"])
    T = env.max_episode_steps
    parts = []
    for idx, pad in chunks(n, batch):
        if rec is None:
            rh = np.zeros((batch, T, env.human_action_size), np.float32)
            rr = np.zeros((batch, T, env.robot_action_size), np.float32)
        else:
            rh, rr = rec[0][pad], rec[1][pad]
        out = f(*(jnp.asarray(args[k][pad]) for k in ("keys", "mix", "variation", "resalt", "robot_strategy")),
                jnp.bool_(replay), jnp.asarray(rh), jnp.asarray(rr))
        parts.append((idx, _host(out)))
    return jax.tree.map(lambda *xs: np.concatenate([x[: len(i)] for (i, _), x in zip(parts, xs)]),
                        *[o for _, o in parts])


def run_requests(env, requests: list[Request], batch: int | None = None) -> list[dict]:
    """The episodes of every request, made together by the task's generator in chunks of ``batch`` (episodes of
    several requests share a call); those asked to be validated are then re-simulated the same way. One dict of
    numpy arrays with a leading (N,) axis per request (``episode_one``'s fields, plus ``valid_success`` /
    ``valid_executed`` where validated)."""
    batch = generator_batch(batch)
    f = generator_fn(env, batch)
    sizes = [len(r.keys) for r in requests]
    if not sum(sizes):
        raise ValueError("no episodes requested")
    S = env.num_strategies
    args = {"keys": np.concatenate([np.asarray(jax.device_get(r.keys)).reshape(-1, 2) for r in requests]),
            "mix": np.concatenate([np.broadcast_to(np.asarray(r.mix, np.float32), (n, S)) for r, n in zip(requests, sizes)]),
            **{k: np.concatenate([np.full(n, int(getattr(r, k)), np.int32) for r, n in zip(requests, sizes)])
               for k in ("variation", "resalt", "robot_strategy")}}
    out = _call_all(env, f, batch, args, False, None)
    check = np.concatenate([np.full(n, bool(r.validate)) for r, n in zip(requests, sizes)])
    if check.any():
        sel = np.flatnonzero(check)
        rep = _call_all(env, f, batch, {k: v[sel] for k, v in args.items()}, True,
                        (out["actions_human"][sel], out["actions_robot"][sel]))
        for k, name in (("success", "valid_success"), ("executed", "valid_executed")):
            out[name] = np.zeros_like(out[k])
            out[name][sel] = rep[k]
    bounds = np.cumsum([0, *sizes])
    res = []
    for r, lo, hi in zip(requests, bounds[:-1], bounds[1:]):
        d = jax.tree.map(lambda x: x[lo:hi], out)
        if not r.validate:
            d.pop("valid_success", None)
            d.pop("valid_executed", None)
        res.append(d)
    return res


def run_episodes(env, keys, mix, variation: int = 0, resalt: int = 0, robot_strategy: int = 0,
                 validate: bool = False, batch: int | None = None) -> dict:
    """The episodes of one ``Request`` (``run_requests``)."""
    return run_requests(env, [Request(keys, mix, variation, resalt, robot_strategy, validate)], batch)[0]


def training_flags(env) -> int:
    """The variation flags of the training split's episodes: ``variations.PROMPT_ROBOT`` where the task's team has
    a prompt robot (the learned robot imitates its most prompt demonstrator), else 0."""
    from cogail_envs import team_of
    from cogail_envs.variations import PROMPT_ROBOT

    team = team_of(env)
    return PROMPT_ROBOT if getattr(team, "prompt_robot", False) else 0


def training_env(env):
    """The env the training split's demonstrations are made in: the task's ``train_env`` options (e.g. a robot that
    starts from more poses) at ``env``'s time limit; ``env`` itself where the task has none."""
    from cogail_envs import get_task

    task = get_task(env.name)
    if not task.train_env:
        return env
    return task.make_training_env(max_episode_steps=env.max_episode_steps)


def generate(env, num: int, mix=None, seed: int = 0, robot_strategy: int | None = None,
             batch: int | None = None, variation: int = 0) -> Episodes:
    """``num`` scripted human-human episodes from generator seed ``seed`` (``variation``: the team's variation id
    and flags, e.g. ``training_flags``; ``robot_strategy``: tests only, see ``episode_one``)."""
    keys = jax.random.split(jax.random.PRNGKey(seed), num)
    out = run_episodes(env, keys, resolve_mix(env, mix), variation=int(variation),
                       robot_strategy=int(robot_strategy or 0), batch=batch)
    return Episodes(**{k: out[k] for k in Episodes._fields})


def select(episodes: Episodes, keep: np.ndarray) -> Episodes:
    """The episodes where ``keep`` (a boolean (N,) mask) holds."""
    return Episodes(*[v[keep] if isinstance(v, np.ndarray) else
                      ({k: np.asarray(x)[keep] for k, x in v.items()} if isinstance(v, dict) else v)
                      for v in episodes])
