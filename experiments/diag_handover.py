"""Why does the learned robot fail the HR-Handover replay protocol? Per-demo diagnostics.

    python experiments/diag_handover.py RUN [N] [--step S] [--human demo|hold|closed] [--robot policy|demo]
    python experiments/diag_handover.py RUN [N] --train [--std-floor F] [--bc-steps B] [--updates U] [--seed S]

Diagnose: loads RUN's latest (or ``--step``) checkpoint and runs the replay protocol of
``evaluate.make_eval_fns`` (robot = pi_R(s, psi(h)), deterministic, against the open-loop human actions of
held-out demonstration i, started from its init) on the first N held-out demos, jitted and vmapped, and
records per-step traces. Per demo it prints success, the robot's first grasp, the human's grasp span (in
the demo and in the replay), the minimum TCP-bar distance (|obs[21:24]|), when the demo's human opens
(a_h[6] > 0 after the first close) versus when the robot arrives, and the largest |normalised obs| (and
which feature), then a summary of failure modes.

``--human``: the human's gripper action in the replay. ``demo`` (the protocol), ``hold``: closed (-1) from
the demo's first close until the end of the demo's hold phase (the step the demo's human fingers are open
again, i.e. the scripted human's H_HOLD -> H_RETREAT switch), ``closed``: closed from the first close to
the end of the episode, so only the env's auto-release (3 steps after the robot holds the lifted bar)
opens it. ``--robot demo`` replays the recorded robot actions too (a physics-determinism check).

``--train`` (bc_single only): makes RUN as ``cogail train --method bc_single --config
experiments/handover_paper.json`` would, but with the normaliser's std floor set to ``--std-floor`` after
``train.fit_normalizer`` (the library default floor is 1e-2), ``--bc-steps`` BC pre-training steps and
``--updates`` bc_single updates; saves the last state as a checkpoint, then diagnoses it (all 60 held-out
demos unless N is given). Nothing in the package is changed.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cogail_jax import checkpoint as ckpt
from cogail_jax import evaluate, train, trainer
from cogail_jax.config import TrainConfig

ROOT = Path(__file__).resolve().parent.parent
OBS_NAMES = ([f"h_pos{i}" for i in range(3)] + [f"h_rot{i}" for i in range(6)]
             + [f"r_pos{i}" for i in range(3)] + [f"r_rot{i}" for i in range(6)]
             + [f"bar_rel_h{i}" for i in range(3)] + [f"bar_rel_r{i}" for i in range(3)]
             + [f"bar_rot{i}" for i in range(6)] + ["gap_h", "gap_r", "grasp_h", "grasp_r", "released"])
H_OPEN_GAP = 0.036 / 0.08  # the scripted human's "fingers open" test, in obs units (gap / MAX_GAP)


def first(mask, default=-1):
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else default


def human_gripper(ah: np.ndarray, obs: np.ndarray, length: int, mode: str) -> tuple[np.ndarray, dict]:
    """The human's actions for the replay (gripper overridden by ``mode``) and the demo's gripper timing."""
    ah = ah.copy()
    g = ah[:length, 6]
    t_close = first(g < 0)
    t_open = first((g > 0) & (np.arange(length) > t_close)) if t_close >= 0 else -1
    # end of the hold phase: the human's fingers are open again after t_open (H_HOLD -> H_RETREAT)
    t_hold_end = first((obs[:length, 30] > H_OPEN_GAP) & (np.arange(length) > max(t_open, 0))) if t_open >= 0 else -1
    if t_hold_end < 0 and t_open >= 0:
        t_hold_end = length
    if mode == "hold" and t_close >= 0:
        ah[t_close:t_hold_end + 1, 6] = -1.0
    elif mode == "closed" and t_close >= 0:
        ah[t_close:, 6] = -1.0
    return ah, {"close": t_close, "open": t_open, "hold_end": t_hold_end}


def make_trace_fn(cfg, env, nets, robot_mode: str):
    """vmapped replay recording per-step traces (replay_one of evaluate.make_eval_fns plus recording)."""
    K, Ah = cfg.history, env.human_action_size
    Tenv = env.max_episode_steps
    _, robot_step = evaluate.make_robot_step(cfg, env, nets)
    actor = nets["actor"].apply

    def freeze(fin, old, new):
        return jax.tree.map(lambda a, b: jnp.where(fin, a, b), old, new)

    def replay_one(params, norm, init, ah, ar, length, ah_after):
        state = env.reset_from(init)
        hist = jnp.repeat(state.obs[None], K + 1, 0)

        def body(carry, t):
            state, hist, prev_ah, fin = carry
            a_h = jnp.where(t < length, ah[jnp.minimum(t, ah.shape[0] - 1)], ah_after)
            nobs = (state.obs - norm["mean"]) / norm["std"]
            if robot_mode == "demo":
                a_r = jnp.where(t < length, ar[jnp.minimum(t, ar.shape[0] - 1)], 0.0)
                nxt = env.step(state, jnp.concatenate([a_h, a_r]))
                nhist = jnp.concatenate([hist[1:], nxt.obs[None]], 0)
            else:
                nxt, nhist, _, a_r = robot_step(params, norm, state, hist, prev_ah, a_h)
            rec = {"obs": state.obs, "nobs_absmax": jnp.max(jnp.abs(nobs)), "nobs_argmax": jnp.argmax(jnp.abs(nobs)),
                   "a_r": a_r, "a_h": a_h, "bar_z": nxt.pipeline_state.xpos[env.obj_body][2],
                   "r_grasp": nxt.info["robot_grasp"], "h_grasp": nxt.info["human_grasp"],
                   "released": nxt.info["released"], "success": nxt.metrics["success"], "fin": fin}
            return (freeze(fin, state, nxt), nhist, a_h, fin | (nxt.done > 0)), rec

        carry = (state, hist, jnp.zeros((Ah,)), jnp.array(False))
        (state, _, _, _), rec = jax.lax.scan(body, carry, jnp.arange(Tenv))
        return state.metrics["success"], rec

    return jax.jit(jax.vmap(replay_one, in_axes=(None, None, 0, 0, 0, 0, 0)))


def demo_stats(obs, ar, length):
    """The demo's own robot: first grasp and |bar - TCP| at that moment."""
    rg = obs[:length, 33] > 0
    t = first(rg)
    return t, (float(np.linalg.norm(obs[t, 21:24])) if t >= 0 else np.nan)


def diagnose(cfg, s, params, norm, n, human_mode, robot_mode, verbose=True, label=""):
    held = s.heldout
    n = min(n, held["init"].shape[0])
    sl = lambda x: np.asarray(x[:n])
    obs_d, ah_d, ar_d, len_d, init_d = sl(held["obs"]), sl(held["ah"]), sl(held["ar"]), sl(held["length"]), sl(held["init"])
    ahs, timing = [], []
    for i in range(n):
        a, tm = human_gripper(ah_d[i], obs_d[i], int(len_d[i]), human_mode)
        ahs.append(a)
        timing.append(tm)
    ahs = np.stack(ahs)
    after = np.zeros((n, env_ah(s)), np.float32)
    if human_mode == "closed":
        after[:, 6] = -1.0
    fn = make_trace_fn(cfg, s.env, s.nets, robot_mode)
    t0 = time.time()
    succ, rec = fn(params, norm, jnp.asarray(init_d), jnp.asarray(ahs), jnp.asarray(ar_d), jnp.asarray(len_d),
                   jnp.asarray(after))
    succ, rec = jax.device_get((succ, rec))
    dt = time.time() - t0
    # the demos' own range of normalised obs, for reference
    ex = s.expert["obs"]
    train_absmax = np.abs((ex - np.asarray(norm["mean"])) / np.asarray(norm["std"])).max(0)
    held_flat = np.concatenate([obs_d[i, :len_d[i]] for i in range(n)])
    held_absmax = np.abs((held_flat - np.asarray(norm["mean"])) / np.asarray(norm["std"])).max(0)
    dg = [demo_stats(obs_d[i], ar_d[i], int(len_d[i])) for i in range(n)]
    grasp_dist = np.nanmedian([d for _, d in dg])
    reach_thr = grasp_dist + 0.015  # "arrived": within 1.5 cm of the demo robot's grasp distance
    rows, modes = [], {}
    for i in range(n):
        live = ~rec["fin"][i]
        T = int(live.sum())  # steps executed before done
        o = rec["obs"][i][:T]
        d = np.linalg.norm(o[:, 21:24], axis=1)
        rg = rec["r_grasp"][i][:T] > 0
        hg = rec["h_grasp"][i][:T] > 0
        t_rg = first(rg)
        t_arr = first(d < reach_thr)
        hg_d = obs_d[i, :len_d[i], 32] > 0
        h_span_demo = (first(hg_d), len(hg_d) - 1 - first(hg_d[::-1]) if hg_d.any() else -1)
        h_span_rep = (first(hg), T - 1 - first(hg[::-1]) if hg.any() else -1)
        bar_z = rec["bar_z"][i][:T]
        # did the bar fall (from lifted to the table) before the robot arrived?
        lifted = bar_z > 0.05
        t_lift = first(lifted)
        t_fall = first((~lifted) & (np.arange(T) > t_lift)) if t_lift >= 0 else -1
        ga = rec["a_h"][i][:T, 6]
        t_open_eff = first((ga > 0) & (np.arange(T) > max(timing[i]["close"], 0))) if timing[i]["close"] >= 0 else -1
        nmax = float(rec["nobs_absmax"][i][:T].max())
        nidx = int(rec["nobs_argmax"][i][:T][np.argmax(rec["nobs_absmax"][i][:T])])
        if succ[i] > 0:
            mode = "success"
        elif t_arr < 0:
            mode = "never reaches"
        elif (t_fall >= 0 and t_fall <= t_arr) or (t_open_eff >= 0 and t_arr > t_open_eff and not rg[:t_open_eff + 1].any()):
            mode = "late (human opened / bar fell first)"
        elif t_rg < 0:
            mode = "reaches, no grasp"
        else:
            mode = "grasps, then fails"
        modes[mode] = modes.get(mode, 0) + 1
        rows.append({"demo": i, "success": int(succ[i] > 0), "mode": mode, "steps": T, "len": int(len_d[i]),
                     "robot_grasp_t": t_rg, "demo_robot_grasp_t": dg[i][0], "human_grasp_demo": h_span_demo,
                     "human_grasp_replay": h_span_rep, "min_dist": float(d.min()), "t_min_dist": int(d.argmin()),
                     "arrive_t": t_arr, "human_close_t": timing[i]["close"], "human_open_t": timing[i]["open"],
                     "hold_end_t": timing[i]["hold_end"], "open_replay_t": t_open_eff, "bar_fall_t": t_fall, "nobs_absmax": nmax,
                     "nobs_argmax": OBS_NAMES[nidx]})
    if verbose:
        print(f"\n== {label} human={human_mode} robot={robot_mode}: {n} demos, replay {dt:.1f} s "
              f"(robot arrives = |bar - TCP| < {reach_thr * 100:.1f} cm; demo robot grasps at {grasp_dist * 100:.1f} cm)")
        print("demo succ  rgrasp(demo) | h-grasp demo   h-grasp replay | min|d| cm @t  arrive | h close open hold_end"
              " | fall | max|nobs| feature        | mode")
        for r in rows:
            print(f"{r['demo']:4d} {r['success']:4d}  {r['robot_grasp_t']:4d} ({r['demo_robot_grasp_t']:4d}) | "
                  f"{r['human_grasp_demo'][0]:4d}-{r['human_grasp_demo'][1]:<4d}    {r['human_grasp_replay'][0]:4d}-"
                  f"{r['human_grasp_replay'][1]:<4d}    | {100 * r['min_dist']:6.1f} @{r['t_min_dist']:<4d} {r['arrive_t']:5d} | "
                  f"  {r['human_close_t']:4d} {r['human_open_t']:4d} {r['hold_end_t']:4d} | {r['bar_fall_t']:4d} | "
                  f"{r['nobs_absmax']:8.1f} {r['nobs_argmax']:14s} | {r['mode']}")
    nm = np.array([r["nobs_absmax"] for r in rows])
    summary = {"label": label, "human": human_mode, "robot": robot_mode, "n": n,
               "success": float(np.mean(succ > 0)), "modes": modes,
               "median_min_dist_cm": float(100 * np.nanmedian([r["min_dist"] for r in rows])),
               "median_arrive_minus_open": float(np.median([r["arrive_t"] - r["human_open_t"] for r in rows
                                                            if r["arrive_t"] >= 0 and r["human_open_t"] >= 0] or [np.nan])),
               "median_robot_grasp_t_minus_demo": float(np.median([r["robot_grasp_t"] - r["demo_robot_grasp_t"] for r in rows
                                                                   if r["robot_grasp_t"] >= 0] or [np.nan])),
               "replay_nobs_absmax_median": float(np.nanmedian(nm)), "replay_nobs_absmax_max": float(np.nanmax(nm)), "nonfinite_episodes": int(np.sum(~np.isfinite(nm))),
               "train_demo_nobs_absmax": float(train_absmax.max()),
               "train_demo_nobs_absmax_feature": OBS_NAMES[int(train_absmax.argmax())],
               "heldout_demo_nobs_absmax": float(held_absmax.max()),
               "heldout_demo_nobs_absmax_feature": OBS_NAMES[int(held_absmax.argmax())]}
    if verbose:
        print("summary:", json.dumps(summary, indent=1))
        small = np.asarray(norm["std"]) < 0.02
        print("features with std < 2e-2:", [f"{OBS_NAMES[j]}={float(np.asarray(norm['std'])[j]):.2g}"
                                            for j in np.flatnonzero(small)])
    return summary, rows


def env_ah(s):
    return s.env.human_action_size


def load_run(run: Path, step: int | None, seed_index: int = 0):
    cfg = TrainConfig.load(run / "config.json")
    s = trainer.build(cfg)
    cfg = s.cfg
    mgr = ckpt.manager(run)
    steps = ckpt.steps(mgr)
    step = steps[-1] if step is None else step
    from cogail_jax import data
    hpath = cfg.heldout or data.ensure_default_demos(s.env, "heldout", cfg.mix)
    s.heldout["ar"] = data.load_demos(hpath, s.env, require_init=True).actions_robot
    abstract = jax.eval_shape(lambda: s.init(cfg.seeds, s.expert))
    state = ckpt.restore(mgr, step, abstract)
    params = jax.tree.map(lambda x: x[seed_index], state.params)  # one seed (the first by default)
    norm = jax.tree.map(lambda x: x[seed_index], state.norm)
    return cfg, s, params, norm, step


def train_bc(run: Path, std_floor: float, bc_steps: int, updates: int, seed: int):
    """bc_single as the CLI would make it, but with the normaliser's std floor overridden."""
    base = json.loads((ROOT / "experiments/handover_paper.json").read_text())
    base = {k: v for k, v in base.items() if not k.startswith("_")}
    upc = min(10, updates)
    cfg = TrainConfig.from_dict({**base, "method": "bc_single", "seeds": [seed], "bc_steps": bc_steps,
                                 "total_steps": updates * 64 * 94, "checkpoint_every": upc,
                                 "updates_per_call": upc}).validate()
    run.mkdir(parents=True, exist_ok=True)
    (run / "config.json").write_text(cfg.to_json())
    s = trainer.build(cfg)
    norm = train.fit_normalizer(s.expert)
    norm = {**norm, "std": np.maximum(s.expert["obs"].std(0), std_floor)}
    init, chunk, nets = train.make_train_fns(s.cfg, s.env, norm)
    t0 = time.time()
    state = init(s.cfg.seeds, s.expert)
    for _ in range(trainer.total_updates(s.cfg) // s.cfg.updates_per_call):
        state, m = chunk(state, s.expert)
    jax.block_until_ready(state)
    print(f"trained {run}: std floor {std_floor}, bc_steps {bc_steps}, {updates} updates, {time.time() - t0:.0f} s; "
          f"last bc loss {float(np.asarray(m['bc_loss'])[-1].mean()):.4f}", flush=True)
    mgr = ckpt.manager(run)
    ckpt.save(mgr, int(trainer.total_updates(s.cfg)), state)
    (run / "diag_train.json").write_text(json.dumps({"std_floor": std_floor, "bc_steps": bc_steps, "updates": updates}))
    # the diagnosis must use this run's normaliser: it is stored in the checkpoint's state.norm
    return s, state


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run")
    p.add_argument("n", nargs="?", type=int, default=60)
    p.add_argument("--step", type=int, default=None)
    p.add_argument("--human", default="demo", help="comma list of demo, hold, closed")
    p.add_argument("--robot", default="policy", choices=("policy", "demo"))
    p.add_argument("--train", action="store_true")
    p.add_argument("--std-floor", type=float, default=1e-2)
    p.add_argument("--bc-steps", type=int, default=3000)
    p.add_argument("--updates", type=int, default=10)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--quiet", action="store_true", help="summaries only")
    p.add_argument("--json", default=None, help="write summaries and rows here")
    a = p.parse_args(argv)
    run = Path(a.run)
    if a.train:
        train_bc(run, a.std_floor, a.bc_steps, a.updates, a.seed)
    cfg, s, params, norm, step = load_run(run, a.step)
    print(f"{run}: {cfg.method}, checkpoint {step}, std floor in use {float(np.min(np.asarray(norm['std']))):.3g}")
    out = []
    for hm in a.human.split(","):
        summ, rows = diagnose(cfg, s, params, norm, a.n, hm, a.robot, verbose=not a.quiet, label=f"{run.name}@{step}")
        if a.quiet:
            print(json.dumps(summ))
        out.append({"summary": summ, "rows": rows})
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1, default=int))


if __name__ == "__main__":
    sys.exit(main())
