"""The scripted team's success in each pose range and held-out slice of a task (CPU-sized).

``python experiments/pose_slices.py --task handover --num 16``: ``num`` episodes of the team in range (no variation)
and in each of its held-out slices (``Team.held_out_slices``: ``variation | pose_slice(axis)``), made by the task's
one generator program (the slices share its calls); prints per set the team's success with the drawn strategy and the
share that also validates by open-loop re-simulation (what the evaluation sets keep), with ``--coplay`` the scripted
human of each set with the co-play scripted robot (``Team.robot_act``, on observables only), and writes them as JSON
with ``--out``."""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from cogail_jax.apps.options import file_out, positive


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--task", required=True)
    p.add_argument("--num", type=positive, default=16)
    p.add_argument("--seed", type=int, default=900)
    p.add_argument("--batch", type=positive, default=None)
    p.add_argument("--slices", default="", help="comma-separated axes (default: the team's)")
    p.add_argument("--validate", action="store_true", help="also re-simulate each episode open-loop")
    p.add_argument("--coplay", action="store_true",
                   help="also the scripted human of each set with the co-play scripted robot (observables only)")
    p.add_argument("--out", type=file_out("pose_slices.json"), default=None)
    a = p.parse_args(argv)
    import cogail_envs
    from cogail_envs.variations import POSE_AXES, pose_slice, slice_name

    from cogail_jax.data.generate import Request, resolve_mix, run_requests

    try:
        team = cogail_envs.get_task(a.task).team
    except cogail_envs.UnknownTaskError as e:
        p.error(f"--task: {e}")
    if team is None:
        with_team = [t for t in cogail_envs.task_names() if cogail_envs.get_task(t).team is not None]
        p.error(f"--task {a.task}: the task has no scripted team to play its episodes: give one of "
                f"{', '.join(with_team)}")
    axes = [x for x in a.slices.split(",") if x] or list(team.held_out_slices)
    if bad := [x for x in axes if x not in team.held_out_slices]:
        have = (f"give comma-separated axes of {', '.join(team.held_out_slices)}" if team.held_out_slices else
                "leave --slices out")
        what = "a pose axis" if bad[0] not in POSE_AXES else f"one of {a.task}'s held-out slices"
        p.error(f"--slices: {bad[0]!r} is not {what}: {have}")
    if a.coplay:
        from cogail_jax.eval import coplay

        if team.human_act is None or team.robot_act is None:
            p.error(f"--coplay: {a.task}'s team has no scripted human and robot to play apart: leave --coplay out")
        if 2 * a.num > coplay.REF_STRIDE:
            p.error(f"--num {a.num}: with --coplay give at most {coplay.REF_STRIDE // 2} episodes per set")
    env = cogail_envs.make_env(a.task)
    sets = [("in-range", 0)] + [(slice_name(x), pose_slice(x)) for x in axes]
    w = resolve_mix(env, "uniform")
    reqs = []
    for i, (_, vid) in enumerate(sets):
        keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(jax.random.PRNGKey(a.seed + i), np.arange(a.num))
        reqs.append(Request(keys, w, vid, validate=a.validate))
    t0 = time.time()
    outs = run_requests(env, reqs, a.batch)
    res = {}
    print(f"| {a.task} set | team success | with validation | mean length |")
    print("| --- | --- | --- | --- |")
    for (name, _), o in zip(sets, outs):
        ok = (o["success"] > 0) & (o["executed"] == o["strategy"])
        val = ok & (o["valid_success"] > 0) & (o["valid_executed"] == o["strategy"]) if a.validate else None
        res[name] = {"episodes": int(len(ok)), "success": float(ok.mean()),
                     "validated": None if val is None else float(val.mean()),
                     "length": float(o["length"][ok].mean()) if ok.any() else None,
                     "failed_strategies": [int(s) for s in o["strategy"][~ok]]}
        v = "-" if val is None else f"{int(val.sum())}/{len(ok)}"
        print(f"| {name} | {int(ok.sum())}/{len(ok)} ({100 * ok.mean():.0f} %) | {v} | "
              f"{res[name]['length'] or 0:.0f} |", flush=True)
    print(f"({time.time() - t0:.0f} s)")
    if a.coplay:
        from cogail_jax.eval import coplay

        t0 = time.time()
        partners = [coplay.SCRIPTED] + [name for name, _ in sets[1:]]
        batch = coplay.episode_batch(env, partners, a.num, ("scripted",), first=a.num)
        out = jax.device_get(coplay.make_coplay_fn(env)(None, None, None, batch))
        print(f"| {a.task} co-play partner | scripted robot (observables only) |")
        print("| --- | --- |")
        for name in partners:
            ok = np.asarray(out["success"][0])[np.asarray(batch["partner"]) == name]
            res.setdefault("coplay", {})[name] = float(ok.mean())
            print(f"| {name} | {int(ok.sum())}/{len(ok)} ({100 * ok.mean():.0f} %) |", flush=True)
        print(f"({time.time() - t0:.0f} s)")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        with open(a.out, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
