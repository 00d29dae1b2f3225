"""The people's trials of Carroll et al. (2019) as episodes of :class:`~cogail_envs.overcooked.env.Overcooked`.

The trials ship in the ``overcooked-ai`` 1.1.0 distribution (``pip install --no-deps overcooked-ai==1.1.0``):
``overcooked_ai_py/data/human_data/clean_{train,test}_trials.pickle``, pandas frames of one row per joint step
(``state`` / ``next_state``: a python dict as a string; ``joint_action``; ``reward``, 5 per delivery;
``layout_name``; ``workerid_num``, the pair; ``round_num``; ``cur_gameloop``, the step). A trial is one pair's
round in one kitchen (``(workerid_num, round_num)``; ~1200 steps), its rows in ``cur_gameloop`` order.

Data conventions, as this module reads them: positions ``[x, y]`` with y down; orientations unit vectors
(``[0, -1]`` up); a player's action ``[dx, dy]`` (``[0, 0]`` stays) or ``"INTERACT"``; the data's ``dish`` is a
plate and its ``soup`` a soup, in a pot (``state = [ingredient, onions, cook_time]``), in a hand or on a counter.
The data's cook counter counts up from the third onion and keeps counting once the soup is ready (21, 22, ...):
a pot's cook steps left is ``max(20 - cook_time, 0)``, the same "cooking / ready" as JaxMARL's countdown.

Splits (:func:`recorded`): ``train`` and ``validation`` come from the training trials, split by pair: the
validation pairs are a fixed quarter (at least 2) of the kitchen's training pairs, chosen by a hash of the pair
id; ``test`` is the test trials (other pairs). Each trial is cut into consecutive episodes of the env's
``max_episode_steps`` (400), the last partial one kept if it has at least a quarter of that (100 steps); an
episode starts from the recorded state at its first step (its ``init``), and comes twice: with the human agent as
the trial's player 0 and as its player 1 (the other person the robot's part; the init's seat), so that a robot learns
both seats. Its observations are the env's
when the recorded joint actions are replayed from there.

:func:`replay_agreement` replays every trial's joint actions open loop through the env from its recorded first
state and counts, per field, the steps whose next state equals the recorded one.
"""
from __future__ import annotations

import ast
import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import kitchen as kt
from .env import DELIVERY_REWARD, INTERACT, NUM_ACTIONS, STAY, Overcooked, one_hot_actions

DATA_DIR = "overcooked_ai_py/data/human_data"
SPLITS = ("train", "validation", "test")
FILES = {"train": "clean_train_trials.pickle", "validation": "clean_train_trials.pickle",
         "test": "clean_test_trials.pickle"}
VALIDATION_SHARE = 0.25
DATA_DELIVERY_REWARD = 5.0
ORIENTATIONS = {(0, -1): 0, (0, 1): 1, (1, 0): 2, (-1, 0): 3}  # -> JaxMARL's direction (= move action) id
DATA_ITEMS = {"onion": 1, "dish": 2, "soup": 3}  # data object name -> item code (kitchen.ITEMS)
# the fields replay_agreement compares, each a group of init-vector entries (deliveries: the step's reward)
FIELDS = ("positions", "orientations", "held", "pots", "counters", "deliveries")


# ---------------------------------------------------------------------------------------------- the files
def trial_file(split: str) -> Path:
    """The trials' pickle of a split (``validation`` reads the training file)."""
    from importlib.metadata import PackageNotFoundError, distribution

    if split not in FILES:
        raise ValueError(f"unknown split {split!r}: choose one of {', '.join(SPLITS)}")
    try:
        path = Path(distribution("overcooked_ai").locate_file(f"{DATA_DIR}/{FILES[split]}"))
    except PackageNotFoundError:
        path = None
    if path is None or not path.exists():
        raise FileNotFoundError("the Overcooked-AI human trials are not installed: run `pip install --no-deps "
                                "overcooked-ai==1.1.0` (its data; none of its dependencies is needed)")
    return path


@functools.lru_cache(maxsize=None)
def _sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def source(split: str) -> dict:
    """Where a split's trials come from: the file inside the distribution and its sha256."""
    return {"file": f"{DATA_DIR}/{FILES[split]}", "sha256": _sha256(str(trial_file(split)))}


@functools.lru_cache(maxsize=None)
def _frame(file: str):
    import pandas as pd

    return pd.read_pickle(file)


# ---------------------------------------------------------------------------------------------- parsing
def parse(text: str):
    """A recorded python literal (a state dict, a joint action): as JSON once its quotes and booleans are JSON's
    (fast), else by ``ast.literal_eval``."""
    try:
        return json.loads(text.replace("'", '"').replace("False", "false").replace("True", "true"))
    except ValueError:
        return ast.literal_eval(text)


def data_action(a) -> int:
    """A player's recorded action (``[dx, dy]`` or ``"INTERACT"``) -> action id (0 up .. 5 interact)."""
    if isinstance(a, str):
        if a.lower() != "interact":
            raise ValueError(f"unknown recorded action {a!r}")
        return INTERACT
    a = tuple(int(v) for v in a)
    return STAY if a == (0, 0) else ORIENTATIONS[a]


def data_init(k: kt.Kitchen, state: dict) -> np.ndarray:
    """The init vector (:mod:`.kitchen`) of a recorded state dict."""
    sl = k.init_slices()
    init = np.zeros(k.init_size, np.float32)
    for i, player in enumerate(state["players"]):
        init[2 * i: 2 * i + 2] = player["position"]
        init[sl["dir"].start + i] = ORIENTATIONS[tuple(player["orientation"])]
        held = player.get("held_object")
        init[sl["held"].start + i] = DATA_ITEMS[held["name"]] if held else 0
    pots = {tuple(p): j for j, p in enumerate(k.pots.tolist())}
    counters = {tuple(c): j for j, c in enumerate(k.counters.tolist())}
    init[sl["pot_timer"]] = kt.COOK_STEPS
    for obj in state["objects"].values():
        cell = tuple(obj["position"])
        if cell in pots:
            _, onions, cook_time = obj["state"]
            init[sl["pot_onions"].start + pots[cell]] = onions
            if onions >= kt.MAX_ONIONS:
                init[sl["pot_timer"].start + pots[cell]] = max(kt.COOK_STEPS - int(cook_time), 0)
        else:
            init[sl["counters"].start + counters[cell]] = DATA_ITEMS[obj["name"]]
    return init


def data_grid(layout: str) -> list[str]:
    """A trial's ``layout`` column (the grid as rows of characters) in the kitchen's cell types' letters."""
    return [row.replace("1", " ").replace("2", " ") for row in parse(layout)]


def kitchen_grid(k: kt.Kitchen) -> list[str]:
    """The kitchen's grid in the data's letters (X counter, P pot, O onion pile, D plate pile, S serving, ' ')."""
    letters = {kt.FLOOR: " ", kt.COUNTER: "X", kt.POT_CELL: "P", kt.ONION_CELL: "O", kt.PLATE_CELL: "D",
               kt.GOAL_CELL: "S"}
    return ["".join(letters[int(c)] for c in row) for row in k.cells]


@dataclass(frozen=True)
class Trial:
    """One pair's round in one kitchen: T joint steps."""

    pair: int
    round: int
    inits: np.ndarray  # (T, I) the recorded state before each step
    next_inits: np.ndarray  # (T, I) the recorded state after each step
    actions: np.ndarray  # (T, 2) action ids of player 0 (human) and player 1 (robot)
    deliveries: np.ndarray  # (T,) soups delivered at each step (data reward / 5)
    grid: tuple  # the recorded layout, in the data's letters


@functools.lru_cache(maxsize=None)
def trials(kitchen: str, file_split: str) -> tuple[Trial, ...]:
    """Every trial of a kitchen in the ``train`` or ``test`` file, ordered by pair and round."""
    if file_split not in ("train", "test"):
        raise ValueError(f"the trial files are 'train' and 'test', not {file_split!r}")
    k = kt.kitchen_geometry(kitchen)
    df = _frame(str(trial_file(file_split)))
    df = df[df.layout_name == kt.KITCHENS[kitchen][1]]
    out = []
    for (pair, rnd), rows in df.groupby(["workerid_num", "round_num"], sort=True):
        rows = rows.sort_values("cur_gameloop")
        inits = np.stack([data_init(k, parse(s)) for s in rows.state])
        next_inits = np.stack([data_init(k, parse(s)) for s in rows.next_state])
        actions = np.array([[data_action(a) for a in parse(j)] for j in rows.joint_action], np.int32)
        deliveries = np.round(rows.reward.to_numpy(np.float64) / DATA_DELIVERY_REWARD).astype(np.int32)
        out.append(Trial(int(pair), int(rnd), inits, next_inits, actions, deliveries,
                         tuple(data_grid(rows.layout.iloc[0]))))
    return tuple(out)


def validation_pairs(kitchen: str) -> tuple[int, ...]:
    """The kitchen's training pairs held out for validation: a quarter of them (at least 2), the first by a hash of
    ``kitchen/pair`` (fixed, independent of the order of the file)."""
    pairs = sorted({t.pair for t in trials(kitchen, "train")})
    n = min(len(pairs), max(2, round(VALIDATION_SHARE * len(pairs))))
    ranked = sorted(pairs, key=lambda p: hashlib.sha256(f"{kitchen}/{p}".encode()).hexdigest())
    return tuple(sorted(ranked[:n]))


def split_trials(kitchen: str, split: str) -> tuple[Trial, ...]:
    """The trials of a split (:data:`SPLITS`)."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}: choose one of {', '.join(SPLITS)}")
    if split == "test":
        return trials(kitchen, "test")
    held = set(validation_pairs(kitchen))
    return tuple(t for t in trials(kitchen, "train") if (t.pair in held) == (split == "validation"))


def episode_cuts(length: int, episode_steps: int) -> list[tuple[int, int]]:
    """``(start, steps)`` of the consecutive episodes a trial of ``length`` steps is cut into (the last partial one
    kept if it has at least a quarter of ``episode_steps``)."""
    cuts = [(s, min(episode_steps, length - s)) for s in range(0, length, episode_steps)]
    return [(s, n) for s, n in cuts if n >= max(1, episode_steps // 4)]


# ---------------------------------------------------------------------------------------------- replay
def _cached(env: Overcooked, kind: str, build):
    cache = env.__dict__.setdefault("_trial_fns", {})
    if kind not in cache:
        cache[kind] = build()
    return cache[kind]


def _episode_fn(env: Overcooked):
    """Jitted ``f(init (B, I), actions (B, T, 12), length (B,)) -> (obs (B, T, D), final metrics)``: the recorded
    actions replayed from ``reset_from(init)``; the state holds still after ``length`` steps."""

    def one(init, actions, length):
        def body(carry, x):
            state, metrics = carry
            t, a = x
            nxt = env.step(state, a)
            live = t < length
            state = jax.tree.map(lambda n, o: jnp.where(live, n, o), nxt, state)
            metrics = jax.tree.map(lambda n, o: jnp.where(live, n, o), nxt.metrics, metrics)
            return (state, metrics), carry[0].obs

        state = env.reset_from(init)
        steps = jnp.arange(actions.shape[0])
        (_, metrics), obs = jax.lax.scan(body, (state, state.metrics), (steps, actions))
        return obs, metrics

    return _cached(env, "episodes", lambda: jax.jit(jax.vmap(one)))


def _trajectory_fn(env: Overcooked):
    """Jitted ``f(init (B, I), actions (B, T, 12)) -> (init vectors (B, T, I), rewards (B, T))``: the states after
    each step of an open-loop replay (no time limit: the state never freezes)."""

    def one(init, actions):
        def body(state, a):
            nxt = env.step(state, a)
            return nxt, (env.encode(nxt), nxt.reward)

        return jax.lax.scan(body, env.reset_from(init), actions)[1]

    return _cached(env, "trajectory", lambda: jax.jit(jax.vmap(one)))


def _batches(n: int, batch: int):
    """Index arrays of ``batch`` entries covering range(n), the last one padded with index 0."""
    for s in range(0, n, batch):
        idx = np.arange(s, min(s + batch, n))
        yield idx, np.concatenate([idx, np.zeros(batch - len(idx), np.int64)])


def recorded(env: Overcooked, split: str, batch: int = 8) -> dict:
    """A split's episodes of the env's kitchen (module docstring), as ``Task.recorded`` returns them: ``obs`` (N, T,
    D) float32, ``actions_human`` / ``actions_robot`` (N, T, 6) one-hot float32 (padded with "stay"), ``length``,
    ``strategy`` and ``executed`` (classify_strategy of the replayed episode), ``success``, ``init`` (N, I),
    ``final_metrics`` {name: (N,)}, ``pair`` (N,) and ``source`` (file, sha256, kitchen, split)."""
    steps = env.max_episode_steps
    inits, actions, lengths, pairs = [], [], [], []
    for trial in split_trials(env.kitchen, split):
        for start, n in episode_cuts(len(trial.actions), steps):
            ids = np.full((steps, 2), STAY, np.int32)
            ids[:n] = trial.actions[start:start + n]
            for seat in (0, 1):  # each episode twice: the human agent as player 0, then as player 1
                inits.append(np.append(trial.inits[start], seat))
                actions.append(one_hot_actions(ids if seat == 0 else ids[:, ::-1]).reshape(steps, 2 * NUM_ACTIONS))
                lengths.append(n)
                pairs.append(trial.pair)
    num = len(lengths)
    inits, actions, lengths = np.stack(inits), np.stack(actions), np.asarray(lengths, np.int32)
    run = _episode_fn(env)
    obs = np.zeros((num, steps, env.observation_size), np.float32)
    metrics = {}
    for real, idx in _batches(num, batch):
        o, m = run(jnp.asarray(inits[idx]), jnp.asarray(actions[idx]), jnp.asarray(lengths[idx]))
        obs[real] = np.asarray(o)[: len(real)]
        for name, v in m.items():
            metrics.setdefault(name, []).append(np.asarray(v)[: len(real)])
    final = {name: np.concatenate(v).astype(np.float32) for name, v in metrics.items()}
    strategy = np.asarray(jax.vmap(env.classify_strategy)(final), np.int32)
    return dict(
        obs=obs, actions_human=actions[..., :NUM_ACTIONS], actions_robot=actions[..., NUM_ACTIONS:], length=lengths,
        strategy=strategy, executed=strategy.copy(), success=final["success"], init=inits.astype(np.float32),
        final_metrics=final, pair=np.asarray(pairs, np.int64),
        source={**source(split), "kitchen": env.kitchen, "split": split},
    )


def _agreement_counts(k: kt.Kitchen, replayed: np.ndarray, delivered: np.ndarray, trial: Trial) -> dict:
    """Per field, the steps of a trial whose replayed next state equals the recorded one."""
    sl = k.init_slices()
    rec = trial.next_inits
    same = replayed == rec

    def all_of(*names):
        cols = np.concatenate([np.arange(sl[n].start, sl[n].stop) for n in names])
        return np.all(same[:, cols], axis=1) if len(cols) else np.ones(len(rec), bool)

    per_step = {
        "positions": all_of("pos"), "orientations": all_of("dir"), "held": all_of("held"),
        "pots": all_of("pot_onions", "pot_timer"), "counters": all_of("counters"),
        "deliveries": delivered == trial.deliveries,
    }
    per_step["all"] = np.logical_and.reduce([per_step[f] for f in FIELDS])
    return {f: int(v.sum()) for f, v in per_step.items()}


def replay_agreement(kitchen: str, split: str, steps: int | None = None, trial_index: int | None = None) -> dict:
    """Every trial of a kitchen's split replayed open loop from its recorded first state: per field (:data:`FIELDS`)
    the steps whose next state equals the recorded ``next_state``, ``all`` (every field at once), ``steps``,
    ``trials`` and ``first_divergence`` (per trial, the first step where any field differs; -1 for none).
    ``steps`` / ``trial_index`` restrict it to each trial's first steps / one trial. ``split`` may be ``train``
    (the whole training file) or ``test``: agreement is a property of the files, not of our split."""
    env = Overcooked(kitchen)
    k = env.geometry
    chosen = trials(kitchen, "test" if split == "test" else "train")
    if trial_index is not None:
        chosen = chosen[trial_index: trial_index + 1]
    length = max(len(t.actions) for t in chosen) if steps is None else steps
    length = -(-length // 100) * 100  # padded to a multiple of 100: the kitchen's trials share one compilation
    acts = np.full((len(chosen), length, 2), STAY, np.int32)
    for i, t in enumerate(chosen):
        n = min(len(t.actions), length)
        acts[i, :n] = t.actions[:n]
    inits = np.stack([np.append(t.inits[0], 0) for t in chosen])  # the human agent as player 0, as recorded
    states, rewards = _trajectory_fn(env)(jnp.asarray(inits),
                                          jnp.asarray(one_hot_actions(acts).reshape(len(chosen), length, -1)))
    states, rewards = np.asarray(states)[..., :-1], np.asarray(rewards)
    total = {f: 0 for f in (*FIELDS, "all")}
    divergence = []
    n_steps = 0
    for i, t in enumerate(chosen):
        n = min(len(t.actions), length if steps is None else steps)
        cut = Trial(t.pair, t.round, t.inits[:n], t.next_inits[:n], t.actions[:n], t.deliveries[:n], t.grid)
        delivered = np.round(rewards[i, :n] / DELIVERY_REWARD).astype(np.int32)
        counts = _agreement_counts(k, states[i, :n], delivered, cut)
        for f in total:
            total[f] += counts[f]
        n_steps += n
        bad = np.flatnonzero(~np.all(states[i, :n] == cut.next_inits, axis=1) | (delivered != cut.deliveries))
        divergence.append(int(bad[0]) if len(bad) else -1)
    return {**total, "steps": n_steps, "trials": len(chosen), "first_divergence": divergence}
