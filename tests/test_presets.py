"""Each method preset builds, runs one tiny train_step, and has exactly its distinguishing terms."""
import jax
import numpy as np
import pytest

from cogail_jax.data import io as data
from cogail_jax.algo import train
from cogail_jax.algo.config import METHODS

EXPECT = {
    # method: (keys that must be in the metrics, keys that must not)
    "cogail": ({"disc_loss", "loss_z", "loss_a", "loss_r", "policy_loss"}, {"loss_q", "bc_loss"}),
    "ma_infogail": ({"disc_loss", "loss_z", "policy_loss"}, {"loss_a", "loss_q", "bc_loss"}),
    "ma_gail": ({"disc_loss", "policy_loss"}, {"loss_z", "loss_a", "loss_q", "bc_loss"}),
    "bc_gail": ({"disc_loss", "policy_loss"}, {"loss_z", "loss_a", "loss_q", "bc_loss"}),
    "diayn": ({"disc_loss", "loss_q", "policy_loss"}, {"loss_z", "loss_a", "bc_loss"}),
    "bc_single": ({"bc_loss"}, {"disc_loss", "policy_loss", "loss_z", "loss_a", "episode_success"}),
    "ppo_bc": ({"policy_loss"}, {"disc_loss", "loss_z", "loss_a", "loss_r", "loss_q", "bc_loss"}),
    "ppo_sp": ({"policy_loss"}, {"disc_loss", "loss_z", "loss_a", "loss_r", "loss_q", "bc_loss"}),
}


@pytest.fixture(scope="module")
def expert(tiny_cfg, fetchq):
    return train.expert_arrays(data.load_demos(tiny_cfg.demos, fetchq), tiny_cfg.history)


def test_every_method_has_expectations():
    assert set(EXPECT) == set(METHODS)


@pytest.mark.parametrize("method", METHODS)
def test_preset_runs_with_its_terms(method, tiny_cfg, fetchq, expert):
    cfg = tiny_cfg.replace(method=method, seeds=(1,), updates_per_call=1, unroll_length=8, bc_steps=2)
    init, chunk, _ = train.make_train_fns(cfg, fetchq, train.fit_normalizer(expert))
    s0 = init(cfg.seeds, expert)
    before = jax.device_get(s0)
    s1, m = chunk(s0, expert)
    keys = set(m)
    must, must_not = EXPECT[method]
    assert must <= keys, (method, keys)
    assert not (must_not & keys), (method, keys)
    assert all(np.all(np.isfinite(np.asarray(v))) for v in m.values())
    after = jax.device_get(s1)
    disc_same = all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(before.params["disc"]),
                                                          jax.tree.leaves(after.params["disc"])))
    if method == "bc_single":  # never calls the discriminator, never steps the environment
        assert disc_same
        assert np.array_equal(before.env_state.obs, after.env_state.obs)
    else:  # the PPO presets train on the task's reward: no discriminator
        assert disc_same == method.startswith("ppo_")
    if method in ("ma_gail", "bc_gail", "bc_single", "ppo_bc", "ppo_sp"):
        assert np.all(np.asarray(after.z) == 0)
    else:
        assert np.any(np.asarray(after.z) != 0)
    if method in ("bc_gail", "ppo_bc"):  # the BC-trained human tower is frozen during GAIL / PPO
        h0, h1 = before.params["actor"]["params"]["human"], after.params["actor"]["params"]["human"]
        assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(h0), jax.tree.leaves(h1)))
        r0, r1 = before.params["actor"]["params"]["robot"], after.params["actor"]["params"]["robot"]
        assert not all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(r0), jax.tree.leaves(r1)))


# ---------------------------------------------------------------- which terms each preset optimises
SHARED = {"L_r"}  # our addition, on by default (lambda_r = 1) for every preset with an environment
TERMS = {
    "cogail": {"gail_human", "gail_robot", "L_z", "L_a"} | SHARED,
    "ma_infogail": {"gail_human", "gail_robot", "L_z"} | SHARED,
    "ma_gail": {"gail_human", "gail_robot"} | SHARED,
    "bc_gail": {"gail_robot"} | SHARED,
    "bc_single": {"bc_robot"},
    "diayn": {"gail_human", "gail_robot", "diversity"} | SHARED,
    "ppo_bc": {"task_robot"},
    "ppo_sp": {"task_human", "task_robot"},
}
BC_TERMS = {  # with bc_steps > 0: BC pre-training; psi learns the demonstrations' codes only with L_a
    "cogail": {"bc_human", "bc_robot", "bc_psi"},
    "ma_infogail": {"bc_human", "bc_robot"},
    "ma_gail": {"bc_human", "bc_robot"},
    "bc_gail": {"bc_human", "bc_robot"},  # the robot gets the same BC as the other presets' robots
    "bc_single": {"bc_robot"},
    "diayn": {"bc_human", "bc_robot"},
    "ppo_bc": {"bc_human", "bc_robot"},
    "ppo_sp": {"bc_human", "bc_robot"},
}


@pytest.mark.parametrize("method", METHODS)
def test_objective_terms_table(method):
    from cogail_jax.algo import losses
    from cogail_jax.algo.config import TrainConfig

    base = TrainConfig(method=method)
    assert losses.objective_terms(base) == TERMS[method]
    assert losses.objective_terms(base.replace(bc_steps=10)) == TERMS[method] | BC_TERMS[method]
    ppo_bc = set() if method in ("bc_single", "ppo_bc", "ppo_sp") else {"ppo_bc"}  # the PPO presets: task reward only
    assert losses.objective_terms(base.replace(bc_coef=1.0)) == TERMS[method] | ppo_bc
    assert losses.objective_terms(base.replace(lambda_r=0.0)) == TERMS[method] - {"L_r"}
    assert losses.objective_terms(base) <= set(losses.TERMS)
    table = losses.preset_table_markdown()
    assert f"| `{method}`" in table and len(table.splitlines()) >= len(METHODS) + 2


def _context(method, tiny_cfg, fetchq, expert, **kw):
    expert = jax.tree.map(jax.numpy.asarray, expert)
    cfg = tiny_cfg.replace(method=method, seeds=(1,), bc_steps=1, bc_coef=1.0, **kw)
    ctx = train.make_context(cfg, fetchq)
    ns = train.fit_normalizer(expert)
    norm = {"mean": ns["mean"], "std": ns["std"]}
    state = train.init_state(ctx, norm, np.zeros((int(ns["num_demos"]), cfg.code_dim), np.float32),
                             jax.random.PRNGKey(0))
    exp_b = train.sample_expert(norm, expert, jax.random.PRNGKey(1), 64)
    gen_b = {**exp_b, "prev_obs": exp_b["obs"], "first": np.zeros(64, bool),  # stands in for generated data
             "z": jax.random.uniform(jax.random.PRNGKey(2), (64, cfg.code_dim), minval=-1, maxval=1)}
    return ctx, state, exp_b, gen_b, expert


def _ppo_batch(gen_b, env):
    """A PPO minibatch (with the generated steps' histories, for L_z's co-policy part) standing in for a rollout's."""
    n = gen_b["obs"].shape[0]
    return {"obs": gen_b["obs"], "z": gen_b["z"], "action": np.zeros((n, env.action_size), np.float32),
            "logp": np.zeros(n, np.float32), "adv": np.linspace(-1, 1, n), "ret": np.zeros(n, np.float32),
            "hist": gen_b["hist"], "prev_obs": gen_b["prev_obs"], "first": gen_b["first"]}


def _norm(tree):
    return max(float(np.abs(x).max()) for x in jax.tree.leaves(tree))


@pytest.mark.parametrize("method", ["cogail", "ma_infogail", "diayn", "ma_gail", "bc_gail"])
def test_only_la_lets_expert_actions_reach_psi(method, tiny_cfg, fetchq, expert):
    """Exactly the presets with L_a train psi on expert actions: the gradient w.r.t. psi of the expert-data
    aux terms (L_a, L_r), of BC pre-training and of PPO+BC is exactly zero without L_a (psi's code enters
    through stop_gradient), nonzero for Co-GAIL's aux and BC objectives; psi learns from generated data (L_z,
    DIAYN's q fit) where the preset has a code."""
    from cogail_jax.algo import losses

    ctx, state, exp_b, gen_b, expert = _context(method, tiny_cfg, fetchq, expert)
    cfg, nets, params = ctx.cfg, ctx.nets, state.params
    psi_grad = lambda f: _norm(jax.grad(lambda p: f({**params, "psi": p}))(params["psi"]))  # noqa: E731
    aux_exp = psi_grad(lambda p: losses.aux_objective(cfg, nets, p, None, exp_b)[0])
    bc = psi_grad(lambda p: losses.bc_objective(cfg, nets, p, exp_b))
    ppo_batch = _ppo_batch(gen_b, fetchq)
    ppo = psi_grad(lambda p: losses.ppo_objective(cfg, nets, p, ppo_batch, exp_b)[0])
    assert ppo == 0.0
    if method == "cogail":
        assert aux_exp > 0 and bc > 0
    else:
        assert aux_exp == 0.0 and bc == 0.0, (aux_exp, bc)
    aux_gen = psi_grad(lambda p: losses.aux_objective(cfg, nets, p, gen_b, None)[0])
    assert (aux_gen > 0) == (method in ("cogail", "ma_infogail", "diayn")), aux_gen
    # BC pre-training leaves psi where it was unless the preset has L_a
    after, _ = train.bc_pretrain(ctx, state, expert)
    moved = _norm(jax.tree.map(lambda a, b: a - b, after.params["psi"], params["psi"]))
    assert (moved > 0) == (method == "cogail"), moved


def test_bc_gail_trains_the_human_by_bc_only(tiny_cfg, fetchq, expert):
    """BC-GAIL: BC pre-training fits both agents (the robot as in every preset); afterwards neither PPO (its
    BC term included) nor the aux step (L_r) moves the human tower or the human's log std."""
    from cogail_jax.algo import losses

    ctx, state, exp_b, gen_b, expert = _context("bc_gail", tiny_cfg, fetchq, expert)
    cfg, nets, params = ctx.cfg, ctx.nets, state.params
    after, _ = train.bc_pretrain(ctx, state, expert)
    for tower in ("human", "robot"):
        assert _norm(jax.tree.map(lambda a, b: a - b, after.params["actor"]["params"][tower],
                                  params["actor"]["params"][tower])) > 0, tower
    batch = {"obs": exp_b["obs"], "z": np.zeros((64, cfg.code_dim), np.float32),
             "action": np.concatenate([exp_b["ah"], exp_b["ar"]], -1), "logp": np.zeros(64, np.float32),
             "adv": np.linspace(-1, 1, 64), "ret": np.zeros(64, np.float32)}
    g, _ = train.ppo_grad(ctx, params, batch, exp_b, True)
    assert _norm(g["actor"]["params"]["human"]) == 0.0 and _norm(g["actor"]["params"]["robot"]) > 0
    log_std = np.asarray(g["actor"]["params"]["log_std"])
    assert np.all(log_std[: fetchq.human_action_size] == 0) and np.any(log_std[fetchq.human_action_size:] != 0)
    aux = jax.grad(lambda a: losses.aux_objective(cfg, nets, {**params, "actor": a}, gen_b, exp_b)[0])(params["actor"])
    assert _norm(aux["params"]["human"]) == 0.0 and _norm(aux["params"]["robot"]) > 0


@pytest.mark.parametrize("decay", [False, True])
def test_aux_and_disc_learning_rates_follow_the_switch(decay, tiny_cfg):
    """aux_lr_decay: the aux and discriminator steps shrink to nothing by the run's end; off: they stay."""
    import optax

    cfg = tiny_cfg.replace(aux_lr_decay=decay)
    _, aux, disc = train.make_optimizers(cfg)
    n = cfg.num_updates * cfg.inner_updates
    p = {"w": np.ones(3, np.float32)}
    g = {"w": np.ones(3, np.float32)}
    for tx in (aux, disc):
        s = tx.init(p)
        first, s = tx.update(g, s, p)
        for _ in range(n - 1):
            _, s = tx.update(g, s, p)
        after, _ = tx.update(g, s, p)  # the step after the run's last one
        ratio = float(np.abs(after["w"]).max() / np.abs(first["w"]).max())
        assert (ratio < 1e-6) if decay else (ratio > 0.9), ratio


@pytest.mark.parametrize("method", ["ma_infogail", "cogail"])
def test_lz_moves_the_co_policy_in_the_ppo_step_without_la(method, tiny_cfg, fetchq, expert):
    """Without L_a (MA-InfoGAIL) the aux step's L_z trains psi only, and the co-policy minimises lambda_z x L_z
    inside the PPO step, psi held fixed (InfoGAIL's joint policy objective); Co-GAIL keeps both parts in the aux
    step beside L_a. Regression: with L_z's co-policy part in the aux step, MA-InfoGAIL's human output weights
    got gradient from L_z alone there, so Adam moved them at the full aux learning rate whatever lambda_z was,
    and the human left its demonstrated behaviour: interpolation 0 % at every checkpoint on GPU."""
    from cogail_jax.algo import losses

    ctx, state, exp_b, gen_b, _ = _context(method, tiny_cfg, fetchq, expert)
    cfg, nets, params = ctx.cfg, ctx.nets, state.params
    in_ppo = method == "ma_infogail"
    assert losses.lz_in_ppo(cfg) == in_ppo
    grad = lambda c, f, k: jax.grad(lambda x: f(c, {**params, k: x}))(params[k])  # noqa: E731
    aux_gen = lambda c, p: losses.aux_objective(c, nets, p, gen_b, None)[0]  # noqa: E731
    assert (_norm(grad(cfg, aux_gen, "actor")) == 0.0) == in_ppo and _norm(grad(cfg, aux_gen, "psi")) > 0
    batch = _ppo_batch(gen_b, fetchq)
    _, m = losses.ppo_objective(cfg, nets, params, batch, exp_b)
    assert ("ppo_lz" in m) == in_ppo
    if in_ppo:
        assert float(m["ppo_lz"]) > 0
        lz_only = lambda c, p: (losses.ppo_objective(c, nets, p, batch, exp_b)[0]  # noqa: E731
                                - losses.ppo_objective(c.replace(lambda_z=0.0), nets, p, batch, exp_b)[0])
        assert _norm(grad(cfg, lz_only, "actor")) > 0 and _norm(grad(cfg, lz_only, "psi")) == 0.0


@pytest.mark.parametrize("method", ["ma_infogail", "diayn", "cogail"])
def test_expert_terms_act_on_codes_the_co_policy_knows(method, tiny_cfg, fetchq, expert):
    """Without L_a psi never learns the demonstrations' codes, so L_r and PPO+BC act on each demonstration's
    own code from BC pre-training (in the prior's square, the codes the co-policy was cloned on), not on psi's
    code of the expert history; Co-GAIL keeps psi's code (its L_a teaches psi the demonstrations' codes).
    Regression: MA-InfoGAIL's robot was fitted to expert actions on psi codes it never sees at interpolation."""
    from cogail_jax.algo import losses

    ctx, state, exp_b, gen_b, expert = _context(method, tiny_cfg, fetchq, expert)
    cfg, nets, params = ctx.cfg, ctx.nets, state.params
    params = train.bc_pretrain(ctx, state, expert)[0].params
    z_demo = np.tanh(np.asarray(params["codes"]))[np.asarray(exp_b["demo"])]
    assert np.all(np.abs(z_demo) < 1)
    z_psi = nets.psi(params["psi"], np.concatenate([exp_b["hist"], exp_b["prev_ah"]], -1))
    _, lr_demo = losses.behaviour_loss(nets.psi, nets.actor, params, exp_b, nets.human_size, z=z_demo)
    _, lr_psi = losses.behaviour_loss(nets.psi, nets.actor, params, exp_b, nets.human_size, z=z_psi)
    _, m = losses.aux_objective(cfg, nets, params, None, exp_b)
    want = lr_psi if method == "cogail" else lr_demo
    assert np.isclose(float(m["loss_r"]), float(want), rtol=1e-5), (float(m["loss_r"]), float(lr_demo), float(lr_psi))
    assert not np.isclose(float(lr_demo), float(lr_psi), rtol=1e-3)
