"""Losses and the objective each method preset optimises.

Pure losses: GAE, PPO (clipped surrogate + value), discriminator (BCE or LSGAN with gradient penalty), L_z,
L_a / L_r, behaviour cloning, DIAYN's q fit and reward. Assembled per preset from ``objective_terms(cfg)``
(the one place that says which terms a preset has): ``aux_objective`` (the psi / co-policy step),
``ppo_objective`` (PPO, + BC with ``bc_coef``) and ``bc_objective`` (BC pre-training; BC-single's training).
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax

from . import actions
from .actions import ActionSpec
from .config import METHODS, TrainConfig, hyper_values
from .networks import gaussian_entropy, gaussian_log_prob  # noqa: F401  (the Gaussian case, used by tests)


def gae(rewards, values, dones, truncations, final_values, last_value, gamma, lam, unroll=1):
    """Generalised advantage estimation over a (T, N) rollout.

    ``dones[t]`` ends the episode after step t; ``truncations[t]`` says it ended by the time limit, not by
    success or failure. A terminal step (done, not truncated) has no next value; a truncated step is
    bootstrapped with ``final_values[t]``, the critic's value of the episode's final observation (before the
    auto-reset replaced it), as the paper's reference PPO does with its bad-transition masks. Either way the
    advantage recursion stops at the episode's end. ``last_value``: the value of the state after step T-1."""

    def body(carry, x):
        adv, next_value = carry
        r, v, d, tr, fv = x
        boot = jnp.where(tr > 0, fv, next_value * (1 - d))
        delta = r + gamma * boot - v
        adv = delta + gamma * lam * (1 - d) * adv
        return (adv, v), adv

    xs = (rewards, values, dones, truncations, final_values)
    _, adv = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), xs, reverse=True, unroll=unroll)
    return adv, adv + values


# bound of the PPO log importance ratio: with the small per-dimension stds of ``bc_std`` (0.01-0.02) a mean that
# moved a few stds within one update's epochs gives log ratios past 88, exp() overflows to inf, inf times a negative
# advantage wins the surrogate's min and the gradient is NaN (seqmanip runs diverged so; docs/notes.md). Within the
# bound nothing changes; a sample past it gets no gradient (as in dual-clip PPO, Ye et al. 2020, whose bound on a
# negative advantage's ratio is 3 rather than e^20)
LOG_RATIO_MAX = 20.0


def ppo_loss(actor_apply, critic_apply, params, batch, clip_eps, value_coef, entropy_coef, normalize_adv=True,
             spec: ActionSpec | None = None):
    """Clipped PPO; ``normalize_adv=False``: the batch's advantages come normalised (over every env shard's
    minibatch: ``shards.moments``). ``spec``: the action's kinds (default: all continuous)."""
    spec = spec or ActionSpec(0, 0)
    mean, log_std = actor_apply(params["actor"], batch["obs"], batch["z"])
    logp = actions.log_prob(spec, mean, log_std, batch["action"])
    log_ratio = jnp.clip(logp - batch["logp"], -LOG_RATIO_MAX, LOG_RATIO_MAX)
    ratio = jnp.exp(log_ratio)
    adv = batch["adv"]
    if normalize_adv:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * adv).mean()
    value = critic_apply(params["critic"], batch["obs"], batch["z"])
    v_loss = 0.5 * ((value - batch["ret"]) ** 2).mean()
    ent = actions.entropy(spec, mean, log_std).mean()
    total = pg + value_coef * v_loss - entropy_coef * ent
    kl = ((ratio - 1) - log_ratio).mean()
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


def noisy_expert_actions(a, log_std, key, spec: ActionSpec | None = None):
    """Instance noise for the discriminator: the expert's actions with the policy's Gaussian action noise
    (``log_std``, no gradient) and the same clip to [-1, 1] as the actions the policy executes. A discrete agent's
    one-hot actions are left as they are (its executed actions are one-hot too)."""
    std = jnp.exp(jax.lax.stop_gradient(log_std))
    noisy = jnp.clip(a + std * jax.random.normal(key, a.shape), -1.0, 1.0)
    if spec is None or spec.continuous:
        return noisy
    return jnp.concatenate([a[..., s:s + n] if d else noisy[..., s:s + n] for s, n, d in spec.segments], -1)


def discriminator_reward(d, kind):
    """Reward from the discriminator output: the logit for BCE (log D - log(1 - D)), D itself for LSGAN."""
    return d


def code_loss(psi_apply, actor_apply, params, batch, human_size, train="both", discrete=False):
    """L_z on generated data: psi(s_{t-K..t}, mu_H(s_{t-1}, z)) should recover z; the human action in the
    history is the policy mean, so the gradient reaches the co-policy. ``train``: "both", "psi" (the
    co-policy held fixed: psi's part, in the aux step) or "policy" (psi held fixed: the co-policy's part, in
    the PPO step; ``lz_in_ppo``). ``discrete``: the human's actions are discrete, and the history holds its
    expected one-hot action (the categorical's probabilities) instead of a mean."""
    sg = jax.lax.stop_gradient
    params = {**params, "actor": sg(params["actor"]) if train == "psi" else params["actor"],
              "psi": sg(params["psi"]) if train == "policy" else params["psi"]}
    mean_prev, _ = actor_apply(params["actor"], batch["prev_obs"], batch["z"])
    a_prev = jnp.where(batch["first"][:, None], 0.0, actions.agent_expected(discrete, mean_prev[:, :human_size]))
    h = jnp.concatenate([batch["hist"], a_prev], -1)
    z_hat = psi_apply(params["psi"], h)
    return jnp.mean(jnp.sum((z_hat - batch["z"]) ** 2, -1))


def behaviour_loss(psi_apply, actor_apply, params, batch, human_size, psi_grad=True, z=None,
                   spec: ActionSpec | None = None):
    """L_a on expert data: the human part of the co-policy, fed psi's code of the expert history, should
    reproduce the expert human action. Also returns the same error for the robot part (L_r, our addition:
    the robot acting with psi's code on expert histories, weighted by ``lambda_r``). ``psi_grad=False``: psi's
    code enters through stop_gradient (presets without L_a: psi learns nothing from expert actions). ``z``:
    the code to act on instead of psi's (``expert_code``). A discrete agent's error is the cross-entropy of its
    expert choices (``actions.agent_error``): L_a / L_r are then negative log-likelihoods."""
    spec = spec or ActionSpec(human_size, 0)
    z_hat = psi_apply(params["psi"], jnp.concatenate([batch["hist"], batch["prev_ah"]], -1)) if z is None else z
    if not psi_grad:
        z_hat = jax.lax.stop_gradient(z_hat)
    mean, _ = actor_apply(params["actor"], batch["obs"], z_hat)
    la = jnp.mean(actions.agent_error(spec.human_discrete, mean[:, :human_size], batch["ah"]))
    lr = jnp.mean(actions.agent_error(spec.robot_discrete, mean[:, human_size:], batch["ar"]))
    return la, lr


def code_spread(z):
    """Match the first two moments of a batch of codes to the prior U(-1, 1)^2 (mean 0, variance 1/3), so
    the codes fill the code space the co-policy is sampled over."""
    return jnp.sum(jnp.mean(z, 0) ** 2) + jnp.sum((jnp.var(z, 0) - 1.0 / 3.0) ** 2)


def bc_loss(psi_apply, actor_apply, params, batch, use_code, target="both", train_psi=True,
            spec: ActionSpec | None = None):
    """Behaviour cloning of the agents' actions (``target``: "both", "human" or "robot").

    Each demonstration has a learned code (``params["codes"]``, tanh-squashed) that the co-policy acts on for the
    whole demonstration, and the codes' moments are pulled to the prior's (U(-1, 1)^2) so that the prior's codes
    are in distribution; with ``train_psi``, psi also regresses the demonstration's code from the history.
    Without ``use_code`` the co-policy acts on z = 0. The error is squared for a continuous agent and the
    cross-entropy for a discrete one (``actions``).
    """
    width = batch["ah"].shape[-1]
    spec = spec or ActionSpec(width, batch["ar"].shape[-1])
    if target == "both":
        joint = jnp.concatenate([batch["ah"], batch["ar"]], -1)
        err = lambda mean: jnp.mean(actions.joint_error(spec, mean, joint))  # noqa: E731
    elif target == "human":
        err = lambda mean: jnp.mean(actions.agent_error(spec.human_discrete, mean[..., :width], batch["ah"]))  # noqa: E731
    else:
        err = lambda mean: jnp.mean(actions.agent_error(spec.robot_discrete, mean[..., width:], batch["ar"]))  # noqa: E731
    z_psi = psi_apply(params["psi"], jnp.concatenate([batch["hist"], batch["prev_ah"]], -1))
    if not use_code:  # the co-policy acts on z = 0
        mean, _ = actor_apply(params["actor"], batch["obs"], jnp.zeros_like(z_psi))
        return err(mean)
    all_codes = jnp.tanh(params["codes"])
    z = all_codes[batch["demo"]]
    mean, _ = actor_apply(params["actor"], batch["obs"], z)
    loss = err(mean)
    if train_psi:
        loss = loss + jnp.mean(jnp.sum((z_psi - jax.lax.stop_gradient(z)) ** 2, -1))
    return loss + 10.0 * code_spread(all_codes)


def bc_residual(cfg: TrainConfig, nets: Nets, params, batch):
    """The co-policy's mean minus the expert's joint action ``(a_H, a_R)`` on an expert minibatch, each step on the
    code BC trains it with (its demonstration's learned code; zero for presets without one)."""
    z = jnp.tanh(params["codes"])[batch["demo"]]
    z = z if cfg.use_code else jnp.zeros_like(z)
    mean, _ = nets.actor(params["actor"], batch["obs"], z)
    return mean - jnp.concatenate([batch["ah"], batch["ar"]], -1)


def diversity_q_loss(psi_apply, params, hist_in, z):
    """DIAYN: fit q(z | h) (psi's network) to the codes of generated data; no gradient reaches the policy."""
    return jnp.mean(jnp.sum((psi_apply(params["psi"], hist_in) - z) ** 2, -1))


def diversity_reward(psi_apply, params, hist_in, z):
    """DIAYN reward log q(z|h) - log p(z) for a unit-variance Gaussian q and the uniform prior on (-1, 1)^2
    (the constants folded in: -0.5 |q(h) - z|^2 + log 4 - log 2 pi)."""
    d = jnp.sum((psi_apply(params["psi"], hist_in) - z) ** 2, -1)
    return -0.5 * d + jnp.log(4.0) - jnp.log(2 * jnp.pi)


# ---------------------------------------------------------------------------------------------------------
# the objective per preset

class Nets(NamedTuple):
    """The networks' apply functions and what the objectives need to know about the action."""

    actor: Callable
    critic: Callable
    psi: Callable
    disc: Callable
    human_size: int
    disc_kind: str  # "bce" | "lsgan"
    spec: ActionSpec | None = None  # the action's kinds (None: every agent continuous)


TERMS = ("gail_human", "gail_robot", "task_human", "task_robot", "L_z", "L_a", "L_r", "diversity", "ppo_bc", "bc_human",
         "bc_robot", "bc_psi")


def objective_terms(cfg: TrainConfig) -> frozenset[str]:
    """Exactly which terms a preset optimises:

    * ``gail_human`` / ``gail_robot``: PPO on the discriminator's reward moves the human / robot actions
    * ``task_human`` / ``task_robot``: PPO on the task's own reward moves them (the PPO presets; in a GAIL preset,
      added to the discriminator's with ``task_reward`` > 0)
    * ``L_z``: psi and the co-policy on code reconstruction from generated data (InfoGAIL); without L_a
      psi's part in the aux step, the co-policy's in the PPO step (``lz_in_ppo``)
    * ``L_a``: behaviour reconstruction of the expert human actions through psi's code (Co-GAIL); the only
      term through which expert actions reach psi
    * ``L_r``: robot-action reconstruction on expert data (our addition, ``lambda_r`` > 0) on psi's code
      where ``L_a`` is on, else on each demonstration's code from BC pre-training (``expert_code``)
    * ``diversity``: DIAYN's reward for the co-policy and psi's fit as q(z | h) on generated data
    * ``ppo_bc``: PPO+BC, both agents' squared error on expert data inside the PPO step (``bc_coef`` > 0)
    * ``bc_human`` / ``bc_robot`` / ``bc_psi``: behaviour cloning of the human / the robot / psi regressing
      each demonstration's code (BC pre-training with ``bc_steps`` > 0; BC-single's whole training)
    """
    if cfg.bc_only:
        return frozenset({"bc_robot"})
    if cfg.task_rl:  # the field's baselines: PPO on the task's reward, BC pre-training, nothing else
        t = {"task_robot"} | (set() if cfg.freeze_human else {"task_human"})
        return frozenset(t | ({"bc_human", "bc_robot"} if cfg.bc_steps > 0 else set()))
    t = {"gail_robot"}
    if not cfg.freeze_human:
        t.add("gail_human")
    if cfg.task_reward > 0:
        t |= {"task_robot"} | (set() if cfg.freeze_human else {"task_human"})
    if cfg.use_lz:
        t.add("L_z")
    if cfg.use_la:
        t.add("L_a")
    if cfg.lambda_r > 0:
        t.add("L_r")
    if cfg.use_diversity:
        t.add("diversity")
    if cfg.bc_coef > 0:
        t.add("ppo_bc")
    if cfg.bc_steps > 0:
        t |= {"bc_human", "bc_robot"} | ({"bc_psi"} if cfg.use_la else set())
    return frozenset(t)


def _human_discrete(nets: Nets) -> bool:
    return bool(nets.spec is not None and nets.spec.human_discrete)


def _code_net(cfg: TrainConfig, nets: Nets):
    """psi, or for a preset without a strategy code the constant z = 0."""
    if cfg.use_code:
        return nets.psi
    return lambda _, h: jnp.zeros(h.shape[:-1] + (cfg.code_dim,))


def lz_in_ppo(cfg: TrainConfig) -> bool:
    """Whether L_z's co-policy part is optimised in the PPO step (psi's part stays in the aux step): for presets
    with L_z but no L_a (MA-InfoGAIL). InfoGAIL's policy minimises its GAIL objective and lambda_z x L_z
    together, and there lambda_z weighs L_z against the surrogate. In the aux step, where Co-GAIL optimises it
    beside L_a, a preset without L_a gives the human's output weights gradient from L_z alone: Adam rescales
    it to the full aux learning rate whatever lambda_z is, and MA-InfoGAIL's human left its demonstrations
    (interpolation 0 % at paper budgets). Co-GAIL measured the same either way (docs/notes.md) and keeps the
    aux step."""
    terms = objective_terms(cfg)
    return "L_z" in terms and "L_a" not in terms


def expert_code(cfg: TrainConfig, params, batch):
    """The code the co-policy acts on in the expert-data terms of a preset without L_a (L_r, PPO+BC): each
    demonstration's own code from BC pre-training (``params["codes"]``, tanh-squashed, held fixed), or
    z = 0 without a strategy code; None where psi's code is meant (Co-GAIL, whose L_a teaches psi the
    demonstrations' codes).

    Without L_a psi learns only from generated data (L_z, DIAYN's q fit): on expert histories its code is not
    one the co-policy was cloned on (BC pre-training uses the demonstrations' codes, spread over the prior's
    square), nor one it is given at interpolation (codes from the prior), so fitting the robot to expert
    actions on it taught the robot a second, unrelated use of z. The demonstrations' codes are the ones the
    co-policy already acts on for those demonstrations and lie in the prior's support; no expert action
    reaches psi either way."""
    if "L_a" in objective_terms(cfg):
        return None
    if not cfg.use_code:
        return jnp.zeros(batch["obs"].shape[:-1] + (cfg.code_dim,))
    return jax.lax.stop_gradient(jnp.tanh(params["codes"])[batch["demo"]])


def aux_objective(cfg: TrainConfig, nets: Nets, params, gen_batch, exp_batch, hp: dict | None = None):
    """The psi / co-policy step: lambda_1 L_z (and DIAYN's q fit) on generated data, lambda_2 L_a and
    lambda_r L_r on expert data, for the terms the preset has. ``gen_batch`` or ``exp_batch`` None leaves
    that data's terms out. ``hp``: the ``config.HYPER`` values (default: ``cfg``'s). Returns
    ``(loss, {term: value})``."""
    hp = hyper_values(cfg) if hp is None else hp
    on = objective_terms(cfg)
    terms = {}
    if gen_batch is not None:
        if "L_z" in on:
            terms["loss_z"] = (hp["lambda_z"], code_loss(nets.psi, nets.actor, params, gen_batch, nets.human_size,
                                                       train="psi" if lz_in_ppo(cfg) else "both",
                                                       discrete=_human_discrete(nets)))
        if "diversity" in on:
            h = jnp.concatenate([gen_batch["hist"], gen_batch["prev_ah"]], -1)
            terms["loss_q"] = (1.0, diversity_q_loss(nets.psi, params, h, gen_batch["z"]))
    if exp_batch is not None and on & {"L_a", "L_r"}:
        la, lr = behaviour_loss(_code_net(cfg, nets), nets.actor, params, exp_batch, nets.human_size,
                                psi_grad="L_a" in on, z=expert_code(cfg, params, exp_batch), spec=nets.spec)
        if "L_a" in on:
            # one learned code per demonstration, psi regressing it (the paper's L_a, on psi's code of each step's
            # history, interpolated 3 % against 48 % on fetchq: docs/notes.md)
            la = bc_loss(nets.psi, nets.actor, params, exp_batch, True, target="human", spec=nets.spec)
            terms["loss_a"] = (cfg.lambda_a, la)
        if "L_r" in on:
            terms["loss_r"] = (cfg.lambda_r, lr)
    total = sum((w * v for w, v in terms.values()), jnp.zeros(()))
    return total, {k: v for k, (_, v) in terms.items()}


def ppo_objective(cfg: TrainConfig, nets: Nets, params, batch, exp_batch, hp: dict | None = None):
    """Clipped PPO on a minibatch; with ``ppo_bc``, + bc_coef x both agents' squared error on an expert
    minibatch, acting on psi's code of the expert history (held fixed: no gradient reaches psi; without L_a
    the demonstration's code, ``expert_code``); with ``L_z`` and no ``L_a`` (``lz_in_ppo``), + lambda_z x L_z on the
    minibatch's own generated steps, psi held fixed (InfoGAIL: the policy minimises the GAIL objective and
    lambda_z L_z together). ``hp``: the ``config.HYPER`` values (default: ``cfg``'s)."""
    hp = hyper_values(cfg) if hp is None else hp
    total, m = ppo_loss(nets.actor, nets.critic, params, batch, hp["clip_eps"], hp["value_coef"], hp["entropy_coef"],
                        normalize_adv=cfg.env_shards == 1, spec=nets.spec)
    if "ppo_bc" in objective_terms(cfg):
        la, lr = behaviour_loss(_code_net(cfg, nets), nets.actor, params, exp_batch, nets.human_size,
                                psi_grad=False, z=expert_code(cfg, params, exp_batch), spec=nets.spec)
        total, m = total + hp["bc_coef"] * (la + lr), {**m, "ppo_bc": la + lr}
    if lz_in_ppo(cfg):
        lz = code_loss(nets.psi, nets.actor, params, batch, nets.human_size, train="policy",
                       discrete=_human_discrete(nets))
        total, m = total + hp["lambda_z"] * lz, {**m, "ppo_lz": lz}
    return total, m


def bc_objective(cfg: TrainConfig, nets: Nets, params, batch):
    """Behaviour cloning on an expert minibatch: both agents on their demonstration's learned code (BC
    pre-training; psi learns to recognise the codes only in presets with L_a), or the robot alone
    (BC-single)."""
    on = objective_terms(cfg)
    target = "both" if "bc_human" in on else "robot"
    return bc_loss(nets.psi, nets.actor, params, batch, cfg.use_code, target, train_psi="bc_psi" in on, spec=nets.spec)


PAPER_WORDING = {  # the paper's section 5 ("Baselines"), one line each
    "cogail": "The complete method: MA-InfoGAIL plus the behaviour reconstruction loss L_a, to cover all "
              "strategies of the demonstrations.",
    "ma_infogail": "MA-GAIL plus InfoGAIL's latent strategy code objective L_z.",
    "ma_gail": "Human and robot policies learned with a shared GAIL objective.",
    "bc_gail": "Human and robot policies trained in isolation: the human by BC, then the robot by GAIL "
               "against the learned human.",
    "bc_single": "Behaviour cloning of the robot policy only; the human is replayed open-loop.",
    "diayn": "A diversity reward encourages the human policy to be as diverse as possible.",
    "ppo_bc": "(Carroll et al. 2019) PPO on the task's reward, the human a frozen BC model of the training people.",
    "ppo_sp": "(Carroll et al. 2019) PPO self-play on the task's reward: both agents trained by PPO.",
}


def preset_table_markdown() -> str:
    """The method presets and the terms each optimises (from ``objective_terms``), as a Markdown table."""
    yes = lambda b: "yes" if b else "-"  # noqa: E731
    rows = ["| preset | paper (section 5) | GAIL human | GAIL robot | task reward | L_z | L_a | L_r | DIAYN | "
            "BC pre-training | PPO+BC | psi learns from |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in METHODS:
        cfg = TrainConfig(method=m, bc_steps=1, bc_coef=1.0)
        t = objective_terms(cfg)
        bc = ", ".join(k[3:] for k in ("bc_human", "bc_robot", "bc_psi") if k in t) or "-"
        psi = ", ".join(n for k, n in (("L_z", "L_z"), ("L_a", "L_a"), ("bc_psi", "BC"),
                                       ("diversity", "q fit (generated data)")) if k in t) or "- (no psi)"
        name = f"`{m}`" + (" (BC only)" if cfg.bc_only else "")
        task = ", ".join(a for a, k in (("human", "task_human"), ("robot", "task_robot")) if k in t) or "-"
        rows.append(f"| {name} | {PAPER_WORDING[m]} | {yes('gail_human' in t)} | {yes('gail_robot' in t)} | {task} | "
                    f"{yes('L_z' in t)} | {yes('L_a' in t)} | {yes('L_r' in t)} | {yes('diversity' in t)} | {bc} | "
                    f"{yes('ppo_bc' in t)} | {psi} |")
    return "\n".join(rows) + (
        "\n\nL_r (`lambda_r`, default 1), BC pre-training (`bc_steps`) and PPO+BC (`bc_coef`, default 0) are our "
        "additions, shared by every preset that has the agent they train (shown switched on). Without L_a, psi "
        "learns nothing from expert actions: L_r and PPO+BC act on each demonstration's code from BC pre-training "
        "(`losses.expert_code`), and L_z's co-policy part is in the PPO step (`losses.lz_in_ppo`); without a strategy code "
        "(`ma_gail`, `bc_gail`, `bc_single`) the co-policy sees z = 0. `bc_gail`'s human is frozen after BC. The "
        "field's baselines `ppo_bc` and `ppo_sp` (for tasks learned from people) optimise the task's own reward with "
        "PPO from BC pre-training, with no discriminator, psi or L_r (`ppo_bc`'s human frozen after BC); "
        "`--set task_reward=W` adds W x the task's reward to a GAIL preset's discriminator reward.")
