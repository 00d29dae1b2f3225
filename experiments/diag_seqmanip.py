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
from diag_seqmanip_trace import make_trace_fn  # noqa: E402


WHO = {0: "-", 1: "H", 2: "R", 3: "both"}


def make_fn(cfg, env, nets, robot_mode):
    """The replay protocol, jitted and vmapped over demos: (metrics, observations per step)."""
    trace = make_trace_fn(cfg, env, nets, robot_mode)

    def run(*args):
        m, rec = trace(*args)
        return m, rec["obs"]

    return run


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
