"""Replay success of the BC start (before any GAIL update), per seed: a cheap CPU proxy for what the GAIL
phase starts from and, on HR-SeqManip, for where replay ends up once the PPO learning rate has decayed.

    python experiments/diag_bc_start.py [--config experiments/seqmanip_paper.json] [--seeds 300,400,500]
        [--n 60] [--set k=v ...]

BC pre-training as the trainer runs it (all seeds vmapped), then the replay protocol of
``diag_seqmanip.py`` (robot deterministic on psi's code, human open-loop) on the first N held-out demos.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diag_seqmanip import make_fn  # noqa: E402

from cogail_jax import data, trainer  # noqa: E402
from cogail_jax.config import TrainConfig  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="experiments/seqmanip_paper.json")
    p.add_argument("--seeds", default="300,400,500")
    p.add_argument("--n", type=int, default=60)
    p.add_argument("--set", action="append", default=[])
    a = p.parse_args()
    fields = {k: v for k, v in json.loads(Path(a.config).read_text()).items() if not k.startswith("_")}
    d = TrainConfig()
    for k, v in (x.split("=", 1) for x in a.set):
        kind = type(getattr(d, k))
        fields[k] = (v.lower() in ("1", "true")) if kind is bool else kind(v) if kind in (int, float) else v
    fields.update(seeds=[int(s) for s in a.seeds.split(",")], num_envs=4, unroll_length=10, total_steps=40)
    s = trainer.build(TrainConfig.from_dict(fields))
    t0 = time.time()
    state = s.init(s.cfg.seeds, s.expert)
    jax.block_until_ready(state.params)
    t_bc = time.time() - t0
    h = s.heldout
    ar = data.load_demos(s.cfg.heldout or data.ensure_default_demos(s.env, "heldout", s.cfg.mix), s.env,
                         require_init=True).actions_robot
    n = min(a.n, len(h["init"]))
    fn = make_fn(s.cfg, s.env, s.nets, "policy")
    strat = np.asarray(h["strategy"][:n])
    res = []
    for i, seed in enumerate(s.cfg.seeds):
        params = jax.tree.map(lambda x: x[i], state.params)
        norm = jax.tree.map(lambda x: x[i], state.norm)
        m, _ = fn(params, norm, jnp.asarray(h["init"][:n]), jnp.asarray(h["ah"][:n]), jnp.asarray(ar[:n]),
                  jnp.asarray(h["length"][:n]))
        succ = np.asarray(m["success"]) > 0
        res.append(succ.mean())
        per = " ".join(f"s{k} {int(succ[strat == k].sum())}/{int((strat == k).sum())}" for k in sorted(set(strat.tolist())))
        print(f"seed {seed}: replay {int(succ.sum())}/{n} ({per})", flush=True)
    print(f"{a.set}: BC start replay {100 * np.mean(res):.1f} +- {100 * np.std(res):.1f} % (BC {t_bc:.0f} s, "
          f"total {time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
