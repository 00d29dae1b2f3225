"""Judge co-play's human proxy before any robot plays with it.

Co-play's proxy (``cogail_jax.eval.coplay``) is an MLP behaviour-cloned on the test split's humans. Here variants of
it are trained the way co-play trains it (``coplay.train_proxy``: 4000 full-batch steps on a GPU, 500 on a CPU), each
from several initial keys, and judged two ways that read no learned robot:

* **prediction**: its action error (MSE, and R^2) on the validation split's humans, people it has not seen;
* **its partner's success**: how often the scripted robot, the partner the test humans were recorded with, completes
  the task with it in closed-loop co-play (co-play's proxy episodes, ``coplay.PROXY_EPISODES`` x ``--episodes``).

Variants: what the proxy reads (``--reads``: ``both`` every observation index, as co-play's; ``object`` not the
absolute orientations; ``world`` not the object-centric features, as ``obs_frame`` names them) and which humans it
learns from (``--humans``: ``test`` the test split, as co-play's; ``test+varied`` the test split with its varied
humans, the ``robust-<variation>`` sets, also test-split humans). The datasets are made first, as ``cogail data``
makes them. Writes ``<out>/proxy_study.json`` and ``<out>/proxy_study.md`` (mean +- std over keys).

    python experiments/proxy_study.py --tasks seqmanip,handover --keys 0,1,2 --out results/proxy_study
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from cogail_jax.apps.options import folder_out, positive

READS = ("both", "object", "world")
HUMANS = ("test", "test+varied")


def check_options(p: argparse.ArgumentParser, a: argparse.Namespace) -> tuple[list[str], list[int]]:
    """The tasks and keys of ``a``, and ``p.error`` with one sentence naming the option and the fix for any option
    that would end the study after it began (its tasks' datasets made, its proxies trained)."""
    from cogail_envs import UnknownTaskError, get_task, task_names

    from cogail_jax.eval import coplay

    tasks = [t for t in a.tasks.split(",") if t]
    if not tasks:
        p.error("--tasks is empty: give comma-separated tasks with a scripted robot, e.g. seqmanip,handover")
    for t in tasks:
        try:
            team = get_task(t).team
        except UnknownTaskError as e:
            p.error(f"--tasks: {e}")
        if team is None or team.robot_act is None:
            scripted = [n for n in task_names() if (tm := get_task(n).team) is not None and tm.robot_act is not None]
            p.error(f"--tasks: {t} has no scripted robot to judge a proxy with: give tasks of {', '.join(scripted)}")
    try:
        keys = [int(k) for k in a.keys.split(",")]
    except ValueError:
        p.error(f"--keys {a.keys}: give comma-separated integers, e.g. 0,1,2")
    if bad := [k for k in keys if not 0 <= k < 2 ** 32]:
        p.error(f"--keys {a.keys}: a key is an integer from 0 to {2 ** 32 - 1}, not {bad[0]}")
    if a.episodes * coplay.PROXY_EPISODES > coplay.REF_STRIDE:
        p.error(f"--episodes {a.episodes}: give at most {coplay.REF_STRIDE // coplay.PROXY_EPISODES} (the proxy plays "
                f"{coplay.PROXY_EPISODES} times as many, and co-play plays at most {coplay.REF_STRIDE} per partner)")
    return tasks, keys


def _arrays(path, env):
    from cogail_jax.data import io as data
    from cogail_jax.eval import rollouts

    return rollouts.heldout_arrays(data.load_demos(path, env, require_init=True))


def _join(sets: list[dict], steps: int) -> dict:
    """Episode sets (``obs``, ``ah``, ``length``) as one, zero-padded to ``steps`` steps."""
    def pad(x):
        x = np.asarray(x, np.float32)
        return np.concatenate([x, np.zeros((len(x), steps - x.shape[1], x.shape[2]), x.dtype)], 1)

    return {"obs": np.concatenate([pad(s["obs"]) for s in sets]), "ah": np.concatenate([pad(s["ah"]) for s in sets]),
            "length": np.concatenate([np.asarray(s["length"]) for s in sets])}


def _steps(d: dict) -> tuple[np.ndarray, np.ndarray]:
    """Every valid step of ``d``: the proxy's observation history (N, H + 1, D) and the human's action."""
    from cogail_jax.eval import coplay

    obs, H = np.asarray(d["obs"], np.float32), max(coplay.PROXY_LAGS)
    padded = np.concatenate([np.repeat(obs[:, :1], H, 1), obs], 1)
    hist = np.stack([padded[:, H - j:H - j + obs.shape[1]] for j in range(H, -1, -1)], 2)
    valid = np.arange(obs.shape[1])[None] < np.asarray(d["length"])[:, None]
    return hist[valid], np.asarray(d["ah"], np.float32)[valid]


def train_variant(data: dict, unread: tuple, key: int, steps: int):
    """The proxy co-play would train on ``data``, except that it never reads the observation indices ``unread``:
    they are zero in its training data and normalise to 0 when it acts (mean 0, std infinite)."""
    import jax.numpy as jnp

    from cogail_jax.eval import coplay

    cols = list(unread)
    if cols:
        data = {**data, "obs": np.array(data["obs"], np.float32)}
        data["obs"][..., cols] = 0.0
    proxy, info = coplay.train_proxy(data, coplay.TEST_SPLIT, steps=steps, seed=key)
    if cols:
        D = data["obs"].shape[-1]
        idx = [i + b * D for b in range(1 + len(coplay.PROXY_LAGS)) for i in cols]
        mean, std = np.array(proxy.mean), np.array(proxy.std)
        mean[idx], std[idx] = 0.0, np.inf
        proxy = proxy._replace(mean=jnp.asarray(mean), std=jnp.asarray(std))
    return proxy, info


def prediction(proxy, hist: np.ndarray, ah: np.ndarray) -> dict:
    import jax.numpy as jnp

    from cogail_jax.eval import coplay

    pred = np.concatenate([np.asarray(coplay.proxy_action(proxy, jnp.asarray(hist[i:i + 8192])))
                           for i in range(0, len(hist), 8192)])
    mse = float(np.mean((pred - ah) ** 2))
    return {"mse": mse, "r2": 1.0 - mse / float(np.mean((ah - ah.mean(0)) ** 2))}


def study_task(task: str, reads: list[str], humans: list[str], keys: list[int], episodes: int, steps: int | None):
    import jax

    from cogail_envs import get_task
    from cogail_jax.algo import train
    from cogail_jax.algo.config import resolve
    from cogail_jax.data import sets
    from cogail_jax.eval import coplay

    cfg = resolve(task, "paper", {})
    files = sets.make_datasets(cfg)  # `cogail data`: found where made already
    env = get_task(task).make_env()
    if get_task(task).team is None:
        raise SystemExit(f"task {task} has no scripted team, so no scripted robot to judge a proxy with: leave it out")
    steps = int(steps or (500 if jax.default_backend() == "cpu" else 4000))
    test = _arrays(files[sets.TEST], env)
    varied = [_arrays(p, env) for name, p in files.items() if name.startswith("robust-")]
    val_hist, val_ah = _steps(_arrays(files[sets.VALIDATION], env))
    data = {"test": test, "test+varied": _join([test, *varied], int(env.max_episode_steps))}
    run = coplay.make_coplay_fn(env)
    eps = coplay.episode_batch(env, [coplay.PROXY], episodes, ("scripted",))
    rows = []
    for h in humans:
        for r in reads:
            unread = train.unread_dims(cfg.replace(obs_frame=r), env)
            for k in keys:
                t = time.time()
                proxy, info = train_variant(data[h], unread, k, steps)
                success = float(np.asarray(run(None, None, proxy, eps)["success"]).mean())
                row = {"task": task, "humans": h, "reads": r, "key": k, "episodes": info["episodes"],
                       "samples": info["samples"], "train_mse": info["loss"],
                       **{f"validation_{n}": v for n, v in prediction(proxy, val_hist, val_ah).items()},
                       "scripted_robot_success": success, "coplay_episodes": int(len(eps["key"])),
                       "seconds": round(time.time() - t, 1)}
                print(json.dumps(row), flush=True)
                rows.append(row)
    return rows


def markdown(rows: list[dict]) -> list[str]:
    lines = ["| task | humans it learns from | reads | keys | training MSE | validation humans' MSE | R^2 | "
             "scripted robot completes (%) |", "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault((r["task"], r["humans"], r["reads"]), []).append(r)
    for (task, h, rd), g in groups.items():
        def ms(k, scale=1.0, f="{:.4f}"):
            v = scale * np.asarray([r[k] for r in g])
            return f"{f.format(v.mean())} +- {f.format(v.std())}"

        lines.append(f"| {task} | {h} | {rd} | {len(g)} | {ms('train_mse')} | {ms('validation_mse')} | "
                     f"{ms('validation_r2', f='{:.3f}')} | {ms('scripted_robot_success', 100, '{:.1f}')} |")
    return lines


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--tasks", default="seqmanip,handover", help="comma-separated tasks with a scripted team")
    p.add_argument("--reads", default=",".join(READS), help=f"what the proxy reads, comma-separated of {READS}")
    p.add_argument("--humans", default=",".join(HUMANS), help=f"what it learns from, comma-separated of {HUMANS}")
    p.add_argument("--keys", default="0,1,2", help="the proxy's initial keys (co-play's is 0)")
    p.add_argument("--episodes", type=positive, default=64,
                   help="co-play episodes per partner, as co-play's; the proxy plays PROXY_EPISODES times as many")
    p.add_argument("--steps", type=positive, default=None, help="proxy training steps (default: co-play's)")
    p.add_argument("--out", type=folder_out, default="results/proxy_study", help="folder for proxy_study.json / .md")
    a = p.parse_args(argv)
    reads, humans = a.reads.split(","), a.humans.split(",")
    for name, got, ok in (("--reads", reads, READS), ("--humans", humans, HUMANS)):
        bad = [x for x in got if x not in ok]
        if bad:
            p.error(f"{name} {','.join(bad)}: choose from {', '.join(ok)}")
    from cogail_jax.apps.cli import enable_compile_cache, set_deterministic

    set_deterministic(True)  # before JAX starts: the same figures from the same command
    enable_compile_cache()
    tasks, keys = check_options(p, a)
    rows = []
    for task in tasks:
        rows += study_task(task, reads, humans, keys, a.episodes, a.steps)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "proxy_study.json").write_text(json.dumps(rows, indent=1))
    (out / "proxy_study.md").write_text("\n".join(["# Co-play's human proxy, judged without a learned robot", "",
                                                   *markdown(rows), ""]))
    print("\n".join(markdown(rows)))


if __name__ == "__main__":
    main()
