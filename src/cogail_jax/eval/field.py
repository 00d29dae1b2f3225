"""The field's protocol for a task learned from people (Carroll et al., NeurIPS 2019): the robot paired with H_proxy.

H_proxy is behaviour cloning of the TEST pairs' people, in both seats (each player's actions on the state as that
player sees it), so it stands for a person the robot has never met: neither training nor checkpoint selection reads
the test split. The robot plays both seats (the env's ``seat_init`` seats the human agent, here the partner, as player
1 or player 0; the robot learned both from the people's recordings of either player), 400-step episodes, at least 100
per seed and seat on an accelerator; reward (the task's, 20 per soup on Overcooked) and the score
(soups) are reported as mean and standard error over every episode, with each seed's mean.

* **Selection**: every checkpoint plays both seats with a BC model of the VALIDATION pairs; the checkpoint with the
  highest mean reward over seeds and seats is selected (ties: the later one).
* **At the selected checkpoint**: H_proxy (both seats, and their mean), the BC model of the TRAINING pairs
  (``bc_train``: what PPO_BC trains with), and self-play (two copies of the robot, one in each seat).
* **H_proxy's own quality**: its action accuracy on held-out test episodes (a copy fitted on the other 80 % of the
  test episodes), and its reward with itself and with that copy of itself.

Every BC model is an MLP (``coplay.PROXY_HIDDEN``) on the task's hand-made features of the state as its player sees
it (``env.person_features``, as the field's BC models read overcooked_ai's; the state itself where a task has none)
and their change over the last 1 and 3 steps, fitted by cross-entropy, drawing its choices from its categorical (as the field's BC agents do); all
of them from fixed keys, so the same data give the same models. One compiled program per pair of agent kinds
(robot or BC model in each seat), the seeds vmapped.
"""
from __future__ import annotations

import hashlib
import inspect
import json
import math
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..algo import actions, networks
from . import coplay

FIELD_SEED = 1357  # episode e of a call starts from fold_in(PRNGKey(FIELD_SEED + call's salt), e)
HOLDOUT = 0.2  # the share of the test episodes H_proxy's accuracy is measured on (by a copy fitted on the rest)
SEATS = (0, 1)


def supported(env) -> bool:
    """Whether the field's protocol applies: a task with discrete agents of the same actions, a ``seat_view`` and a
    ``seat_init``."""
    spec = actions.spec_of(env)
    return bool(len(getattr(env, "seat_view", ()) or ()) and hasattr(env, "seat_init") and spec.human_discrete
                and spec.robot_discrete
                and spec.human_size == spec.robot_size)


def sizes() -> dict:
    """Episodes per seed and seat (at the selected checkpoint, and per checkpoint for selection) and BC updates:
    the field's counts on an accelerator, tiny ones on a CPU."""
    if jax.default_backend() == "cpu":
        return {"episodes": 4, "select_episodes": 2, "bc_steps": 300}
    return {"episodes": 100, "select_episodes": 32, "bc_steps": 4000}


# ------------------------------------------------------------------------------------------------ BC models
def person_view(env, obs: jax.Array) -> jax.Array:
    """What the BC models of people read of observations ``obs`` (..., D): the task's hand-made features where it has
    them (``env.person_features``, as the field's BC models read overcooked_ai's), else the observations."""
    fn = getattr(env, "person_features", None)
    if fn is None:
        return obs
    flat = obs.reshape(-1, obs.shape[-1])
    return jax.vmap(fn)(flat).reshape(*obs.shape[:-1], -1)


def seat_samples(env, obs, ah, ar, length) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both players' steps of a split as BC samples: player 0's actions ``ah`` on the state as recorded, player 1's
    ``ar`` on the state as it sees it (``seat_view``). Returns the inputs (``coplay.proxy_inputs``), the one-hot
    targets and each sample's episode."""
    obs, length = np.asarray(obs, np.float32), np.asarray(length)
    H = max(coplay.PROXY_LAGS)
    xs, ys, eps = [], [], []
    valid = np.arange(obs.shape[1])[None] < length[:, None]
    views = jax.jit(lambda o: person_view(env, o))
    for view, act in ((obs, ah), (obs[..., np.asarray(env.seat_view)], ar)):
        view = np.asarray(views(jnp.asarray(view)))
        padded = np.concatenate([np.repeat(view[:, :1], H, 1), view], 1)
        hist = np.stack([padded[:, H - j:H - j + view.shape[1]] for j in range(H, -1, -1)], 2)
        xs.append(np.asarray(coplay.proxy_inputs(jnp.asarray(hist)))[valid])
        ys.append(np.asarray(act, np.float32)[valid])
        eps.append(np.broadcast_to(np.arange(len(length))[:, None], valid.shape)[valid])
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(eps)


def fit_bc(x: np.ndarray, y: np.ndarray, steps: int, seed: int) -> coplay.Proxy:
    """A BC model of samples ``(x, y)`` (cross-entropy, full-batch Adam, ``steps`` updates from ``PRNGKey(seed)``)."""
    import optax

    mean, std = x.mean(0), np.maximum(x.std(0), 1e-3)
    layers = coplay._init_layers(jax.random.PRNGKey(seed), (x.shape[1], *coplay.PROXY_HIDDEN, y.shape[1]))
    opt = optax.adam(coplay.PROXY_LR)

    @jax.jit
    def fit(layers, x, y):
        def loss_fn(layers):
            logits = coplay._mlp(coplay.Proxy(layers, mean, std), x, squash=False)
            return -jnp.mean(jnp.sum(y * jax.nn.log_softmax(logits, -1), -1))

        def body(carry, _):
            layers, st = carry
            g = jax.grad(loss_fn)(layers)
            up, st = opt.update(g, st, layers)
            return (optax.apply_updates(layers, up), st), None

        (layers, _), _ = jax.lax.scan(body, (layers, opt.init(layers)), None, length=steps)
        return layers

    return coplay.Proxy(fit(layers, jnp.asarray(x), jnp.asarray(y)), jnp.asarray(mean), jnp.asarray(std))


def held_out_episodes(obs: np.ndarray, env) -> np.ndarray:
    """(N,) bool: the test episodes H_proxy's accuracy is measured on, every ``1 / HOLDOUT``-th window of play. An
    episode recorded in both seats (the same observations, one the other's ``seat_view``) is one window: both of its
    copies are held out together, or the copy fitted would have seen the held-out steps from the other seat. Windows
    are told apart by all their observations, not the first: every trial of a kitchen starts from the same state."""
    obs = np.ascontiguousarray(obs)
    perm = np.asarray(env.seat_view)
    window, seen = np.zeros(len(obs), np.int64), {}
    for i, o in enumerate(obs):
        key = min(o.tobytes(), np.ascontiguousarray(o[..., perm]).tobytes())
        window[i] = seen.setdefault(key, len(seen))
    every = int(round(1 / HOLDOUT))
    return window % every == every - 1


def accuracy(model: coplay.Proxy, x: np.ndarray, y: np.ndarray) -> float:
    """The share of samples whose most likely choice is the person's."""
    logits = np.asarray(coplay._mlp(model, jnp.asarray(x), squash=False))
    return float(np.mean(logits.argmax(-1) == y.argmax(-1)))


def split_arrays(path, env) -> dict:
    from ..data import io as data

    d = data.load_demos(path, env)
    return {"obs": d.obs, "ah": d.actions_human, "ar": d.actions_robot, "length": d.length}


# ------------------------------------------------------------------------------------------------ the program
def make_play(env, cfg, nets, kinds: tuple[str, str], other: tuple | None = None):
    """Jitted ``play(agent0, agent1, keys, human_seat) -> {"reward", "score"}`` (each (S, E)): E episodes of the
    task's time limit from the task's start with the human agent seated as player ``human_seat`` (an int32 array:
    one program for both seats; episode e's from
    ``keys[e]``); the agent in the human's slot (``agent0``) and in the robot's (``agent1``) each a learned robot
    (``{"params", "norm"}`` with a leading seed axis S, vmapped) or a BC model (``coplay.Proxy``, the same for every
    seed), as ``kinds`` says ("robot" or "bc"); a robot is :func:`robot`'s dict, whose ``code`` (0 or 1 per seed)
    says whether it acts on psi's code, so robots of every preset with the same networks share one program. The env's observation is the human slot's view: a BC model reads its
    own view, a robot its partner's (as it was trained), the other slot's through ``seat_view``. ``other``: ``(cfg,
    nets)`` of the robot in the robot's slot where it is another run's (cross-play; default: ``cfg``'s and
    ``nets``')."""
    perm = jnp.asarray(np.asarray(env.seat_view))
    Ah, T = env.human_action_size, env.max_episode_steps
    slot_cfgs = (cfg, cfg if other is None else other[0])
    slot_nets = (nets, nets if other is None else other[1])
    Ks = [c.history if c is not None and k == "robot" else 0 for c, k in zip(slot_cfgs, kinds)]
    H = max(*Ks, max(coplay.PROXY_LAGS))

    def robot_fn(n, K):
        psi, actor = n["psi"].apply, n["actor"].apply

        def robot_act(agent, view_hist, prev_partner, key):  # one episode: the robot reads its partner's view
            norm = agent["norm"]  # as the replay protocol's robot (rollouts.make_robot_step), its code switch data
            h = networks.history_input(norm, view_hist[-(K + 1):])
            z = psi(agent["params"]["psi"], jnp.concatenate([h, prev_partner])) * agent["code"]
            mean, _ = actor(agent["params"]["actor"], networks.policy_input(norm, view_hist), z)
            return actions.agent_act(True, mean[Ah:], key)

        return robot_act

    acts = [robot_fn(n, K) if k == "robot" else None for n, K, k in zip(slot_nets, Ks, kinds)]

    def one_seed(a0, a1, keys, human_seat):
        E = keys.shape[0]
        state = jax.vmap(lambda k: env.reset_from(env.seat_init(env.sample_init(k), human_seat)))(keys)
        hist = jnp.repeat(state.obs[:, None], H + 1, 1)

        def body(carry, t):
            state, hist, prev, ret = carry
            step_keys = jax.vmap(lambda k: jax.random.fold_in(k, t))(keys)
            out = []
            for slot, (kind, agent) in enumerate(zip(kinds, (a0, a1))):  # slot 0: the human agent's, 1: the robot's
                k = jax.vmap(lambda kk: jax.random.fold_in(kk, slot + 1))(step_keys)
                if kind == "robot":  # its partner's view: the env's observation in the robot's slot, else swapped
                    view = hist if slot == 1 else hist[..., perm]
                    a = jax.vmap(acts[slot], in_axes=(None, 0, 0, 0))(agent, view, prev[:, 1 - slot], k)
                else:  # its own view
                    view = hist if slot == 0 else hist[..., perm]
                    a = jax.vmap(lambda h, kk: coplay.proxy_action(agent, person_view(env, h), True, kk))(
                        view[:, -(max(coplay.PROXY_LAGS) + 1):], k)
                out.append(a)
            nxt = jax.vmap(env.step)(state, jnp.concatenate(out, -1))
            hist = jnp.concatenate([hist[:, 1:], nxt.obs[:, None]], 1)
            return (nxt, hist, jnp.stack(out, 1), ret + nxt.reward), None

        prev = jnp.zeros((E, 2, Ah), jnp.float32)
        (state, _, _, ret), _ = jax.lax.scan(body, (state, hist, prev, jnp.zeros((E,), jnp.float32)),
                                             jnp.arange(T))
        score = state.metrics[env.score_metric] if env.score_metric else state.metrics["success"]
        return {"reward": ret, "score": score}

    axes = tuple(0 if k == "robot" else None for k in kinds)
    if all(a is None for a in axes):  # no seed axis: one "seed"
        return jax.jit(lambda a0, a1, keys, seat: jax.tree.map(lambda x: x[None], one_seed(a0, a1, keys, seat)))
    return jax.jit(jax.vmap(one_seed, in_axes=(*axes, None, None)))


def episode_keys(n: int, salt: int) -> jax.Array:
    return jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(FIELD_SEED + salt), i))(jnp.arange(n))


def robot(cfg, evalp: dict) -> dict:
    """A learned robot as :func:`make_play` takes it, from a checkpoint's evaluation parameters ``evalp``
    (``{"params", "norm"}``, a leading seed axis): its actor, psi, normaliser and ``code`` (per seed: 1 where the
    preset acts on psi's code, else 0)."""
    p = evalp["params"]
    seeds = jax.tree.leaves(p["actor"])[0].shape[0]
    return {"params": {"actor": p["actor"], "psi": p["psi"]}, "norm": evalp["norm"],
            "code": jnp.full((seeds,), 1.0 if cfg.use_code else 0.0, jnp.float32)}


def stats(out: dict, seeds) -> dict:
    """Mean, standard error (over every episode) and per-seed means of ``reward`` and ``score`` ((S, E) arrays)."""
    res = {}
    for k in ("reward", "score"):
        x = np.asarray(out[k], np.float64)
        res[k] = {"mean": float(x.mean()), "se": float(x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else 0.0,
                  "per_seed": {str(s): float(v) for s, v in zip(seeds, x.mean(1))}}
    res["episodes"] = int(np.asarray(out["reward"]).size)
    return res


def _pool(a: dict, b: dict, seeds) -> dict:
    return stats({k: np.concatenate([np.asarray(a[k]), np.asarray(b[k])], 1) for k in ("reward", "score")}, seeds)


def _stack(trees: list):
    return jax.tree.map(lambda *x: jnp.concatenate(x, 0), *trees)


# ------------------------------------------------------------------------------------------------ BC models, kept
def models_path(files: dict, n: dict, env=None) -> Path | None:
    """Where the BC models and H_proxy's quality of these splits are kept between runs (every run of a task fits the
    same ones): a file in the compilation cache's folder named by the splits' contents, the sizes ``n`` and this
    module's, co-play's and the features' (``env.person_features``) code; None without a cache folder."""
    from ..runtime import xla

    root = xla.compile_cache_dir()
    if root is None:
        return None
    h = hashlib.sha256()
    for k in ("train", "validation", "test"):
        h.update(Path(files[k]).read_bytes())
    features = getattr(env, "person_features", None)
    for mod in (__file__, coplay.__file__, *([inspect.getsourcefile(features)] if features is not None else [])):
        h.update(Path(mod).read_bytes())
    h.update(json.dumps({**n, "seed": FIELD_SEED, "backend": jax.default_backend()}, sort_keys=True).encode())
    return root / "field" / f"{h.hexdigest()[:24]}.npz"


def _save(path: Path, models: dict, quality: dict) -> None:
    flat = {"quality": np.asarray(json.dumps(quality))}
    for name, m in models.items():
        flat[f"{name}/mean"], flat[f"{name}/std"] = np.asarray(m.mean), np.asarray(m.std)
        for i, (w, b) in enumerate(m.layers):
            flat[f"{name}/w{i}"], flat[f"{name}/b{i}"] = np.asarray(w), np.asarray(b)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, **flat)
    os.replace(tmp, path)


def _load(path: Path) -> tuple[dict, dict]:
    with np.load(path) as z:
        quality = json.loads(str(z["quality"]))
        models = {}
        for name in {k.split("/")[0] for k in z.files if "/" in k}:
            layers = [(jnp.asarray(z[f"{name}/w{i}"]), jnp.asarray(z[f"{name}/b{i}"]))
                      for i in range(sum(k.startswith(f"{name}/w") for k in z.files))]
            models[name] = coplay.Proxy(layers, jnp.asarray(z[f"{name}/mean"]), jnp.asarray(z[f"{name}/std"]))
    return models, quality


class Field:
    """The programs and BC models of one run's field evaluation (see the module docstring). The BC models and
    H_proxy's quality are the same for every run on the same splits: made by the first and kept
    (:func:`models_path`), read by the others."""

    def __init__(self, s, n: dict | None = None):
        self.s, self.n = s, dict(n or sizes())
        self.programs: dict = {}
        from ..data import sets

        files = {**{k: sets.split_path(s.cfg, k) for k in ("train",) if k not in (s.files or {})}, **(s.files or {})}
        self.path = models_path(files, self.n, s.env)
        if self.path is not None and self.path.is_file():
            models, self.quality = _load(self.path)
        else:
            models, self.quality = self._fit(files), None
        self.h_proxy, self.bc_train = models["h_proxy"], models["bc_train"]
        self.bc_validation, self.copy = models["bc_validation"], models["copy"]

    def _fit(self, files: dict) -> dict:
        env, steps = self.s.env, self.n["bc_steps"]
        splits = {k: split_arrays(files[k], env) for k in ("train", "validation", "test")}
        xs = {k: seat_samples(env, v["obs"], v["ah"], v["ar"], v["length"]) for k, v in splits.items()}
        models = {"h_proxy": fit_bc(*xs["test"][:2], steps, 0), "bc_train": fit_bc(*xs["train"][:2], steps, 0),
                  "bc_validation": fit_bc(*xs["validation"][:2], steps, 0)}
        x, y, ep = xs["test"]
        held = held_out_episodes(splits["test"]["obs"], env)
        models["copy"] = fit_bc(x[~held[ep]], y[~held[ep]], steps, 1)
        self.accuracy = {"accuracy_heldout": accuracy(models["copy"], x[held[ep]], y[held[ep]]),
                         "heldout_episodes": int(held.sum()), "samples": int(len(x)),
                         "accuracy_train_samples": accuracy(models["h_proxy"], x, y)}
        return models

    def play(self, a0, a1, kinds: tuple[str, str], episodes: int, salt: int, human_seat: int = 0) -> dict:
        if kinds not in self.programs:
            self.programs[kinds] = make_play(self.s.env, self.s.cfg, self.s.nets, kinds)
        out = self.programs[kinds](a0, a1, episode_keys(episodes, salt), jnp.asarray(human_seat, jnp.int32))
        return jax.tree.map(np.asarray, jax.device_get(out))

    def with_partner(self, robot: dict, partner, episodes: int, salt: int, seeds=None) -> dict:
        """The robot in each seat with a BC ``partner``: {"seat0", "seat1", "both"} stats (seat k: the robot's)."""
        seeds = self.s.cfg.seeds if seeds is None else seeds
        r0 = self.play(partner, robot, ("bc", "robot"), episodes, salt, human_seat=1)
        r1 = self.play(partner, robot, ("bc", "robot"), episodes, salt, human_seat=0)
        return {"seat0": stats(r0, seeds), "seat1": stats(r1, seeds), "both": _pool(r0, r1, seeds)}

    def select(self, robots: list[dict]) -> list[float]:
        """Each robot's mean reward over its seeds and both seats with the validation pairs' BC model
        (``select_episodes`` per seed and seat): ``SELECT_BATCH`` robots side by side in one call (the last call
        padded with its last robot), so that selection over every checkpoint takes a few calls of one program."""
        S, e = len(self.s.cfg.seeds), self.n["select_episodes"]
        size, means = min(SELECT_BATCH, len(robots)), []
        for i in range(0, len(robots), size):
            chunk = robots[i:i + size]
            batch = _stack(chunk + [chunk[-1]] * (size - len(chunk)))
            r = np.stack([self.play(self.bc_validation, batch, ("bc", "robot"), e, 1, human_seat=seat)["reward"]
                          for seat in (1, 0)])  # (seat, robot x seed, episode)
            means += r.reshape(2, size, S, e).mean((0, 2, 3))[:len(chunk)].tolist()
        return means

    def lower_plays(self, evalp: dict, checkpoints: int) -> list:
        """What :func:`evaluate` plays for a run of ``checkpoints`` checkpoints, lowered from the shapes of its
        evaluation parameters ``evalp`` (``{"params", "norm"}``, a leading seed axis, placed as the checkpoints' parameters
        will be: ``jax.ShapeDtypeStruct`` with their sharding): selection's batch with the
        validation pairs' model, the selected robot with a BC model, and self-play. Compiled ahead (while the run
        trains), the evaluation finds them in the compilation cache."""
        bot = robot(self.s.cfg, evalp)
        size = min(SELECT_BATCH, checkpoints)
        batch = jax.tree.map(lambda x: jax.ShapeDtypeStruct((size * x.shape[0],) + x.shape[1:], x.dtype,
                                                            sharding=getattr(x, "sharding", None)
                                                            if isinstance(x, jax.ShapeDtypeStruct) else None), bot)
        seat = jnp.asarray(0, jnp.int32)
        for kinds in (("bc", "robot"), ("robot", "robot")):
            if kinds not in self.programs:
                self.programs[kinds] = make_play(self.s.env, self.s.cfg, self.s.nets, kinds)
        with_bc, self_play = self.programs[("bc", "robot")], self.programs[("robot", "robot")]
        return [with_bc.lower(self.bc_validation, batch, episode_keys(self.n["select_episodes"], 1), seat),
                with_bc.lower(self.h_proxy, bot, episode_keys(self.n["episodes"], 0), seat),
                self_play.lower(bot, bot, episode_keys(self.n["episodes"], 3), seat)]

    def proxy_quality(self) -> dict:
        if self.quality is not None:
            return self.quality
        one = (0,)
        e = self.n["episodes"]
        itself = self.play(self.h_proxy, self.h_proxy, ("bc", "bc"), e, 7)
        copy = self.play(self.h_proxy, self.copy, ("bc", "bc"), e, 7)
        self.quality = {**self.accuracy, "with_itself": stats(itself, one), "with_copy": stats(copy, one)}
        if self.path is not None:
            _save(self.path, {"h_proxy": self.h_proxy, "bc_train": self.bc_train, "bc_validation": self.bc_validation,
                              "copy": self.copy}, self.quality)
        return self.quality


SELECT_BATCH = 16  # checkpoints played together in selection


def prepare(cfg) -> Path | None:
    """Fit and keep the BC models and H_proxy's quality of ``cfg``'s splits before any run evaluates (`cogail data`
    does, beside compiling the training programs ahead): a run's evaluation then reads them, and runs side by side
    never each fit them. Their file; None where the field's protocol does not apply or no cache folder keeps them.
    The splits must be made (``data.sets.make_datasets``)."""
    from types import SimpleNamespace

    from cogail_envs import get_task

    from ..data import sets

    env = get_task(cfg.task).make_env()
    if not supported(env):
        return None
    files = {k: sets.split_path(cfg, k, env=env) for k in (sets.TRAIN, sets.VALIDATION, sets.TEST)}
    if models_path(files, sizes(), env) is None:
        return None
    f = Field(SimpleNamespace(env=env, cfg=cfg, files=files, nets=None))
    f.proxy_quality()
    return f.path


def evaluate(s, load, steps: list[int], n: dict | None = None) -> dict:
    """results.json's ``field`` for a run's set-up ``s`` (its splits' files in ``s.files``), ``load(step)`` giving a
    checkpoint's evaluation parameters: selection over ``steps`` with the validation pairs' BC model, then H_proxy,
    the training pairs' BC model and self-play at the selected checkpoint, and H_proxy's quality."""
    f = Field(s, n)
    quality = f.proxy_quality()
    steps = [int(st) for st in steps]
    per_ckpt = dict(zip(steps, f.select([robot(s.cfg, load(st)) for st in steps])))
    best = max(per_ckpt.values())
    chosen = max(st for st, v in per_ckpt.items() if v == best)
    bot = robot(s.cfg, load(chosen))
    seeds = s.cfg.seeds
    sp = _pool(f.play(bot, bot, ("robot", "robot"), f.n["episodes"], 3, 0),
               f.play(bot, bot, ("robot", "robot"), f.n["episodes"], 3, 1), seeds)
    return {
        "protocol": {"episodes_per_seed_and_seat": f.n["episodes"], "selection_episodes": f.n["select_episodes"],
                     "bc_steps": f.n["bc_steps"], "seed": FIELD_SEED, "score": s.env.score_metric or "success",
                     "horizon": s.env.max_episode_steps},
        "selected": {"checkpoint": int(chosen), "validation_reward": per_ckpt},
        "h_proxy": f.with_partner(bot, f.h_proxy, f.n["episodes"], 0),
        "bc_train": f.with_partner(bot, f.bc_train, f.n["episodes"], 2),
        "self_play": sp,
        "proxy_quality": quality,
    }


def _signature(cfg, agent: dict) -> tuple:
    """What a robot's program depends on: its history and its networks' shapes (not its preset)."""
    shapes = tuple((str(path), x.shape[1:], str(x.dtype)) for path, x in
                   jax.tree_util.tree_flatten_with_path({"params": agent["params"], "norm": agent["norm"]})[0])
    return cfg.history, shapes


def crossplay(env, robots: dict, episodes: int) -> dict:
    """The cross-play matrix of learned robots: ``robots`` {label: (cfg, nets, eval params with a seed axis S, the
    same S for all)}; each ordered pair plays both seats, A in the human agent's slot (reading its partner's view
    through ``seat_view``), B in the robot's. Returns {A: {B: stats}} (reward and score, mean +- s.e., both seats
    pooled); the diagonal is each robot's self-play. Robots with the same networks are one group: every pair of
    two groups plays in one program, all its pairs side by side."""
    keys = episode_keys(episodes, 5)
    bots = {k: (cfg, nets, robot(cfg, p)) for k, (cfg, nets, p) in robots.items()}
    groups: dict = {}
    for label, (cfg, nets, agent) in bots.items():
        groups.setdefault(_signature(cfg, agent), []).append(label)
    out: dict = {}
    for ga in groups.values():
        for gb in groups.values():
            (cfg_a, nets_a, _), (cfg_b, nets_b, _) = bots[ga[0]], bots[gb[0]]
            pairs = [(a, b) for a in ga for b in gb]
            S = bots[ga[0]][2]["code"].shape[0]
            A = _stack([bots[a][2] for a, _ in pairs])  # (pairs x seeds, ...)
            B = _stack([bots[b][2] for _, b in pairs])
            play = make_play(env, cfg_a, nets_a, ("robot", "robot"), other=(cfg_b, nets_b))
            r = [jax.tree.map(np.asarray, jax.device_get(play(A, B, keys, jnp.asarray(seat, jnp.int32))))
                 for seat in SEATS]
            for i, (a, b) in enumerate(pairs):
                part = [{k: x[k][i * S:(i + 1) * S] for k in ("reward", "score")} for x in r]
                out.setdefault(a, {})[b] = _pool(part[0], part[1], bots[a][0].seeds)
    return {a: {b: out[a][b] for b in robots} for a in robots}


def crossplay_markdown(matrix: dict, name: str = "") -> list[str]:
    labels = list(matrix)
    rows = [f"| {name} human's slot \\ robot's slot | " + " | ".join(labels) + " |", "|" + " --- |" * (len(labels) + 1)]
    for a in labels:
        cells = [f"{matrix[a][b]['reward']['mean']:.1f} +- {matrix[a][b]['reward']['se']:.1f}" for b in labels]
        rows.append(f"| {a} | " + " | ".join(cells) + " |")
    return rows


def markdown(fd: dict) -> list[str]:
    """results.md's section of the field's protocol."""
    def cell(d):
        return f"{d['reward']['mean']:.1f} +- {d['reward']['se']:.1f} ({d['score']['mean']:.2f} +- {d['score']['se']:.2f})"

    p, q = fd["protocol"], fd["proxy_quality"]
    lines = ["", f"The field's protocol (Carroll et al. 2019): reward over {p['horizon']} steps, mean +- s.e. over "
             f"episodes ({p['score']} in brackets), {p['episodes_per_seed_and_seat']} episodes per seed and seat, at "
             f"checkpoint {fd['selected']['checkpoint']} (selected with a BC model of the validation pairs):", "",
             "| partner | robot as player 0 | robot as player 1 | both seats |", "| --- | --- | --- | --- |"]
    for name, key in (("H_proxy (BC of the test pairs)", "h_proxy"), ("BC of the training pairs", "bc_train")):
        d = fd[key]
        lines.append(f"| {name} | {cell(d['seat0'])} | {cell(d['seat1'])} | {cell(d['both'])} |")
    lines.append(f"| itself (self-play) | - | - | {cell(fd['self_play'])} |")
    lines += ["", f"H_proxy: action accuracy {100 * q['accuracy_heldout']:.1f} % on {q['heldout_episodes']} held-out "
              f"test episodes (a copy fitted on the others); with itself {cell(q['with_itself'])}, with that copy "
              f"{cell(q['with_copy'])}."]
    return lines


__all__ = ["supported", "sizes", "evaluate", "markdown", "Field", "make_play", "robot", "seat_samples", "fit_bc",
           "stats", "crossplay", "crossplay_markdown", "models_path"]
