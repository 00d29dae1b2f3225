"""Co-GAIL as one compiled function (laid out like brax's ``training/agents/ppo/train.py``).

``make_train_fns(cfg, env, norm_stats)`` returns ``init(seeds, expert) -> TrainState`` and
``chunk(state, expert) -> (state, metrics)``: ``cfg.updates_per_call`` train steps, each of which is

1. ``rollout.rollout``: ``num_envs x unroll_length`` env steps with per-episode strategy codes;
2. ``inner_updates`` x (``aux_step``: psi / co-policy on ``losses.aux_objective``; ``disc_step``: the
   discriminator, BCE or LSGAN + gradient penalty) on minibatches of generated and expert data;
3. ``rewards``: discriminator (+ DIAYN) rewards, return-normalised; GAE with time-outs bootstrapped;
4. ``ppo_update``: ``ppo_epochs`` of clipped PPO (+ BC) over minibatches.

Every function below is a module-level function of explicit arguments: ``Context`` carries the static parts
(config, env, networks, optimizers). Everything is vmapped over a leading seed axis and scanned over
updates, so the host only logs and saves; ``parallel.SeedChunk`` runs the seed axis over devices.
"""
from __future__ import annotations

from functools import partial
from typing import Any, NamedTuple

import flax.struct as struct
import jax
import jax.numpy as jnp
import numpy as np
import optax

from . import actions, losses, shards
from .config import HYPER, TrainConfig, chunk_key, hyper_values, program_key
from .networks import disc_kind, history_input, make_networks, policy_input
from ..runtime.parallel import SeedChunk
from ..runtime.programs import stored
from .rollout import Carry, code_grid, initial_carry, rollout


class TrainState(struct.PyTreeNode):
    """Everything needed to resume exactly (one seed; the trainer stacks seeds on a leading axis)."""

    params: dict  # actor, critic, psi, codes (one learned code per demonstration, pre-tanh), disc
    ppo_opt: Any
    aux_opt: Any
    disc_opt: Any
    norm: dict  # observation normaliser (mean, std) fitted on the training demonstrations
    ret_rms: dict  # running mean / var / count of discounted returns (reward normalisation)
    ret_acc: jax.Array  # (num_envs,) running discounted return
    env_state: Any  # batched brax State
    z: jax.Array  # (num_envs, code_dim)
    hist: jax.Array  # (num_envs, K + 1, obs_dim) raw observations s_{t-K..t}
    prev_ah: jax.Array  # (num_envs, human_action_size) a^H_{t-1}
    code_counter: jax.Array  # int32: next grid cell in cycle order
    rng: jax.Array
    update: jax.Array  # int32: updates done

    @property
    def carry(self) -> Carry:
        return Carry(self.env_state, self.z, self.hist, self.prev_ah, self.code_counter)

    def with_carry(self, c: Carry) -> "TrainState":
        return self.replace(env_state=c.env_state, z=c.z, hist=c.hist, prev_ah=c.prev_ah, code_counter=c.code_counter)


class Context(NamedTuple):
    """The parts of training: config, task, networks (modules and apply functions), optimizers, and ``hp``, the
    values of the config's ``HYPER`` fields that the update uses (the training program's arguments while it is
    traced, else the config's own numbers); the config's own decide which terms are on."""

    cfg: TrainConfig
    env: Any
    modules: dict  # flax modules: actor, critic, psi, disc
    nets: losses.Nets
    ppo_tx: optax.GradientTransformation
    aux_tx: optax.GradientTransformation
    disc_tx: optax.GradientTransformation
    hp: dict


def make_context(cfg: TrainConfig, env, hp: dict | None = None) -> Context:
    """``hp``: the ``HYPER`` values to use (e.g. traced arguments), else ``cfg``'s."""
    hp = hyper_values(cfg) if hp is None else hp
    modules = make_networks(cfg, env)
    nets = losses.Nets(*(modules[k].apply for k in ("actor", "critic", "psi", "disc")), env.human_action_size,
                       disc_kind(cfg, env), actions.spec_of(env))
    return Context(cfg, env, modules, nets, *make_optimizers(cfg, hp), hp)


def make_optimizers(cfg: TrainConfig, hp: dict | None = None):
    hp = hyper_values(cfg) if hp is None else hp
    total = cfg.num_updates * cfg.ppo_epochs * cfg.num_minibatches
    sched = optax.linear_schedule(hp["lr"], 0.0, total)
    ppo = optax.chain(optax.clip_by_global_norm(hp["max_grad_norm"]), optax.adam(sched, eps=1e-5))
    inner = cfg.num_updates * (cfg.ppo_epochs * cfg.num_minibatches if cfg.bc_only else cfg.inner_updates)
    decay = (lambda lr: optax.linear_schedule(lr, 0.0, inner)) if cfg.aux_lr_decay else (lambda lr: lr)
    aux = optax.chain(optax.clip_by_global_norm(hp["max_grad_norm"]), optax.adam(decay(hp["aux_lr"])))
    disc = optax.adam(decay(hp["disc_lr"]))
    return ppo, aux, disc


def expert_arrays(demos, history: int, capacity: int = 0) -> dict[str, np.ndarray]:
    """Flatten padded demonstrations into per-step arrays with psi histories (numpy, done once). ``count``: the
    number of steps; the arrays have ``max(count, capacity)`` rows, zeros after ``count`` (never sampled), so that a
    training set's programs can be compiled for shapes its config fixes before the set is made
    (``runs.expert_capacity``)."""
    obs, ah, ar, hist, prev, demo = [], [], [], [], [], []
    for i in range(demos.num):
        n = int(demos.length[i])
        o = demos.obs[i, :n]
        idx = np.clip(np.arange(n)[:, None] + np.arange(-history, 1)[None], 0, None)
        obs.append(o)
        ah.append(demos.actions_human[i, :n])
        ar.append(demos.actions_robot[i, :n])
        hist.append(o[idx])
        p = np.zeros_like(demos.actions_human[i, :n])
        p[1:] = demos.actions_human[i, : n - 1]
        prev.append(p)
        demo.append(np.full((n,), i, np.int32))
    cat = lambda xs: np.concatenate(xs, 0).astype(np.float32)  # noqa: E731
    out = {"obs": cat(obs), "ah": cat(ah), "ar": cat(ar), "hist": cat(hist), "prev_ah": cat(prev),
           "demo": np.concatenate(demo, 0)}
    count = len(out["demo"])
    pad = max(int(capacity) - count, 0)
    out = {k: np.concatenate([v, np.zeros((pad,) + v.shape[1:], v.dtype)]) if pad else v for k, v in out.items()}
    return {**out, "count": np.int32(count)}


def expert_steps(expert) -> Any:
    """How many rows of ``expert`` are demonstration steps (``count``; all of them in arrays without it)."""
    return expert["count"] if "count" in expert else expert["obs"].shape[0]


def sample_expert(norm, expert, key, n):
    """A minibatch of ``n`` expert steps, observations and histories normalised."""
    i = jax.random.randint(key, (n,), 0, expert_steps(expert))
    return {"obs": policy_input(norm, expert["hist"][i]), "ah": expert["ah"][i], "ar": expert["ar"][i],
            "hist": history_input(norm, expert["hist"][i]), "prev_ah": expert["prev_ah"][i],
            "demo": expert["demo"][i]}


def all_finite(tree) -> jax.Array:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]))


# ------------------------------------------------------------------------------------------------ init
def init_state(ctx: Context, norm: dict, code_init, rng) -> TrainState:
    """Fresh networks, optimizers and episodes for one seed."""
    cfg, env, mods = ctx.cfg, ctx.env, ctx.modules
    k_a, k_c, k_p, k_d, k_env, k_z, rng = jax.random.split(rng, 7)
    d, z0 = env.observation_size, jnp.zeros((1, cfg.code_dim))
    d_in = 2 * d if cfg.motion else d  # networks.policy_input
    params = {
        "actor": mods["actor"].init(k_a, jnp.zeros((1, d_in)), z0),
        "critic": mods["critic"].init(k_c, jnp.zeros((1, d_in)), z0),
        "psi": mods["psi"].init(k_p, jnp.zeros((1, (cfg.history + 1) * d + env.human_action_size))),
        "codes": code_init + 0.1 * jax.random.normal(k_z, code_init.shape),
        "disc": mods["disc"].init(k_d, jnp.zeros((1, d_in + env.action_size))),
    }
    c = initial_carry(cfg, env, k_env, k_z)
    params = with_ema_start(cfg, params)
    state = TrainState(
        params=params,
        ppo_opt=ctx.ppo_tx.init({"actor": params["actor"], "critic": params["critic"]}),
        aux_opt=ctx.aux_tx.init({"actor": params["actor"], "psi": params["psi"], "codes": params["codes"]}),
        disc_opt=ctx.disc_tx.init(params["disc"]),
        norm=norm,
        ret_rms={"mean": jnp.zeros(()), "var": jnp.ones(()), "count": jnp.asarray(1e-4, jnp.float32)},
        ret_acc=jnp.zeros((cfg.num_envs,)),
        env_state=None, z=None, hist=None, prev_ah=None, code_counter=None,
        rng=rng, update=jnp.zeros((), jnp.int32))
    return state.with_carry(c)


# ------------------------------------------------------------------------------------------------ policy average
EMA_PARAMS = ("actor", "psi")  # what the delivered policy averages (config.policy_ema)


def with_ema_start(cfg: TrainConfig, params: dict) -> dict:
    """``params`` with the moving average (``params["ema"]``) restarted at the current actor and psi."""
    if not cfg.policy_ema:
        return params
    return {**params, "ema": {k: params[k] for k in EMA_PARAMS}}


def ema_update(cfg: TrainConfig, params: dict) -> dict:
    """One step of the moving average towards the current actor and psi (no-op when ``policy_ema`` is 0)."""
    if not cfg.policy_ema:
        return params
    d = cfg.policy_ema
    ema = jax.tree.map(lambda e, p: d * e + (1.0 - d) * p, params["ema"], {k: params[k] for k in EMA_PARAMS})
    return {**params, "ema": ema}


def policy_params(params: dict) -> dict:
    """The parameters the delivered policy acts with: the moving average's actor and psi where the run keeps one
    (``policy_ema``), else the trained ones."""
    return {**params, **params["ema"]} if "ema" in params else params


# ------------------------------------------------------------------------------------------------ BC
def bc_pretrain(ctx: Context, state: TrainState, expert):
    """``bc_steps`` of behaviour cloning before training (``losses.bc_objective``): both agents on each
    demonstration's learned code; psi learns to recognise the codes only in presets with L_a."""
    cfg = ctx.cfg
    tx = optax.adam(cfg.bc_lr)
    rng, key, key_std = jax.random.split(state.rng, 3)
    names = ("actor", "psi", "codes") if "bc_psi" in losses.objective_terms(cfg) else ("actor", "codes")
    sub = {k: state.params[k] for k in names}

    def body(carry, key):
        sub, opt = carry
        b = sample_expert(state.norm, expert, key, cfg.inner_batch)
        loss, g = jax.value_and_grad(lambda p: losses.bc_objective(cfg, ctx.nets, {**state.params, **p}, b))(sub)
        upd, opt = tx.update(g, opt, sub)
        return (optax.apply_updates(sub, upd), opt), loss

    (sub, _), bc_losses = jax.lax.scan(body, (sub, tx.init(sub)), jax.random.split(key, cfg.bc_steps))
    params = {**state.params, **sub}
    if cfg.bc_std:
        params = with_bc_std(ctx, params, sample_expert(state.norm, expert, key_std, BC_STD_SAMPLE))
    return state.replace(params=with_ema_start(cfg, params), rng=rng), bc_losses[-1]


BC_STD_SAMPLE = 8192  # expert steps the residual's RMS is measured on
BC_STD_MIN = 0.01


def with_bc_std(ctx: Context, params: dict, batch: dict) -> dict:
    """``params`` with the co-policy's log std set per action dimension to the RMS of the cloned mean's residual on
    the expert ``batch`` (the maximum-likelihood std of the cloned Gaussian; ``bc_std``), clipped to
    [``BC_STD_MIN``, exp(``init_log_std``)]."""
    res = losses.bc_residual(ctx.cfg, ctx.nets, params, batch)
    rms = jnp.sqrt(jnp.mean(res ** 2, 0))
    log_std = jnp.clip(jnp.log(jnp.maximum(rms, 1e-12)), jnp.log(BC_STD_MIN), ctx.cfg.init_log_std)
    actor = params["actor"]
    if not ctx.nets.spec.continuous:  # a discrete agent has no std: its entries stay as they were (unread)
        keep = jnp.concatenate([jnp.full((n,), d) for _, n, d in ctx.nets.spec.segments])
        log_std = jnp.where(keep, actor["params"]["log_std"], log_std)
    return {**params, "actor": {**actor, "params": {**actor["params"], "log_std": log_std}}}


def bc_step(ctx: Context, state: TrainState, expert):
    """BC-single's update: supervised steps of the robot on the demonstrations; no rollout, no discriminator."""
    cfg = ctx.cfg
    rng, key = jax.random.split(state.rng)

    def body(carry, key):
        sub, opt = carry
        b = sample_expert(state.norm, expert, shards.key(cfg, key), shards.local_batch(cfg, cfg.inner_batch))
        loss, g = jax.value_and_grad(lambda p: losses.bc_objective(cfg, ctx.nets, {**state.params, **p}, b))(sub)
        upd, opt = ctx.aux_tx.update(shards.mean(cfg, g), opt, sub)
        return (optax.apply_updates(sub, upd), opt), loss

    sub = {"actor": state.params["actor"], "psi": state.params["psi"], "codes": state.params["codes"]}
    keys = jax.random.split(key, cfg.ppo_epochs * cfg.num_minibatches)
    (sub, opt), bc = jax.lax.scan(body, (sub, state.aux_opt), keys)
    params = ema_update(cfg, {**state.params, **sub})
    state = state.replace(params=params, aux_opt=opt, rng=rng, update=state.update + 1)
    return state, {"bc_loss": shards.mean(cfg, bc.mean()), "nonfinite": (~all_finite(state.params)).astype(jnp.float32)}


# ------------------------------------------------------------------------------------------------ inner updates
AUX_TERMS = frozenset({"L_z", "L_a", "L_r", "diversity"})


def aux_step(ctx: Context, params, aux_opt, gen_b, exp_b):
    """One step of psi, the co-policy and the per-demonstration codes on ``losses.aux_objective``."""
    if not losses.objective_terms(ctx.cfg) & AUX_TERMS:
        return params, aux_opt, {}
    sub = {"actor": params["actor"], "psi": params["psi"], "codes": params["codes"]}
    (_, m), g = jax.value_and_grad(
        lambda s: losses.aux_objective(ctx.cfg, ctx.nets, {**params, **s}, gen_b, exp_b, ctx.hp), has_aux=True)(sub)
    upd, aux_opt = ctx.aux_tx.update(shards.mean(ctx.cfg, g), aux_opt, sub)
    return {**params, **optax.apply_updates(sub, upd)}, aux_opt, m


def disc_step(ctx: Context, params, disc_opt, gen_b, exp_b, key):
    """One discriminator step: expert (s, a_H, a_R) against generated (s, executed a); with
    ``disc_instance_noise`` the expert actions get the co-policy's action noise (of ``params``) and clip."""
    cfg, nets = ctx.cfg, ctx.nets
    a_e = jnp.concatenate([exp_b["ah"], exp_b["ar"]], -1)
    if cfg.disc_instance_noise:
        a_e = losses.noisy_expert_actions(a_e, params["actor"]["params"]["log_std"], jax.random.fold_in(key, 1),
                                          nets.spec)
    x_e = jnp.concatenate([exp_b["obs"], a_e], -1)
    x_p = jnp.concatenate([gen_b["obs"], gen_b["act"]], -1)
    (_, m), g = jax.value_and_grad(
        lambda p: losses.discriminator_loss(nets.disc, p, x_e, x_p, nets.disc_kind, ctx.hp["gp_coef"], key),
        has_aux=True
    )(params["disc"])
    upd, disc_opt = ctx.disc_tx.update(shards.mean(cfg, g), disc_opt, params["disc"])
    return optax.apply_updates(params["disc"], upd), disc_opt, m


def inner_updates(ctx: Context, state: TrainState, flat, expert, key):
    """``inner_updates`` x (aux_step, disc_step) on fresh minibatches of generated (``flat``) and expert data."""
    cfg, norm = ctx.cfg, state.norm
    nb = shards.local_batch(cfg, cfg.inner_batch)  # this env shard's share of each minibatch

    def body(carry, key):
        params, aux_opt, disc_opt = carry
        k_g, k_e, k_gp = jax.random.split(key, 3)
        gen = jax.tree.map(lambda x: x[jax.random.randint(k_g, (nb,), 0, flat["obs"].shape[0])], flat)
        exp_b = sample_expert(norm, expert, k_e, nb)
        gen_b = {"obs": policy_input(norm, gen["hist"]), "act": gen["act"], "hist": history_input(norm, gen["hist"]),
                 "prev_obs": policy_input(norm, gen["hist"], 1), "first": gen["first"], "z": gen["z"],
                 "prev_ah": gen["prev_ah"]}
        new, aux_opt, aux_m = aux_step(ctx, params, aux_opt, gen_b, exp_b)
        if ctx.cfg.task_rl:  # no discriminator
            return (new, aux_opt, disc_opt), aux_m
        # the discriminator's instance noise is that of the co-policy that generated `gen`
        disc, disc_opt, dm = disc_step(ctx, params, disc_opt, gen_b, exp_b, k_gp)
        return ({**new, "disc": disc}, aux_opt, disc_opt), {**dm, **aux_m}

    carry = (state.params, state.aux_opt, state.disc_opt)
    (params, aux_opt, disc_opt), m = jax.lax.scan(body, carry, jax.random.split(key, cfg.inner_updates))
    return state.replace(params=params, aux_opt=aux_opt, disc_opt=disc_opt), jax.tree.map(jnp.mean, m)


# ------------------------------------------------------------------------------------------------ rewards, PPO
def normalize_returns(cfg: TrainConfig, gamma, ret_rms, ret_acc, r, done):
    """Rewards divided by the running std of the discounted return (discount ``gamma``); its accumulator restarts at
    episode ends."""

    def body(ret, x):
        r_t, d_t = x
        ret = ret * gamma + r_t
        return ret * (1 - d_t), ret

    ret_acc, rets = jax.lax.scan(body, ret_acc, (r, done), unroll=cfg.scan_unroll)
    (b_mean, b_var), b_count = shards.moments(cfg, rets), rets.size * shards.count(cfg)
    delta = b_mean - ret_rms["mean"]
    tot = ret_rms["count"] + b_count
    mean = ret_rms["mean"] + delta * b_count / tot
    m2 = ret_rms["var"] * ret_rms["count"] + b_var * b_count + delta**2 * ret_rms["count"] * b_count / tot
    ret_rms = {"mean": mean, "var": m2 / tot, "count": tot}
    return ret_rms, ret_acc, r / jnp.sqrt(ret_rms["var"] + 1e-8)


def rewards(ctx: Context, state: TrainState, traj):
    """The discriminator's reward (+ DIAYN's diversity reward, + ``task_reward`` x the task's); the PPO presets' the
    task's alone; returns ``(state, normalised, raw)``."""
    cfg, nets = ctx.cfg, ctx.nets
    if cfg.task_rl:
        r = traj["task_reward"]
    else:
        x = jnp.concatenate([policy_input(state.norm, traj["hist"]), traj["act"]], -1)
        r = losses.discriminator_reward(nets.disc(state.params["disc"], x), nets.disc_kind)
        if cfg.task_reward > 0:
            r = r + ctx.hp["task_reward"] * traj["task_reward"]
    if "diversity" in losses.objective_terms(cfg):
        h = jnp.concatenate([history_input(state.norm, traj["hist"]), traj["prev_ah"]], -1)
        r = r + ctx.hp["diversity_coef"] * losses.diversity_reward(nets.psi, state.params, h, traj["z"])
    if not cfg.reward_norm:
        return state, r, r
    rms, acc, r_norm = normalize_returns(cfg, ctx.hp["gamma"], state.ret_rms, state.ret_acc, r, traj["done"])
    return state.replace(ret_rms=rms, ret_acc=acc), r_norm, r


def mask_frozen_human(human_size: int, g_actor):
    """BC-GAIL: no gradient reaches the human tower or the human action's log std."""

    def f(path, x):
        keys = [getattr(k, "key", None) for k in path]
        if "human" in keys:
            return jnp.zeros_like(x)
        if "log_std" in keys:
            return x * (jnp.arange(x.shape[-1]) >= human_size)
        return x

    return jax.tree_util.tree_map_with_path(f, g_actor)


def ppo_grad(ctx: Context, params, batch, exp_b, moves):
    """Gradient of ``losses.ppo_objective`` w.r.t. actor and critic, as the PPO step applies it: none reaches
    the actor while it does not ``moves`` (policy_cooldown), nor the human's actions in presets without
    ``gail_human`` (BC-GAIL's frozen human). Returns ``(grads, metrics)``."""
    sub = {"actor": params["actor"], "critic": params["critic"]}
    (_, m), g = jax.value_and_grad(
        lambda p: losses.ppo_objective(ctx.cfg, ctx.nets, {**params, **p}, batch, exp_b, ctx.hp), has_aux=True)(sub)
    g_actor = jax.tree.map(lambda x: x * moves, g["actor"])
    if ctx.cfg.freeze_human:
        g_actor = mask_frozen_human(ctx.nets.human_size, g_actor)
    return {**g, "actor": g_actor}, m


def ppo_update(ctx: Context, state: TrainState, traj, adv, ret, key, expert):
    """``ppo_epochs`` of ``losses.ppo_objective`` over shuffled minibatches of the rollout (actor, critic)."""
    cfg, nets = ctx.cfg, ctx.nets
    n, on = shards.local_envs(cfg) * cfg.unroll_length, losses.objective_terms(cfg)
    obs_n = policy_input(state.norm, traj["hist"]).reshape(n, -1)
    z, action = traj["z"].reshape(n, -1), traj["action"].reshape(n, -1)
    # log-probs under the co-policy as the inner (L_z / L_a) updates left it: the PPO ratio starts at 1
    mean, log_std = nets.actor(state.params["actor"], obs_n, z)
    logp_old = jax.lax.stop_gradient(actions.log_prob(nets.spec, mean, log_std, action))
    flat = {"obs": obs_n, "z": z, "action": action, "logp": logp_old, "adv": adv.reshape(n), "ret": ret.reshape(n)}
    if losses.lz_in_ppo(cfg):  # L_z's co-policy part, on the rollout's own steps
        hist = traj["hist"].reshape((n,) + traj["hist"].shape[2:])
        flat.update(hist=history_input(state.norm, hist), prev_obs=policy_input(state.norm, hist, 1),
                    first=traj["first"].reshape(n))
    mb = n // cfg.num_minibatches
    # policy_cooldown: the last updates train the critic only
    moves = state.update < cfg.num_updates - cfg.policy_cooldown

    def minibatch(carry, x):
        idx, k_bc = x[:2]
        sub, opt = carry
        batch = jax.tree.map(lambda x: x[idx], flat)
        if shards.count(cfg) > 1:  # the advantages normalised over every shard's minibatch together
            a_mean, a_var = x[2:]
            batch = {**batch, "adv": (batch["adv"] - a_mean) / (jnp.sqrt(a_var) + 1e-8)}
        nb = shards.local_batch(cfg, cfg.inner_batch)
        exp_b = sample_expert(state.norm, expert, k_bc, nb) if "ppo_bc" in on else None
        g, m = ppo_grad(ctx, {**state.params, **sub}, batch, exp_b, moves)
        upd, opt = ctx.ppo_tx.update(shards.mean(cfg, g), opt, sub)
        return (optax.apply_updates(sub, upd), opt), m

    def epoch(carry, key):
        perm = jax.random.permutation(key, n)[: mb * cfg.num_minibatches].reshape(cfg.num_minibatches, mb)
        k_bc = jax.random.split(jax.random.fold_in(key, 1), cfg.num_minibatches)  # leaves perm's stream as it was
        if shards.count(cfg) == 1:
            return jax.lax.scan(minibatch, carry, (perm, k_bc))
        # every minibatch's advantage moments over all shards, gathered once per epoch (not twice per minibatch:
        # each gather waits for the other devices, and fetchq's 16 minibatches made 32 such waits an update)
        adv = flat["adv"][perm]
        a_mean = shards.mean(cfg, adv.mean(1))
        a_var = shards.mean(cfg, jnp.mean((adv - a_mean[:, None]) ** 2, 1))
        return jax.lax.scan(minibatch, carry, (perm, k_bc, a_mean, a_var))

    sub = {"actor": state.params["actor"], "critic": state.params["critic"]}
    (sub, opt), m = jax.lax.scan(epoch, (sub, state.ppo_opt), jax.random.split(key, cfg.ppo_epochs))
    return state.replace(params={**state.params, **sub}, ppo_opt=opt), jax.tree.map(jnp.mean, m)


# ------------------------------------------------------------------------------------------------ one update
def train_step(ctx: Context, state: TrainState, expert):
    """One Co-GAIL update: rollout -> aux / discriminator -> rewards, GAE -> PPO."""
    cfg = ctx.cfg
    if cfg.bc_only:
        return bc_step(ctx, state, expert)
    rng, k_roll, k_inner, k_ppo = jax.random.split(state.rng, 4)
    k_roll, k_inner, k_ppo = (shards.key(cfg, k) for k in (k_roll, k_inner, k_ppo))  # each env shard its own
    carry, traj, last_value = rollout(cfg, ctx.env, ctx.nets.actor, ctx.nets.critic, state.params, state.norm,
                                      state.carry, k_roll)
    state = state.with_carry(carry).replace(rng=rng)
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), traj)
    state, inner_m = inner_updates(ctx, state, flat, expert, k_inner)
    state, r_norm, r_raw = rewards(ctx, state, traj)
    adv, ret = losses.gae(r_norm, traj["value"], traj["done"], traj["truncation"], traj["final_value"], last_value,
                          ctx.hp["gamma"], ctx.hp["gae_lambda"], cfg.scan_unroll)
    state, ppo_m = ppo_update(ctx, state, traj, adv, ret, k_ppo, expert)
    state = state.replace(params=ema_update(cfg, state.params))
    episodes = shards.total(cfg, traj["done"].sum())
    metrics = {**shards.mean(cfg, {**inner_m, **ppo_m, "reward": r_raw.mean()}), "episodes": episodes,
               "episode_success": shards.total(cfg, traj["success"].sum()) / jnp.maximum(episodes, 1.0),
               # episodes the time limit ended (bootstrapped); MJX steps that diverged (episode ended)
               **shards.total(cfg, {"timeouts": traj["truncation"].sum(), "env_failures": traj["env_failed"].sum()}),
               "nonfinite": (~all_finite(state.params)).astype(jnp.float32)}
    return state.replace(update=state.update + 1), metrics


def make_train_fns(cfg: TrainConfig, env, norm_stats: dict[str, np.ndarray]):
    """Build ``init(seeds, expert) -> state``, the jitted ``chunk(state, expert) -> (state, metrics)``
    (a ``parallel.SeedChunk``) and the flax modules."""
    ctx = make_context(cfg.validate(), env)
    norm = {k: jnp.asarray(norm_stats[k], jnp.float32) for k in ("mean", "std", "motion_std") if k in norm_stats}
    n_demos = int(norm_stats["num_demos"])
    code_init = (jnp.arctanh(jnp.asarray(demo_code_init(norm_stats["features"], cfg.code_dim), jnp.float32))
                 if "features" in norm_stats else jnp.zeros((n_demos, cfg.code_dim)))
    # made once: every init() call of these functions reuses the compiled programs, and later runs of the same
    # config and code load them instead of tracing them again (programs.stored); the normaliser and the initial codes
    # are the initial state's arguments, so its program does not depend on the data (``compile_ahead``)
    init_jit = stored(jax.vmap(partial(init_state, ctx), in_axes=(None, None, 0)), "init", program_key(cfg))
    bc_jit = stored(jax.vmap(partial(bc_pretrain, ctx), in_axes=(0, None)), "bc", program_key(cfg))

    def keys(seeds):
        return jnp.stack([jax.random.PRNGKey(int(s)) for s in seeds])

    def init(seeds, expert):
        state = init_jit(norm, code_init, keys(seeds))
        if cfg.bc_steps:
            state, _ = bc_jit(state, expert)
        return state

    def compile_ahead(seeds, expert):
        """Compile the initial state's and BC's programs as ``init(seeds, expert)`` runs them on this process's
        first device (``expert``: arrays or ``jax.ShapeDtypeStruct``), reading no data; returns the state's
        shapes, placed as ``init`` places it (for the training chunk's ``lower``)."""
        k = jax.eval_shape(lambda: keys(seeds))
        init_jit.lower(norm, code_init, k).compile()
        here = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        placed = lambda t: jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=here), t)  # noqa: E731
        state = placed(init_jit.eval_shape(norm, code_init, k))
        if cfg.bc_steps:
            bc_jit.lower(state, expert).compile()
            state = placed(bc_jit.eval_shape(state, expert)[0])
        return state

    def traced(hyper):  # the context with the HYPER values the program is given (parallel.SeedChunk's extra)
        return make_context(ctx.cfg, env, {name: hyper[i] for i, name in enumerate(HYPER)})

    def chunk(state, expert, hyper):  # with env shards: one per device, shards.AXIS bound by parallel.SeedChunk's shard_map
        step = jax.vmap(partial(train_step, traced(hyper)), in_axes=(0, None))
        return jax.lax.scan(lambda s, _: step(s, expert), state, None, length=cfg.updates_per_call)

    def chunk_here(state, expert, hyper):  # every env shard on this device, side by side: shards.AXIS bound by vmap
        c, flags, e = traced(hyper), env_leaves(state), shards.count(cfg)
        split = jax.tree.map(lambda f, x: (x.reshape(x.shape[:1] + (e, x.shape[1] // e) + x.shape[2:]) if f else
                                           jnp.broadcast_to(x[:, None], x.shape[:1] + (e,) + x.shape[1:])), flags, state)
        step = jax.vmap(jax.vmap(partial(train_step, c), in_axes=(0, None), axis_name=shards.AXIS), in_axes=(0, None))
        split, m = jax.lax.scan(lambda s, _: step(s, expert), split, None, length=cfg.updates_per_call)
        state = jax.tree.map(lambda f, x: x.reshape(x.shape[:1] + (-1,) + x.shape[3:]) if f else x[:, 0], flags, split)
        return state, jax.tree.map(lambda x: x[:, :, 0], m)  # (updates, seeds): the same on every shard

    def abstract(seeds, expert):  # init's output shapes (from kept programs: no tracing where they are found)
        state = init_jit.eval_shape(norm, code_init, jax.eval_shape(lambda: keys(seeds)))
        return bc_jit.eval_shape(state, expert)[0] if cfg.bc_steps else state

    init.abstract, init.compile_ahead = abstract, compile_ahead
    one = chunk if shards.count(cfg) == 1 else chunk_here
    # the update's hyperparameters are the program's argument (``extra``), not constants: a run that changes only
    # their values runs the training program kept for another (``config.chunk_key``)
    hyper = np.array([hyper_values(cfg)[name] for name in HYPER], np.float32)
    return init, SeedChunk(one, cfg.multi_device_mode, key=chunk_key(cfg), env_fn=chunk, env_leaves=env_leaves,
                           extra=hyper), ctx.modules


ENV_FIELDS = ("ret_acc", "env_state", "z", "hist", "prev_ah")  # TrainState's fields with an env axis


def env_leaves(state: TrainState):
    """``state``'s tree with True at every leaf that has an env axis (after the seed axis), False elsewhere."""
    flags = jax.tree.map(lambda _: False, state)
    return flags.replace(**{f: jax.tree.map(lambda _: True, getattr(state, f)) for f in ENV_FIELDS})


# ------------------------------------------------------------------------------------------------ normaliser, codes
MOTION_STD_FLOOR = 1e-3  # floor of the per-step change's std (a thousandth of the observation's units)


def fit_normalizer(expert: dict[str, np.ndarray], std_floor: float = 1e-2, unread=(),
                   motion: bool = False) -> dict[str, np.ndarray]:
    """Observation mean/std of the training demonstrations (std floored at ``std_floor`` so near-constant
    features, e.g. an MJX gripper's tilt, do not blow up when a policy drifts from them), the number of
    demonstrations (BC pre-training learns one code per demonstration) and each demonstration's trajectory
    features (the per-demonstration codes start from their principal components). The observation indices
    ``unread`` normalise to 0 (mean 0, std infinite): no network reads them. ``motion``: also ``motion_std``, the std
    of the per-step change of each feature within the demonstrations (0 at their first steps, as a history starts),
    floored at ``MOTION_STD_FLOOR`` (``networks.policy_input``)."""
    n = int(expert_steps(expert))
    expert = {k: np.asarray(expert[k])[:n] for k in ("obs", "demo")}
    mean, std = expert["obs"].mean(0), np.maximum(expert["obs"].std(0), std_floor)
    unread = list(unread)
    if unread:
        mean, std = mean.copy(), std.copy()
        mean[unread], std[unread] = 0.0, np.inf
    out = {"mean": mean, "std": std, "num_demos": int(expert["demo"].max()) + 1,
           "features": demo_features((expert["obs"] - mean) / std, expert["demo"])}
    if motion:
        o, d = expert["obs"], expert["demo"]
        change = np.where((d[1:] == d[:-1])[:, None], o[1:] - o[:-1], 0.0)
        change = np.concatenate([np.zeros_like(o[:1]), change], 0)
        m_std = np.maximum(change.std(0), MOTION_STD_FLOOR).astype(np.float32)
        if unread:
            m_std[unread] = np.inf
        out["motion_std"] = m_std
    return out


def unread_dims(cfg: TrainConfig, env) -> tuple[int, ...]:
    """The observation indices ``cfg``'s networks do not read (``obs_frame``): the env's object-centric features
    ("world"), its absolute orientations ("object") or none ("both")."""
    key = {"world": "object_frame_dims", "object": "orientation_dims"}.get(cfg.obs_frame)
    return tuple(getattr(env, key, ())) if key else ()


def demo_features(obs_n: np.ndarray, demo: np.ndarray, points: int = 16) -> np.ndarray:
    """One vector per demonstration: its normalised observations at ``points`` evenly spaced fractions of
    its length (so demonstrations of different lengths compare phase by phase)."""
    out = []
    for i in range(int(demo.max()) + 1):
        o = obs_n[demo == i]
        idx = np.round(np.linspace(0, len(o) - 1, points)).astype(int)
        out.append(o[idx].reshape(-1))
    return np.stack(out).astype(np.float32)


def demo_code_init(features: np.ndarray, code_dim: int, edge: float = 0.9) -> np.ndarray:
    """Initial per-demonstration codes (after tanh) from the demonstrations themselves: the first ``code_dim``
    principal components of their trajectory features, each rank-spread evenly over (-edge, edge). Demos that
    behave alike start close, so each strategy starts as one region of the code square whose area follows
    its share of the demos, instead of being scattered over it by a random init."""
    f = np.asarray(features, np.float64)
    n = f.shape[0]
    if n < 2:
        return np.zeros((n, code_dim), np.float32)
    f = f - f.mean(0)
    _, _, vt = np.linalg.svd(f, full_matrices=False)
    pcs = f @ vt[:code_dim].T
    if pcs.shape[1] < code_dim:
        pcs = np.pad(pcs, ((0, 0), (0, code_dim - pcs.shape[1])))
    ranks = np.argsort(np.argsort(pcs, 0, kind="stable"), 0, kind="stable")
    return (edge * (2 * (ranks + 0.5) / n - 1)).astype(np.float32)


__all__ = ["TrainState", "Context", "ENV_FIELDS", "env_leaves", "make_context", "make_train_fns", "train_step", "aux_step", "disc_step", "ppo_grad",
           "ppo_update", "bc_pretrain",
           "expert_arrays", "expert_steps", "fit_normalizer", "unread_dims", "demo_code_init", "demo_features", "code_grid"]
