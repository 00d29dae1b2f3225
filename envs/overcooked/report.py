"""The figures of ``docs/overcooked.md`` as Markdown tables: the replay agreement of every kitchen's trials, the
datasets' sizes and how the people's episodes spread over the strategies (``python -m cogail_envs.overcooked``)."""
from __future__ import annotations

import time

import numpy as np

from . import kitchen as kt
from . import trials as tr
from .env import Overcooked


def _pct(n: int, total: int) -> str:
    return f"{100.0 * n / total:.2f} %" if total else "-"


def agreement_table() -> str:
    """Every trial of both files replayed open loop (:func:`trials.replay_agreement`): per kitchen and file the
    steps whose next state matches the recorded one, per field and in all."""
    head = ["kitchen", "file", "trials", "steps", *tr.FIELDS, "all", "diverged trials"]
    rows = []
    total = {f: 0 for f in (*tr.FIELDS, "all", "steps", "trials")}
    for kitchen in kt.KITCHENS:
        for split in ("train", "test"):
            a = tr.replay_agreement(kitchen, split)
            for f in total:
                total[f] += a[f]
            diverged = sum(d >= 0 for d in a["first_divergence"])
            rows.append([kitchen, split, a["trials"], a["steps"], *(a[f] for f in tr.FIELDS), a["all"], diverged])
    rows.append(["**all**", "", total["trials"], total["steps"], *(total[f] for f in tr.FIELDS), total["all"], ""])
    share = ["", "", "", "share", *(_pct(total[f], total["steps"]) for f in (*tr.FIELDS, "all")), ""]
    return _markdown(head, [*rows, share])


def cook_counter_overrun() -> dict:
    """How often a recorded pot's cook counter is past 20 (a ready soup still in its pot): the steps of both files'
    full pots (pot-steps after each step), those whose counter reads more than 20 (the steps JaxMARL shows as
    "ready", 0) and the largest reading."""
    pots = {data: {tuple(p) for p in kt.kitchen_geometry(ours).pots.tolist()}
            for ours, (_, data) in kt.KITCHENS.items()}
    full = over = top = 0
    for split in ("train", "test"):
        df = tr._frame(str(tr.trial_file(split)))
        for layout, s in zip(df.layout_name, df.next_state):
            for obj in tr.parse(s)["objects"].values():
                if tuple(obj["position"]) in pots[layout] and obj["state"][1] >= kt.MAX_ONIONS:
                    cook = int(obj["state"][2])
                    full += 1
                    over += cook > kt.COOK_STEPS
                    top = max(top, cook)
    return {"full_pot_steps": full, "past_20": over, "max_cook_time": top}


def dataset_rows(kitchens=tuple(kt.KITCHENS)) -> list[dict]:
    """Per kitchen and split: pairs, trials, windows of play, steps, windows per strategy id (labelled with the
    trial's player 0 as the human), deliveries and the time :func:`trials.recorded` took (seconds, this process;
    the first split of a kitchen parses its trials and compiles the replay). The files hold each window twice, the
    human agent as player 0 and then as player 1: the counts here are of the first copies."""
    rows = []
    for kitchen in kitchens:
        env = Overcooked(kitchen)
        for split in tr.SPLITS:
            t0 = time.perf_counter()
            r = tr.recorded(env, split)
            seconds = time.perf_counter() - t0
            rows.append(dict(kitchen=kitchen, split=split, pairs=len(set(r["pair"].tolist())),
                             trials=len(tr.split_trials(kitchen, split)), **window_counts(env, r), seconds=seconds))
    return rows


def window_counts(env: Overcooked, r: dict) -> dict:
    """Windows of play, their steps, windows per strategy id and deliveries of a split (:func:`trials.recorded`),
    each window counted once: its copy with the trial's player 0 as the human (the files hold each twice)."""
    first = slice(0, None, 2)
    return dict(episodes=len(r["length"][first]), steps=int(r["length"][first].sum()),
                strategies=np.bincount(r["strategy"][first], minlength=env.num_strategies + 1).tolist(),
                soups=float(r["final_metrics"]["soups"][first].sum()))


def split_table(rows: list[dict]) -> str:
    head = ["kitchen", "split", "pairs", "trials", "episodes", "steps", "soups served", "recorded() s"]
    body = [[r["kitchen"], r["split"], r["pairs"], r["trials"], r["episodes"], r["steps"], int(r["soups"]),
             f"{r['seconds']:.1f}"] for r in rows]
    return _markdown(head, body)


def strategy_table(rows: list[dict]) -> str:
    names = Overcooked.strategy_names
    head = ["kitchen", "split", *(f"{i} {n}" for i, n in enumerate(("none", *names)))]
    body = [[r["kitchen"], r["split"], *r["strategies"]] for r in rows]
    totals = np.sum([r["strategies"] for r in rows], axis=0)
    body.append(["**all**", "", *totals.tolist()])
    return _markdown(head, body)


def _markdown(head: list, rows: list[list]) -> str:
    lines = ["| " + " | ".join(str(h) for h in head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def main() -> None:
    rows = dataset_rows()
    print("## Datasets\n\n" + split_table(rows) + "\n")
    print("## Strategies\n\n" + strategy_table(rows) + "\n")
    print("## Replay agreement\n\n" + agreement_table() + "\n")
    print("cook counter:", cook_counter_overrun())
