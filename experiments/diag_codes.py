"""Where do the strategies live in the code space? A diagnosis of a fetchq run's interpolation shares.

    python experiments/diag_codes.py RUN [--checkpoint N] [--grid 10]

For every seed of the run, at one checkpoint (default: the latest), prints
  * the learned per-demonstration codes tanh(codes) grouped by the demonstration's strategy (count, mean, std);
  * the share of the code square (-1, 1)^2 whose nearest demonstration code belongs to each strategy (the shares
    the interpolation would give if the co-policy did what its nearest demonstration did);
  * the interpolation map: the strategy of the deterministic rollout from each cell of a grid x grid code grid
    (0 = failure), and its shares.
Comparing the last two tells whether a skewed interpolation comes from the codes' layout or from the policy.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cogail_jax import checkpoint as ckpt  # noqa: E402
from cogail_jax import data, evaluate, trainer  # noqa: E402
from cogail_jax.config import TrainConfig  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--checkpoint", type=int, default=None, help="checkpoint step (default: the latest)")
    ap.add_argument("--grid", type=int, default=10, help="interpolation grid side (grid^2 codes)")
    a = ap.parse_args(argv)
    run = Path(a.run)
    cfg = TrainConfig.load(run / "config.json").replace(eval_codes=a.grid * a.grid)
    s = trainer.build(cfg)
    cfg = s.cfg
    mgr = ckpt.manager(run)
    step = a.checkpoint if a.checkpoint is not None else ckpt.steps(mgr)[-1]
    state = ckpt.restore(mgr, step, jax.eval_shape(lambda: s.init(cfg.seeds, s.expert)))
    demos = data.load_demos(cfg.demos or data.ensure_default_demos(s.env, "train", cfg.mix, verbose=False), s.env)
    strat = np.asarray(demos.strategy)
    seeds_eval, codes = evaluate.make_eval_fns(cfg, s.env, s.nets)
    held = {k: v for k, v in s.heldout.items() if k != "strategy"}
    out = jax.device_get(seeds_eval(state.params, state.norm, held, jax.random.PRNGKey(12345)))
    codes = np.asarray(codes)
    K = int(strat.max())
    print(f"run {run}  checkpoint {step}  mix {cfg.mix}  demos per strategy "
          f"{[int((strat == k).sum()) for k in range(1, K + 1)]}")
    for i, seed in enumerate(cfg.seeds):
        dc = np.tanh(np.asarray(state.params["codes"][i]))
        print(f"\nseed {seed}: demo codes")
        for k in range(1, K + 1):
            c = dc[strat == k]
            print(f"  strategy {k}: n={len(c):3d}  mean {np.round(c.mean(0), 2)}  std {np.round(c.std(0), 2)}")
        near = strat[np.argmin(((codes[:, None] - dc[None]) ** 2).sum(-1), 1)]
        vor = [float((near == k).mean()) for k in range(1, K + 1)]
        st = np.asarray(out["interp_strategy"][i])
        act = [float((st == k).mean()) for k in range(1, K + 1)]
        print(f"  nearest-demo-code shares {np.round(vor, 2)}   interpolation shares {np.round(act, 2)}"
              f"   success {float(np.mean(out['interp_success'][i])):.2f}   replay {float(np.mean(out['replay_success'][i])):.2f}")
        # failed rollouts: the strategy their first fetch started (a-d), or '.' when nobody fetched
        m = {k: np.asarray(v[i]) for k, v in out["interp_metrics"].items()}
        started = np.where(m["first"] == 1, np.where(m["human_room"] == 1, 2, 4),
                           np.where(m["first"] == 2, np.where(m["robot_room"] == 2, 1, 3), 0))
        cell = [str(int(v)) if v > 0 else ("abcd"[u - 1] if u > 0 else ".") for v, u in zip(st, started)]
        g = a.grid
        print("  interpolation map (rows: z_y from +1 down to -1; a-d: failed after starting 1-4)   nearest-demo map")
        for y in reversed(range(g)):
            row = [cell[x * g + y] for x in range(g)]
            print("   " + " ".join(row) + "        " + " ".join(str(int(near[x * g + y])) for x in range(g)))


if __name__ == "__main__":
    main()
