"""Robustness protocol: replay against humans that differ from the demonstrators.

The held-out replay test uses trajectories of the same scripted generator as training, so it cannot tell a
robot that follows the human from one that replays the demonstrators' timing. Here the scripted HUMAN of
each task's team (:mod:`cogail_envs.variations`) is varied -- ``slow``, ``fast``, ``pauses``, ``detour``,
``noise``, ``change_of_mind`` (what each means per task: the team modules' docstrings) -- while the scripted
robot keeps reacting to what the human actually does. Every varied episode is a real, successful
human-human episode, and is kept only if it is validated by re-simulation: both agents' recorded actions,
replayed open-loop from the recorded initial state, make the env report success with the same strategy id.

:func:`ensure_robustness_sets` writes (and caches) one HDF5 file per variation in the dataset schema
(:mod:`cogail_jax.data.io`), ``data/<task>_<mix>_robust-<variation>.hdf5``, made by the task's generator
(:mod:`.generate`: the variation is an argument, so one compiled program serves every variation, and the
variations' episodes share its calls).
Generator seeds: 100 + variation index (test split), 200 + index (validation split), distinct from the
default sets' 0 (train), 1 (test) and 2 (validation). File attrs: the usual ones plus ``variation``,
``variation_id``, ``split``, ``requested``, ``attempted``, ``team_success``, ``validated``, ``yield`` and
``robust_version``; each demo carries ``gen_index`` (its episode index in the generator: the same key with
no variation gives the unvaried "twin" episode, same initial state, strategy and within-strategy draws).

:func:`blind_robot_success` measures where a robot that follows the human and one that does not part ways:
the twin's recorded robot actions (a robot with the demonstrators' timing that ignores the human) replayed
open-loop against the varied human, and against an in-distribution human (the twin re-drawn with fresh
per-step randomness: reaction delays, short pauses, noise).

Evaluation of a trained robot (``trainer.eval_run(run, extra_sets=ensure_robustness_sets(env))``) replays
pi_R(s, psi(h)) against the recorded human actions of each file; :func:`robustness_figure` plots the
result per variation next to the in-distribution replay.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cogail_envs.variations import HELD_OUT, POSE_AXES, VARIATIONS, held_out_sets, variation_id

from cogail_envs import team_of

from .generate import (Request, chunks, generator_batch, replay_fn, resolve_mix, run_episodes, run_requests,
                       training_flags, training_env)
from .io import _stored_version, data_dir, default_count, load_demos, missing, save_demos

ROBUST_VERSION = 3  # bump when the variations change (cached files are regenerated)
SPLIT_SEED = {"test": 100, "validation": 200, "train": 300}  # + the variation's index
PREFIX = "robust-"

__all__ = ["VARIATIONS", "protocol_variations", "ensure_robustness_sets", "generate_varied", "blind_robot_success", "robust_path", "variation_seed", "validate_episodes", "ensure_varied_training_set"]


class VariedEpisodes(NamedTuple):
    """Padded batch of episodes (the fields :func:`data.save_demos` writes) and each one's generator index."""

    obs: np.ndarray
    actions_human: np.ndarray
    actions_robot: np.ndarray
    length: np.ndarray
    strategy: np.ndarray
    executed: np.ndarray
    success: np.ndarray
    init: np.ndarray
    final_metrics: dict
    gen_index: np.ndarray


HELD_OUT_SEED = 50  # + the split's seed: the held-out pose slice's generator seed (+ 1 + the axis' index per axis)


def variation_seed(variation: str, split: str = "test") -> int:
    if split not in SPLIT_SEED:
        raise ValueError(f"unknown split {split!r}: use {', '.join(SPLIT_SEED)}")
    if variation == HELD_OUT:
        return SPLIT_SEED[split] + HELD_OUT_SEED
    if variation.startswith(HELD_OUT + "_"):
        return SPLIT_SEED[split] + HELD_OUT_SEED + 1 + POSE_AXES.index(variation[len(HELD_OUT) + 1:])
    return SPLIT_SEED[split] + VARIATIONS.index(variation)


def protocol_variations(env) -> tuple[str, ...]:
    """The evaluation's varied humans of ``env``'s task: :data:`VARIATIONS`, and where its team draws held-out pose
    slices one set per slice (``pose_heldout_<axis>``, ``variations.held_out_sets``)."""
    from cogail_envs import get_task

    return tuple(VARIATIONS) + held_out_sets(get_task(env.name).team)


def robust_path(task: str, variation: str, mix: str = "uniform", split: str = "test", num: int = 0) -> Path:
    default = default_count(task, "test")
    tail = ("" if split == "test" else f"_{split}") + (f"_{num}" if num and num != default else "")
    return data_dir() / f"{task}_{mix}_{PREFIX}{variation}{tail}.hdf5"


def _episode_keys(seed: int, index: np.ndarray) -> jax.Array:
    return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(jax.random.PRNGKey(seed), jnp.asarray(index, jnp.uint32))


def _hold_pad(env, actions: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Actions after each episode's end replaced by "stand still": zero motion, the gripper (MJX tasks: the last
    dim of a 7-dim agent action) kept as it was at the last recorded step."""
    out = np.array(actions, np.float32, copy=True)
    T = out.shape[1]
    t = np.arange(T)[None, :, None]
    n = np.asarray(length)[:, None, None]
    last = out[np.arange(len(out)), np.maximum(np.asarray(length) - 1, 0)][:, None, :]
    hold = np.zeros_like(out)
    if out.shape[-1] == 7:  # gripper command of the MJX tasks' (dx, dy, dz, drx, dry, drz, g)
        hold[..., 6] = last[..., 6]
    return np.where(t < n, out, hold)


def _pad_time(a: np.ndarray, T: int) -> np.ndarray:
    if a.shape[1] >= T:
        return a[:, :T]
    return np.concatenate([a, np.zeros((a.shape[0], T - a.shape[1], a.shape[2]), a.dtype)], 1)


def validate_episodes(env, init, actions_human, actions_robot, batch: int | None = None) -> dict[str, np.ndarray]:
    """Open-loop re-simulation of recorded episodes (arrays padded to ``max_episode_steps`` or shorter):
    ``success``, ``executed`` and ``length`` per episode."""
    T = env.max_episode_steps
    ah, ar = _pad_time(np.asarray(actions_human, np.float32), T), _pad_time(np.asarray(actions_robot, np.float32), T)
    init = np.asarray(init, np.float32)
    batch = generator_batch(batch)
    f = replay_fn(env, batch)
    out = {k: np.zeros(len(init), d) for k, d in (("success", np.float32), ("executed", np.int32), ("length", np.int32))}
    for idx, pad in chunks(len(init), batch):
        r = jax.device_get(f(jnp.asarray(init[pad]), jnp.asarray(ah[pad]), jnp.asarray(ar[pad])))
        for k in out:
            out[k][idx] = np.asarray(r[k])[: len(idx)]
    return out


# ------------------------------------------------------------------------------------------ generation
def _attempts(num: int) -> int:
    """Episodes tried first for ``num`` kept ones (most validate)."""
    return max(4, int(np.ceil(num * 1.25)) + 2)


class VariedSpec(NamedTuple):
    """A varied set to make: ``num`` episodes of ``variation`` from generator seed ``seed`` (``following_partner``:
    see ``generate_varied``; ``flags``: further variation flags, e.g. ``generate.training_flags``)."""

    variation: str
    num: int
    seed: int
    following_partner: bool = False
    flags: int = 0


def generate_varied_sets(env, specs: list[VariedSpec], mix="uniform", batch: int | None = None,
                         max_attempts: int | None = None) -> list[tuple[VariedEpisodes, dict]]:
    """``generate_varied`` for several sets at once: each round tries episodes of every set still short of its
    ``num`` in the same generator calls (``generate.run_requests``), so the sets share chunks."""
    from cogail_envs.variations import FOLLOWING_PARTNER

    vids = []
    for sp in specs:
        vid = variation_id(sp.variation)
        if sp.following_partner:
            if not team_of(env).partner_can_follow:
                raise ValueError(f"{env.name}'s scripted robot has no following mode")
            vid |= FOLLOWING_PARTNER
        vids.append(vid | int(sp.flags))
    batch = generator_batch(batch)
    w = resolve_mix(env, mix)
    limit = [max_attempts or 5 * sp.num for sp in specs]
    state = [{"kept": [], "attempted": 0, "team_ok": 0, "valid": 0, "start": 0,
              "size": min(_attempts(sp.num), lim)} for sp, lim in zip(specs, limit)]

    def short(i):
        st = state[i]
        return sum(len(k["length"]) for k in st["kept"]) < specs[i].num and st["attempted"] < limit[i]

    while todo := [i for i in range(len(specs)) if short(i)]:
        index = {i: np.arange(state[i]["start"], state[i]["start"] + state[i]["size"]) for i in todo}
        outs = run_requests(env, [Request(_episode_keys(specs[i].seed, index[i]), w, vids[i], validate=True)
                                  for i in todo], batch)
        for i, out in zip(todo, outs):
            st = state[i]
            ok = (out["success"] > 0) & (out["executed"] == out["strategy"])
            good = ok & (out.pop("valid_success") > 0) & (out.pop("valid_executed") == out["strategy"])
            st["start"] += st["size"]
            st["attempted"] += st["size"]
            st["size"] = min(batch, limit[i] - st["attempted"])
            st["team_ok"] += int(ok.sum())
            st["valid"] += int(good.sum())
            sel = jax.tree.map(lambda v: v[good], out)
            sel["gen_index"] = index[i][good]
            st["kept"].append(sel)
    res = []
    for sp, st in zip(specs, state):
        kept = st["kept"]
        cat = jax.tree.map(lambda *xs: np.concatenate(xs)[: sp.num], *kept)
        eps = VariedEpisodes(**{k: cat[k] for k in VariedEpisodes._fields})
        res.append((eps, {"attempted": st["attempted"], "team_success": st["team_ok"], "validated": st["valid"],
                          "yield": st["valid"] / max(st["attempted"], 1), "kept": int(len(eps.length))}))
    return res


def generate_varied(env, variation: str, num: int, mix="uniform", seed: int | None = None, split: str = "test",
                    batch: int | None = None, max_attempts: int | None = None,
                    following_partner: bool = False) -> tuple[VariedEpisodes, dict]:
    """``num`` varied episodes that succeed (with the strategy drawn) and validate by re-simulation, and the
    yield: ``{"attempted", "team_success", "validated", "yield"}`` (yield = validated / attempted over all the
    generator calls that were run). Tries a quarter more than ``num`` first, then chunks of ``batch`` until ``num``
    are kept or ``max_attempts`` (default 5 num) were tried; the kept ones are the first ``num`` that validate, in
    generator order. ``following_partner``: the scripted robot follows the human's apparent strategy
    (:mod:`cogail_envs.variations`; teams with ``partner_can_follow``), with the same human draws."""
    seed = variation_seed(variation, split) if seed is None else int(seed)
    return generate_varied_sets(env, [VariedSpec(variation, num, seed, following_partner)], mix, batch,
                                max_attempts)[0]


def _file_ok(path: Path, env, variation: str, num: int, split: str) -> bool:
    import h5py

    if not path.exists() or _stored_version(path) != env.version:
        return False
    try:
        with h5py.File(path, "r") as f:
            a = f.attrs
            return (int(a.get("robust_version", -1)) == ROBUST_VERSION and str(a.get("variation", "")) == variation
                    and int(a.get("requested", -1)) == num and str(a.get("split", "")) == split)
    except OSError:
        return False


def write_robust_file(path: Path, env, eps: VariedEpisodes, variation: str, mix: str, seed: int, split: str,
                      num: int, stats: dict) -> Path:
    import h5py

    path = Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.robust.hdf5")
    save_demos(tmp, env, eps, mixture=mix, seed=seed)
    with h5py.File(tmp, "a") as f:
        f.attrs.update(variation=variation, variation_id=variation_id(variation), split=split, requested=int(num),
                       robust_version=ROBUST_VERSION, **{k: v for k, v in stats.items()})
        for i in range(len(eps.length)):
            f["data"][f"demo_{i}"].attrs["gen_index"] = int(eps.gen_index[i])
    os.replace(tmp, path)
    return path


def ensure_robustness_sets(env, mix="uniform", split: str = "test", num: int = 0, variations=VARIATIONS,
                           batch: int | None = None, verbose: bool = True, make: bool = True) -> dict[str, Path]:
    """``{"robust-<variation>": path}``: one HDF5 file of ``num`` varied, validated episodes per variation (0: the
    size of the task's test split), generated when missing or when the env's physics or the variations changed;
    with ``make=False`` such a file raises ``MissingDataError`` instead."""
    out, todo = {}, []
    num = num or default_count(env.name, "test")
    for v in variations:
        variation_id(v)
        path = robust_path(env.name, v, str(mix), split, num)
        if not _file_ok(path, env, v, num, split):
            if not make:
                raise missing(path, f"the varied human '{v}' ({split})")
            todo.append((v, path))
        out[PREFIX + v] = path
    if todo:  # every missing variation made in the same generator calls
        if verbose:
            print(f"making {num} episodes of each of {len(todo)} varied humans for {env.name} ({split}, seeds "
                  f"{', '.join(str(variation_seed(v, split)) for v, _ in todo)})", flush=True)
        made = generate_varied_sets(env, [VariedSpec(v, num, variation_seed(v, split)) for v, _ in todo], mix,
                                    batch)
        for (v, path), (eps, stats) in zip(todo, made):
            if verbose:
                print(f"  '{v}': {stats['validated']}/{stats['attempted']} succeeded and validated "
                      f"(yield {100 * stats['yield']:.0f} %), kept {stats['kept']} -> {path}", flush=True)
            write_robust_file(path, env, eps, v, str(mix), variation_seed(v, split), split, num, stats)
    return out


def varied_training_path(team_path: Path, per_variation: int) -> Path:
    return Path(team_path).with_name(f"{Path(team_path).stem}_varied{per_variation}.hdf5")


def ensure_varied_training_set(env, mix="uniform", num: int = 0, per_variation: int = 10, verbose: bool = True,
                               batch: int | None = None, make: bool = True) -> Path:
    """The default training set (``data.ensure_default_demos``) plus ``per_variation`` varied-human episodes of each
    of the protocol's variations, made like the test's varied humans (successful, validated by re-simulation) from
    the training split's generator seeds (300 + the variation's index, disjoint from the test's and validation's):
    ``data/<task>_<mix>_train[_N]_varied<k>.hdf5``, made on first use and cached. Where the task's scripted robot
    can follow the human (its team's ``partner_can_follow``), its change-of-mind episodes have the robot start on the
    strategy the human's first leg suggests and recover when the human turns (a demonstration of adapting); where
    its team has a prompt robot, every episode's robot is prompt, as in the default training set."""
    import h5py

    from .io import ensure_default_demos

    env = training_env(env)  # the task's training env (e.g. a robot that starts from more poses)
    team_path = ensure_default_demos(env, "train", mix, verbose=verbose, num=num, make=make)
    path = varied_training_path(team_path, per_variation)
    follows = bool(team_of(env).partner_can_follow)
    if path.exists() and _stored_version(path) == env.version:
        with h5py.File(path, "r") as f:
            if (int(f.attrs.get("robust_version", -1)) == ROBUST_VERSION
                    and bool(f.attrs.get("following_partner", False)) == follows):
                return path
    if not make:
        raise missing(path, "the training set with varied humans")
    team = load_demos(team_path, env, require_init=True)
    specs = [VariedSpec(v, per_variation, variation_seed(v, "train"), follows and v == "change_of_mind",
                        training_flags(env)) for v in VARIATIONS]
    parts = [team, *(eps for eps, _ in generate_varied_sets(env, specs, mix, batch))]
    if verbose:
        print(f"adding {per_variation} varied-human episodes per variation to {team_path} -> {path}", flush=True)
    T = max(p.obs.shape[1] for p in parts)

    def cat(name):
        xs = [np.asarray(getattr(p, name)) for p in parts]
        if xs[0].ndim == 3:
            xs = [np.pad(x, ((0, 0), (0, T - x.shape[1]), (0, 0))) for x in xs]
        return np.concatenate(xs)

    fields = ("obs", "actions_human", "actions_robot", "length", "strategy", "init")
    team_m = team.metrics or {}
    keys = [k for k in team_m if all(k in (p.final_metrics or {}) for p in parts[1:])]
    metrics = {k: np.concatenate([np.asarray(team_m[k])] + [np.asarray(p.final_metrics[k]) for p in parts[1:]])
               for k in keys}
    from types import SimpleNamespace

    eps = SimpleNamespace(**{f: cat(f) for f in fields}, final_metrics=metrics)
    tmp = save_demos(path.with_name(f"{path.name}.{os.getpid()}.varied.hdf5"), env, eps, mixture=str(mix),
                     seed=variation_seed(VARIATIONS[0], "train"))
    with h5py.File(tmp, "a") as f:
        f.attrs.update(robust_version=ROBUST_VERSION, varied_per_variation=int(per_variation),
                       team_demos=int(len(team.length)), following_partner=follows)
    os.replace(tmp, path)
    return path


def read_attrs(path) -> tuple[dict, np.ndarray]:
    """A robustness file's attrs and its demos' ``gen_index`` (in demo order)."""
    import h5py

    with h5py.File(path, "r") as f:
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        names = sorted((k for k in f["data"] if k.startswith("demo_")), key=lambda s: int(s[5:]))
        gen = np.asarray([int(f["data"][k].attrs["gen_index"]) for k in names])
    return attrs, gen


# ------------------------------------------------------------------------------------------ blind robot
def twin_episodes(env, varied_file, batch: int | None = None, resalt: int = 0) -> dict[str, np.ndarray]:
    """The unvaried twins of a robustness file's episodes (same generator keys, variation 0: same initial state,
    strategy and episode-level draws), padded to ``max_episode_steps``; ``resalt`` > 0 re-draws their per-step
    randomness. Keys: obs, actions_human, actions_robot, length, success, executed, strategy, init."""
    import h5py

    attrs, gen = read_attrs(varied_file)
    n = len(gen)
    w = resolve_mix(env, attrs.get("mixture", "uniform"))
    o = run_episodes(env, _episode_keys(int(attrs["seed"]), gen), w, resalt=resalt, batch=batch)
    out = {k: o[k] for k in ("obs", "actions_human", "actions_robot", "length", "success", "executed", "strategy",
                             "init")}
    with h5py.File(varied_file, "r") as f5:
        inits = np.stack([np.asarray(f5["data"][f"demo_{i}"]["init"][()]) for i in range(n)])
        strategy = np.asarray([int(f5["data"][f"demo_{i}"].attrs["strategy"]) for i in range(n)])
    if not np.allclose(out["init"], inits, atol=1e-5) or not np.array_equal(out["strategy"], strategy):
        raise ValueError(f"{varied_file}: the regenerated twins do not match the file's episodes (other generator?)")
    return out


def blind_robot_success(env, varied_file, batch: int | None = None) -> dict:
    """A robot that ignores the human: the recorded robot actions of each varied episode's unvaried twin (same
    initial state, strategy and within-strategy draws) replayed open-loop against

    * the varied human's recorded actions (``varied``), and
    * an in-distribution human: the twin re-drawn with fresh per-step randomness (``in_distribution``; only
      twins whose own scripted episode succeeded count).

    Success counts only with the intended strategy. The scripted robot of the team, which follows the human,
    succeeds on 100 % of the varied episodes by construction (they were kept because it did).
    Returns ``{"variation", "episodes", "varied", "in_distribution", "by_strategy": {name: {...}}}``."""
    attrs, _ = read_attrs(varied_file)
    demos = load_demos(varied_file, env, require_init=True)
    n, T = demos.num, env.max_episode_steps
    twin = twin_episodes(env, varied_file, batch)
    ref = twin_episodes(env, varied_file, batch, resalt=1)
    robot = _hold_pad(env, twin["actions_robot"], twin["length"])
    human_var = _hold_pad(env, _pad_time(demos.actions_human, T), demos.length)
    human_ref = _hold_pad(env, ref["actions_human"], ref["length"])
    r_var = validate_episodes(env, demos.init, human_var, robot, batch)
    r_ref = validate_episodes(env, demos.init, human_ref, robot, batch)
    s = demos.strategy
    ok_var = (r_var["success"] > 0) & (r_var["executed"] == s)
    ok_ref = (r_ref["success"] > 0) & (r_ref["executed"] == s)
    ref_valid = (ref["success"] > 0) & (ref["executed"] == s)
    by = {}
    for k, name in enumerate(env.strategy_names, start=1):
        m = s == k
        if m.any():
            by[name] = {"episodes": int(m.sum()), "varied": float(ok_var[m].mean()),
                        "in_distribution": float(ok_ref[m & ref_valid].mean()) if (m & ref_valid).any() else None}
    return {"variation": str(attrs.get("variation", "")), "episodes": int(n), "varied": float(ok_var.mean()),
            "in_distribution": float(ok_ref[ref_valid].mean()) if ref_valid.any() else None,
            "in_distribution_episodes": int(ref_valid.sum()),
            "mean_length": {"varied": float(demos.length.mean()), "twin": float(twin["length"].mean())},
            "by_strategy": by}


def main(argv=None) -> None:
    """``python -m cogail_jax.data.varied --task TASK [--num 60]``: make the sets, print the yields and the
    blind-robot figures (Markdown) and write a JSON of them."""
    import argparse
    import json

    import cogail_envs

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--task", required=True, help="a task name or my_pkg.my_module:TASK")
    p.add_argument("--num", type=int, default=60)
    p.add_argument("--mix", default="uniform")
    p.add_argument("--split", default="test")
    p.add_argument("--batch", type=int, default=None)
    p.add_argument("--variations", default=",".join(VARIATIONS))
    p.add_argument("--out", default=None, help="JSON with yields and blind-robot figures")
    a = p.parse_args(argv)
    env = cogail_envs.make_env(a.task)
    vs = [v for v in a.variations.split(",") if v]
    paths = ensure_robustness_sets(env, a.mix, a.split, a.num, vs, batch=a.batch)
    res = {}
    print(f"| {a.task} variation | yield | episodes | mean length (twin) | blind robot: in-distribution | varied |")
    print("| --- | --- | --- | --- | --- | --- |")
    for v in vs:
        attrs, _ = read_attrs(paths[PREFIX + v])
        b = blind_robot_success(env, paths[PREFIX + v], batch=a.batch)
        res[v] = {"yield": float(attrs["yield"]), "validated": int(attrs["validated"]),
                  "attempted": int(attrs["attempted"]), **b}
        ind = "-" if b["in_distribution"] is None else f"{100 * b['in_distribution']:.0f} %"
        print(f"| {v} | {attrs['validated']}/{attrs['attempted']} ({100 * attrs['yield']:.0f} %) | {b['episodes']} | "
              f"{b['mean_length']['varied']:.0f} ({b['mean_length']['twin']:.0f}) | {ind} | {100 * b['varied']:.0f} % |",
              flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
