"""Where does the learned robot fail the HR-SeqManip replay protocol? Per-stage diagnostics.

    python experiments/diag_seqmanip.py RUN [N] [--step S] [--robot policy|demo]

Loads RUN's latest (or ``--step``) checkpoint (first seed) and runs the replay protocol (robot =
pi_R(s, psi(h)) deterministic, human = open-loop actions of held-out demo i from its init) on the first N
held-out demos, jitted and vmapped. ``--robot demo`` replays the recorded robot actions too (a determinism
check of the physics: it should succeed on every demo). Per strategy it prints how far the episodes got
(handover, drawer opened by whom, object placed by whom, drawer closed by whom, success) next to the demos,
and the step at which the robot's TCP first strays more than 3 cm from the demo's.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diag_handover import load_run  # noqa: E402

from cogail_jax import evaluate  # noqa: E402

WHO = {0: "-", 1: "H", 2: "R", 3: "both"}


def make_fn(cfg, env, nets, robot_mode):
    K, Ah = cfg.history, env.human_action_size
    _, robot_step = evaluate.make_robot_step(cfg, env, nets)

    def one(params, norm, init, ah, ar, length):
        state = env.reset_from(init)
        hist = jnp.repeat(state.obs[None], K + 1, 0)

        def body(carry, t):
            state, hist, prev_ah, fin = carry
            a_h = jnp.where(t < length, ah[jnp.minimum(t, ah.shape[0] - 1)], 0.0)
            if robot_mode == "demo":
                a_r = jnp.where(t < length, ar[jnp.minimum(t, ar.shape[0] - 1)], 0.0)
                nxt = env.step(state, jnp.concatenate([a_h, a_r]))
                nhist = jnp.concatenate([hist[1:], nxt.obs[None]], 0)
            else:
                nxt, nhist, _, _ = robot_step(params, norm, state, hist, prev_ah, a_h)
            new = jax.tree.map(lambda a, b: jnp.where(fin, a, b), state, nxt)
            return (new, nhist, a_h, fin | (nxt.done > 0)), state.obs

        carry = (state, hist, jnp.zeros((Ah,)), jnp.array(False))
        (state, _, _, _), obs = jax.lax.scan(body, carry, jnp.arange(env.max_episode_steps))
        return state.metrics, obs

    return jax.jit(jax.vmap(one, in_axes=(None, None, 0, 0, 0, 0)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("n", type=int, nargs="?", default=60)
    p.add_argument("--step", type=int)
    p.add_argument("--robot", choices=("policy", "demo"), default="policy")
    a = p.parse_args()
    cfg, s, params, norm, step = load_run(a.run, a.step)
    h = s.heldout
    n = min(a.n, len(h["init"]))
    fn = make_fn(cfg, s.env, s.nets, a.robot)
    m, obs = jax.device_get(fn(params, norm, jnp.asarray(h["init"][:n]), jnp.asarray(h["ah"][:n]),
                               jnp.asarray(h["ar"][:n]), jnp.asarray(h["length"][:n])))
    strat, length = np.asarray(h["strategy"][:n]), np.asarray(h["length"][:n])
    demo_obs = np.asarray(h["obs"][:n])
    print(f"{a.run} checkpoint {step}, robot={a.robot}, {n} held-out demos: "
          f"success {100 * float(np.mean(m['success'])):.1f} %")
    names = getattr(s.env, "strategy_names", None) or {}
    for sid in sorted(set(strat.tolist())):
        idx = np.where(strat == sid)[0]
        print(f"\nstrategy {sid} {names[sid - 1] if isinstance(names, (list, tuple)) else ''} ({len(idx)} demos)")
        print(" demo  succ  handover  opened  placed  closed  max_open  stray@ / len")
        for i in idx:
            L = int(length[i])
            T = min(L, obs.shape[1])
            dev = np.linalg.norm(obs[i, :T, 9:12] - demo_obs[i, :T, 9:12], axis=1)
            stray = int(np.argmax(dev > 0.03)) if np.any(dev > 0.03) else -1
            print(f" {i:4d}  {int(m['success'][i]):4d}  {int(m['handover'][i]):8d}  {WHO[int(m['opened_by'][i])]:>6}  "
                  f"{WHO[int(m['placed_by'][i])]:>6}  {WHO[int(m['closed_by'][i])]:>6}  {float(m['max_open'][i]):8.3f}"
                  f"  {stray:6d} / {L}")


if __name__ == "__main__":
    main()
