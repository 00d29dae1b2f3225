"""The robustness figures: replay success against each varied human (:mod:`cogail_jax.data.varied`) beside the
in-distribution replay, at the reported checkpoints and per checkpoint."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from cogail_envs.variations import VARIATIONS

from ..data.varied import PREFIX


def _entry(e) -> dict:
    """{"mean", "std", "by_strategy"} from a float, a {"mean"/"success", "std", "by_strategy"} dict or an eval_run
    extra-set entry ({"selected": {...}, "paper_protocol": {...}})."""
    if isinstance(e, (int, float)):
        return {"mean": float(e), "std": 0.0, "by_strategy": {}}
    if "selected" in e or "paper_protocol" in e:
        e = e.get("selected") or e.get("paper_protocol")
    mean = e.get("mean", e.get("success"))
    return {"mean": float(mean), "std": float(e.get("std", 0.0) or 0.0), "by_strategy": dict(e.get("by_strategy") or {})}


def parse_results(results: dict) -> dict[str, dict]:
    """``{"in-distribution": entry, <variation>: entry, ...}`` from eval_run's results (results.json: the
    in-distribution replay at the selected checkpoint, else the paper-protocol one; the extra sets named
    ``robust-<variation>``) or from a flat ``{name: rate or {"mean", "std", "by_strategy"}}`` dict."""
    out = {}
    if "extra_sets" in results:
        sel = results.get("selected") or {}
        rep = sel.get("replay") or (results.get("paper_protocol") or {}).get("replay")
        if rep:
            out["in-distribution"] = {**_entry(rep), "by_strategy": dict(results.get("replay_by_strategy") or {})}
        for name, e in (results.get("extra_sets") or {}).items():
            if name.startswith(PREFIX) and isinstance(e, dict):
                out[name[len(PREFIX):]] = _entry(e)
        return out
    for name, e in results.items():
        key = "in-distribution" if name in ("in_distribution", "in-distribution", "replay") else name
        out[key[len(PREFIX):] if key.startswith(PREFIX) else key] = _entry(e)
    return out


def robustness_figure(results: dict, out_png, blind: dict | None = None, title: str | None = None) -> Path:
    """Bars: replay success per variation next to the in-distribution replay (overall, with the std over seeds,
    and per strategy where known). ``blind``: optional ``{variation: blind_robot_success(...)}`` drawn as markers
    (the robot that ignores the human: in-distribution and varied)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = parse_results(results)
    names = (["in-distribution"] if "in-distribution" in rows else []) + [v for v in VARIATIONS if v in rows]
    names += [k for k in rows if k not in names]
    strategies = []
    for n in names:
        strategies += [s for s in rows[n]["by_strategy"] if s not in strategies]
    series = ["all", *strategies]
    width = 0.8 / len(series)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(names) + 2), 4.0))
    colors = plt.get_cmap("tab10")
    for j, s in enumerate(series):
        vals = [rows[n]["mean"] if s == "all" else rows[n]["by_strategy"].get(s, np.nan) for n in names]
        vals = [np.nan if v is None else 100 * v for v in vals]
        err = [100 * rows[n]["std"] for n in names] if s == "all" else None
        ax.bar(x - 0.4 + width * (j + 0.5), vals, width, yerr=err, capsize=3, label=s,
               color="0.3" if s == "all" else colors(j - 1), alpha=1.0 if s == "all" else 0.75)
    if blind:
        bx, by_ = [], []
        ind = [b["in_distribution"] for b in blind.values() if b.get("in_distribution") is not None]
        if ind and "in-distribution" in names:
            bx.append(names.index("in-distribution"))
            by_.append(100 * float(np.mean(ind)))
        for v, b in blind.items():
            if v in names:
                bx.append(names.index(v))
                by_.append(100 * b["varied"])
        bx = np.asarray(bx, float) - 0.4 + width * 0.5  # over the "all" bars: overall against overall
        ax.plot(bx, by_, "rv", markersize=9, label="blind robot (ignores the human)")
    ax.set_xticks(x, names, rotation=20)
    ax.set_ylabel("replay success (%)")
    ax.set_ylim(0, 105)
    ax.set_title(title or "Robustness: replay against varied humans")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


def robustness_curve_figure(results: dict, out_png, title: str | None = None) -> Path | None:
    """Lines: the seed-mean replay success of each varied-human set at every checkpoint (results.json's
    ``extra_sets[robust-<variation>]["curve"]``) next to the in-distribution test replay, with the checkpoint
    selected on validation marked. None (nothing written) when the results hold no such curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ckpts = results.get("checkpoints") or []
    lines = {}
    if (results.get("curves") or {}).get("replay_success"):
        lines["in-distribution"] = results["curves"]["replay_success"]
    for name, e in (results.get("extra_sets") or {}).items():
        if name.startswith(PREFIX) and isinstance(e, dict) and e.get("curve"):
            lines[name[len(PREFIX):]] = e["curve"]
    lines = {k: np.asarray(v, float).mean(0) for k, v in lines.items() if np.shape(v)[-1] == len(ckpts)}
    if len(lines) < 2 or not ckpts:
        return None
    fig, ax = plt.subplots(figsize=(7.0, 4.0))
    for name, y in lines.items():
        ax.plot(ckpts, 100 * y, lw=2.2 if name == "in-distribution" else 1.2, marker="o", ms=2.5,
                color="k" if name == "in-distribution" else None, label=name)
    sel = (results.get("selected") or {}).get("checkpoint")
    if sel is not None:
        ax.axvline(sel, color="tab:green", ls="--", lw=1.0, label="selected on validation")
    ax.set_xlabel("update")
    ax.set_ylabel("replay success (%), mean over seeds")
    ax.set_ylim(-3, 103)
    ax.grid(alpha=0.3)
    ax.set_title(title or "Robustness per checkpoint")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


