"""Closed-loop co-play: the robot acts with a *reacting* human model instead of an open-loop recording.

Partners of the robot (each episode's human):

* ``scripted``: the task's scripted human (``Team.human_act``), seeing only what a person at the table sees (the
  physics state), never the robot's plan or phase; and each of its variations (:mod:`cogail_envs.variations`),
  named after it; where the team draws held-out pose and place slices (``Team.held_out``), ``pose_heldout_<axis>``
  per slice (``Team.held_out_slices``): that human presenting the object in the slice of that one degree of freedom,
  the closed-loop counterpart of the replayed ``robust-pose_heldout_<axis>`` set
  (a reacting human waits for the robot wherever the recording's human went on with its own partner's timing);
* ``proxy``: a human proxy, a small MLP obs -> a_H (deterministic mean) trained by behaviour cloning on the TEST
  split's human actions alone (Carroll et al., NeurIPS 2019), from a fixed key (:func:`train_proxy`).

Robots: the learned one, pi_R(s, psi(h)) deterministic as in replay, at the reported checkpoints; and, as the
reference, the task's scripted robot on observables only (``Team.robot_act``: it infers from the state what the
human does and which strategy the human's moves show). Each scripted agent has its own team state, drawn with its
own key: the robot's never holds the human's plan.

Every (partner, robot, episode) runs in ONE jitted program (:func:`make_coplay_fn`): a ``lax.scan`` over time, the
episodes vmapped, the partner and the robot per-episode data (the variation id, whether the human is the proxy,
whether the robot is the scripted one), so one compilation serves every partner. Episode ``i`` of every partner
and robot starts from the same key (``fold_in(PRNGKey(COPLAY_SEED), i)``): the same starting situations and the
same scripted human draws, paired across partners and robots. The program plays every episode once per seed of the
learned robot; the scripted robot, which has no seed, plays other episodes in each of those copies (copy ``p``:
episode ``i + p * REF_STRIDE``, :func:`episode_keys`), so that the reference's rate, the denominator of the ratio a
learned robot is judged by, rests on as many episodes as the learned robot's mean over seeds. A task whose team has no ``human_act`` has the
proxy alone as partner; one without ``robot_act`` has no scripted reference.
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..algo import actions
from ..algo.networks import policy_input

COPLAY_SEED = 2468  # episode i's key: fold_in(PRNGKey(COPLAY_SEED), i)
ROBOT_SALT = 4_242  # the scripted robot's own team-state key: fold_in(episode key, ROBOT_SALT)
PROXY_SEED = 0  # the proxy's initial parameters
PROXY_HIDDEN = (256, 256)
PROXY_LR = 1e-3
SCRIPTED, PROXY = "scripted", "proxy"
# the scripted robot's copy p (one per seed of the learned robot) plays episodes i + p * REF_STRIDE
REF_STRIDE = 1_000_000
# the proxy plays this many times the other partners' episodes: its success is rare on some tasks (seqmanip's proxy
# finishes about 1 episode in 10 with any robot), and a ratio of two such rates is noise at the others' count
PROXY_EPISODES = 4
EPISODE_KEYS = ("index", "variation", "proxy", "scripted_robot")  # an episode batch's device arrays
TEST_SPLIT = "test"


class CoplayError(ValueError):
    """A co-play request that cannot be met; the message names the thing and the fix."""


def _team(env):
    from cogail_envs import get_task

    try:
        return get_task(env.name).team
    except Exception:  # noqa: BLE001  (an env whose task is not registered has no scripted team)
        return None


def partners(env) -> list[str]:
    """The task's co-play partners: ``scripted`` and each variation's name where the team has ``human_act``
    (variations where it implements them; ``pose_heldout_<axis>`` per held-out pose slice it draws), then ``proxy``."""
    from cogail_envs.variations import VARIATIONS, held_out_sets

    team = _team(env)
    out = []
    if team is not None and team.human_act is not None:
        out = [SCRIPTED, *(VARIATIONS if team.variations else ()), *held_out_sets(team)]
    return out + [PROXY]


def has_scripted_robot(env) -> bool:
    """Whether the task's team has an observable-only scripted robot (``Team.robot_act``)."""
    team = _team(env)
    return team is not None and team.robot_act is not None


# ---------------------------------------------------------------------------------------------- the human proxy
class Proxy(NamedTuple):
    """The behaviour-cloned human: MLP layers ``[(W, b), ...]`` (tanh hidden units) on the observation and its
    change over the last 1 and 3 steps (:func:`proxy_inputs`), normalised with ``mean`` / ``std``;
    :func:`proxy_action` is its deterministic action. (On the observation alone, handover's proxy reached over the
    bar and on, never grasping it: 0 of 16 co-play episodes with the scripted robot, on the CPU; with its previous
    action 4 of 12; with the observation's recent change 10 of 12.)"""

    layers: list
    mean: jax.Array
    std: jax.Array


PROXY_LAGS = (1, 3)  # the proxy reads how the observation changed over these many steps


def proxy_inputs(hist: jax.Array) -> jax.Array:
    """What the proxy reads of ``hist`` (..., max(PROXY_LAGS) + 1, D), the last observations, oldest first (the
    first observation repeated before the episode's start): the newest and its change over each of PROXY_LAGS."""
    obs = hist[..., -1, :]
    return jnp.concatenate([obs, *(obs - hist[..., -1 - k, :] for k in PROXY_LAGS)], -1)


def proxy_action(proxy: Proxy, hist: jax.Array, discrete: bool = False, key: jax.Array | None = None) -> jax.Array:
    """The proxy's human action after the observations ``hist`` (see :func:`proxy_inputs`; clipped to [-1, 1]).
    ``discrete``: the human's actions are discrete choices, and the proxy's outputs their logits: its action is a
    choice drawn from them with ``key`` (one-hot), as the field's behaviour-cloned humans act (Carroll et al. 2019: a
    deterministic clone of a person gets stuck where people do not)."""
    if discrete:
        logits = _mlp(proxy, proxy_inputs(hist), squash=False)
        return jax.nn.one_hot(jax.random.categorical(key, logits), logits.shape[-1], dtype=jnp.float32)
    return _mlp(proxy, proxy_inputs(hist))


def _mlp(proxy: Proxy, inputs: jax.Array, squash: bool = True) -> jax.Array:
    x = (inputs - proxy.mean) / proxy.std
    for i, (w, b) in enumerate(proxy.layers):
        x = x @ w + b
        if i < len(proxy.layers) - 1:
            x = jnp.tanh(x)
    return jnp.clip(x, -1.0, 1.0) if squash else x


def data_digest(obs, ah, length) -> str:
    """sha256 of a demonstration set's valid steps (observations, human actions, lengths): what the proxy was
    trained on, checkable against the test split."""
    obs, ah, length = np.asarray(obs, np.float32), np.asarray(ah, np.float32), np.asarray(length, np.int64)
    h = hashlib.sha256(length.tobytes())
    for i, n in enumerate(length):
        h.update(np.ascontiguousarray(obs[i, :n]).tobytes())
        h.update(np.ascontiguousarray(ah[i, :n]).tobytes())
    return h.hexdigest()


def _init_layers(key, sizes):
    layers = []
    for k, (a, b) in zip(jax.random.split(key, len(sizes) - 1), zip(sizes[:-1], sizes[1:])):
        layers.append((jax.random.normal(k, (a, b), jnp.float32) / np.sqrt(a), jnp.zeros((b,), jnp.float32)))
    return layers


def train_proxy(demos: dict, split: str, steps: int = 2000, seed: int = PROXY_SEED,
                hidden: tuple = PROXY_HIDDEN, file: str | None = None, discrete: bool = False) -> tuple[Proxy, dict]:
    """Behaviour-clone the human of the TEST split: an MLP (:func:`proxy_inputs`) -> a_H (mean squared error on every valid step,
    full batch Adam, ``steps`` updates in one jitted ``lax.scan``, initial parameters from ``PRNGKey(seed)``; so
    the same data give the same proxy). ``demos``: the split as the evaluation loads it
    (``rollouts.heldout_arrays``: ``obs``, ``ah``, ``length``); ``split``: its name, which must be ``test`` (the
    proxy stands for people the robot has not seen: neither the training nor the validation humans). ``discrete``:
    the human's actions are one-hot choices, and the proxy is fitted by cross-entropy instead (its outputs are
    logits; :func:`proxy_action`).

    Returns the proxy and its record: ``split``, ``file``, ``episodes``, ``samples``, ``digest``
    (:func:`data_digest` of the data), ``steps``, ``hidden``, ``loss`` (final training loss) and ``loss_curve``
    (the loss at 11 points of training)."""
    if split != TEST_SPLIT:
        raise CoplayError(f"the human proxy trains on the test split's humans only, not the {split!r} split: pass "
                          "the test split (Setup.heldout)")
    import optax

    obs, ah, length = np.asarray(demos["obs"], np.float32), np.asarray(demos["ah"], np.float32), \
        np.asarray(demos["length"])
    valid = np.arange(obs.shape[1])[None] < length[:, None]
    H = max(PROXY_LAGS)
    padded = np.concatenate([np.repeat(obs[:, :1], H, 1), obs], 1)  # the first observation before the start
    hist = np.stack([padded[:, H - j:H - j + obs.shape[1]] for j in range(H, -1, -1)], 2)  # (N, T, H + 1, D)
    x, y = np.asarray(proxy_inputs(jnp.asarray(hist)))[valid], ah[valid]
    if not len(x):
        raise CoplayError("the test split has no steps to train the human proxy on: generate or pass a test split "
                          "with episodes")
    mean = x.mean(0)
    std = np.maximum(x.std(0), 1e-3)
    layers = _init_layers(jax.random.PRNGKey(seed), (x.shape[1], *hidden, y.shape[1]))
    opt = optax.adam(PROXY_LR)

    @jax.jit
    def fit(layers, x, y):
        def loss_fn(layers):
            if discrete:
                logits = _mlp(Proxy(layers, mean, std), x, squash=False)
                return -jnp.mean(jnp.sum(y * jax.nn.log_softmax(logits, -1), -1))
            return jnp.mean((_mlp(Proxy(layers, mean, std), x) - y) ** 2)

        def body(carry, _):
            layers, st = carry
            loss, g = jax.value_and_grad(loss_fn)(layers)
            up, st = opt.update(g, st, layers)
            return (optax.apply_updates(layers, up), st), loss

        (layers, _), losses = jax.lax.scan(body, (layers, opt.init(layers)), None, length=steps)
        return layers, losses, loss_fn(layers)

    layers, losses, final = fit(layers, jnp.asarray(x), jnp.asarray(y))
    losses = np.asarray(losses)
    info = {"split": split, "file": None if file is None else str(file), "episodes": int(len(length)),
            "samples": int(len(x)), "digest": data_digest(obs, ah, length), "steps": int(steps),
            "hidden": list(hidden), "loss": float(final), "kind": "categorical" if discrete else "mean",
            "accuracy": float(np.mean(np.argmax(np.asarray(_mlp(Proxy(layers, jnp.asarray(mean), jnp.asarray(std)),
                                                                     jnp.asarray(x), squash=False)), -1)
                                      == np.argmax(y, -1))) if discrete else None,
            "loss_curve": [float(losses[min(int(round(i * (steps - 1) / 10)), steps - 1)]) for i in range(11)]}
    return Proxy(layers, jnp.asarray(mean), jnp.asarray(std)), info


# -------------------------------------------------------------------------------------------- the device program
def episode_batch(env, names: list[str], episodes: int, robots: tuple = ("learned", "scripted"),
                  first: int = 0) -> dict:
    """The co-play episodes of partners ``names`` (``partners(env)``), ``episodes`` each (episodes ``first`` ..
    ``first + episodes - 1``; the proxy ``PROXY_EPISODES`` times as many, its first ``episodes`` the others'), with
    each of ``robots`` (``learned``, ``scripted``): ``index`` (E,) the episode's number, ``variation`` (E,),
    ``proxy`` (E,) bool, ``scripted_robot`` (E,) bool, and the host-side ``key`` (E, 2) (copy 0's, see
    :func:`episode_keys`) and ``partner`` / ``robot`` labels of each episode."""
    from cogail_envs.variations import variation_id

    most = episodes * (PROXY_EPISODES if PROXY in names else 1)
    if first + most > REF_STRIDE:
        raise CoplayError(f"co-play plays at most {REF_STRIDE} episodes per partner: ask for fewer episodes")
    index = np.arange(first, first + most, dtype=np.int32)
    rows = {"index": [], "variation": [], "proxy": [], "scripted_robot": [], "partner": [], "robot": []}
    for robot in robots:
        for name in names:
            n = episodes * (PROXY_EPISODES if name == PROXY else 1)
            rows["index"].append(index[:n])
            rows["variation"].append(np.full(n, 0 if name in (SCRIPTED, PROXY) else variation_id(name),
                                             np.int32))
            rows["proxy"].append(np.full(n, name == PROXY))
            rows["scripted_robot"].append(np.full(n, robot == "scripted"))
            rows["partner"] += [name] * n
            rows["robot"] += [robot] * n
    out = {k: np.concatenate(v) for k, v in rows.items() if k not in ("partner", "robot")}
    out["partner"], out["robot"] = np.asarray(rows["partner"]), np.asarray(rows["robot"])
    out["key"] = np.asarray(episode_keys(out["index"], out["scripted_robot"], 1)[0])
    return out


def episode_keys(index, scripted_robot, copies: int) -> jax.Array:
    """(copies, E, 2): each episode's key in each copy of the program (one per seed of the learned robot):
    ``fold_in(PRNGKey(COPLAY_SEED), index)`` for the learned robot's episodes in every copy and for the scripted
    robot's in copy 0; the scripted robot's copy ``p`` plays episode ``index + p * REF_STRIDE`` instead (other starts
    and other human draws), where a robot without a seed would otherwise repeat copy 0."""
    index, scripted_robot = jnp.asarray(index), jnp.asarray(scripted_robot)
    p = jnp.arange(copies, dtype=index.dtype)[:, None]
    shifted = index[None] + jnp.where(scripted_robot[None], p * REF_STRIDE, 0)
    return jax.vmap(jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(COPLAY_SEED), i)))(shifted)


def _flat(x):
    return x.reshape((x.shape[0] * x.shape[1],) + x.shape[2:])


def make_coplay_fn(env, cfg=None, nets=None):
    """Jitted ``run(params, norm, proxy, eps) -> {"success", "strategy", "length"}`` (each (P, E)): every co-play
    episode of ``eps`` (:func:`episode_batch`'s arrays ``key``, ``variation``, ``proxy``, ``scripted_robot``)
    under each of the P parameter sets of the learned robot (``params`` / ``norm`` with a leading axis P), in one
    ``lax.scan`` over the time limit. A scripted-robot episode does not depend on the parameters (it is the same for
    every P). Without ``cfg`` / ``nets`` there is no learned robot: call ``run(None, None, proxy, eps)`` with every
    episode's ``scripted_robot`` set (P = 1). ``proxy``: a :class:`Proxy`, or None where no episode uses it."""
    from cogail_envs.variations import NONE

    team = _team(env)
    human_act = team.human_act if team is not None else None
    robot_act = team.robot_act if team is not None else None
    Ah, T = env.human_action_size, env.max_episode_steps
    spec = actions.spec_of(env)
    learned = cfg is not None and nets is not None
    if learned:
        from .rollouts import make_robot_step

        psi_code, _ = make_robot_step(cfg, env, nets)
        actor = nets["actor"].apply
        K = cfg.history
    else:
        K = 0
    H = max(K, max(PROXY_LAGS))  # observations kept: psi's K + 1 and the proxy's

    def start(key, ep):
        k_init, k_team, k_run = jax.random.split(key, 3)
        state = env.reset_from(env.sample_init(k_init))
        ts_h = ts_r = ()
        if human_act is not None:
            ts_h, _ = team.init(env, k_team, env.uniform_mix(), jnp.where(ep["proxy"], NONE, ep["variation"]))
        if robot_act is not None:
            ts_r, _ = team.init(env, jax.random.fold_in(key, ROBOT_SALT), env.uniform_mix(), NONE)
        return state, ts_h, ts_r, k_run

    def act(params, norm, proxy, state, hist, prev_ah, ts_h, ts_r, k_run, ep):
        k_h, k_r = jax.random.split(jax.random.fold_in(k_run, state.info["t"]))
        a_h = jnp.zeros((Ah,), jnp.float32)
        if human_act is not None:
            ts_h, a_h = human_act(env, ts_h, state, k_h)
        if proxy is not None:
            a_h = jnp.where(ep["proxy"], proxy_action(proxy, hist, spec.human_discrete, jax.random.fold_in(k_h, 1)),
                            a_h)
        a_r = jnp.zeros((env.robot_action_size,), jnp.float32)
        if learned:
            z = psi_code(params, norm, hist[-(K + 1):], prev_ah)
            mean, _ = actor(params["actor"], policy_input(norm, hist), z)
            a_r = actions.agent_act(spec.robot_discrete, mean[Ah:], jax.random.fold_in(k_r, 2))
        if robot_act is not None:
            ts_r, a_s = robot_act(env, ts_r, state, k_r)
            if hasattr(env, "policy_robot_action"):  # the env takes the robot's actions in the object's frame
                a_s = env.policy_robot_action(state.obs, a_s)
            a_r = jnp.where(ep["scripted_robot"], a_s, a_r)
        return jnp.concatenate([a_h, a_r]), a_h, ts_h, ts_r

    per_ep = jax.vmap(act, in_axes=(None, None, None, 0, 0, 0, 0, 0, 0, 0))
    per_param = jax.vmap(per_ep, in_axes=(0, 0, None, 0, 0, 0, 0, 0, 0, None))

    def run(params, norm, proxy, eps):
        E = eps["index"].shape[0]
        P = jax.tree.leaves(params)[0].shape[0] if learned else 1
        keys = episode_keys(eps["index"], eps["scripted_robot"], P)
        first = jax.vmap(jax.vmap(start), in_axes=(0, None))(keys, eps)
        state, ts_h, ts_r, k_run = jax.tree.map(_flat, first)
        hist = jnp.repeat(state.obs[:, None], H + 1, 1)
        unflat = lambda x: x.reshape((P, E) + x.shape[1:])  # noqa: E731

        def body(carry, _):
            state, hist, prev_ah, ts_h, ts_r, fin = carry
            action, a_h, ts_h, ts_r = per_param(params, norm, proxy, *jax.tree.map(
                unflat, (state, hist, prev_ah, ts_h, ts_r, k_run)), eps)
            action, a_h, ts_h, ts_r = jax.tree.map(_flat, (action, a_h, ts_h, ts_r))
            nxt = jax.vmap(env.step)(state, action)
            state = jax.vmap(lambda f, o, n: jax.tree.map(lambda a, b: jnp.where(f, a, b), o, n))(fin, state, nxt)
            hist = jnp.concatenate([hist[:, 1:], state.obs[:, None]], 1)
            return (state, hist, a_h, ts_h, ts_r, fin | (nxt.done > 0)), None

        carry = (state, hist, jnp.zeros((P * E, Ah), jnp.float32), ts_h, ts_r, jnp.zeros((P * E,), bool))
        (state, _, _, _, _, _), _ = jax.lax.scan(body, carry, None, length=T)
        m = state.metrics
        out = {"success": m["success"], "strategy": jax.vmap(env.classify_strategy)(m), "length": state.info["t"]}
        if env.score_metric:
            out["score"] = m[env.score_metric]
        return jax.tree.map(unflat, out)

    if learned:  # its trace kept between runs (``programs.stored``): the config fixes env, networks and team
        from ..algo.config import program_key
        from ..runtime.programs import stored

        jitted = stored(run, "coplay", ("coplay", program_key(cfg)))
    else:
        jitted = jax.jit(run)

    def call(params, norm, proxy, eps):
        eps = {k: jnp.asarray(eps[k]) for k in EPISODE_KEYS}
        return jitted(params, norm, proxy, eps) if learned else jitted(None, None, proxy, eps)

    def lower(params, norm, proxy, eps):  # ahead of time: arrays or jax.ShapeDtypeStruct for params / norm
        eps = {k: jnp.asarray(eps[k]) for k in EPISODE_KEYS}
        return jitted.lower(params, norm, proxy, eps) if learned else jitted.lower(None, None, proxy, eps)

    call.lower = lower
    return call


# ------------------------------------------------------------------------------------------------- the reporting
def _per_partner(success: np.ndarray, batch: dict, robot: str, seeds) -> dict:
    """{partner: {"mean", "std", "per_seed"}} of a (P, E) success array for the episodes of ``robot``."""
    out = {}
    for name in dict.fromkeys(batch["partner"]):
        sel = (batch["partner"] == name) & (batch["robot"] == robot)
        if not sel.any():
            continue
        per_seed = success[:, sel].mean(1)
        out[str(name)] = {"mean": float(per_seed.mean()), "std": float(per_seed.std()),
                          "per_seed": {str(s): float(v) for s, v in zip(seeds, per_seed)}}
    return out


def default_episodes() -> int:
    """Co-play episodes per partner and robot when none is given: 64 on an accelerator, 4 on a CPU."""
    return 4 if jax.default_backend() == "cpu" else 64


class Prepared(NamedTuple):
    """What co-play needs before it reads a checkpoint (:func:`prepare`): the proxy and its record, the partners,
    whether a scripted robot plays, the episode batch and the compiled program."""

    proxy: Proxy
    proxy_info: dict
    names: list
    scripted: bool
    episodes: int
    batch: dict
    run: object


def prepare(s, episodes: int | None = None, proxy_steps: int | None = None) -> Prepared:
    """Co-play's set-up for a run's set-up ``s`` (``runs.Setup``, its test split loaded): the proxy trained on
    ``s.heldout`` (the test split), the episode batch and the program (``run.lower(params, norm, proxy, batch)``
    lowers it ahead of time, for one checkpoint's ``params`` / ``norm`` with a leading seed axis, arrays or
    ``jax.ShapeDtypeStruct``). ``cogail train --eval`` makes it while training runs."""
    env, cfg = s.env, s.cfg
    if s.heldout is None:
        raise CoplayError("co-play needs the test split to train the human proxy on: build the set-up with the "
                          "test split (need_heldout=True)")
    episodes = int(episodes or default_episodes())
    proxy_steps = int(proxy_steps or (500 if jax.default_backend() == "cpu" else 4000))
    proxy, proxy_info = train_proxy(s.heldout, TEST_SPLIT, steps=proxy_steps, file=(s.files or {}).get("test"),
                                    discrete=actions.spec_of(env).human_discrete)
    names, scripted = partners(env), has_scripted_robot(env)
    batch = episode_batch(env, names, episodes, ("learned", "scripted") if scripted else ("learned",))
    return Prepared(proxy, proxy_info, names, scripted, episodes, batch, make_coplay_fn(env, cfg, s.nets))


def evaluate(s, checkpoints: dict[str, tuple[int, dict]], episodes: int | None = None,
             proxy_steps: int | None = None, prepared: Prepared | None = None) -> dict:
    """The co-play results of a run's set-up ``s`` (``runs.Setup``, its test split loaded): the proxy trained on
    ``s.heldout`` (the test split), then every partner with the learned robot at each of ``checkpoints``
    ({name: (update, eval_params)}: e.g. the one selected on validation and the paper-protocol replay one) and with
    the scripted robot; one compiled program, one call per checkpoint. ``prepared``: :func:`prepare`'s result
    (made with the same ``episodes``), else made here. The dict that results.json's ``coplay`` holds
    (:func:`markdown` writes it)."""
    p = prepared or prepare(s, episodes, proxy_steps)
    cfg, batch = s.cfg, p.batch
    learned, ref = {}, None
    done: dict[int, dict] = {}
    for key, (step, state) in checkpoints.items():
        if step not in done:
            done[step] = jax.tree.map(np.asarray, jax.device_get(p.run(state["params"], state["norm"], p.proxy,
                                                                        batch)))
        out = done[step]
        learned[key] = {"checkpoint": int(step), "success": _per_partner(out["success"], batch, "learned", cfg.seeds)}
        if "score" in out:  # the task's score (e.g. soups served) per episode, beside the success rate
            learned[key]["score"] = _per_partner(out["score"], batch, "learned", cfg.seeds)
            learned[key]["score_name"] = s.env.score_metric
        if p.scripted and ref is None:  # each copy played other episodes: the mean over all of them
            copies = out["success"].shape[0]
            ref = {k: v["mean"] for k, v in _per_partner(out["success"], batch, "scripted", range(copies)).items()}
    res = {"partners": p.names, "episodes": p.episodes,
           "proxy_episodes": p.episodes * PROXY_EPISODES if PROXY in p.names else 0, "seed": COPLAY_SEED,
           "scripted_robot_copies": len(cfg.seeds) if p.scripted else 0,
           "learned": learned,
           "scripted_robot": ref, "proxy": dict(p.proxy_info)}
    if ref is not None:
        res["proxy"]["success_with_scripted_robot"] = ref.get(PROXY)
    return res


def _footnote(c: dict) -> str:
    """What results.md's co-play partners and robots are: a clause for each kind of partner in ``c["partners"]``
    (the scripted human, its variations, its held-out pose slices, the proxy) and a sentence on the scripted robot
    where ``c`` has its reference; nothing on what the task does not have."""
    from cogail_envs.variations import HELD_OUT, VARIATIONS, is_held_out_set

    names = c["partners"]
    parts = []
    if SCRIPTED in names:
        parts.append("scripted: the task's scripted human, reacting to what the robot does and seeing only the state")
    if varied := [n for n in names if n in VARIATIONS]:
        parts.append(f"{', '.join(varied)}: that human with the variation of that name")
    if held := [n for n in names if is_held_out_set(n)]:
        parts.append("pose_heldout_<axis>: that human presenting the object in the held-out slice of that degree of "
                     "freedom, every other in range" if any(n != HELD_OUT for n in held) else
                     "pose_heldout: that human presenting the object in the task's held-out slice")
    if PROXY in names and (p := c.get("proxy")):
        extra = (f"; with the scripted robot it succeeds in {100 * p['success_with_scripted_robot']:.1f} %"
                 if p.get("success_with_scripted_robot") is not None else "")
        parts.append(f"proxy: an MLP {tuple(p['hidden'])} on the state and its change over the last 1 and 3 steps, "
                     f"behaviour-cloned on the {p['split']} split's humans alone ({p['episodes']} episodes, "
                     f"{p['samples']} steps, {p['steps']} updates, final loss {p['loss']:.4g}{extra})")
    text = "; ".join(parts) + "." if parts else ""
    if c.get("scripted_robot"):
        text += (" The scripted robot acts on the state alone" + (" too" if SCRIPTED in names else "")
                 + " (it reads the strategy off the human's moves).")
    return text.strip()


def markdown(c: dict) -> list[str]:
    """results.md's co-play section (``evaluate``'s dict)."""
    keys = list(c["learned"])
    head = ["partner", *[f"learned robot, {k.replace('_', ' ')} checkpoint ({c['learned'][k]['checkpoint']})"
                         for k in keys]]
    if c.get("scripted_robot"):
        head.append("scripted robot (reference)")
    proxy_n = f", the proxy {c['proxy_episodes']}" if c.get("proxy_episodes") else ""
    copies = c.get("scripted_robot_copies") or 1
    ref_n = (f"; the scripted robot {copies} times as many, its first ones from the same starts"
             if c.get("scripted_robot") and copies > 1 else ", the same starts for every partner and robot")
    lines = ["", "Closed-loop co-play (success, %; mean +- std over seeds; "
             f"{c['episodes']} episodes per partner{proxy_n}{ref_n}):", "",
             "| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for name in c["partners"]:
        row = [name]
        for k in keys:
            e = c["learned"][k]["success"].get(name)
            row.append("-" if e is None else f"{100 * e['mean']:.1f} +- {100 * e['std']:.1f}")
        if c.get("scripted_robot"):
            v = c["scripted_robot"].get(name)
            row.append("-" if v is None else f"{100 * v:.1f}")
        lines.append("| " + " | ".join(row) + " |")
    scored = [k for k in keys if "score" in c["learned"][k]]
    if scored:
        name = c["learned"][scored[0]].get("score_name", "score")
        lines += ["", f"Co-play {name} per episode (mean +- std over seeds):", "",
                  "| partner | " + " | ".join(f"learned robot, {k.replace('_', ' ')} checkpoint" for k in scored) + " |",
                  "|" + " --- |" * (len(scored) + 1)]
        for partner in c["partners"]:
            row = [partner]
            for k in scored:
                e = c["learned"][k]["score"].get(partner)
                row.append("-" if e is None else f"{e['mean']:.2f} +- {e['std']:.2f}")
            lines.append("| " + " | ".join(row) + " |")
    if note := _footnote(c):
        lines += ["", note]
    return lines


def figure(c: dict, out_png, title: str | None = None) -> Path:
    """Bars per partner: the learned robot (selected checkpoint, else the first reported; std over seeds) next
    to the scripted robot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    key = "selected" if "selected" in c["learned"] else next(iter(c["learned"]))
    names = c["partners"]
    lv = [c["learned"][key]["success"].get(n, {}) for n in names]
    x = np.arange(len(names))
    ref = c.get("scripted_robot")
    w = 0.4 if ref else 0.7
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * len(names) + 2), 4.0))
    ax.bar(x - (w / 2 if ref else 0), [100 * e.get("mean", np.nan) for e in lv], w,
           yerr=[100 * e.get("std", 0.0) for e in lv], capsize=3, color="tab:blue",
           label=f"learned robot ({key.replace('_', ' ')} checkpoint {c['learned'][key]['checkpoint']})")
    if ref:
        ax.bar(x + w / 2, [100 * ref.get(n, np.nan) for n in names], w, color="0.55", label="scripted robot")
    ax.set_xticks(x, names, rotation=20)
    ax.set_ylabel("co-play success (%)")
    ax.set_ylim(0, 122)
    ax.set_yticks(range(0, 101, 20))
    ax.set_title(title or "Closed-loop co-play per human partner")
    ax.legend(fontsize=8, loc="upper center", ncol=2)
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


__all__ = ["partners", "has_scripted_robot", "Proxy", "PROXY_LAGS", "proxy_inputs", "proxy_action", "train_proxy", "data_digest", "episode_batch", "episode_keys", "Prepared", "prepare",
           "make_coplay_fn", "evaluate", "markdown", "figure", "CoplayError", "COPLAY_SEED", "SCRIPTED", "PROXY"]
