"""How far does the GAIL phase move the co-policy off its BC start? (HR-SeqManip / handover, CPU-sized.)

    python experiments/diag_drift.py RUN UPDATES [--envs 200] [--n 30] [--set k=v ...]

Loads RUN's checkpoint 0 (the BC start; first seed), trains it on for UPDATES Co-GAIL updates with RUN's
config and the overrides (few envs, so it fits a CPU; the learning-rate schedule stays the paper's
1000-update one), and runs the replay protocol of ``diag_seqmanip.py`` on the first N held-out demos before
and after. Prints one line per evaluation.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diag_seqmanip import make_fn  # noqa: E402

from cogail_jax import checkpoint as ckpt  # noqa: E402
from cogail_jax import trainer  # noqa: E402
from cogail_jax.config import TrainConfig  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("updates", type=int)
    p.add_argument("--envs", type=int, default=200)
    p.add_argument("--n", type=int, default=30)
    p.add_argument("--every", type=int, default=0, help="also evaluate every this many updates")
    p.add_argument("--set", action="append", default=[])
    a = p.parse_args()
    base = TrainConfig.load(a.run / "config.json")
    d = TrainConfig()
    over = {k: type(getattr(d, k))(v) for k, v in (x.split("=", 1) for x in a.set)}
    unroll = over.pop("unroll_length", 10)
    cfg = base.replace(num_envs=a.envs, unroll_length=unroll, seeds=base.seeds[:1], updates_per_call=10,
                       checkpoint_every=10, total_steps=1000 * a.envs * unroll, bc_steps=0, **over)
    s = trainer.build(cfg)
    mgr = ckpt.manager(a.run)
    s0 = trainer.build(base.replace(seeds=base.seeds[:1]))
    start = ckpt.restore(mgr, 0, jax.eval_shape(lambda: s0.init(s0.cfg.seeds, s0.expert)))
    state = s.init(s.cfg.seeds, s.expert)
    state = state.replace(params=start.params, norm=start.norm)
    h = s.heldout
    from cogail_jax import data
    hpath = cfg.heldout or data.ensure_default_demos(s.env, "heldout", cfg.mix)
    ar = data.load_demos(hpath, s.env, require_init=True).actions_robot
    n = min(a.n, len(h["init"]))
    fn = make_fn(s.cfg, s.env, s.nets, "policy")

    def replay(st):
        params = jax.tree.map(lambda x: x[0], st.params)
        norm = jax.tree.map(lambda x: x[0], st.norm)
        m, _ = fn(params, norm, jnp.asarray(h["init"][:n]), jnp.asarray(h["ah"][:n]), jnp.asarray(ar[:n]),
                  jnp.asarray(h["length"][:n]))
        m = jax.device_get(m)
        strat = np.asarray(h["strategy"][:n])
        per = " ".join(f"s{k}={int(np.sum(m['success'][strat == k]))}/{int(np.sum(strat == k))}"
                       for k in sorted(set(strat.tolist())))
        return int(np.sum(m["success"])), per

    print(f"{a.run} {over} envs={a.envs}: update 0 replay {replay(state)}", flush=True)
    t0 = time.time()
    done = 0
    while done < a.updates:
        state, m = s.chunk(state, s.expert)
        done += s.cfg.updates_per_call
        mm = {k: float(np.asarray(v).mean()) for k, v in m.items()}
        line = (f"update {done}: reward {mm['reward']:.3f} entropy {mm['entropy']:.2f} succ {mm['episode_success']:.3f}"
                + (f" ppo_bc {mm['ppo_bc']:.4f}" if "ppo_bc" in mm else "") + f" loss_r {mm.get('loss_r', 0):.4f}"
                + f" ({time.time() - t0:.0f} s)")
        if (a.every and done % a.every == 0) or done >= a.updates:
            line += f" replay {replay(state)}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
