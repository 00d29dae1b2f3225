"""The reporting protocol: figures per checkpoint and seed -> results.json / results.md and figures.

Reporting (``summarize``): every checkpoint is evaluated on the test split (replay, interpolation, latent codes)
and on the validation split (replay, interpolation). results.json reports

* ``paper_protocol``: the paper's figure, for replay and interpolation separately: the checkpoint that maximises
  the mean over seeds of the test success, with mean +- std over seeds there (std: population, ddof 0);
* ``selected``: the checkpoint that maximises the mean over seeds of the validation replay success, with its
  test figures (replay and interpolation): nothing is chosen on the test set, so this is the honest headline;
* ``last``: the last checkpoint's test figures;
* ``per_seed_best``: each seed's own best checkpoint (inflated; for reference only).

Ties (equal seed means) go to the later checkpoint, in every selection. The breakdowns (strategy distribution,
replay by strategy, events, latent map, handover spots) are computed at the selected checkpoint.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .rollouts import REPLAY_MARGIN


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


SELECTION_RULE = ("the checkpoint with the highest mean over seeds of the validation replay success "
                  "(ties: the later checkpoint)")


def stat(values, seeds) -> dict:
    """Mean +- std (population, ddof 0) over seeds, and the value of each seed."""
    v = [float(x) for x in values]
    return {"mean": float(np.mean(v)), "std": float(np.std(v)), "per_seed": dict(zip(map(str, seeds), v))}


def argmax_seed_mean(curves) -> int:
    """Index of the checkpoint whose mean over seeds is highest; ties go to the later checkpoint.
    ``curves``: (seeds, checkpoints) success rates."""
    m = np.round(np.asarray(curves, np.float64).mean(0), 9)  # equal counts give equal means, whatever the order
    return int(len(m) - 1 - np.argmax(m[::-1]))


def _per_ckpt_rate(per_ckpt, steps, key, S) -> np.ndarray:
    return np.array([[float(np.mean(per_ckpt[s][key][i])) for s in steps] for i in range(S)])


def strategy_distribution(strategy, success, strategy_names) -> tuple[dict, dict]:
    """Shares of the executed strategies among successful interpolation rollouts: pooled over seeds, and per
    seed. ``strategy`` / ``success``: (seeds, rollouts)."""
    names = ["none", *strategy_names]
    per_seed, total = [], np.zeros(len(names))
    for st, ok in zip(np.asarray(strategy), np.asarray(success) > 0):
        counts = np.bincount(np.asarray(st)[ok], minlength=len(names)).astype(float)[: len(names)]
        total += counts
        per_seed.append({n: float(c / max(ok.sum(), 1)) for n, c in zip(names[1:], counts[1:])})
    tot = max(total[1:].sum(), 1)
    return {n: float(c / tot) for n, c in zip(names[1:], total[1:])}, per_seed


def summarize(task: str, method: str, seeds, per_ckpt: dict[int, dict], strategy_names, codes,
              heldout_strategy=None) -> dict:
    """The reporting protocol (module docstring) from the evaluations of every checkpoint.

    ``per_ckpt[step]``: arrays with a leading seed axis: ``replay_success`` (seeds, test episodes),
    ``interp_success`` / ``interp_strategy`` (seeds, codes), optionally ``val_replay_success`` (seeds, validation
    episodes), ``val_interp_success`` / ``val_interp_strategy`` (seeds, codes: the validation interpolation),
    ``interp_metrics`` / ``replay_metrics`` (name -> (seeds, n)). Without validation results there is
    no ``selected`` checkpoint (None) and the breakdowns are at the last checkpoint. ``heldout_strategy``: each
    test demonstration's strategy id (for the replay success per strategy)."""
    steps = sorted(per_ckpt)
    S = len(seeds)
    rep = _per_ckpt_rate(per_ckpt, steps, "replay_success", S)
    itp = _per_ckpt_rate(per_ckpt, steps, "interp_success", S)
    has_val = all("val_replay_success" in per_ckpt[st] for st in steps)
    val = _per_ckpt_rate(per_ckpt, steps, "val_replay_success", S) if has_val else None
    has_vi = all("val_interp_success" in per_ckpt[st] for st in steps)
    vitp = _per_ckpt_rate(per_ckpt, steps, "val_interp_success", S) if has_vi else None
    c_r, c_i, last = argmax_seed_mean(rep), argmax_seed_mean(itp), len(steps) - 1
    c_v = argmax_seed_mean(val) if has_val else None
    at = c_v if has_val else last  # where the breakdowns are computed: never chosen on the test set

    def dist(c, prefix=""):
        r = per_ckpt[steps[c]]
        return strategy_distribution(r[prefix + "interp_strategy"], r[prefix + "interp_success"], strategy_names)

    def figures(c):
        out = {"checkpoint": int(steps[c]), "replay": stat(rep[:, c], seeds), "interpolation": stat(itp[:, c], seeds)}
        if has_val:
            out["validation_replay"] = stat(val[:, c], seeds)
        if has_vi:
            out["validation_interpolation"] = stat(vitp[:, c], seeds)
        return out

    best_r, best_i = rep.argmax(1), itp.argmax(1)
    res = {
        "task": task,
        "method": method,
        "seeds": list(map(int, seeds)),
        "checkpoints": steps,
        "paper_protocol": {
            "rule": "for replay and interpolation separately: the checkpoint with the highest mean over seeds "
                    "of the test success (ties: the later checkpoint); mean +- std over seeds there",
            "replay": {"checkpoint": int(steps[c_r]), **stat(rep[:, c_r], seeds)},
            "interpolation": {"checkpoint": int(steps[c_i]), **stat(itp[:, c_i], seeds),
                              "strategy_distribution": dist(c_i)[0]},
        },
        "selected": {"rule": SELECTION_RULE, **figures(c_v)} if has_val else None,
        "last": figures(last),
        "per_seed_best": {
            "note": "each seed's own best checkpoint on test: inflated, for reference only",
            "replay": {**stat(rep[np.arange(S), best_r], seeds),
                       "checkpoint": {str(sd): int(steps[best_r[i]]) for i, sd in enumerate(seeds)}},
            "interpolation": {**stat(itp[np.arange(S), best_i], seeds),
                              "checkpoint": {str(sd): int(steps[best_i[i]]) for i, sd in enumerate(seeds)}},
        },
        "breakdowns_at": {"checkpoint": int(steps[at]),
                          "basis": "selected on validation" if has_val else "last checkpoint (no validation set)"},
    }
    d, d_seed = dist(at)
    res["strategy_distribution"] = d
    res["strategy_distribution_per_seed"] = dict(zip(map(str, seeds), d_seed))
    if has_vi:  # the same, from the validation interpolation rollouts: choices about diversity are made on it
        res["validation_strategy_distribution"] = dist(at, "val_")[0]
    r_at = per_ckpt[steps[at]]
    if "interp_metrics" in r_at:
        im = r_at["interp_metrics"]
        levels = event_levels(im)
        ev = [interpolation_events({k: np.asarray(v)[i] for k, v in im.items()}, levels) for i in range(S)]
        res["interpolation_events"] = {k: float(np.mean([e.get(k, 0.0) for e in ev])) for k in ev[0]}
    if heldout_strategy is not None:
        hs = np.asarray(heldout_strategy)
        res["replay_by_strategy"] = replay_by_strategy(r_at["replay_success"], hs, strategy_names)
        if "replay_metrics" in r_at:  # how far the replays got, per strategy
            rm = r_at["replay_metrics"]
            levels = event_levels(rm)
            res["replay_events_by_strategy"] = {}
            for k, name in enumerate(strategy_names, start=1):
                if (hs == k).any():
                    ev = [interpolation_events({m: np.asarray(v[i])[hs == k] for m, v in rm.items()}, levels)
                          for i in range(S)]
                    res["replay_events_by_strategy"][name] = {m: float(np.mean([e.get(m, 0.0) for e in ev]))
                                                              for m in ev[0]}
    res["curves"] = {"replay_success": rep.tolist(), "interpolation_success": itp.tolist()}
    if has_val:
        res["curves"]["validation_replay_success"] = val.tolist()
    if has_vi:
        res["curves"]["validation_interpolation_success"] = vitp.tolist()
    return res


def reported_checkpoints(res: dict) -> list[int]:
    """The checkpoints a results.json reports figures of: the one selected on validation, the paper protocol's (each
    column), the last, and each seed's own best (each column)."""
    out = set()
    for key in ("selected", "last"):
        if isinstance(res.get(key), dict):
            out.add(int(res[key]["checkpoint"]))
    if isinstance((res.get("field") or {}).get("selected"), dict):  # the field's protocol's own selection
        out.add(int(res["field"]["selected"]["checkpoint"]))
    for col in ("replay", "interpolation"):
        pp = (res.get("paper_protocol") or {}).get(col)
        if isinstance(pp, dict):
            out.add(int(pp["checkpoint"]))
        best = ((res.get("per_seed_best") or {}).get(col) or {}).get("checkpoint")
        if isinstance(best, dict):
            out |= {int(v) for v in best.values()}
    return sorted(out)


def selected_checkpoint(res: dict) -> tuple[int | None, int | None]:
    """(seed, checkpoint) of a results.json for showing one robot (``cogail play``, ``cogail video``): the
    checkpoint selected on validation and, there, the seed with the best validation replay success (ties: the
    first seed). Results without a selected checkpoint: the paper-protocol replay checkpoint and its best seed on
    test; results made before the reporting protocol: the first seed's best replay checkpoint. (None, None) if
    the results name no checkpoint."""
    def best_seed(d):
        per = (d or {}).get("per_seed") or {}
        return int(max(per, key=lambda k: (per[k], -list(per).index(k)))) if per else None

    if isinstance(res.get("selected"), dict):
        return best_seed(res["selected"].get("validation_replay")), int(res["selected"]["checkpoint"])
    if isinstance(res.get("paper_protocol"), dict):
        pp = res["paper_protocol"]["replay"]
        return best_seed(pp), int(pp["checkpoint"])
    if isinstance(res.get("best_checkpoint"), dict) and res["best_checkpoint"]:
        seed = next(iter(res["best_checkpoint"]))
        return int(seed), int(res["best_checkpoint"][seed]["replay"])
    return None, None


def replay_by_strategy(success, strategy, strategy_names) -> dict[str, float]:
    """Replay success (mean over seeds) of the episodes of each strategy. ``success``: (seeds, episodes)."""
    success, strategy = np.asarray(success, np.float64), np.asarray(strategy)
    return {name: float(success[:, strategy == k].mean(1).mean())
            for k, name in enumerate(strategy_names, start=1) if (strategy == k).any()}


def summarize_extra_set(success, strategy, seeds, strategy_names, checkpoints: dict[str, int], file=None) -> dict:
    """An extra test set replayed at given checkpoints. ``success``: {"selected": (seeds, episodes), ...} with the
    same keys as ``checkpoints`` (e.g. selected, paper_protocol)."""
    out = {"file": None if file is None else str(file), "episodes": int(np.asarray(strategy).shape[0])}
    for key, step in checkpoints.items():
        out[key] = {"checkpoint": int(step), **stat(np.asarray(success[key], np.float64).mean(1), seeds),
                    "by_strategy": replay_by_strategy(success[key], strategy, strategy_names)}
    return out


def _f(d) -> str:
    return f"{100 * d['mean']:.1f} +- {100 * d['std']:.1f}"


def _seeds(d) -> str:
    return ", ".join(f"{k}: {100 * v:.0f}" for k, v in d["per_seed"].items())


def extra_set_markdown(name: str, e: dict) -> list[str]:
    lines = [f"| {name} | {e['episodes']} |"]
    for key in ("selected", "paper_protocol"):
        lines[0] += (f" {_f(e[key])} (ckpt {e[key]['checkpoint']}) |" if e.get(key) else " - |")
    return lines


def _training_success_line(ts: dict | None) -> list[str]:
    """One sentence on the co-policy's success in its own training episodes (``trainer``'s ``training_success``)."""
    cs = ts["checkpoints"] if ts else []
    spans = [(a + 1, c, r) for a, c, r in zip([0] + cs[:-1], cs, ts["mean"]) if r is not None] if ts else []
    if not spans:
        return []
    (a0, c0, r0), (a1, c1, r1) = spans[0], spans[-1]
    return ["", f"The co-policy's own training episodes (both agents the co-policy) succeeded {100 * r0:.1f} % over "
            f"updates {a0}-{c0} and {100 * r1:.1f} % over updates {a1}-{c1} (mean over seeds; windows of at least one "
            "time limit, so that the failures, which end there, count beside the successes; every window: results.json's "
            "training_success)."]


def results_markdown(res: dict) -> str:
    if "paper_protocol" not in res:  # results written before the reporting protocol
        return _results_markdown_per_seed(res)
    pp, sel, last, psb = res["paper_protocol"], res.get("selected"), res["last"], res["per_seed_best"]
    lines = [
        f"# {res['method']} on {res['task']}",
        "",
        f"Seeds {', '.join(map(str, res['seeds']))}; {len(res['checkpoints'])} checkpoints. Success in % on the test "
        "set, mean +- std over seeds (per seed in brackets).",
        "",
        "| checkpoint choice | checkpoint (update) | replay | interpolation |",
        "| --- | --- | --- | --- |",
    ]
    if sel:
        vi = f", interpolation {_f(sel['validation_interpolation'])}" if sel.get("validation_interpolation") else ""
        lines.append(f"| **selected on validation** (validation replay {_f(sel['validation_replay'])}{vi}) | "
                     f"{sel['checkpoint']} | **{_f(sel['replay'])}** ({_seeds(sel['replay'])}) | "
                     f"**{_f(sel['interpolation'])}** ({_seeds(sel['interpolation'])}) |")
    lines += [
        f"| paper protocol (max over checkpoints of the seed mean, per column) | replay {pp['replay']['checkpoint']}, "
        f"interpolation {pp['interpolation']['checkpoint']} | {_f(pp['replay'])} ({_seeds(pp['replay'])}) | "
        f"{_f(pp['interpolation'])} ({_seeds(pp['interpolation'])}) |",
        f"| last | {last['checkpoint']} | {_f(last['replay'])} | {_f(last['interpolation'])} |",
        f"| per-seed best (inflated, reference only) | per seed | {_f(psb['replay'])} | {_f(psb['interpolation'])} |",
        "",
        ("Selected: " + SELECTION_RULE + ". " if sel else "No validation set was evaluated: no selected checkpoint. ")
        + f"The breakdowns below are at checkpoint {res['breakdowns_at']['checkpoint']} "
        f"({res['breakdowns_at']['basis']})."
        + (f" Every checkpoint acts with the moving average of its trained co-policy and psi (policy_ema "
           f"{res['policy_ema']})." if res.get("policy_ema") else ""),
        *_training_success_line(res.get("training_success")),
        "",
        "Strategies among successful interpolation rollouts:",
        "",
        "| strategy | share (%) | share at the paper-protocol interpolation checkpoint (%) | share, validation "
        "rollouts (%) |",
        "| --- | --- | --- | --- |",
    ]
    ppd, vd = pp["interpolation"].get("strategy_distribution", {}), res.get("validation_strategy_distribution")
    lines += [f"| {k} | {100 * v:.1f} | {100 * ppd.get(k, 0.0):.1f} | {f'{100 * vd.get(k, 0.0):.1f}' if vd else '-'} |"
              for k, v in res["strategy_distribution"].items()]
    if res.get("replay_by_strategy"):
        lines += ["", "Replay success by the test demonstration's strategy (mean over seeds): "
                  + ", ".join(f"{k} {100 * v:.1f} %" for k, v in res["replay_by_strategy"].items())]
    for name, ev in (res.get("replay_events_by_strategy") or {}).items():
        lines += ["", f"Events in replays of {name} demonstrations: "
                  + ", ".join(f"{k} {100 * v:.0f} %" for k, v in ev.items())]
    if res.get("interpolation_events"):
        lines += ["", "Events in all interpolation rollouts (mean over seeds): "
                  + ", ".join(f"{k} {100 * v:.0f} %" for k, v in res["interpolation_events"].items())]
    if res.get("extra_sets"):
        lines += ["", "Extra test sets (replay success, %):", "",
                  "| set | episodes | at the selected checkpoint | at the paper-protocol replay checkpoint |",
                  "| --- | --- | --- | --- |"]
        for name, e in res["extra_sets"].items():
            lines += extra_set_markdown(name, e)
        lines += ["", f"An extra set's replay ends at the task's time limit, or {100 * REPLAY_MARGIN:.0f} % of it "
                  "after the end of the human's recording where that is later: a slow or hesitant human's recording "
                  "can run into the limit's last steps, and the clock would decide instead of the robot (the test and "
                  "validation splits: the time limit, as in the paper)."]
        if any(name.startswith("patient-") for name in res["extra_sets"]):
            lines += ["", "patient-*: the same recordings replayed with a patient human, who does not let go of what "
                      "the robot has not taken yet but waits for it and then goes on with its recording; the plain "
                      "replay lets go when the recorded human did, so a robot a few steps later than the "
                      "demonstrator fails there."]
        if res.get("train_varied"):
            lines += ["", f"The training set held {res['train_varied']} varied-human episodes of each variation "
                      "(train_varied): the robust-* sets are kinds of person the robot was trained on, not new ones."]
    if res.get("field"):
        from .field import markdown as field_markdown

        lines += field_markdown(res["field"])
    if res.get("coplay"):
        from .coplay import markdown as coplay_markdown

        lines += coplay_markdown(res["coplay"])
    return "\n".join(lines) + "\n"


def _results_markdown_per_seed(res: dict) -> str:
    f = _f
    lines = [
        f"# {res['method']} on {res['task']}",
        "",
        f"Seeds {', '.join(map(str, res['seeds']))}; {len(res['checkpoints'])} checkpoints; best checkpoint per seed.",
        "",
        "| metric | mean +- std (%) | per seed |",
        "| --- | --- | --- |",
        f"| replay success | {f(res['replay_success'])} | {_seeds(res['replay_success'])} |",
        f"| interpolation success | {f(res['interpolation_success'])} | {_seeds(res['interpolation_success'])} |",
    ]
    return "\n".join(lines) + "\n"


def extra_set_results(res: dict, name: str) -> dict:
    """The results.json of one extra set's own directory (``replay_results_dir``): the run's identity, the set's
    entry, and ``replay_success``: the set's figure at the checkpoint selected on validation (else the
    paper-protocol replay checkpoint)."""
    e = res["extra_sets"][name]
    head = e.get("selected") or e.get("paper_protocol")
    return {"task": res["task"], "method": res["method"], "seeds": res["seeds"], "set": name, **e,
            "replay_success": {k: head[k] for k in ("mean", "std", "per_seed")}, "checkpoint": head["checkpoint"]}


def extra_set_results_markdown(r: dict) -> str:
    lines = [f"# {r['method']} on {r['task']}: replay against {r['set']}", "",
             f"{r['episodes']} episodes from {r.get('file')}; replay success in %, mean +- std over seeds.", "",
             "| set | episodes | at the selected checkpoint | at the paper-protocol replay checkpoint |",
             "| --- | --- | --- | --- |", *extra_set_markdown(r["set"], r)]
    for key in ("selected", "paper_protocol"):
        if r.get(key) and r[key]["by_strategy"]:
            lines += ["", f"By strategy ({key.replace('_', ' ')}): "
                      + ", ".join(f"{k} {100 * v:.1f} %" for k, v in r[key]["by_strategy"].items())]
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


def write_spots(path: Path, res: dict, keys: tuple, interp_metrics: dict, interp_success, demo_metrics,
                what: str = "spots") -> Path:
    """Where the strategy happened (``keys``: the x, y, z metrics of a task's ``Task.spots``) in successful
    interpolation rollouts, beside the demonstrations': top (XY) and side (XZ) views (the paper's Fig. 4a)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = np.asarray(interp_success) > 0
    kx, ky, kz = keys
    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    for ax, (a, b, label) in zip(axes, ((kx, ky, "top view (XY)"), (kx, kz, "side view (XZ)"))):
        if demo_metrics is not None and a in demo_metrics:
            ax.scatter(demo_metrics[a], demo_metrics[b], s=10, c="lightgray", label="demonstrations")
        xs = np.asarray(interp_metrics[a]).reshape(-1)[ok.reshape(-1)]
        ys = np.asarray(interp_metrics[b]).reshape(-1)[ok.reshape(-1)]
        ax.scatter(xs, ys, s=14, c="tab:green", label=f"{res['method']} interpolation ({ok.sum()} successes)")
        ax.set_xlabel(f"{a} (m)")
        ax.set_ylabel(f"{b} (m)")
        ax.set_title(f"{what}, {label}")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def save_results(run_dir: Path, res: dict) -> None:
    (run_dir / "results.json").write_text(json.dumps(res, indent=2))
    (run_dir / "results.md").write_text(results_markdown(res))
