"""The evaluation's device programs (the paper's protocols), jitted and vmapped over seeds.

* interpolation: ``eval_codes`` codes on a uniform grid over (-1, 1)^2; the co-policy acts for both agents
  deterministically (action means); success rate and the executed strategies. Run twice per checkpoint, from two
  independent draws of initial states: the reported one (``EVAL_SEED``) and a validation one
  (``VALIDATION_EVAL_SEED``), on which choices about diversity (a variant, its settings) are made.
* replay: the robot acts with pi_R(s, psi(h)) (deterministic) against open-loop replays of held-out human
  trajectories, each episode started where its demonstration started; success rate. An episode ends at the
  task's time limit. A human from outside the test and validation splits (a varied human, your own recordings)
  may end its recording in the limit's last steps (a slow or hesitant one): its replay lasts until ``REPLAY_MARGIN``
  of the limit after its recording ends where that is later, so that the clock does not decide for the person.
* latent map: the mean psi code of each held-out demonstration.

The reporting of these figures is :mod:`cogail_jax.eval.protocol`.
"""
from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..algo import actions
from ..algo.config import TrainConfig, program_key
from ..algo.networks import policy_input
from ..runtime.programs import stored


EVAL_SEED = 12345  # the interpolation rollouts' initial states: split(PRNGKey(EVAL_SEED), eval_codes), one per code
VALIDATION_EVAL_SEED = 54321  # the validation interpolation rollouts' initial states, drawn the same way
REPLAY_MARGIN = 0.2  # a margin replay runs at least this share of the time limit past the end of the recording


def replay_margin(env) -> int:
    """Steps a replay runs, at least, past the end of the human's recording (``REPLAY_MARGIN`` of the limit)."""
    return int(round(REPLAY_MARGIN * env.max_episode_steps))


def replay_steps(env, lengths, margin=None) -> int:
    """Time steps that a batch of replays of recordings of ``lengths`` runs (the width to pad a batch's recordings
    to): the time limit, or the longest recording with a margin (``margin``: bool per recording; default all) plus
    ``replay_margin`` where that is more."""
    lengths = np.asarray(lengths)
    if margin is not None:
        lengths = lengths[np.asarray(margin, bool)]
    longest = int(lengths.max()) if lengths.size else 0
    return max(int(env.max_episode_steps), longest + replay_margin(env))


def interpolation_codes(n: int) -> jnp.ndarray:
    """n codes uniformly over (-1, 1)^2: a sqrt(n) x sqrt(n) grid of cell centres (n a square), else random."""
    k = int(round(math.sqrt(n)))
    if k * k == n:
        c = jnp.linspace(-1 + 1 / k, 1 - 1 / k, k)
        return jnp.stack(jnp.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
    return jax.random.uniform(jax.random.PRNGKey(0), (n, 2), minval=-1, maxval=1)


EVAL_SEED = 97  # a discrete agent's choices in evaluation: episode i's draw at step t from fold_in(fold_in(key, i), t)


def make_robot_step(cfg: TrainConfig, env, nets):
    """The robot of the replay protocol (and of ``cogail play``): pi_R(s, psi(h)), deterministic.

    Returns ``(psi_code, robot_step)``:

    * ``psi_code(params, norm, hist, prev_ah) -> z``: psi's code of the history ``hist`` (K + 1 raw
      observations s_{t-K..t}) and the human's previous action (zeros for presets without a code);
    * ``robot_step(params, norm, state, hist, prev_ah, a_h, key=None) -> (next_state, next_hist, z, a_r)``: one
      env step with the human's action ``a_h`` given and the robot's action from pi_R(s, psi(h)) (a discrete robot's
      choice is drawn with ``key``, else its most likely one: ``actions.act``).
    """
    actor, psi = nets["actor"].apply, nets["psi"].apply
    Ah, spec = env.human_action_size, actions.spec_of(env)

    def normalize(norm, x):
        return (x - norm["mean"]) / norm["std"]

    def psi_code(params, norm, hist, prev_ah):
        h = normalize(norm, hist).reshape(-1)
        z = psi(params["psi"], jnp.concatenate([h, prev_ah]))
        return z if cfg.use_code else jnp.zeros_like(z)

    def robot_step(params, norm, state, hist, prev_ah, a_h, key=None):
        z = psi_code(params, norm, hist, prev_ah)
        mean, _ = actor(params["actor"], policy_input(norm, hist), z)
        a_r = (actions.agent_mode(spec.robot_discrete, mean[Ah:]) if key is None else
               actions.agent_act(spec.robot_discrete, mean[Ah:], key))
        nxt = env.step(state, jnp.concatenate([a_h, a_r]))
        return nxt, jnp.concatenate([hist[1:], nxt.obs[None]], 0), z, a_r

    return psi_code, robot_step


def _freeze(fin, old, new):
    return jax.tree.map(lambda a, b: jnp.where(fin, a, b), old, new)


def _flat(x):
    """(P, E, ...) -> (P * E, ...) (explicit sizes: MJX states hold empty arrays)."""
    return x.reshape((x.shape[0] * x.shape[1],) + x.shape[2:])


def _episodes_fn(cfg: TrainConfig, env, nets):
    """``run(params, norm, eps) -> final metrics (P, E)``: every episode of ``eps`` under every parameter set
    (``params`` / ``norm`` with a leading axis P: checkpoints x seeds), in one ``lax.scan`` over time.

    ``eps`` (leading axis E): ``init`` (initial conditions), ``replay`` (bool), ``code`` (the interpolation code),
    ``ah`` / ``length`` (the recorded human of a replay), ``patient`` and ``margin`` (bool). A replay episode's robot
    acts from pi_R(s, psi(h)) and its human replays ``ah``; a patient one's human waits where the task's
    ``replay_hold`` says (it would let go of what the robot has not taken yet) and then goes on with its recording
    from where it stopped; an interpolation episode's co-policy acts for both agents with ``code``; all deterministic (action
    means), the episode frozen from its end on. An episode ends at a terminal state (success, failure) or at the
    time limit, which a ``margin`` replay pushes back to ``replay_margin`` steps after its recording ended (its
    waits included); the scan runs ``max(limit, eps["ah"].shape[1])`` steps (pad to ``replay_steps``). The
    environment steps once per time step for all P x E episodes on one flat axis, so the physics is traced (and
    compiled) once, under one vmap."""
    actor = nets["actor"].apply
    Ah, Tenv, margin = env.human_action_size, env.max_episode_steps, replay_margin(env)
    spec = actions.spec_of(env)
    psi_code, _ = make_robot_step(cfg, env, nets)

    def act(params, norm, state, hist, prev_ah, ep, p, key):
        """The joint action and the human's; ``p``: the replayed human's position in its recording."""
        z = jnp.where(ep["replay"], psi_code(params, norm, hist, prev_ah),
                      ep["code"] if cfg.use_code else jnp.zeros_like(ep["code"]))
        mean, _ = actor(params["actor"], policy_input(norm, hist), z)
        a = actions.act(spec, mean, key)
        recorded = jnp.where(p < ep["length"], ep["ah"][jnp.minimum(p, ep["ah"].shape[0] - 1)], 0.0)
        wait, a_wait = env.replay_hold(state, recorded)
        wait = wait & ep["patient"] & ep["replay"]
        a_h = jnp.where(ep["replay"], jnp.where(wait, a_wait, recorded), a[:Ah])
        return jnp.concatenate([a_h, a[Ah:]]), a_h, p + 1 - wait.astype(p.dtype)

    per_param = jax.vmap(act, in_axes=(None, None, 0, 0, 0, 0, 0, 0))  # episodes
    act_all = jax.vmap(per_param, in_axes=(0, 0, 0, 0, 0, None, 0, None))  # parameter sets (the same draws)

    def run(params, norm, eps):
        P, E = jax.tree.leaves(params)[0].shape[0], eps["init"].shape[0]
        first = jax.vmap(env.reset_from)(eps["init"])
        state = jax.tree.map(lambda x: _flat(jnp.broadcast_to(x, (P,) + x.shape)), first)
        hist = jnp.repeat(state.obs[:, None], cfg.history + 1, 1)
        late_ok = _flat(jnp.broadcast_to(eps["replay"] & eps["margin"], (P, E)))
        length = _flat(jnp.broadcast_to(jnp.where(eps["replay"], eps["length"], 0), (P, E)))
        never = jnp.iinfo(jnp.int32).max - margin

        def body(carry, step):
            state, hist, prev_ah, fin, pos, rec_end = carry
            unflat = lambda x: x.reshape((P, E) + x.shape[1:])  # noqa: E731
            # a discrete agent's draws: episode i's at this step, the same for every parameter set
            keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(EVAL_SEED), i), step)
                            )(jnp.arange(E))
            action, a_h, pos = act_all(params, norm, jax.tree.map(unflat, state), unflat(hist), unflat(prev_ah),
                                       eps, unflat(pos), keys)
            pos = _flat(pos)
            nxt = jax.vmap(env.step)(state, _flat(action))
            t = nxt.info["t"]
            rec_end = jnp.minimum(rec_end, jnp.where(pos >= length, t, never))  # when the recording ran out
            terminal = (nxt.done > 0) & ~(nxt.info["truncation"] > 0)
            timeout = (t >= Tenv) & (~late_ok | (t >= rec_end + margin))
            hist = jnp.concatenate([hist[:, 1:], nxt.obs[:, None]], 1)
            return (jax.vmap(_freeze)(fin, state, nxt), hist, _flat(a_h), fin | terminal | timeout, pos,
                    rec_end), None

        carry = (state, hist, jnp.zeros((P * E, Ah)), jnp.zeros((P * E,), bool), jnp.zeros((P * E,), jnp.int32),
                 jnp.where(length > 0, never, 0))
        steps = max(Tenv, eps["ah"].shape[1])
        (state, _, _, _, _, _), _ = jax.lax.scan(body, carry, jnp.arange(steps))
        return jax.tree.map(lambda x: x.reshape((P, E) + x.shape[1:]), state.metrics)

    return run


def replay_episodes(episodes: dict, code_dim: int) -> dict:
    """Replay episodes (``init``, ``ah``, ``length``, optional ``patient`` and ``margin``) in the form
    ``_episodes_fn`` runs."""
    n = episodes["length"].shape[0]
    return {"init": episodes["init"], "ah": episodes["ah"], "length": episodes["length"],
            "patient": jnp.asarray(episodes.get("patient", jnp.zeros((n,), bool)), bool),
            "margin": jnp.asarray(episodes.get("margin", jnp.zeros((n,), bool)), bool),
            "replay": jnp.ones((n,), bool), "code": jnp.zeros((n, code_dim), jnp.float32)}


def make_replay_fn(cfg: TrainConfig, env, nets):
    """Jitted ``replay(params, norm, episodes) -> final metrics (seeds, episodes)`` (``replay.lower(...)``: its
    program lowered for those arguments' shapes, to compile ahead of time): the replay protocol alone
    (params / norm with a leading seed axis; ``episodes``: ``heldout_arrays`` without ``strategy``). Replays the
    extra test sets at the reported checkpoints (``trainer.eval_run``, ``trainer.eval_extra_sets``); with
    ``extra_curves`` ``eval_run`` replays them in the batch of ``make_eval_fn`` instead."""
    episodes = _episodes_fn(cfg, env, nets)
    run = stored(lambda params, norm, ep: episodes(params, norm, replay_episodes(ep, cfg.code_dim)), "replay",
                 program_key(cfg))

    def padded(ep):  # recordings padded to the steps the replays run (a host-side shape)
        width = replay_steps(env, np.asarray(jax.device_get(ep["length"])), ep.get("margin"))
        ah = ep["ah"]
        if ah.shape[1] < width:
            ah = jnp.concatenate([jnp.asarray(ah), jnp.zeros((ah.shape[0], width - ah.shape[1]) + ah.shape[2:],
                                                            jnp.asarray(ah).dtype)], 1)
        return {**ep, "ah": ah}

    def replay(params, norm, ep):
        return run(params, norm, padded(ep))

    replay.lower = lambda params, norm, ep: run.lower(params, norm, padded(ep))  # ahead of time (shapes suffice)
    return replay


def make_eval_fn(cfg: TrainConfig, env, nets):
    """Jitted ``evaluate(params, norm, episodes) -> outputs`` of the evaluation protocols at several checkpoints
    and seeds in one device program: params / norm stacked (checkpoints, seeds, ...); ``episodes``:
    ``heldout_arrays`` without ``strategy`` (e.g. ``stack_sets`` of test and validation). The interpolation
    rollouts (the ``eval_codes`` grid, from the initial states of ``EVAL_SEED`` and of ``VALIDATION_EVAL_SEED``, the
    same for every checkpoint and seed) and the replays run in one batch (``_episodes_fn``). Outputs, each
    (checkpoints, seeds, ...): ``interp_success`` / ``interp_strategy`` / ``interp_metrics`` (per code),
    ``val_interp_success`` / ``val_interp_strategy`` (the validation rollouts, per code), ``replay_success`` /
    ``replay_metrics`` (per episode) and ``latent`` (psi's mean code of each episode)."""
    run = _episodes_fn(cfg, env, nets)
    psi_code, _ = make_robot_step(cfg, env, nets)
    K, codes = cfg.history, interpolation_codes(cfg.eval_codes)
    n = codes.shape[0]

    def latent_one(params, norm, obs, prev_ah, length):
        T = obs.shape[0]
        idx = jnp.clip(jnp.arange(T)[:, None] + jnp.arange(-K, 1)[None], 0, None)
        z = jax.vmap(lambda h, p: psi_code(params, norm, h, p))(obs[idx], prev_ah)
        mask = (jnp.arange(T) < length)[:, None]
        return (z * mask).sum(0) / jnp.maximum(length, 1)

    latent = jax.vmap(jax.vmap(latent_one, in_axes=(None, None, 0, 0, 0)), in_axes=(0, 0, None, None, None))

    def evaluate(params, norm, held):
        C, S = jax.tree.leaves(params)[0].shape[:2]
        params, norm = jax.tree.map(_flat, (params, norm))
        rp = replay_episodes(held, cfg.code_dim)
        T = rp["ah"].shape[1]
        init = jnp.concatenate([jax.vmap(env.sample_init)(jax.random.split(jax.random.PRNGKey(seed), n))
                                for seed in (EVAL_SEED, VALIDATION_EVAL_SEED)])
        interp = {"init": init, "replay": jnp.zeros((2 * n,), bool), "patient": jnp.zeros((2 * n,), bool),
                  "margin": jnp.zeros((2 * n,), bool), "code": jnp.concatenate([codes, codes]),
                  "ah": jnp.zeros((2 * n, T, env.human_action_size)), "length": jnp.zeros((2 * n,), jnp.int32)}
        eps = jax.tree.map(lambda a, b: jnp.concatenate([a, b.astype(a.dtype)]), interp, rp)
        m = run(params, norm, eps)
        im, vm, rm = (jax.tree.map(lambda x, a=a, b=b: x[:, a:b], m) for a, b in ((0, n), (n, 2 * n), (2 * n, None)))
        strategy = jax.vmap(jax.vmap(env.classify_strategy))
        out = {"interp_success": im["success"], "interp_strategy": strategy(im), "interp_metrics": im,
               "val_interp_success": vm["success"], "val_interp_strategy": strategy(vm),
               "replay_success": rm["success"], "replay_metrics": rm,
               "latent": latent(params, norm, held["obs"], held["prev_ah"], held["length"])}
        return jax.tree.map(lambda x: x.reshape((C, S) + x.shape[1:]), out)

    return stored(evaluate, "evaluate", program_key(cfg))


def heldout_arrays(demos, patient: bool = False, margin: bool = False) -> dict[str, np.ndarray]:
    """A demonstration set as replay episodes; ``patient``: its humans wait for the robot; ``margin``: they may end
    their recordings late (``_episodes_fn``)."""
    prev = np.zeros_like(demos.actions_human)
    prev[:, 1:] = demos.actions_human[:, :-1]
    return {"init": demos.init, "ah": demos.actions_human, "length": demos.length, "obs": demos.obs, "prev_ah": prev,
            "strategy": demos.strategy, "patient": np.full(demos.length.shape, bool(patient)),
            "margin": np.full(demos.length.shape, bool(margin))}


def stack_sets(sets: dict[str, dict], steps: int = 0) -> tuple[dict[str, np.ndarray], dict[str, slice]]:
    """Episode sets (``heldout_arrays``) as one batch: zero-padded to the longest episode (at least ``steps``, e.g.
    the env's ``max_episode_steps``, so that the shapes do not depend on the data) and concatenated along the
    episode axis, so that one compiled evaluation program serves them all (e.g. test and validation: they differ
    in data only). Returns the batch (without ``strategy``) and each set's slice of the episode axis."""
    keys = ("init", "ah", "length", "obs", "prev_ah", "patient", "margin")
    T = max([int(steps)] + [int(v["ah"].shape[1]) for v in sets.values()])
    out, slices, i = {k: [] for k in keys}, {}, 0
    for name, v in sets.items():
        n = int(v["length"].shape[0])
        slices[name] = slice(i, i + n)
        i += n
        for k in keys:
            x = np.asarray(v[k]) if k in v else np.zeros((n,), bool)
            if x.ndim == 3 and x.shape[1] < T:
                x = np.concatenate([x, np.zeros((n, T - x.shape[1], x.shape[2]), x.dtype)], 1)
            out[k].append(x)
    return {k: np.concatenate(v, 0) for k, v in out.items()}, slices


