"""Co-GAIL as one compiled function.

``make_train_fns(cfg, env, expert)`` returns ``init(seeds) -> TrainState`` and
``train_chunk(state, expert) -> (state, metrics)``: ``cfg.updates_per_call`` Co-GAIL updates, each of
which is

1. a vmapped rollout of ``num_envs x unroll_length`` steps with per-episode strategy codes z (a 5 x 5 grid
   visited in cycle order plus U[-noise, noise], resampled inside the step whenever an episode ends);
2. ``inner_updates`` discriminator updates (BCE or LSGAN + gradient penalty) and psi / co-policy updates on
   lambda_1 L_z (generated data) + lambda_2 L_a (expert data);
3. discriminator rewards (return-normalised), GAE and ``ppo_epochs`` of clipped PPO over minibatches.

Everything is vmapped over a leading seed axis and scanned over updates, so the host only logs and saves.
"""
from __future__ import annotations

from typing import Any, Callable

import flax.struct as struct
import jax
import jax.numpy as jnp
import numpy as np
import optax

from . import losses
from .config import TrainConfig
from .networks import Actor, Critic, Discriminator, Psi, gaussian_log_prob


class TrainState(struct.PyTreeNode):
    """Everything needed to resume exactly (one seed; the trainer stacks seeds on a leading axis)."""

    params: dict  # actor, critic, psi, disc
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


def code_grid(n: int) -> jnp.ndarray:
    """n x n grid of cell centres over (-1, 1)^2, row-major (the cycle order)."""
    c = jnp.linspace(-1 + 1 / n, 1 - 1 / n, n)
    return jnp.stack(jnp.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)


def expert_arrays(demos, history: int, states: bool = False) -> dict[str, np.ndarray]:
    """Flatten padded demonstrations into per-step arrays with psi histories (numpy, done once). With
    ``states``, also the demonstrations' simulator snapshots (``snap``) and the flat index of the step each
    was taken before (``snap_idx``), for ``TrainConfig.demo_reset``."""
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
    cat = lambda xs: np.concatenate(xs, 0).astype(np.float32)
    out = {"obs": cat(obs), "ah": cat(ah), "ar": cat(ar), "hist": cat(hist), "prev_ah": cat(prev),
           "demo": np.concatenate(demo, 0)}
    if states:
        d, t = demos.state_steps()
        start = np.concatenate([[0], np.cumsum(demos.length[:-1])]).astype(np.int64)
        out["snap"] = demos.states[d, t // demos.state_stride].astype(np.float32)
        out["snap_idx"] = (start[d] + t).astype(np.int32)
    return out


def make_networks(cfg: TrainConfig, env, disc_kind: str):
    return {
        "actor": Actor(env.action_size, cfg.init_log_std, env.human_action_size if cfg.freeze_human else 0),
        "critic": Critic(),
        "psi": Psi(cfg.code_dim),
        "disc": Discriminator(squash=disc_kind == "lsgan"),
    }


def make_optimizers(cfg: TrainConfig):
    total = cfg.num_updates * cfg.ppo_epochs * cfg.num_minibatches
    sched = optax.linear_schedule(cfg.lr, 0.0, total)
    ppo = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(sched, eps=1e-5))
    aux = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(cfg.aux_lr))
    disc = optax.adam(cfg.disc_lr)
    return ppo, aux, disc


def make_train_fns(cfg: TrainConfig, env, norm_stats: dict[str, np.ndarray]):
    """Build ``init(seeds) -> state`` and the jitted ``train_chunk(state, expert) -> (state, metrics)``."""
    cfg.validate()
    disc_kind = env.discriminator_loss if cfg.disc_loss == "auto" else cfg.disc_loss
    nets = make_networks(cfg, env, disc_kind)
    actor, critic, psi, disc = (nets[k].apply for k in ("actor", "critic", "psi", "disc"))
    ppo_tx, aux_tx, disc_tx = make_optimizers(cfg)
    N, T, K, Ah = cfg.num_envs, cfg.unroll_length, cfg.history, env.human_action_size
    D = env.observation_size
    grid = code_grid(cfg.code_grid)
    G = grid.shape[0]
    norm_mean = jnp.asarray(norm_stats["mean"], jnp.float32)
    norm_std = jnp.asarray(norm_stats["std"], jnp.float32)
    n_demos = int(norm_stats["num_demos"])
    code_init = (jnp.arctanh(jnp.asarray(demo_code_init(norm_stats["features"], cfg.code_dim), jnp.float32))
                 if cfg.code_init == "pca" and "features" in norm_stats else jnp.zeros((n_demos, cfg.code_dim)))

    def normalize(norm, x):
        return (x - norm["mean"]) / norm["std"]

    def zero_code(_, h):  # presets without a strategy code: the co-policy always sees z = 0
        return jnp.zeros(h.shape[:-1] + (cfg.code_dim,))

    def mask_frozen_human(g_actor):
        """BC-GAIL: no gradient reaches the human tower or the human action's log std."""
        if not cfg.freeze_human:
            return g_actor

        def f(path, x):
            keys = [getattr(k, "key", None) for k in path]
            if "human" in keys:
                return jnp.zeros_like(x)
            if "log_std" in keys:
                return x * (jnp.arange(x.shape[-1]) >= Ah)
            return x

        return jax.tree_util.tree_map_with_path(f, g_actor)

    def hist_input(norm, hist):  # (..., K+1, D) raw -> (..., (K+1) D) normalised
        h = normalize(norm, hist)
        return h.reshape(*h.shape[:-2], (K + 1) * D)

    def new_codes(counter, done, key):
        """Codes for the envs whose episode (re)starts: next grid cells in cycle order plus noise."""
        idx = counter + jnp.cumsum(done.astype(jnp.int32)) - 1
        z = grid[idx % G] + jax.random.uniform(key, (N, cfg.code_dim), minval=-cfg.code_noise, maxval=cfg.code_noise)
        z = jnp.clip(z, -1.0, 1.0)
        z = z if cfg.use_code else jnp.zeros_like(z)
        return z, counter + jnp.sum(done.astype(jnp.int32))

    # ------------------------------------------------------------------ init
    def init_one(rng):
        k_a, k_c, k_p, k_d, k_env, k_z, rng = jax.random.split(rng, 7)
        obs0 = jnp.zeros((1, D))
        z0 = jnp.zeros((1, cfg.code_dim))
        params = {
            "actor": nets["actor"].init(k_a, obs0, z0),
            "critic": nets["critic"].init(k_c, obs0, z0),
            "psi": nets["psi"].init(k_p, jnp.zeros((1, (K + 1) * D + Ah))),
            # one learned code per demonstration (pre-tanh): BC pre-training and, with la_codes="demo", L_a
            "codes": code_init + 0.1 * jax.random.normal(k_z, (int(norm_stats["num_demos"]), cfg.code_dim)),
            "disc": nets["disc"].init(k_d, jnp.zeros((1, D + env.action_size))),
        }
        env_state = jax.vmap(env.reset)(jax.random.split(k_env, N))
        if cfg.demo_reset > 0:  # the rollout's fresh states carry where they started (the first ones: the task's)
            env_state = env_state.replace(info={**env_state.info, "from_demo": jnp.zeros((N,))})
        if cfg.stagger_episodes:  # first episodes end at spread-out times (legged_gym's random episode_length_buf)
            t0 = jax.random.randint(jax.random.fold_in(k_env, 1), (N,), 0, env.max_episode_steps)
            env_state = env_state.replace(info={**env_state.info, "t": t0.astype(env_state.info["t"].dtype)})
        z, counter = new_codes(jnp.zeros((), jnp.int32), jnp.ones((N,), bool), k_z)
        return TrainState(
            params=params,
            ppo_opt=ppo_tx.init({"actor": params["actor"], "critic": params["critic"]}),
            aux_opt=aux_tx.init({"actor": params["actor"], "psi": params["psi"], "codes": params["codes"]}),
            disc_opt=disc_tx.init(params["disc"]),
            norm={"mean": norm_mean, "std": norm_std},
            ret_rms={"mean": jnp.zeros(()), "var": jnp.ones(()), "count": jnp.asarray(1e-4, jnp.float32)},
            ret_acc=jnp.zeros((N,)),
            env_state=env_state,
            z=z,
            hist=jnp.repeat(env_state.obs[:, None], K + 1, axis=1),
            prev_ah=jnp.zeros((N, Ah)),
            code_counter=counter,
            rng=rng,
            update=jnp.zeros((), jnp.int32),
        )

    # ------------------------------------------------------------------ BC pre-training
    def bc_one(state: TrainState, expert):
        if cfg.bc_steps == 0:
            return state
        tx = optax.adam(cfg.bc_lr)
        rng, key, k_codes = jax.random.split(state.rng, 3)
        # one learned code per demonstration (tanh-squashed), so the co-policy learns to act on a code held
        # for the whole episode (as in the rollouts) and psi learns to recognise it from the history
        sub = {"actor": state.params["actor"], "psi": state.params["psi"],
               "codes": state.params["codes"]}

        def body(carry, key):
            sub, opt = carry
            b = sample_expert(state.norm, expert, key, cfg.inner_batch)
            loss, g = jax.value_and_grad(lambda p: losses.bc_loss(
                psi, actor, p, b, cfg.use_code, cfg.lambda_spread, cfg.bc_codes, cfg.bc_target))(sub)
            upd, opt = tx.update(g, opt, sub)
            return (optax.apply_updates(sub, upd), opt), loss

        (sub, _), bc_losses = jax.lax.scan(body, (sub, tx.init(sub)), jax.random.split(key, cfg.bc_steps))
        return state.replace(params={**state.params, **sub}, rng=rng), bc_losses[-1]

    def sample_expert(norm, expert, key, n):
        i = jax.random.randint(key, (n,), 0, expert["obs"].shape[0])
        b = {"obs": normalize(norm, expert["obs"][i]), "ah": expert["ah"][i], "ar": expert["ar"][i],
             "hist": hist_input(norm, expert["hist"][i]), "prev_ah": expert["prev_ah"][i], "demo": expert["demo"][i]}
        if cfg.bc_code_noise > 0:
            b["code_noise"] = cfg.bc_code_noise * jax.random.normal(jax.random.fold_in(key, 1), (n, cfg.code_dim))
        return b

    # ------------------------------------------------------------------ one Co-GAIL update
    def rollout(state: TrainState, key, expert):
        params, norm = state.params, state.norm
        # One batch of fresh episodes per rollout, not per step: an env whose episode ends takes its fresh state
        # (for MJX tasks a reset costs a forward pass, so resetting every env every step doubled the step's cost).
        # An env that ends twice within one unroll restarts from the same initial state (with a new code).
        key, k_pool = jax.random.split(key)
        fresh = jax.vmap(env.reset)(jax.random.split(k_pool, N))
        fresh_hist = jnp.repeat(fresh.obs[:, None], K + 1, 1)
        fresh_ah = jnp.zeros((N, Ah))
        from_demo = jnp.zeros((N,), bool)
        if cfg.demo_reset > 0:  # reference-state initialisation: some fresh episodes start inside a demonstration
            k_pick, k_use = jax.random.split(jax.random.fold_in(k_pool, 1))
            j = jax.random.randint(k_pick, (N,), 0, expert["snap"].shape[0])
            idx = expert["snap_idx"][j]
            mid = jax.vmap(env.restore)(expert["snap"][j])
            from_demo = jax.random.uniform(k_use, (N,)) < cfg.demo_reset
            fresh = jax.tree.map(lambda a, b: jnp.where(from_demo.reshape((N,) + (1,) * (a.ndim - 1)), a, b), mid, fresh)
            fresh_hist = jnp.where(from_demo[:, None, None],
                                   jnp.concatenate([expert["hist"][idx][:, :-1], mid.obs[:, None]], 1), fresh_hist)
            fresh_ah = jnp.where(from_demo[:, None], expert["prev_ah"][idx], fresh_ah)
            demo_z = jnp.tanh(params["codes"][expert["demo"][idx]]) if cfg.use_code else jnp.zeros((N, cfg.code_dim))
        fresh = fresh.replace(info={**fresh.info, "from_demo": from_demo.astype(jnp.float32)}) \
            if cfg.demo_reset > 0 else fresh

        def body(carry, key):
            env_state, z, hist, prev_ah, counter = carry
            k_act, k_code = jax.random.split(key)
            obs_n = normalize(norm, env_state.obs)
            mean, log_std = actor(params["actor"], obs_n, z)
            value = critic(params["critic"], obs_n, z)
            a = mean + jnp.exp(log_std) * jax.random.normal(k_act, mean.shape)
            logp = gaussian_log_prob(mean, log_std, a)
            act = jnp.clip(a, -1.0, 1.0)
            nxt = jax.vmap(env.step)(env_state, act)
            done = nxt.done > 0
            tr = {"obs": env_state.obs, "z": z, "hist": hist, "prev_ah": prev_ah, "first": env_state.info["t"] == 0,
                  "action": a, "act": act, "logp": logp, "value": value, "done": done.astype(jnp.float32),
                  "success": nxt.metrics["success"] * done,
                  "env_failed": nxt.info.get("failed", jnp.zeros(done.shape))}
            if cfg.demo_reset > 0:  # which episodes started from the task's initial distribution
                tr["fresh_done"] = done * (1 - env_state.info["from_demo"])
            z_new, counter = new_codes(counter, done, k_code)
            if cfg.demo_reset > 0:
                z_new = jnp.where(from_demo[:, None], demo_z, z_new)

            def pick(r, n):
                return jnp.where(done.reshape(done.shape + (1,) * (n.ndim - 1)), r, n)

            env_state = jax.tree.map(pick, fresh, nxt)
            hist = pick(fresh_hist, jnp.concatenate([hist[:, 1:], nxt.obs[:, None]], 1))
            prev_ah = pick(fresh_ah, act[:, :Ah])
            z = pick(z_new, z)
            return (env_state, z, hist, prev_ah, counter), tr

        carry = (state.env_state, state.z, state.hist, state.prev_ah, state.code_counter)
        (env_state, z, hist, prev_ah, counter), traj = jax.lax.scan(body, carry, jax.random.split(key, T))
        last_value = critic(params["critic"], normalize(norm, env_state.obs), z)
        state = state.replace(env_state=env_state, z=z, hist=hist, prev_ah=prev_ah, code_counter=counter)
        return state, traj, last_value

    def inner_updates(state: TrainState, flat, expert, key):
        """Discriminator and psi / co-policy (L_z, L_a) updates on minibatches of generated and expert data."""
        norm = state.norm

        def body(carry, key):
            params, aux_opt, disc_opt = carry
            k_g, k_e, k_gp = jax.random.split(key, 3)
            gi = jax.random.randint(k_g, (cfg.inner_batch,), 0, flat["obs"].shape[0])
            gen = jax.tree.map(lambda x: x[gi], flat)
            exp_b = sample_expert(norm, expert, k_e, cfg.inner_batch)
            # psi and co-policy on lambda_1 L_z + lambda_2 L_a
            gen_b = {"hist": hist_input(norm, gen["hist"]), "prev_obs": normalize(norm, gen["hist"][:, -2]),
                     "first": gen["first"], "z": gen["z"]}

            def aux_loss(sub):
                p = {**params, **sub}
                terms = {}
                if cfg.use_lz:
                    terms["loss_z"] = (cfg.lambda_z, losses.code_loss(psi, actor, p, gen_b, Ah))
                if cfg.use_diversity:
                    h_gen = jnp.concatenate([gen_b["hist"], gen["prev_ah"]], -1)
                    terms["loss_q"] = (1.0, losses.diversity_q_loss(psi, p, h_gen, gen["z"]))
                if cfg.use_la and cfg.la_codes == "demo":
                    la_demo = losses.bc_loss(psi, actor, p, exp_b, True, codes="demo", target="human")
                if cfg.use_la or cfg.use_lr:
                    la, lr, spread = losses.behaviour_loss(psi if cfg.use_code else zero_code, actor, p, exp_b, Ah)
                    if cfg.use_la and cfg.la_codes == "demo":
                        la = la_demo
                    if cfg.use_la:
                        terms["loss_a"] = (cfg.lambda_a, la)
                        if cfg.lambda_spread > 0:
                            terms["loss_spread"] = (cfg.lambda_spread, spread)
                    if cfg.use_lr:
                        terms["loss_r"] = (cfg.lambda_r, lr)
                total = sum(w * v for w, v in terms.values())
                return total, {k: v for k, (_, v) in terms.items()}

            sub = {"actor": params["actor"], "psi": params["psi"], "codes": params["codes"]}
            aux_m = {}
            if cfg.use_lz or cfg.use_la or cfg.use_lr or cfg.use_diversity:
                (_, aux_m), g = jax.value_and_grad(aux_loss, has_aux=True)(sub)
                upd, aux_opt = aux_tx.update(g, aux_opt, sub)
                sub = optax.apply_updates(sub, upd)
            # discriminator
            a_e = jnp.concatenate([exp_b["ah"], exp_b["ar"]], -1)
            if cfg.disc_instance_noise:  # the policy's action noise and clip on the expert's actions too
                a_e = losses.noisy_expert_actions(a_e, params["actor"]["params"]["log_std"], jax.random.fold_in(k_gp, 1))
            x_e = jnp.concatenate([exp_b["obs"], a_e], -1)
            x_p = jnp.concatenate([normalize(norm, gen["obs"]), gen["act"]], -1)
            (_, dm), g = jax.value_and_grad(
                lambda p: losses.discriminator_loss(disc, p, x_e, x_p, disc_kind, cfg.gp_coef, k_gp), has_aux=True
            )(params["disc"])
            upd, disc_opt = disc_tx.update(g, disc_opt, params["disc"])
            params = {**params, **sub, "disc": optax.apply_updates(params["disc"], upd)}
            return (params, aux_opt, disc_opt), {**dm, **aux_m}

        carry = (state.params, state.aux_opt, state.disc_opt)
        (params, aux_opt, disc_opt), m = jax.lax.scan(body, carry, jax.random.split(key, cfg.inner_updates))
        return state.replace(params=params, aux_opt=aux_opt, disc_opt=disc_opt), jax.tree.map(jnp.mean, m)

    def rewards(state: TrainState, traj):
        x = jnp.concatenate([normalize(state.norm, traj["obs"]), traj["act"]], -1)
        r = losses.discriminator_reward(disc(state.params["disc"], x), disc_kind)
        if cfg.use_diversity:
            h = jnp.concatenate([hist_input(state.norm, traj["hist"]), traj["prev_ah"]], -1)
            r = r + cfg.diversity_coef * losses.diversity_reward(psi, state.params, h, traj["z"])
        if not cfg.reward_norm:
            return state, r, r

        def body(ret, x):
            r_t, d_t = x
            ret = ret * cfg.gamma + r_t
            return ret * (1 - d_t), ret

        ret_acc, rets = jax.lax.scan(body, state.ret_acc, (r, traj["done"]))
        rms = state.ret_rms
        b_mean, b_var, b_count = rets.mean(), rets.var(), rets.size
        delta = b_mean - rms["mean"]
        tot = rms["count"] + b_count
        mean = rms["mean"] + delta * b_count / tot
        m2 = rms["var"] * rms["count"] + b_var * b_count + delta**2 * rms["count"] * b_count / tot
        rms = {"mean": mean, "var": m2 / tot, "count": tot}
        return state.replace(ret_rms=rms, ret_acc=ret_acc), r / jnp.sqrt(rms["var"] + 1e-8), r

    def ppo_update(state: TrainState, traj, adv, ret, key, expert):
        n = T * N
        obs_n = normalize(state.norm, traj["obs"]).reshape(n, D)
        z, action = traj["z"].reshape(n, -1), traj["action"].reshape(n, -1)
        # log-probs under the co-policy as the inner (L_z / L_a) updates left it: the PPO ratio starts at 1
        mean, log_std = actor(state.params["actor"], obs_n, z)
        logp_old = jax.lax.stop_gradient(gaussian_log_prob(mean, log_std, action))
        flat = {"obs": obs_n, "z": z, "action": action, "logp": logp_old, "adv": adv.reshape(n), "ret": ret.reshape(n)}
        mb = n // cfg.num_minibatches

        def epoch(carry, key):
            def minibatch(carry, x):
                idx, k_bc = x
                sub, opt = carry
                batch = jax.tree.map(lambda x: x[idx], flat)
                exp_b = sample_expert(state.norm, expert, k_bc, cfg.inner_batch) if cfg.bc_coef > 0 else None

                def loss(p):
                    total, m = losses.ppo_loss(actor, critic, p, batch, cfg.clip_eps, cfg.value_coef, cfg.entropy_coef)
                    if cfg.bc_coef > 0:  # PPO+BC: both agents' actions on expert data, psi's code (held fixed here)
                        la, lr, _ = losses.behaviour_loss(psi if cfg.use_code else zero_code, actor,
                                                          {**state.params, **p}, exp_b, Ah)
                        total, m = total + cfg.bc_coef * (la + lr), {**m, "ppo_bc": la + lr}
                    return total, m

                (_, m), g = jax.value_and_grad(loss, has_aux=True)(sub)
                # critic warm-up / cool-down: the actor is not moved by PPO for the first `policy_warmup` and the
                # last `policy_cooldown` updates
                moves = (state.update >= cfg.policy_warmup) & (state.update < cfg.num_updates - cfg.policy_cooldown)
                g = {**g, "actor": mask_frozen_human(jax.tree.map(lambda x: x * moves, g["actor"]))}
                upd, opt = ppo_tx.update(g, opt, sub)
                return (optax.apply_updates(sub, upd), opt), m

            perm = jax.random.permutation(key, n)[: mb * cfg.num_minibatches].reshape(cfg.num_minibatches, mb)
            k_bc = jax.random.split(jax.random.fold_in(key, 1), cfg.num_minibatches)  # leaves perm's stream as it was
            return jax.lax.scan(minibatch, carry, (perm, k_bc))

        sub = {"actor": state.params["actor"], "critic": state.params["critic"]}
        (sub, opt), m = jax.lax.scan(epoch, (sub, state.ppo_opt), jax.random.split(key, cfg.ppo_epochs))
        return state.replace(params={**state.params, **sub}, ppo_opt=opt), jax.tree.map(jnp.mean, m)

    def bc_step(state: TrainState, expert):
        """BC-single: supervised updates of the robot on the demonstrations; no rollout, no discriminator."""
        rng, key = jax.random.split(state.rng)

        def body(carry, key):
            sub, opt = carry
            b = sample_expert(state.norm, expert, key, cfg.inner_batch)
            loss, g = jax.value_and_grad(lambda p: losses.bc_loss(
                psi, actor, p, b, False, target="robot"))(sub)
            upd, opt = aux_tx.update(g, opt, sub)
            return (optax.apply_updates(sub, upd), opt), loss

        sub = {"actor": state.params["actor"], "psi": state.params["psi"], "codes": state.params["codes"]}
        (sub, opt), bc = jax.lax.scan(body, (sub, state.aux_opt),
                                      jax.random.split(key, cfg.ppo_epochs * cfg.num_minibatches))
        state = state.replace(params={**state.params, **sub}, aux_opt=opt, rng=rng, update=state.update + 1)
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(state.params)]))
        return state, {"bc_loss": bc.mean(), "nonfinite": (~finite).astype(jnp.float32)}

    def train_step(state: TrainState, expert):
        if cfg.bc_only:
            return bc_step(state, expert)
        rng, k_roll, k_inner, k_ppo = jax.random.split(state.rng, 4)
        state = state.replace(rng=rng)
        state, traj, last_value = rollout(state, k_roll, expert)
        flat = jax.tree.map(lambda x: x.reshape((T * N,) + x.shape[2:]), traj)
        state, inner_m = inner_updates(state, flat, expert, k_inner)
        state, r_norm, r_raw = rewards(state, traj)
        adv, ret = losses.gae(r_norm, traj["value"], traj["done"], last_value, cfg.gamma, cfg.gae_lambda)
        state, ppo_m = ppo_update(state, traj, adv, ret, k_ppo, expert)
        episodes = traj["done"].sum()
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(state.params)]))
        metrics = {**inner_m, **ppo_m, "reward": r_raw.mean(), "episodes": episodes,
                   "episode_success": traj["success"].sum() / jnp.maximum(episodes, 1.0),
                   **({"fresh_episode_success": (traj["success"] * traj["fresh_done"]).sum()
                       / jnp.maximum(traj["fresh_done"].sum(), 1.0)} if cfg.demo_reset > 0 else {}),
                   "env_failures": traj["env_failed"].sum(),  # MJX steps that diverged (episode ended)
                   "nonfinite": (~finite).astype(jnp.float32)}
        return state.replace(update=state.update + 1), metrics

    # ------------------------------------------------------------------ seed-vmapped, scanned, jitted
    init_jit = jax.jit(jax.vmap(init_one))  # made once: every init() call of these functions reuses the compiled
    bc_jit = jax.jit(jax.vmap(bc_one, in_axes=(0, None)))  # programs

    def init(seeds, expert):
        keys = jnp.stack([jax.random.PRNGKey(int(s)) for s in seeds])
        state = init_jit(keys)
        if cfg.bc_steps:
            state, _ = bc_jit(state, expert)
        return state

    def chunk(state, expert):
        step = jax.vmap(train_step, in_axes=(0, None))
        return jax.lax.scan(lambda s, _: step(s, expert), state, None, length=cfg.updates_per_call)

    return init, SeedChunk(chunk, cfg.multi_device_mode), nets


class SeedChunk:
    """The jitted ``chunk(state, expert) -> (state, metrics)`` (``updates_per_call`` seed-vmapped train steps).

    When the state's seed axis is sharded over a mesh (``trainer.place_on_devices``), each device runs its own
    seeds as an independent program, in one of two ways (``multi``):

    * ``"shard_map"``: one SPMD program under ``shard_map``. Left to jit's sharding propagation instead, MJX's
      solver loops (whose stopping test reduces over the whole batch) put an all-reduce over the devices into
      every solver iteration, and two H200s ran handover at 0.25x the speed of one.
    * ``"per_device"``: the single-device program, compiled once per device and dispatched to all devices from
      a thread pool; its per-device outputs are put back together as the sharded state. On 2 x H200 XLA's GPU
      compiler crashes (segmentation fault inside ``backend_compile_and_load``) on the 2-device ``shard_map``
      program of the MJX tasks, while their single-device program compiles.
    """

    def __init__(self, fn, multi: str = "shard_map"):
        self.fn = fn
        self.multi = multi
        self._plain = jax.jit(fn, donate_argnums=(0,))
        self._sharded = {}
        self._pool = None

    @staticmethod
    def _mesh(state):
        from jax.sharding import NamedSharding

        sh = getattr(jax.tree.leaves(state)[0], "sharding", None)
        if not isinstance(sh, NamedSharding) or sh.mesh.size <= 1 or "seeds" not in sh.mesh.axis_names:
            return None
        return sh.mesh

    def _for(self, state):
        from jax.sharding import PartitionSpec as P

        mesh = self._mesh(state)
        if mesh is None:
            return self._plain
        if mesh not in self._sharded:
            f = jax.shard_map(self.fn, mesh=mesh, in_specs=(P("seeds"), P()),
                              out_specs=(P("seeds"), P(None, "seeds")), check_vma=False)
            self._sharded[mesh] = jax.jit(f, donate_argnums=(0,))
        return self._sharded[mesh]

    def _per_device(self, mesh, state, expert):
        from concurrent.futures import ThreadPoolExecutor

        from jax.sharding import NamedSharding, PartitionSpec as P

        devs = list(mesh.devices.flat)
        n = len(devs)

        def shard(x, i):  # what device i holds of x
            return next(sh.data for sh in x.addressable_shards if sh.device == devs[i])

        def piece(x, i):  # device i's block of the seed axis (replicated empty leaves: an empty block)
            if x.size == 0:
                return jax.device_put(np.zeros((x.shape[0] // n,) + x.shape[1:], x.dtype), devs[i])
            return shard(x, i)

        def whole(parts, axis, spec):
            shape = list(parts[0].shape)
            shape[axis] *= n
            if parts[0].size == 0:  # placed as trainer.place_on_devices places empty leaves: replicated
                return jax.device_put(np.zeros(shape, parts[0].dtype), NamedSharding(mesh, P()))
            return jax.make_array_from_single_device_arrays(tuple(shape), NamedSharding(mesh, spec), list(parts))

        args = [(jax.tree.map(lambda x: piece(x, i), state), jax.tree.map(lambda x: shard(x, i), expert))
                for i in range(n)]
        del state
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=n)
        outs = list(self._pool.map(lambda a: self._plain(*a), args))  # first call: the n compilations in parallel
        new_state = jax.tree.map(lambda *p: whole(p, 0, P("seeds")), *[o[0] for o in outs])
        metrics = jax.tree.map(lambda *p: whole(p, 1, P(None, "seeds")), *[o[1] for o in outs])
        return new_state, metrics

    def __call__(self, state, expert):
        mesh = self._mesh(state)
        if mesh is not None and self.multi == "per_device":
            return self._per_device(mesh, state, expert)
        return self._for(state)(state, expert)

    def lower(self, state, expert):
        return self._for(state).lower(state, expert)

    def _cache_size(self) -> int:
        return self._plain._cache_size() + sum(f._cache_size() for f in self._sharded.values())


def fit_normalizer(expert: dict[str, np.ndarray], std_floor: float = 1e-2) -> dict[str, np.ndarray]:
    """Observation mean/std of the training demonstrations (std floored at ``std_floor`` so near-constant
    features, e.g. an MJX gripper's tilt, do not blow up when a policy drifts from them), the number of
    demonstrations (BC pre-training learns one code per demonstration) and each demonstration's trajectory
    features (for ``code_init="pca"``)."""
    mean, std = expert["obs"].mean(0), np.maximum(expert["obs"].std(0), std_floor)
    return {"mean": mean, "std": std, "num_demos": int(expert["demo"].max()) + 1,
            "features": demo_features((expert["obs"] - mean) / std, expert["demo"])}


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


__all__ = ["TrainState", "make_train_fns", "expert_arrays", "fit_normalizer", "demo_code_init", "demo_features", "code_grid", "Callable"]
