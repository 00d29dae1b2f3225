"""Throughput benchmarks: env-only (random actions) and the full Co-GAIL update, in env steps/s."""
from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp


def env_throughput(env, num_envs: int, steps: int = 200, reps: int = 3) -> dict:
    """Random actions, vmapped over ``num_envs``, ``steps`` steps in a lax.scan, auto-reset by select from one
    batch of fresh states per call (as the trainer's rollout does)."""

    @jax.jit
    def run(state, key):
        key, k_pool = jax.random.split(key)
        fresh = jax.vmap(env.reset)(jax.random.split(k_pool, num_envs))

        def body(s, k1):
            a = jax.random.uniform(k1, (num_envs, env.action_size), minval=-1, maxval=1)
            nxt = jax.vmap(env.step)(s, a)
            done = nxt.done > 0
            s = jax.tree.map(lambda r, n: jnp.where(done.reshape(done.shape + (1,) * (n.ndim - 1)), r, n), fresh, nxt)
            return s, nxt.reward.sum()
        return jax.lax.scan(body, state, jax.random.split(key, steps))

    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), num_envs))
    t0 = time.time()
    state, r = run(state, jax.random.PRNGKey(1))
    jax.block_until_ready(r)
    compile_s = time.time() - t0
    t0 = time.time()
    for i in range(reps):
        state, r = run(state, jax.random.PRNGKey(2 + i))
    jax.block_until_ready(r)
    dt = time.time() - t0
    return {"num_envs": num_envs, "env_steps_per_s": num_envs * steps * reps / dt, "compile_s": compile_s}


def train_throughput(cfg, env, expert, norm, calls: int = 3, devices=None) -> dict:
    from ..algo import train
    from .train_loop import place_on_devices

    init, chunk, _ = train.make_train_fns(cfg, env, norm)
    state = init(cfg.seeds, expert)
    state, expert = place_on_devices(state, expert, devices, len(cfg.seeds), cfg.env_shards)
    t0 = time.time()
    state, m = chunk(state, expert)
    jax.block_until_ready(m)
    compile_s = time.time() - t0
    first = params_digest(state.params)  # after the first call: compares layouts (one process or several)
    t0 = time.time()
    for _ in range(calls):
        state, m = chunk(state, expert)
    jax.block_until_ready(m)
    dt = time.time() - t0
    steps = calls * cfg.updates_per_call * cfg.steps_per_update * len(cfg.seeds)
    return {"num_envs": cfg.num_envs, "seeds": len(cfg.seeds), "env_steps_per_s": steps / dt,
            "updates_per_s": calls * cfg.updates_per_call / dt, "compile_s": compile_s,
            "params_first_call": first, "params_last_call": params_digest(state.params)}


def params_digest(params) -> str:
    """SHA-256 of the parameters' bytes (gathered from every process): equal digests, equal parameters."""
    import hashlib

    import numpy as np

    from ..runtime import distributed

    h = hashlib.sha256()
    for x in jax.tree.leaves(distributed.to_host(params)):
        h.update(np.ascontiguousarray(x).tobytes())
    return h.hexdigest()[:16]


def _replicate_for_pmap(x, devices, axis_name="i"):
    """``jax.device_put_replicated`` (removed from jax, still called by brax 0.14.2's PPO): stack ``x`` once per
    device and place it with the sharding that a ``jax.pmap`` over ``axis_name`` gives its outputs (taken from
    a pmapped identity: a ``NamedSharding`` whose mesh axis is ``axis_name``). brax's training epoch is a pmap
    over axis "i" that is fed its own outputs, and the new jit-based pmap keys its compilation cache on the
    input sharding: placed any other way (our first shim put the stack on one device; a mesh axis of another
    name does the same), the state of the second epoch differs from the first's and the epoch compiles again,
    inside the timed epoch: brax's figure came out ~100x too low."""
    sharding = jax.pmap(lambda a: a, axis_name=axis_name, devices=devices)(jnp.zeros(len(devices))).sharding
    return jax.tree.map(lambda a: jax.device_put(jnp.stack([jnp.asarray(a)] * len(devices)), sharding), x)


def _shim_jax_for_brax() -> None:
    if not hasattr(jax, "device_put_replicated"):
        from brax.training.agents.ppo import train as ppo

        jax.device_put_replicated = lambda x, devices: _replicate_for_pmap(
            x, devices, getattr(ppo, "_PMAP_AXIS_NAME", "i"))


def brax_ppo_throughput(env, num_envs: int, unroll_length: int = 94, num_minibatches: int = 4,
                        epochs: int = 4, updates: int = 4) -> dict:
    """The peer: brax's own PPO trainer on the same env, batch and network sizes, with the env's fixed
    reward (fetchq: the success flag). Two training epochs of ``updates`` updates each, no evaluation
    (``run_evals=False``); the figure is brax's own ``training/sps`` of the second epoch (the first compiles).
    ``compile_s`` is the first epoch's wall-clock, set-up and compilation included."""
    import functools

    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo

    _shim_jax_for_brax()

    stamps = []
    per_update = num_envs * unroll_length
    t0 = time.time()
    ppo.train(
        environment=env, num_timesteps=per_update * updates * 2, num_envs=num_envs,
        episode_length=env.max_episode_steps, unroll_length=unroll_length,
        batch_size=max(1, num_envs // num_minibatches), num_minibatches=num_minibatches,
        num_updates_per_batch=epochs, num_evals=3, run_evals=False, seed=0,
        network_factory=functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(128,) * 4,
                                          value_hidden_layer_sizes=(128,) * 4),
        progress_fn=lambda step, metrics: stamps.append((time.time(), step, metrics.get("training/sps"))))
    (t1, _, _), (t2, _, sps) = stamps[0], stamps[-1]
    return {"num_envs": num_envs, "seeds": 1, "env_steps_per_s": float(sps), "compile_s": t1 - t0,
            "second_epoch_s": t2 - t1}


def main(task: str, sizes=(64, 1024, 8192), out: str | None = None, env_only: bool = False,
         steps: int = 200, peer: bool = True, unroll: int = 94, calls: int = 3, train_rows: bool = True,
         seed_sets=((300,), (300, 400, 500)), devices=None, env_shards: int = 1, task_settings: bool = False,
         updates_per_call: int | None = None, train_only: bool = False) -> list[dict]:
    """The table's rows. ``devices``/``env_shards``: the train rows run as `cogail train --devices D --env-shards E`
    (sizes: every seed's whole env batch, over all shards); ``task_settings``: their config is the task's own
    settings (its ``default_config()``) instead of the field defaults."""
    import cogail_envs

    from ..data import io as data
    from ..algo import train
    from ..algo.config import TrainConfig, resolve
    from ..runtime import distributed

    env = cogail_envs.make_env(task)
    sizes_env = sizes
    if distributed.processes() > 1 or train_only:  # the train rows only (several processes: printed by process 0)
        env_only, peer, sizes_env = False, False, ()
    if train_rows and not env_only:  # the demonstrations feed the discriminator and the BC terms (the peer needs
        from ..data import sets       # none): found first, made by `cogail data --task T`

        base = resolve(task) if task_settings else TrainConfig(task=task)
        demos = data.load_demos(sets.split_path(base, sets.TRAIN, env=env), env)
        expert = train.expert_arrays(demos, base.history)
        norm = train.fit_normalizer(expert, base.obs_std_floor, train.unread_dims(base, env), base.motion)
    rows = []
    for n in sizes_env:
        r = env_throughput(env, n, steps=steps)
        rows.append({"task": task, "kind": "env-only", **r})
        print(json.dumps(rows[-1]), flush=True)
        _write(rows, out)
    if env_only:
        _table(rows, out)
        return rows
    for n in sizes:
        for seeds in seed_sets if train_rows else ():
            cfg = base.replace(num_envs=n, seeds=seeds, unroll_length=unroll,
                               updates_per_call=updates_per_call or min(5, calls + 1), total_steps=n * unroll * 100,
                               num_minibatches=4 if (n * unroll // env_shards) % 4 == 0 else 1,
                               env_shards=env_shards).validate()
            r = train_throughput(cfg, env, expert, norm, calls=calls, devices=devices)
            rows.append({"task": task, "kind": "co-gail train_step", **r, "env_shards": env_shards,
                         "devices": jax.device_count() if devices == "all" else int(devices or 1),
                         "processes": distributed.processes()})
            print(json.dumps(rows[-1]), flush=True)
            _write(rows, out)
        if peer:
            r = brax_ppo_throughput(env, n, unroll_length=unroll, num_minibatches=4 if n % 4 == 0 else 1)
            rows.append({"task": task, "kind": "brax ppo (peer)", **r})
            print(json.dumps(rows[-1]), flush=True)
            _write(rows, out)
    _table(rows, out)
    return rows


def _table(rows, out):
    from ..runtime import distributed

    if not distributed.primary():
        return
    print(f"{'task':9} {'kind':20} {'envs':>6} {'seeds':>5} {'env steps/s':>12} {'compile s':>9}")
    for r in rows:
        print(f"{r['task']:9} {r['kind']:20} {r['num_envs']:>6} {r.get('seeds', 1):>5} "
              f"{r['env_steps_per_s']:>12.3g} {r['compile_s']:>9.1f}")
    _write(rows, out)


def _write(rows, out):
    """The JSON is rewritten after every row, so a run cut by a time limit keeps the rows it finished."""
    from ..runtime import distributed

    if out and distributed.primary():
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps({"device": str(jax.devices()[0]), "rows": rows}, indent=2))


def add_arguments(p) -> None:
    from .options import positive, positive_list, seeds

    p.add_argument("task", nargs="?", default=None, help="a task name or my_pkg.my_module:TASK (its training split "
                   "must exist: `cogail data --task T`)")
    p.add_argument("out", nargs="?", default=None, help="JSON output path")
    p.add_argument("--sizes", type=positive_list, default=(64, 1024, 8192), help="comma-separated batch sizes")
    p.add_argument("--steps", type=positive, default=200, help="env steps per timed call")
    p.add_argument("--env-only", action="store_true", help="skip the train_step rows")
    p.add_argument("--no-peer", action="store_true", help="skip brax's PPO")
    p.add_argument("--peer-only", action="store_true", help="skip the Co-GAIL train_step rows (env-only and brax)")
    p.add_argument("--train-only", action="store_true", help="the Co-GAIL train_step rows alone")
    p.add_argument("--unroll", type=positive, default=94, help="rollout length per update")
    p.add_argument("--calls", type=positive, default=3, help="timed train_step calls per row")
    p.add_argument("--seeds", type=seeds, default=None, help="the train rows' seeds, e.g. 300 (default: one row with 300, one "
                   "with 300,400,500)")
    p.add_argument("--devices", default=None, help="the train rows over N devices or 'all' (as `cogail train`)")
    p.add_argument("--env-shards", type=positive, default=1, help="the train rows' env shards (as `cogail train`)")
    p.add_argument("--task-settings", action="store_true",
                   help="the train rows with the task's own settings (default: the config's field defaults)")
    p.add_argument("--updates-per-call", type=positive, default=None, help="updates per timed call (default calls + 1, "
                   "at most 5)")
    p.add_argument("--phases", nargs="+", default=None, metavar="RUN",
                   help="benchmark nothing: print the seconds of each phase (demos, bc, compile, train, eval, "
                        "write, total) of these runs, their parts, and every program they compiled (count, XLA and "
                        "tracing seconds), read from RUN/speed.json, as markdown tables")


def phases_report(runs) -> str:
    """The markdown tables of the runs' RUN/speed.json: seconds per phase (``timing.phases_table``), the phases'
    parts (``timing.parts_table``) and the compiled programs (``timing.compiles_table``); a run without one is an
    error."""
    from ..runtime import timing
    from .runs import RunError

    records = []
    for run in runs:
        rec = timing.read(run)
        if not rec:
            raise RunError(f"{run} has no readable {timing.FILE}: train the run with `cogail train` first")
        records.append((str(run), rec))
    return (timing.phases_table(records) + "\n\n" + timing.parts_table(records) + "\n\n"
            + timing.compiles_table(records))


def run_from_args(a) -> None:
    from ..runtime.paths import output_file

    if a.phases:
        print(phases_report(a.phases))
        return
    if not a.task:
        from ..algo.config import ConfigError

        raise ConfigError("no task given: pass one, e.g. `cogail bench TASK` (or --phases RUN ...)")
    if a.out:
        output_file(a.out, "out", "bench.json")
    seed_sets = ((300,), (300, 400, 500)) if a.seeds is None else (a.seeds,)
    main(a.task, a.sizes, a.out, a.env_only, a.steps, not a.no_peer,
         a.unroll, a.calls, not a.peer_only, seed_sets, a.devices, a.env_shards, a.task_settings,
         a.updates_per_call, a.train_only)


def cli(argv=None):
    import argparse

    from ..runtime.xla import enable_compile_cache

    p = argparse.ArgumentParser(prog="python -m cogail_jax.apps.bench", description="Throughput table (env steps/s).")
    add_arguments(p)
    a = p.parse_args(argv)
    enable_compile_cache()
    run_from_args(a)


if __name__ == "__main__":
    cli()
