"""Several GPUs: Co-GAIL train_step throughput with the seed axis sharded over the visible devices, against
one device at the same per-device batch (one seed of --envs environments per device).

    python experiments/multi_gpu.py --task fetchq --envs 8192
"""
import argparse
import json
from pathlib import Path

from cogail_jax.apps.options import file_out, positive


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="fetchq")
    p.add_argument("--envs", type=positive, default=8192)
    p.add_argument("--unroll", type=positive, default=94)
    p.add_argument("--calls", type=positive, default=3)
    p.add_argument("--updates-per-call", type=positive, default=4, help="updates per jitted call (dispatch amortised)")
    p.add_argument("--out", type=file_out("multi_gpu.json"), help="JSON output path")
    p.add_argument("--only-multi", action="store_true", help="skip the one-device row (diagnosing the sharded run)")
    a = p.parse_args(argv)
    if a.out and a.only_multi:
        p.error("--out: --only-multi writes no file (it has no speed-up to record): drop --out or --only-multi")
    import cogail_envs
    import jax

    try:
        cogail_envs.get_task(a.task)
    except cogail_envs.UnknownTaskError as e:
        p.error(f"--task: {e}")

    from cogail_jax.apps import bench
    from cogail_jax.data import io as data
    from cogail_jax.algo import train
    from cogail_jax.algo.config import ConfigError, TrainConfig

    n = len(jax.devices())
    rows = []
    runs = (((300,), None), (tuple(300 + 100 * i for i in range(n)), "all"))
    try:  # the runs' settings, checked before the demonstrations are made or anything compiles
        TrainConfig(task=a.task, num_envs=a.envs, unroll_length=a.unroll, seeds=runs[1][0],
                    updates_per_call=a.updates_per_call, total_steps=a.envs * a.unroll * 100).validate()
    except ConfigError as e:
        p.error(f"--envs {a.envs} --unroll {a.unroll} --updates-per-call {a.updates_per_call}: {e}")
    env = cogail_envs.make_env(a.task)
    expert = train.expert_arrays(data.load_demos(data.ensure_default_demos(env, "train"), env), 4)
    norm = train.fit_normalizer(expert)
    for seeds, devices in runs[1:] if a.only_multi else runs:
        cfg = TrainConfig(task=a.task, num_envs=a.envs, unroll_length=a.unroll, seeds=seeds,
                          updates_per_call=a.updates_per_call,
                          total_steps=a.envs * a.unroll * 100)
        r = bench.train_throughput(cfg, env, expert, norm, calls=a.calls, devices=devices)
        rows.append({"devices": 1 if devices is None else n, **r})
        print(json.dumps(rows[-1]), flush=True)
    if a.only_multi:
        return
    speedup = rows[1]['env_steps_per_s'] / rows[0]['env_steps_per_s']
    print(f"{a.task}: speed-up with {n} devices at the same per-device batch: {speedup:.2f}x")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps({"task": a.task, "devices": n, "rows": rows, "speedup": speedup,
                                           "args": vars(a)}, indent=2))


if __name__ == "__main__":
    main()
