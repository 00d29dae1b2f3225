"""The paper's evaluation protocols, jitted and vmapped over seeds.

* interpolation: ``eval_codes`` codes on a uniform grid over (-1, 1)^2; the co-policy acts for both agents
  deterministically (action means); success rate and the executed strategies.
* replay: the robot acts with pi_R(s, psi(h)) (deterministic) against open-loop replays of held-out human
  trajectories, each episode started where its demonstration started; success rate.
* latent map: the mean psi code of each held-out demonstration.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .config import TrainConfig


def interpolation_codes(n: int) -> jnp.ndarray:
    """n codes uniformly over (-1, 1)^2: a sqrt(n) x sqrt(n) grid of cell centres (n a square), else random."""
    k = int(round(math.sqrt(n)))
    if k * k == n:
        c = jnp.linspace(-1 + 1 / k, 1 - 1 / k, k)
        return jnp.stack(jnp.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
    return jax.random.uniform(jax.random.PRNGKey(0), (n, 2), minval=-1, maxval=1)


def make_robot_step(cfg: TrainConfig, env, nets):
    """The robot of the replay protocol (and of ``cogail play``): pi_R(s, psi(h)), deterministic.

    Returns ``(psi_code, robot_step)``:

    * ``psi_code(params, norm, hist, prev_ah) -> z``: psi's code of the history ``hist`` (K + 1 raw
      observations s_{t-K..t}) and the human's previous action (zeros for presets without a code);
    * ``robot_step(params, norm, state, hist, prev_ah, a_h) -> (next_state, next_hist, z, a_r)``: one env
      step with the human's action ``a_h`` given and the robot's action from pi_R(s, psi(h)).
    """
    actor, psi = nets["actor"].apply, nets["psi"].apply
    Ah = env.human_action_size

    def normalize(norm, x):
        return (x - norm["mean"]) / norm["std"]

    def psi_code(params, norm, hist, prev_ah):
        h = normalize(norm, hist).reshape(-1)
        z = psi(params["psi"], jnp.concatenate([h, prev_ah]))
        return z if cfg.use_code else jnp.zeros_like(z)

    def robot_step(params, norm, state, hist, prev_ah, a_h):
        z = psi_code(params, norm, hist, prev_ah)
        mean, _ = actor(params["actor"], normalize(norm, state.obs), z)
        a_r = jnp.clip(mean[Ah:], -1, 1)
        nxt = env.step(state, jnp.concatenate([a_h, a_r]))
        return nxt, jnp.concatenate([hist[1:], nxt.obs[None]], 0), z, a_r

    return psi_code, robot_step


def make_eval_fns(cfg: TrainConfig, env, nets):
    actor = nets["actor"].apply
    K, Ah = cfg.history, env.human_action_size
    Tenv = env.max_episode_steps
    psi_code, robot_step = make_robot_step(cfg, env, nets)

    def normalize(norm, x):
        return (x - norm["mean"]) / norm["std"]

    def freeze(fin, old, new):
        return jax.tree.map(lambda a, b: jnp.where(fin, a, b), old, new)

    def interp_one(params, norm, z, rng):
        z = z if cfg.use_code else jnp.zeros_like(z)
        state = env.reset(rng)

        def body(carry, _):
            state, fin, metrics = carry
            mean, _ = actor(params["actor"], normalize(norm, state.obs), z)
            nxt = env.step(state, jnp.clip(mean, -1, 1))
            metrics = freeze(fin, metrics, nxt.metrics)
            return (freeze(fin, state, nxt), fin | (nxt.done > 0), metrics), None

        (state, _, metrics), _ = jax.lax.scan(body, (state, jnp.array(False), state.metrics), None, length=Tenv)
        return {"success": metrics["success"], "strategy": env.classify_strategy(metrics), "metrics": metrics}

    def replay_one(params, norm, init, ah, length):
        state = env.reset_from(init)
        hist = jnp.repeat(state.obs[None], K + 1, 0)

        def body(carry, t):
            state, hist, prev_ah, fin = carry
            a_h = jnp.where(t < length, ah[jnp.minimum(t, ah.shape[0] - 1)], 0.0)
            nxt, hist, _, _ = robot_step(params, norm, state, hist, prev_ah, a_h)
            return (freeze(fin, state, nxt), hist, a_h, fin | (nxt.done > 0)), None

        carry = (state, hist, jnp.zeros((Ah,)), jnp.array(False))
        (state, _, _, _), _ = jax.lax.scan(body, carry, jnp.arange(Tenv))
        return state.metrics

    def latent_one(params, norm, obs, prev_ah, length):
        T = obs.shape[0]
        idx = jnp.clip(jnp.arange(T)[:, None] + jnp.arange(-K, 1)[None], 0, None)
        z = jax.vmap(lambda h, p: psi_code(params, norm, h, p))(obs[idx], prev_ah)
        mask = (jnp.arange(T) < length)[:, None]
        return (z * mask).sum(0) / jnp.maximum(length, 1)

    codes = interpolation_codes(cfg.eval_codes)

    @jax.jit
    def evaluate(params, norm, heldout, rng):
        """For one seed: interpolation over the code grid, replay over held-out demos, latent codes."""
        keys = jax.random.split(rng, codes.shape[0])
        it = jax.vmap(interp_one, in_axes=(None, None, 0, 0))(params, norm, codes, keys)
        rp = jax.vmap(replay_one, in_axes=(None, None, 0, 0, 0))(
            params, norm, heldout["init"], heldout["ah"], heldout["length"])
        lat = jax.vmap(latent_one, in_axes=(None, None, 0, 0, 0))(
            params, norm, heldout["obs"], heldout["prev_ah"], heldout["length"])
        return {"interp_success": it["success"], "interp_strategy": it["strategy"], "interp_metrics": it["metrics"],
                "replay_success": rp["success"], "replay_metrics": rp, "latent": lat}

    seeds_eval = jax.jit(jax.vmap(evaluate, in_axes=(0, 0, None, None)))
    return seeds_eval, codes


def heldout_arrays(demos) -> dict[str, np.ndarray]:
    prev = np.zeros_like(demos.actions_human)
    prev[:, 1:] = demos.actions_human[:, :-1]
    return {"init": demos.init, "ah": demos.actions_human, "length": demos.length, "obs": demos.obs, "prev_ah": prev,
            "strategy": demos.strategy}


def interpolation_events(metrics: dict, levels: dict[str, int] | None = None) -> dict[str, float]:
    """How often each of a task's episode events happened in a set of rollouts (interpolation, or the replays
    of one strategy's held-out demonstrations), successful or not: for an
    event metric with values 0..3 (e.g. seqmanip's ``opened_by``: 1 human, 2 robot), the share of rollouts with
    each non-zero value (``opened_by=1``); for a 0/1 metric, the share with 1. Continuous metrics (positions)
    are left out. ``metrics``: name -> array whose last axis is the rollouts. Shows how far failed rollouts get
    through a multi-phase task. ``levels`` (from ``event_levels`` of a larger set) fixes which metrics count
    and their values, so that subsets report the same keys."""
    out = {}
    for k, top in (levels if levels is not None else event_levels(metrics)).items():
        v = np.asarray(metrics[k], np.float64)
        if top <= 1:
            out[k] = float(np.mean(v == 1))
        else:
            out.update({f"{k}={x}": float(np.mean(v == x)) for x in range(1, top + 1)})
    return out


def event_levels(metrics: dict) -> dict[str, int]:
    """The event metrics of a set of rollouts (integer values 0..3) and the largest value each takes."""
    out = {}
    for k in sorted(metrics):
        v = np.asarray(metrics[k], np.float64)
        if v.size and np.all(v == np.round(v)) and v.min() >= 0 and v.max() <= 3:
            out[k] = max(int(v.max()), 1)
    return out


def summarize(task: str, method: str, seeds, per_ckpt: dict[int, dict], strategy_names, codes,
              heldout_strategy=None) -> dict:
    """Best checkpoint per seed (by replay success; interpolation's own best too), mean +- std over seeds.
    Also, at those checkpoints: replay success per held-out strategy (``heldout_strategy``: each held-out
    demonstration's strategy id) and the interpolation rollouts' events (``interpolation_events``)."""
    steps = sorted(per_ckpt)
    S = len(seeds)
    rep = np.array([[float(np.mean(per_ckpt[s]["replay_success"][i])) for s in steps] for i in range(S)])
    itp = np.array([[float(np.mean(per_ckpt[s]["interp_success"][i])) for s in steps] for i in range(S)])
    best_r = rep.argmax(1)
    best_i = itp.argmax(1)

    def stat(values):
        v = [float(x) for x in values]
        return {"mean": float(np.mean(v)), "std": float(np.std(v)), "per_seed": dict(zip(map(str, seeds), v))}

    names = ["none", *strategy_names]
    dist_per_seed = {}
    counts_total = np.zeros(len(names))
    for i, seed in enumerate(seeds):
        r = per_ckpt[steps[best_i[i]]]
        st = np.asarray(r["interp_strategy"][i])
        succ = np.asarray(r["interp_success"][i]) > 0
        counts = np.bincount(st[succ], minlength=len(names)).astype(float)
        counts_total += counts
        dist_per_seed[str(seed)] = {n: float(c / max(succ.sum(), 1)) for n, c in zip(names[1:], counts[1:])}
    tot = max(counts_total[1:].sum(), 1)
    extra = {}
    if all("interp_metrics" in per_ckpt[st] for st in steps):
        im = [per_ckpt[steps[best_i[i]]]["interp_metrics"] for i in range(S)]
        levels = event_levels({k: np.stack([m[k][i] for i, m in enumerate(im)]) for k in im[0]})
        ev = [interpolation_events({k: v[i] for k, v in im[i].items()}, levels) for i in range(S)]
        extra["interpolation_events"] = {k: float(np.mean([e.get(k, 0.0) for e in ev])) for k in ev[0]}
    if heldout_strategy is not None:
        hs = np.asarray(heldout_strategy)
        by = {}
        for k, name in enumerate(strategy_names, start=1):
            if (hs == k).any():
                by[name] = float(np.mean([np.mean(np.asarray(per_ckpt[steps[best_r[i]]]["replay_success"][i])[hs == k])
                                          for i in range(S)]))
        extra["replay_by_strategy"] = by
        if all("replay_metrics" in per_ckpt[st] for st in steps):  # how far the replays got, per strategy
            extra["replay_events_by_strategy"] = {}
            rm = [per_ckpt[steps[best_r[i]]]["replay_metrics"] for i in range(S)]
            levels = event_levels({m: np.stack([r[m][i] for i, r in enumerate(rm)]) for m in rm[0]})
            for k, name in enumerate(strategy_names, start=1):
                if (hs == k).any():
                    ev = [interpolation_events({m: np.asarray(v[i])[hs == k] for m, v in rm[i].items()}, levels)
                          for i in range(S)]
                    extra["replay_events_by_strategy"][name] = {m: float(np.mean([e.get(m, 0.0) for e in ev]))
                                                                for m in ev[0]}
    return {
        "task": task,
        "method": method,
        "seeds": list(map(int, seeds)),
        "checkpoints": steps,
        "replay_success": stat(rep[np.arange(S), best_r]),
        "interpolation_success": stat(itp[np.arange(S), best_i]),
        "strategy_distribution": {n: float(c / tot) for n, c in zip(names[1:], counts_total[1:])},
        "strategy_distribution_per_seed": dist_per_seed,
        "best_checkpoint": {str(s): {"replay": int(steps[best_r[i]]), "interpolation": int(steps[best_i[i]])}
                            for i, s in enumerate(seeds)},
        "curves": {"replay_success": rep.tolist(), "interpolation_success": itp.tolist()},
        **extra,
    }


def results_markdown(res: dict) -> str:
    f = lambda d: f"{100 * d['mean']:.1f} +- {100 * d['std']:.1f}"
    lines = [
        f"# {res['method']} on {res['task']}",
        "",
        f"Seeds {', '.join(map(str, res['seeds']))}; {len(res['checkpoints'])} checkpoints; best checkpoint per seed.",
        "",
        "| metric | mean +- std (%) | per seed |",
        "| --- | --- | --- |",
        f"| replay success | {f(res['replay_success'])} | "
        + ", ".join(f"{k}: {100 * v:.0f}" for k, v in res["replay_success"]["per_seed"].items()) + " |",
        f"| interpolation success | {f(res['interpolation_success'])} | "
        + ", ".join(f"{k}: {100 * v:.0f}" for k, v in res["interpolation_success"]["per_seed"].items()) + " |",
        "",
        "Strategies among successful interpolation rollouts:",
        "",
        "| strategy | share (%) |",
        "| --- | --- |",
    ]
    lines += [f"| {k} | {100 * v:.1f} |" for k, v in res["strategy_distribution"].items()]
    if res.get("replay_by_strategy"):
        lines += ["", "Replay success by the held-out demonstration's strategy (best replay checkpoints, mean over "
                  "seeds): " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in res["replay_by_strategy"].items())]
    for name, ev in (res.get("replay_events_by_strategy") or {}).items():
        lines += ["", f"Events in replays of {name} demonstrations: "
                  + ", ".join(f"{k} {100 * v:.0f} %" for k, v in ev.items())]
    if res.get("interpolation_events"):
        lines += ["", "Events in all interpolation rollouts (best interpolation checkpoints, mean over seeds): "
                  + ", ".join(f"{k} {100 * v:.0f} %" for k, v in res["interpolation_events"].items())]
    lines += ["", "Best checkpoint (update) per seed: "
              + ", ".join(f"{s}: replay {b['replay']}, interpolation {b['interpolation']}"
                          for s, b in res["best_checkpoint"].items())]
    return "\n".join(lines) + "\n"


def write_figures(run_dir: Path, res: dict, latent: np.ndarray | None, latent_strategy: np.ndarray | None,
                  strategy_names) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = []
    fig, ax = plt.subplots(figsize=(5, 3))
    names = list(res["strategy_distribution"])
    ax.bar(range(len(names)), [100 * res["strategy_distribution"][n] for n in names], color="tab:blue")
    ax.set_xticks(range(len(names)), [str(i + 1) for i in range(len(names))])
    ax.set_xlabel("strategy")
    ax.set_ylabel("% of successful rollouts")
    ax.set_title(f"{res['method']} on {res['task']}: interpolation")
    fig.tight_layout()
    p = run_dir / "strategy_distribution.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    out.append(p)
    if latent is not None:
        fig, ax = plt.subplots(figsize=(4, 4))
        for k in np.unique(latent_strategy):
            m = latent_strategy == k
            label = strategy_names[k - 1] if 0 < k <= len(strategy_names) else "unknown"
            ax.scatter(latent[m, 0], latent[m, 1], s=14, label=f"{k}: {label}")
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.set_xlabel("z[0]")
        ax.set_ylabel("z[1]")
        ax.set_title("latent map: mean psi code\nper held-out demonstration", fontsize=10)
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = run_dir / "latent_map.png"
        fig.savefig(p, dpi=120)
        plt.close(fig)
        out.append(p)
    return out


def write_handover_spots(run_dir: Path, res: dict, interp_metrics: dict, interp_success, demo_metrics) -> Path:
    """Handover spots of successful interpolation rollouts beside the demonstrations' spots: top (XY) and
    side (XZ) views (paper Fig. 4a)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = np.asarray(interp_success) > 0
    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    for ax, (a, b, label) in zip(axes, (("x", "y", "top view (XY)"), ("x", "z", "side view (XZ)"))):
        if demo_metrics is not None and f"handover_{a}" in demo_metrics:
            ax.scatter(demo_metrics[f"handover_{a}"], demo_metrics[f"handover_{b}"], s=10, c="lightgray",
                       label="demonstrations")
        xs = np.asarray(interp_metrics[f"handover_{a}"]).reshape(-1)[ok.reshape(-1)]
        ys = np.asarray(interp_metrics[f"handover_{b}"]).reshape(-1)[ok.reshape(-1)]
        ax.scatter(xs, ys, s=14, c="tab:green", label=f"{res['method']} interpolation ({ok.sum()} successes)")
        ax.set_xlabel(f"{a} (m)")
        ax.set_ylabel(f"{b} (m)")
        ax.set_title(label)
        ax.legend(fontsize=7)
    fig.tight_layout()
    p = run_dir / "handover_spots.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    return p


def save_results(run_dir: Path, res: dict) -> None:
    (run_dir / "results.json").write_text(json.dumps(res, indent=2))
    (run_dir / "results.md").write_text(results_markdown(res))
