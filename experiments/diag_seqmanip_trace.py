"""Per-step traces of HR-SeqManip replays: where the learned robot goes with the bar.

    python experiments/diag_seqmanip_trace.py RUN OUT.npz [--seed-index I] [--step S] [--n N]

Loads RUN's checkpoint ``--step`` (default: the best replay checkpoint of seed ``--seed-index`` in RUN's
results.json, else the latest), and runs the replay protocol (human = open-loop actions of held-out demo i,
robot = pi_R(s, psi(h)) deterministic) on the first N held-out demos, and the same demos with the recorded
robot actions (the reference). Writes OUT.npz with, per demo and step, both runs' world-frame robot and human
TCP, bar position, drawer opening, robot action, grasp flags, psi's code and the observation, the episodes' metrics, and the
checkpoint's parameters and normaliser (``params_msgpack``: flax.serialization bytes of {params, norm}) so the
policy can be studied on a CPU without the 300 MB checkpoint.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diag_handover import load_run  # noqa: E402

from cogail_envs import mjx_common as mc  # noqa: E402
from cogail_jax import evaluate  # noqa: E402


def make_trace_fn(cfg, env, nets, robot_mode):
    K, Ah = cfg.history, env.human_action_size
    psi_code, robot_step = evaluate.make_robot_step(cfg, env, nets)

    def one(params, norm, init, ah, ar, length):
        state = env.reset_from(init)
        hist = jnp.repeat(state.obs[None], K + 1, 0)

        def body(carry, t):
            state, hist, prev_ah, fin = carry
            a_h = jnp.where(t < length, ah[jnp.minimum(t, ah.shape[0] - 1)], 0.0)
            if robot_mode == "demo":
                a_r = jnp.where(t < length, ar[jnp.minimum(t, ar.shape[0] - 1)], 0.0)
                z = psi_code(params, norm, hist, prev_ah)
                nxt = env.step(state, jnp.concatenate([a_h, a_r]))
                nhist = jnp.concatenate([hist[1:], nxt.obs[None]], 0)
            else:
                nxt, nhist, z, a_r = robot_step(params, norm, state, hist, prev_ah, a_h)
            d = state.pipeline_state
            rec = {"obs": state.obs, "r_tcp": mc.tcp_pos(d, env.robot), "h_tcp": mc.tcp_pos(d, env.human),
                   "obj": env._obj_pos(d), "opening": env._opening(d), "a_r": a_r, "a_h": a_h, "z": z,
                   "r_grasp": state.info["robot_grasp"], "h_grasp": state.info["human_grasp"],
                   "r_handle": state.info["robot_handle"], "fin": fin}
            new = jax.tree.map(lambda a, b: jnp.where(fin, a, b), state, nxt)
            return (new, nhist, a_h, fin | (nxt.done > 0)), rec

        carry = (state, hist, jnp.zeros((Ah,)), jnp.array(False))
        (state, _, _, _), rec = jax.lax.scan(body, carry, jnp.arange(env.max_episode_steps))
        return state.metrics, rec

    return jax.jit(jax.vmap(one, in_axes=(None, None, 0, 0, 0, 0)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--seed-index", type=int, default=0)
    p.add_argument("--step", type=int)
    p.add_argument("--n", type=int, default=60)
    a = p.parse_args()
    step = a.step
    res = a.run / "results.json"
    if step is None and res.exists():
        r = json.loads(res.read_text())
        seed = str(r["seeds"][a.seed_index])
        step = int(r["best_checkpoint"][seed]["replay"])
    cfg, s, params, norm, step = load_run(a.run, step, seed_index=a.seed_index)
    h = s.heldout
    n = min(a.n, len(h["init"]))
    args = [jnp.asarray(h[k][:n]) for k in ("init", "ah", "ar", "length")]
    out = {"step": step, "seed": cfg.seeds[a.seed_index], "strategy": np.asarray(h["strategy"][:n]),
           "length": np.asarray(h["length"][:n])}
    for mode in ("policy", "demo"):
        m, rec = jax.device_get(make_trace_fn(cfg, s.env, s.nets, mode)(params, norm, *args))
        out.update({f"{mode}_{k}": np.asarray(v) for k, v in {**m, **rec}.items()})
        print(f"{mode}: success {100 * float(np.mean(m['success'])):.1f} % "
              + " ".join(f"s{sid}={100 * float(np.mean(m['success'][out['strategy'] == sid])):.0f}%"
                         for sid in sorted(set(out["strategy"].tolist()))))
    out["params_msgpack"] = np.frombuffer(flax.serialization.to_bytes(
        jax.device_get({"params": params, "norm": norm})), np.uint8)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(a.out, **out)
    print(f"wrote {a.out} (checkpoint {step}, seed {out['seed']}, {n} demos)")


if __name__ == "__main__":
    main()
