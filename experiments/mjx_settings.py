"""MJX solver / contact settings vs. speed and task fidelity (CPU, small batches).

For one task and a list of settings this measures

* env-only throughput: ``num_envs`` vmapped envs with uniform random actions, ``steps`` env steps in one
  jitted ``lax.scan`` (AOT-compiled first, so compile time is reported apart), best of ``reps`` runs
  (the machine may be shared; the minimum is the least disturbed run). XLA's own flop estimate of the
  compiled scan is printed too (``cost_analysis``; no profiler involved);
* the scripted human-human team (:func:`cogail_jax.demos.team_rollout_fn`, uniform mix): success rate,
  fraction classified as the intended strategy, mean length, and the wall time of that rollout.

A setting is ``default`` (the env constructor's defaults), ``baseline`` (the settings the tasks used
before this study: ``it4-ls8-sub4-c4``) or a dash-separated list of changes to the baseline: ``itN``
(Newton iterations), ``lsN`` (line-search iterations), ``subN`` (substeps; the timestep becomes 0.02 / N
so the env step stays 0.02 s), ``cN`` (finger-pad condim, 4 or 3), ``nowalls`` (seqmanip only: no drawer
side-wall pairs). Speedups are relative to ``baseline`` when it is in the list, else to the first setting.

    python experiments/mjx_settings.py --task handover --settings baseline it2-ls4 c3 sub2 sub2-it2-ls4-c3

Measured (CPU, 2 cores shared with other work, 64 envs x 50 steps, 64 scripted episodes, seed 0). One
run per setting, in sequence (the handover baseline in a separate, less loaded run), so the single
ratios are noisy:

| task | setting | env steps/s | speedup | scripted success | classified as intended |
|---|---|---|---|---|---|
| handover | baseline (it4 ls8, 4 x 5 ms, condim 4) | 1664 | 1.00x | 100% | 100% |
| handover | it2-ls4 | 2048 | 1.23x | 100% | 100% |
| handover | c3 | 2171 | 1.30x | 100% | 100% |
| handover | sub2 (2 x 10 ms) | 2886 | 1.73x | 100% | 100% |
| handover | sub2-it2-ls4-c3 | 5410 | 3.25x | 100% | 100% |
| seqmanip | baseline | 1397 | 1.00x | 100% | 100% |
| seqmanip | it2-ls4 | 1582 | 1.13x | 100% | 100% |
| seqmanip | c3 | 1688 | 1.21x | 100% | 100% |
| seqmanip | sub2 | 2477 | 1.77x | 100% | 100% |
| seqmanip | sub2-it2-ls4-c3 | 3530 | 2.53x | 100% | 100% |

Interleaved re-measurement (``--settings baseline default baseline default --no-scripted --reps 5``,
``default`` = sub2-it2-ls4-c3, now the default of both tasks): handover 2201 / 5624 / 2145 / 5519 env
steps/s (2.56x), seqmanip 1250 / 3590 / 1382 / 3781 (2.80x). Scripted team with the new defaults,
128 more episodes (seed 1): handover 128 / 128 succeed and are classified as intended; seqmanip
128 / 128 (60 human-hands-over, 68 robot-opens; mean length 417 / 386 steps, as before). XLA's flop
estimate (``cost_analysis``, loop bodies counted once) drops only ~15% (condim 3): most of the gain is
fewer loop trips (2 instead of 4 substeps, at most 2 Newton / 4 line-search iterations), which the
estimate does not see. The GPU ratio may differ from the CPU one: re-measure there.
"""
from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from cogail_envs import make_env
from cogail_jax.demos import team_rollout_fn

ENV_DT = 0.02


def parse(spec: str, task: str) -> dict:
    """Setting spec -> env constructor kwargs."""
    if spec == "default":
        return {}
    kw = dict(iterations=4, ls_iterations=8, n_substeps=4, timestep=0.005, finger_condim=4)  # baseline
    if spec == "baseline":
        return kw
    for tok in spec.split("-"):
        if tok == "nowalls":
            if task != "seqmanip":
                raise ValueError("nowalls is a seqmanip option")
            kw["side_walls"] = False
        elif tok.startswith("it"):
            kw["iterations"] = int(tok[2:])
        elif tok.startswith("ls"):
            kw["ls_iterations"] = int(tok[2:])
        elif tok.startswith("sub"):
            n = int(tok[3:])
            kw["n_substeps"], kw["timestep"] = n, ENV_DT / n
        elif tok.startswith("c"):
            kw["finger_condim"] = int(tok[1:])
        else:
            raise ValueError(f"bad setting token {tok!r} in {spec!r}")
    return kw


def env_only(env, num_envs: int, steps: int, reps: int) -> dict:
    def run(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (num_envs, env.action_size), minval=-1.0, maxval=1.0)
            s = jax.vmap(env.step)(s, a)
            return s, s.reward.sum()
        return jax.lax.scan(body, state, jax.random.split(key, steps))

    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), num_envs))
    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(state, jax.random.PRNGKey(1)).compile()
    compile_s = time.perf_counter() - t0
    try:
        ca = compiled.cost_analysis()
        ca = ca[0] if isinstance(ca, (list, tuple)) else ca
        flops = float(ca.get("flops", float("nan")))
    except Exception:  # cost analysis is best effort
        flops = float("nan")
    times = []
    for i in range(reps):
        t0 = time.perf_counter()
        state, r = compiled(state, jax.random.PRNGKey(2 + i))
        jax.block_until_ready((state, r))
        times.append(time.perf_counter() - t0)
    ok = bool(np.all(np.isfinite(np.asarray(state.obs))))
    return dict(steps_per_s=num_envs * steps / min(times),
                steps_per_s_median=num_envs * steps / float(np.median(times)),
                compile_s=compile_s, xla_flops=flops, finite=ok)


def scripted(env, num: int, seed: int) -> dict:
    fn = team_rollout_fn(env, num)
    mix = env.uniform_mix()
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    compiled = fn.lower(key, mix).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = jax.device_get(compiled(key, mix))
    run_s = time.perf_counter() - t0
    strat, execd, succ, length = (np.asarray(out[k]) for k in ("strategy", "executed", "success", "length"))
    per = {int(s): dict(n=int((strat == s).sum()), success=float(succ[strat == s].mean()),
                        correct=float((execd[strat == s] == s).mean()), length=float(length[strat == s].mean()))
           for s in np.unique(strat)}
    return dict(episodes=num, success=float(succ.mean()), correct=float((execd == strat).mean()),
                length=float(length.mean()), rollout_s=run_s,
                rollout_steps_per_s=num * env.max_episode_steps / run_s, rollout_compile_s=compile_s, per_strategy=per)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="handover", choices=("handover", "seqmanip"))
    p.add_argument("--settings", nargs="+", default=["baseline", "it2-ls4", "c3", "sub2", "sub2-it2-ls4-c3"])
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--episodes", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-scripted", action="store_true", help="env-only timing")
    p.add_argument("--out", default=None, help="append one JSON line per setting to this file")
    a = p.parse_args(argv)

    rows = []
    for spec in a.settings:
        kw = parse(spec, a.task)
        env = make_env(a.task, **kw)
        row = dict(task=a.task, setting=spec, kwargs=kw, npair=int(env.mj_model.npair), dt=env.dt)
        row.update(env_only(env, a.envs, a.steps, a.reps))
        if not a.no_scripted:
            row.update(scripted(env, a.episodes, a.seed))
        rows.append(row)
        print(json.dumps(row), flush=True)
        if a.out:
            with open(a.out, "a") as f:
                f.write(json.dumps(row) + "\n")

    base = next((r["steps_per_s"] for r in rows if r["setting"] == "baseline"), rows[0]["steps_per_s"])
    print(f"\n{a.task}: {a.envs} envs x {a.steps} steps, best of {a.reps}; "
          f"scripted: {a.episodes} episodes, uniform mix")
    print("| setting | env steps/s | speedup | XLA GFLOP (loop bodies once) | scripted success "
          "| classified as intended | mean length |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        sc = (("-", "-", "-") if a.no_scripted
              else (f"{r['success']:.1%}", f"{r['correct']:.1%}", f"{r['length']:.0f}"))
        print(f"| {r['setting']} | {r['steps_per_s']:.0f} | {r['steps_per_s'] / base:.2f}x | "
              f"{r['xla_flops'] / 1e9:.3f} | {sc[0]} | {sc[1]} | {sc[2]} |")


if __name__ == "__main__":
    main()
