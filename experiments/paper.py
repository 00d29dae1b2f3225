"""Rebuild the paper's tables: Table 1 (replay), Table 2 (interpolation), Fig. 3 (strategy proportions on
fetchq for the D1 / D2 mixtures), for every task x method (3 seeds each, one vmapped program per run).

    python experiments/paper.py --tasks fetchq --methods cogail,ma_gail --out results/paper [--mixes uniform,D1,D2]

Each (task, method, mixture) trains with ``experiments/<task>_paper.json`` into ``<out>/runs/...`` (resuming a
finished or interrupted run instead of starting again), evaluates every checkpoint, and the tables are written
to ``<out>/table1_replay.md``, ``<out>/table2_interpolation.md``, ``<out>/fig3_strategies.{md,png}`` and
``<out>/paper.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent

PAPER_REPLAY = {  # Table 1 of the paper (mean, std in %)
    "bc_single": {"fetchq": (21.1, 1.9), "handover": (13.3, 3.3), "seqmanip": (15.0, 2.3)},
    "bc_gail": {"fetchq": (27.2, 5.0), "handover": (14.1, 4.6), "seqmanip": (16.6, 7.1)},
    "ma_gail": {"fetchq": (30.0, 3.4), "handover": (23.7, 5.3), "seqmanip": (21.0, 3.7)},
    "ma_infogail": {"fetchq": (40.0, 1.7), "handover": (27.8, 4.4), "seqmanip": (26.6, 8.8)},
    "diayn": {"fetchq": (44.4, 8.4), "handover": (22.7, 1.5), "seqmanip": (18.3, 7.1)},
    "cogail": {"fetchq": (53.3, 4.4), "handover": (43.9, 6.3), "seqmanip": (40.0, 8.2)},
}
PAPER_INTERP = {  # Table 2 of the paper
    "ma_gail": {"fetchq": (78.5, 7.2), "handover": (99.2, 1.4), "seqmanip": (46.2, 10.3)},
    "ma_infogail": {"fetchq": (80.2, 3.0), "handover": (96.4, 4.1), "seqmanip": (51.7, 7.5)},
    "diayn": {"fetchq": (80.2, 3.6), "handover": (86.2, 9.0), "seqmanip": (45.4, 7.9)},
    "cogail": {"fetchq": (82.1, 3.1), "handover": (81.2, 3.1), "seqmanip": (31.6, 2.5)},
}


def run_one(task, method, mix, seeds, out: Path, extra: dict, every: int = 1) -> dict:
    from cogail_jax import trainer
    from cogail_jax.config import TrainConfig

    fields = json.loads((ROOT / f"{task}_paper.json").read_text())
    fields.pop("_comment", None)
    cfg = TrainConfig.from_dict({**fields, **extra, "task": task, "method": method, "mix": mix,
                                 "seeds": tuple(seeds)}).validate()
    run = out / "runs" / f"{task}-{method}-{mix}"
    resume = (run / "config.json").exists()
    trainer.train_run(cfg, run, resume=resume, progress=False)
    return trainer.eval_run(run, progress=False, every=every)


def fmt(d):
    return f"{100 * d['mean']:.1f} +- {100 * d['std']:.1f}"


def tables(results: dict, tasks, methods, out: Path) -> None:
    rows1 = ["| method | " + " | ".join(f"{t} (ours) | {t} (paper)" for t in tasks) + " |",
             "| --- |" + " --- | --- |" * len(tasks)]
    rows2 = list(rows1[:2])
    for m in methods:
        r1, r2 = [m], [m]
        for t in tasks:
            res = results.get(f"{t}/{m}/uniform")
            p1, p2 = PAPER_REPLAY.get(m, {}).get(t), PAPER_INTERP.get(m, {}).get(t)
            r1 += [fmt(res["replay_success"]) if res else "-", f"{p1[0]} +- {p1[1]}" if p1 else "-"]
            r2 += [fmt(res["interpolation_success"]) if res else "-", f"{p2[0]} +- {p2[1]}" if p2 else "-"]
        rows1.append("| " + " | ".join(r1) + " |")
        rows2.append("| " + " | ".join(r2) + " |")
    (out / "table1_replay.md").write_text("# Table 1: replay success (%)\n\n" + "\n".join(rows1) + "\n")
    (out / "table2_interpolation.md").write_text("# Table 2: interpolation success (%)\n\n" + "\n".join(rows2) + "\n")
    fig3 = [k for k in results if k.startswith("fetchq/") and not k.endswith("/uniform")]
    if fig3:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        lines = ["# Fig. 3: strategies among successful fetchq interpolation rollouts (%)", "",
                 "| method | mixture | s1 | s2 | s3 | s4 |", "| --- | --- | --- | --- | --- | --- |"]
        mixes = sorted({k.split("/")[2] for k in fig3})
        fig, axes = plt.subplots(1, len(mixes), figsize=(5 * len(mixes), 3.5), squeeze=False)
        for ax, mix in zip(axes[0], mixes):
            ms = [m for m in methods if f"fetchq/{m}/{mix}" in results]
            for j, m in enumerate(ms):
                dist = list(results[f"fetchq/{m}/{mix}"]["strategy_distribution"].values())
                lines.append(f"| {m} | {mix} | " + " | ".join(f"{100 * v:.0f}" for v in dist) + " |")
                ax.bar([i + j * 0.8 / len(ms) for i in range(4)], [100 * v for v in dist], width=0.8 / len(ms), label=m)
            ax.set_xticks(range(4), ["s1", "s2", "s3", "s4"])
            ax.set_title(f"fetchq {mix}")
            ax.set_ylabel("% of successful rollouts")
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "fig3_strategies.png", dpi=120)
        (out / "fig3_strategies.md").write_text("\n".join(lines) + "\n")
    (out / "paper.json").write_text(json.dumps(results, indent=2))


ORDER = ("bc_single", "bc_gail", "ma_gail", "ma_infogail", "diayn", "cogail")


def table_axes(results: dict, tasks, methods):
    """Tasks and methods to tabulate: those asked for plus those already in paper.json (earlier calls)."""
    keys = [k.split("/") for k in results]
    ts = [t for t in ("fetchq", "handover", "seqmanip") if t in tasks or any(k[0] == t for k in keys)]
    ms = [m for m in ORDER if m in methods or any(k[1] == m for k in keys)]
    return ts, ms


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tasks", default="fetchq")
    p.add_argument("--methods", default="cogail,ma_infogail,ma_gail,bc_gail,bc_single,diayn")
    p.add_argument("--mixes", default="uniform", help="fetchq mixtures (D1, D2 give Fig. 3)")
    p.add_argument("--seeds", default="300,400,500")
    p.add_argument("--out", default="results/paper")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="override config fields")
    p.add_argument("--eval-every", type=int, default=1, help="evaluate every k-th checkpoint (default: all)")
    p.add_argument("--force", action="store_true", help="redo runs already in <out>/paper.json")
    p.add_argument("--merge", nargs="+", default=[], metavar="DIR",
                   help="train nothing: add the paper.json of each DIR (runs made side by side, e.g. by "
                        "experiments/gpu_grid.sh) to --out's and rewrite the tables")
    a = p.parse_args(argv)
    sys.path.insert(0, str(ROOT.parent / "src"))
    from cogail_jax.config import TrainConfig

    extra = {}
    for item in a.set:
        k, v = item.split("=", 1)
        kind = type(getattr(TrainConfig(), k))
        extra[k] = kind(v)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    tasks, methods = a.tasks.split(","), a.methods.split(",")
    seeds = [int(s) for s in a.seeds.split(",")]
    results = json.loads((out / "paper.json").read_text()) if (out / "paper.json").exists() else {}
    if a.merge:
        for d in a.merge:
            if (Path(d) / "paper.json").is_file():
                results.update(json.loads((Path(d) / "paper.json").read_text()))
        tables(results, *table_axes(results, [], []), out)
        tasks = []
    for t in tasks:
        for m in methods:
            for mix in (a.mixes.split(",") if t == "fetchq" else ["uniform"]):
                if f"{t}/{m}/{mix}" in results and not a.force:
                    print(f"{t:9} {m:12} {mix:8} already in {out / 'paper.json'} (--force to redo)", flush=True)
                    continue
                res = run_one(t, m, mix, seeds, out, extra, a.eval_every)
                results[f"{t}/{m}/{mix}"] = {k: res[k] for k in ("replay_success", "interpolation_success",
                                                                  "strategy_distribution", "best_checkpoint")}
                print(f"{t:9} {m:12} {mix:8} replay {fmt(res['replay_success'])}  "
                      f"interp {fmt(res['interpolation_success'])}", flush=True)
                tables(results, *table_axes(results, tasks, methods), out)
    print((out / "table1_replay.md").read_text())
    print((out / "table2_interpolation.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
