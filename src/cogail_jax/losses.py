"""Losses: PPO (clipped surrogate + value), discriminator (BCE or LSGAN with gradient penalty), L_z, L_a."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from .networks import gaussian_entropy, gaussian_log_prob


def gae(rewards, values, dones, last_value, gamma, lam):
    """Generalised advantage estimation over a (T, N) rollout; ``dones[t]`` ends the episode after step t."""

    def body(carry, x):
        adv, next_value = carry
        r, v, d = x
        delta = r + gamma * next_value * (1 - d) - v
        adv = delta + gamma * lam * (1 - d) * adv
        return (adv, v), adv

    _, adv = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), (rewards, values, dones), reverse=True)
    return adv, adv + values


def ppo_loss(actor_apply, critic_apply, params, batch, clip_eps, value_coef, entropy_coef):
    mean, log_std = actor_apply(params["actor"], batch["obs"], batch["z"])
    logp = gaussian_log_prob(mean, log_std, batch["action"])
    ratio = jnp.exp(logp - batch["logp"])
    adv = batch["adv"]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * adv).mean()
    value = critic_apply(params["critic"], batch["obs"], batch["z"])
    v_loss = 0.5 * ((value - batch["ret"]) ** 2).mean()
    ent = gaussian_entropy(log_std).mean()
    total = pg + value_coef * v_loss - entropy_coef * ent
    kl = ((ratio - 1) - jnp.log(ratio)).mean()
    return total, {"policy_loss": pg, "value_loss": v_loss, "entropy": ent, "approx_kl": kl}


def discriminator_loss(disc_apply, params, expert, policy, kind, gp_coef, rng):
    """BCE (expert -> 1) or LSGAN (expert -> +1, policy -> -1) plus a gradient penalty on interpolates."""
    d_e = disc_apply(params, expert)
    d_p = disc_apply(params, policy)
    if kind == "bce":
        loss = optax.sigmoid_binary_cross_entropy(d_e, 1.0).mean() + optax.sigmoid_binary_cross_entropy(d_p, 0.0).mean()
        acc_e, acc_p = (d_e > 0).mean(), (d_p < 0).mean()
    else:
        loss = ((d_e - 1) ** 2).mean() + ((d_p + 1) ** 2).mean()
        acc_e, acc_p = (d_e > 0).mean(), (d_p < 0).mean()
    alpha = jax.random.uniform(rng, (expert.shape[0], 1))
    mix = alpha * expert + (1 - alpha) * policy
    grads = jax.vmap(jax.grad(lambda x: disc_apply(params, x[None])[0]))(mix)
    gp = ((jnp.linalg.norm(grads, axis=-1) - 1) ** 2).mean()
    return loss + gp_coef * gp, {"disc_loss": loss, "disc_gp": gp, "disc_acc_expert": acc_e, "disc_acc_policy": acc_p}


def noisy_expert_actions(actions, log_std, key):
    """Instance noise for the discriminator: the expert's actions with the policy's Gaussian action noise
    (``log_std``, no gradient) and the same clip to [-1, 1] as the actions the policy executes."""
    std = jnp.exp(jax.lax.stop_gradient(log_std))
    return jnp.clip(actions + std * jax.random.normal(key, actions.shape), -1.0, 1.0)


def discriminator_reward(d, kind):
    """Reward from the discriminator output: the logit for BCE (log D - log(1 - D)), D itself for LSGAN."""
    return d


def code_loss(psi_apply, actor_apply, params, batch, human_size):
    """L_z on generated data: psi(s_{t-K..t}, mu_H(s_{t-1}, z)) should recover z; the human action in the
    history is the policy mean, so the gradient reaches the co-policy."""
    mean_prev, _ = actor_apply(params["actor"], batch["prev_obs"], batch["z"])
    a_prev = jnp.where(batch["first"][:, None], 0.0, mean_prev[:, :human_size])
    h = jnp.concatenate([batch["hist"], a_prev], -1)
    z_hat = psi_apply(params["psi"], h)
    return jnp.mean(jnp.sum((z_hat - batch["z"]) ** 2, -1))


def behaviour_loss(psi_apply, actor_apply, params, batch, human_size):
    """L_a on expert data: the human part of the co-policy, fed psi's code of the expert history, should
    reproduce the expert human action. Also returns the same error for the robot part (L_r, our addition:
    the robot acting with psi's code on expert histories, weighted by ``lambda_r``)."""
    z_hat = psi_apply(params["psi"], jnp.concatenate([batch["hist"], batch["prev_ah"]], -1))
    mean, _ = actor_apply(params["actor"], batch["obs"], z_hat)
    la = jnp.mean(jnp.sum((mean[:, :human_size] - batch["ah"]) ** 2, -1))
    lr = jnp.mean(jnp.sum((mean[:, human_size:] - batch["ar"]) ** 2, -1))
    return la, lr, code_spread(z_hat)


def code_spread(z):
    """Match the first two moments of a batch of codes to the prior U(-1, 1)^2 (mean 0, variance 1/3), so
    the codes psi gives expert behaviour fill the code space the co-policy is sampled over."""
    return jnp.sum(jnp.mean(z, 0) ** 2) + jnp.sum((jnp.var(z, 0) - 1.0 / 3.0) ** 2)


def bc_loss(psi_apply, actor_apply, params, batch, use_code, spread_coef=0.0, codes="demo", target="both"):
    """Behaviour cloning of both agents' actions.

    ``codes="demo"``: each demonstration has a learned code (``params["codes"]``, tanh-squashed) that the
    co-policy acts on for the whole demonstration, psi regresses it from the history, and the codes' moments
    are pulled to the prior's (U(-1, 1)^2) so that the prior's codes are in distribution.
    ``codes="psi"``: the co-policy acts on psi's code of each step's history.
    """
    z_psi = psi_apply(params["psi"], jnp.concatenate([batch["hist"], batch["prev_ah"]], -1))
    if target == "both":
        target = jnp.concatenate([batch["ah"], batch["ar"]], -1)
        pick = lambda m: m
    else:
        h = batch["ah"].shape[-1]
        target = batch["ah"] if target == "human" else batch["ar"]
        pick = (lambda m: m[..., :h]) if target is batch["ah"] else (lambda m: m[..., h:])
    if not use_code:
        mean, _ = actor_apply(params["actor"], batch["obs"], jnp.zeros_like(z_psi))
        return jnp.mean(jnp.sum((pick(mean) - target) ** 2, -1))
    if codes == "demo":
        all_codes = jnp.tanh(params["codes"])
        z = all_codes[batch["demo"]]
        mean, _ = actor_apply(params["actor"], batch["obs"], z + batch.get("code_noise", 0.0))
        recog = jnp.mean(jnp.sum((z_psi - jax.lax.stop_gradient(z)) ** 2, -1))
        return jnp.mean(jnp.sum((pick(mean) - target) ** 2, -1)) + recog + 10.0 * code_spread(all_codes)
    mean, _ = actor_apply(params["actor"], batch["obs"], z_psi)
    return jnp.mean(jnp.sum((pick(mean) - target) ** 2, -1)) + spread_coef * code_spread(z_psi)


def diversity_q_loss(psi_apply, params, hist_in, z):
    """DIAYN: fit q(z | h) (psi's network) to the codes of generated data; no gradient reaches the policy."""
    return jnp.mean(jnp.sum((psi_apply(params["psi"], hist_in) - z) ** 2, -1))


def diversity_reward(psi_apply, params, hist_in, z):
    """DIAYN reward log q(z|h) - log p(z) for a unit-variance Gaussian q and the uniform prior on (-1, 1)^2
    (the constants folded in: -0.5 |q(h) - z|^2 + log 4 - log 2 pi)."""
    d = jnp.sum((psi_apply(params["psi"], hist_in) - z) ** 2, -1)
    return -0.5 * d + jnp.log(4.0) - jnp.log(2 * jnp.pi)
