import json
import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cogail_jax.runtime import checkpoint as ckpt
from cogail_jax.data import io as data
from cogail_jax.runtime import tblog
from cogail_jax.runtime import timing
from cogail_jax.algo import train
from cogail_jax.apps import eval_runner, runs, train_loop
from cogail_jax.algo.config import ConfigError


@pytest.fixture(scope="module")
def setup(tiny_cfg, fetchq):
    demos = data.load_demos(tiny_cfg.demos, fetchq)
    expert = train.expert_arrays(demos, tiny_cfg.history)
    init, chunk, nets = train.make_train_fns(tiny_cfg, fetchq, train.fit_normalizer(expert))
    return init, chunk, expert


@pytest.fixture(scope="module")
def trained(setup, tiny_cfg):
    """Run 8 calls (16 updates) of the shared jitted chunk; keep the per-call metrics."""
    init, chunk, expert = setup
    state = init(tiny_cfg.seeds, expert)
    history = []
    for _ in range(8):
        state, m = chunk(state, expert)
        history.append(jax.device_get(m))
    return state, history


def test_metrics_shapes_and_values(trained, tiny_cfg):
    state, history = trained
    m = history[0]
    S, U = len(tiny_cfg.seeds), tiny_cfg.updates_per_call
    for k in ("disc_loss", "loss_z", "loss_a", "policy_loss", "value_loss", "episode_success", "nonfinite"):
        assert m[k].shape == (U, S), k
        assert np.all(np.isfinite(m[k])), k
    assert np.all(m["nonfinite"] == 0)
    assert np.asarray(state.update).tolist() == [16, 16]
    assert state.z.shape == (S, tiny_cfg.num_envs, 2)
    assert np.all(np.abs(np.asarray(state.z)) <= 1.0)


def test_no_recompilation_after_first_call(setup, trained, tiny_cfg, caplog):
    init, chunk, expert = setup
    state, _ = trained
    with caplog.at_level(logging.WARNING), jax.log_compiles(True):
        state, m = chunk(state, expert)
        jax.block_until_ready(m)
    assert not [r for r in caplog.records if "Compiling" in r.getMessage() and "chunk" in r.getMessage()]
    assert chunk._cache_size() == 1


def test_programs_are_loaded_not_traced_again(setup, trained, tiny_cfg, fetchq):
    """The same config's functions made again (as by a later run) load the kept initial-state and chunk programs
    (``programs.stored``): nothing is traced, the update is bitwise the traced program's, and ``init.abstract``
    gives the state's shapes."""
    init, chunk, expert = setup
    init2, chunk2, _ = train.make_train_fns(tiny_cfg, fetchq, train.fit_normalizer(expert))
    shapes = init2.abstract(tiny_cfg.seeds, expert)
    a, ma = chunk(init(tiny_cfg.seeds, expert), expert)
    b, mb = chunk2(init2(tiny_cfg.seeds, expert), expert)
    assert chunk2._plain.traces == 0
    for x, y in zip(jax.tree.leaves((a, ma)), jax.tree.leaves((b, mb))):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert jax.tree.structure(shapes) == jax.tree.structure(a)
    assert [s.shape for s in jax.tree.leaves(shapes)] == [x.shape for x in jax.tree.leaves(a)]


def test_a_new_value_of_an_update_hyperparameter_runs_the_kept_program(setup, tiny_cfg, fetchq, monkeypatch):
    """The update's real-valued hyperparameters (config.HYPER: lr, clip_eps, bc_coef, ...) are the training
    program's arguments: another value of them loads the kept program (nothing traced) and trains with that value,
    bitwise as a program traced for it; a term switched on or off (0 or not) is another program."""
    from cogail_jax.runtime import programs

    init, chunk, expert = setup
    cfg = tiny_cfg.replace(lr=tiny_cfg.lr * 3, clip_eps=0.1)
    norm = train.fit_normalizer(expert)
    init2, chunk2, _ = train.make_train_fns(cfg, fetchq, norm)
    a, _ = chunk(init(tiny_cfg.seeds, expert), expert)
    b, mb = chunk2(init2(cfg.seeds, expert), expert)
    assert chunk2._plain.traces == 0 and chunk2._plain.key == chunk._plain.key
    assert not all(np.array_equal(np.asarray(x), np.asarray(y))  # the new values are used
                   for x, y in zip(jax.tree.leaves(a.params["actor"]), jax.tree.leaves(b.params["actor"])))
    monkeypatch.setattr(programs, "program_dir", lambda: None)  # traced for cfg, nothing kept or loaded
    init3, chunk3, _ = train.make_train_fns(cfg, fetchq, norm)
    c, mc = chunk3(init3(cfg.seeds, expert), expert)
    assert chunk3._plain.traces == 1
    for x, y in zip(jax.tree.leaves((b, mb)), jax.tree.leaves((c, mc))):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    switched = train.make_train_fns(tiny_cfg.replace(entropy_coef=0.01), fetchq, norm)[1]
    assert switched._plain.key != chunk._plain.key


def test_codes_cycle_through_grid(setup, tiny_cfg):
    init, chunk, expert = setup
    state = init(tiny_cfg.seeds, expert)
    grid = np.asarray(train.code_grid(5))
    z = np.asarray(state.z[0])  # first episodes take grid cells 0..num_envs-1 (+ noise)
    assert np.all(np.abs(z - grid[: tiny_cfg.num_envs]) <= tiny_cfg.code_noise + 1e-6)
    assert int(state.code_counter[0]) == tiny_cfg.num_envs


def test_learning_reduces_behaviour_loss(trained):
    _, history = trained
    for key, factor in (("loss_a", 0.85), ("loss_r", 0.85)):
        first = history[0][key].mean(0)
        last = history[-1][key].mean(0)
        assert np.all(last < factor * first), (key, first, last)


def test_discriminator_learns_to_tell_policy_from_expert(setup, tiny_cfg, fetchq):
    """disc_step alone, on expert steps against the same states with a random policy's actions: from chance to
    better than chance. (Inside a 16-update run the policy moves too, so accuracy there is no clean signal.)"""
    init, _, expert = setup
    state = jax.tree.map(lambda x: x[0], init(tiny_cfg.seeds[:1], expert))
    ctx = train.make_context(tiny_cfg, fetchq)
    ex = jax.tree.map(jax.numpy.asarray, expert)

    def body(carry, key):
        disc, opt = carry
        k_e, k_a, k_gp = jax.random.split(key, 3)
        exp_b = train.sample_expert(state.norm, ex, k_e, 128)
        gen_b = {"obs": exp_b["obs"], "act": jax.random.uniform(k_a, (128, fetchq.action_size), minval=-1, maxval=1)}
        disc, opt, m = train.disc_step(ctx, {**state.params, "disc": disc}, opt, gen_b, exp_b, k_gp)
        return (disc, opt), (m["disc_acc_expert"] + m["disc_acc_policy"]) / 2

    run = jax.jit(lambda carry, keys: jax.lax.scan(body, carry, keys))
    _, acc = run((state.params["disc"], state.disc_opt), jax.random.split(jax.random.PRNGKey(0), 400))
    acc = np.asarray(acc)
    # the gradient penalty keeps the discriminator smooth, so it learns slowly: chance at first, clearly above
    # it after 400 steps (a sign error or a broken input would keep it at or below chance)
    assert acc[:50].mean() < 0.52 and acc[-50:].mean() > 0.56, (acc[:50].mean(), acc[-50:].mean())


def test_one_seed_with_scan_unroll_equals_its_seed_of_the_vmapped_run(setup, tiny_cfg, fetchq):
    """Seed 5 run alone equals seed 5 of the seed-vmapped two-seed run, and scan_unroll (the rollout's, GAE's and
    the return normaliser's scans unrolled) changes the program, not the update: the lone seed's run unrolls by 3,
    which does not divide the unroll (16), so the scans' remainder steps are covered too (one program for both)."""
    from cogail_jax.algo.config import ConfigError

    init, chunk, expert = setup
    both, m_both = chunk(init((3, 5), expert), expert)
    cfg = tiny_cfg.replace(seeds=(5,), scan_unroll=3)
    init1, chunk1, _ = train.make_train_fns(cfg, fetchq, train.fit_normalizer(expert))
    one, m_one = chunk1(init1((5,), expert), expert)
    a = jax.tree.leaves(jax.tree.map(lambda x: np.asarray(x[1]), both.params))
    b = jax.tree.leaves(jax.tree.map(lambda x: np.asarray(x[0]), one.params))
    # vmapped matmuls may be fused differently: equal to float32 round-off
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=2e-5, atol=2e-6)
    np.testing.assert_allclose(np.asarray(m_one["approx_kl"])[:, 0], np.asarray(m_both["approx_kl"])[:, 1],
                               rtol=1e-4, atol=1e-7)
    with pytest.raises(ConfigError, match="scan-unroll"):
        tiny_cfg.replace(scan_unroll=0).validate()


def _final_params(run_dir, cfg):
    s = runs.build(cfg, need_heldout=False)
    mgr = ckpt.manager(run_dir)
    st = ckpt.restore(mgr, max(ckpt.steps(mgr)), jax.eval_shape(lambda: s.init(cfg.seeds, s.expert)))
    return max(ckpt.steps(mgr)), jax.tree.leaves(jax.device_get(st.params)), st.params


def test_resume_is_exact(tiny_cfg, tmp_path):
    """A run stopped after 2 updates and resumed ends bitwise where the uninterrupted run ends, the policy average
    (``policy_ema``, on here) included; the finished run's evaluation, speed record and run info."""
    cfg = tiny_cfg.replace(policy_ema=0.5)
    full = train_loop.train_run(cfg, tmp_path / "full", progress=False)
    part = train_loop.train_run(cfg, tmp_path / "part", progress=False, stop_after=2)
    assert ckpt.steps(ckpt.manager(part)) == [2]  # the newest training state; a policy at every checkpoint
    assert ckpt.steps(ckpt.policy_manager(part)) == [2]
    speed_part = timing.read(part)
    with pytest.raises(runs.RunError, match="--resume"):
        train_loop.train_run(cfg, tmp_path / "part", progress=False)
    train_loop.train_run(cfg, tmp_path / "part", resume=True, progress=False)
    speed_resumed = timing.read(part)  # the resumed call's seconds are added to the first call's
    assert speed_resumed["wall"]["train"] > speed_part["wall"]["train"]
    assert speed_resumed["phases"]["demos"] > speed_part["phases"]["demos"]
    assert speed_resumed["phases"]["bc"] == speed_part["phases"]["bc"]  # no BC on resume
    assert speed_part["env_steps_per_s"] is None and speed_resumed["env_steps_per_s"] > 0  # one call: no steady state
    sa, pa, params = _final_params(full, cfg)
    sb, pb, _ = _final_params(part, cfg)
    assert sa == sb == runs.total_updates(cfg)
    assert len(pa) == len(pb) > len(jax.tree.leaves(params["ema"])) > 0  # the average is in the state compared
    for x, y in zip(pa, pb):
        np.testing.assert_array_equal(x, y)  # bitwise
    info = json.loads((full / "run_info.json").read_text())
    assert info["versions"]["jax"] and "devices" in info
    assert json.loads((full / "config.json").read_text())["task"] == "fetchq"

    # eval on the finished run writes the paper's tables
    res = eval_runner.eval_run(full, progress=False)
    for k in ("task", "method", "seeds", "paper_protocol", "last", "per_seed_best", "strategy_distribution"):
        assert k in res
    assert set(res["paper_protocol"]["replay"]) >= {"checkpoint", "mean", "std", "per_seed"}
    assert set(res["per_seed_best"]["replay"]["checkpoint"]) == {"3", "5"}
    assert (full / "results.md").read_text().startswith("# cogail on fetchq")
    assert res["policy_ema"] == 0.5 and "moving average" in (full / "results.md").read_text()  # the policy evaluated
    assert (full / "strategy_distribution.png").exists() and (full / "latent_map.png").exists()
    ts = res["training_success"]  # the co-policy's own episodes from the TensorBoard logs (none ends in so few steps)
    windows = tblog.episode_windows(res["checkpoints"], -(-300 // cfg.unroll_length))  # fetchq: 300 steps
    assert ts["checkpoints"] == windows and all(r is None or 0 <= r <= 1 for r in ts["mean"])
    assert tblog.training_success(part, cfg.seeds, cfg.steps_per_update, windows) == ts
    for seed in cfg.seeds:  # the resumed run's TensorBoard logs hold every update once, as the uninterrupted run's
        tag = ("train/disc_loss",)
        logged = [tblog.read_scalars(r / "tb" / f"seed_{seed}", tag)[tag[0]] for r in (full, part)]
        assert len(logged[0]) == runs.total_updates(cfg) and logged[0] == logged[1], logged

    # RUN/speed.json: every phase of the training and of the evaluation, in seconds
    speed = json.loads((full / "speed.json").read_text())
    assert set(speed["phases"]) == set(timing.PHASES)
    assert all(isinstance(v, float) and v >= 0 for v in [*speed["phases"].values(), speed["total"]])
    assert speed["phases"]["eval"] > 0 and speed["total"] >= sum(speed["phases"].values())
    assert speed["phases"]["start"] > 0  # the run folder and the devices, before the demonstrations
    assert speed["env_steps_per_s"] > 0 and speed["updates"] == runs.total_updates(cfg)
    assert speed["device"] and isinstance(speed["deterministic_ops"], bool) and speed["task"] == "fetchq"
    parts = speed["train_parts"]  # BC and the chunk compiled beside it; the calls after the first, checkpoints apart
    assert parts["bc_run"] > 0 and parts["chunk_compile"] > 0 and parts["compile_wait"] >= 0
    assert speed["compiles"]["chunk"]["count"] == 1  # compiled beside init and BC, for the shapes the calls have
    assert parts["calls"] == runs.total_updates(cfg) // cfg.updates_per_call - 1
    assert parts["median_call"] > 0 and parts["checkpoint_excess"] >= 0 and parts["other_excess"] >= 0


def test_policy_average_is_delivered_and_leaves_training_alone(setup, tiny_cfg, fetchq):
    """``policy_ema``: the moving average of the actor and psi starts at the (BC'd) networks, follows them with its
    decay, is what evaluation reads, and does not change what is trained (its bitwise resume: test_resume_is_exact)."""
    from cogail_jax.algo.config import ConfigError

    init, chunk, expert = setup
    ref, _ = chunk(init(tiny_cfg.seeds, expert), expert)
    assert "ema" not in ref.params  # off: the state (and its checkpoints) as before
    cfg = tiny_cfg.replace(policy_ema=0.5)
    init_e, chunk_e, _ = train.make_train_fns(cfg, fetchq, train.fit_normalizer(expert))
    s0 = init_e(cfg.seeds, expert)
    for k in ("actor", "psi"):
        for x, y in zip(jax.tree.leaves(s0.params["ema"][k]), jax.tree.leaves(s0.params[k])):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    flat = lambda tree: np.concatenate([np.ravel(x) for x in jax.tree.leaves(jax.device_get(tree))])  # noqa: E731
    a0 = flat(s0.params["actor"])  # the chunk donates its input state
    s1, _ = chunk_e(s0, expert)
    trained = {k: v for k, v in s1.params.items() if k != "ema"}
    for x, y in zip(jax.tree.leaves(jax.device_get(trained)), jax.tree.leaves(jax.device_get(ref.params))):
        np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-7)
    a1, e1 = flat(s1.params["actor"]), flat(s1.params["ema"]["actor"])
    assert 0 < np.abs(e1 - a0).max() and 0 < np.abs(e1 - a1).max()  # moved towards the trained actor, not onto it
    assert np.abs(e1 - a1).max() < np.abs(a0 - a1).max()
    np.testing.assert_array_equal(flat(runs.eval_params(s1)["params"]["actor"]), e1)  # evaluation (and play, video) act with the average

    one = {"actor": {"w": np.float32(2.0)}, "psi": {"w": np.float32(4.0)}}  # the update rule itself
    stepped = train.ema_update(cfg, {"actor": {"w": np.float32(0.0)}, "psi": {"w": np.float32(0.0)}, "ema": one})
    assert float(stepped["ema"]["actor"]["w"]) == 1.0 and float(stepped["ema"]["psi"]["w"]) == 2.0
    assert train.policy_params(stepped)["actor"] is stepped["ema"]["actor"]

    # resumed bitwise and named in the report: test_resume_is_exact (which runs with the average on)
    with pytest.raises(ConfigError, match="policy_ema"):
        tiny_cfg.replace(policy_ema=1.0).validate()


def test_bc_pretraining_beats_untrained_policy_and_its_abstract_state_matches(tiny_cfg, fetchq):
    from cogail_jax.eval import rollouts
    from cogail_jax.eval import protocol

    demos = data.load_demos(tiny_cfg.demos, fetchq)
    held = rollouts.heldout_arrays(data.load_demos(tiny_cfg.demos, fetchq, require_init=True))
    held = {k: v for k, v in held.items() if k != "strategy"}
    expert = train.expert_arrays(demos, tiny_cfg.history)
    cfg = tiny_cfg.replace(bc_steps=3000, seeds=(1,))
    init, _, nets = train.make_train_fns(cfg, fetchq, train.fit_normalizer(expert))
    ev = rollouts.make_eval_fn(cfg, fetchq, nets)
    one = lambda t: jax.tree.map(lambda x: x[None], t)  # noqa: E731  (one checkpoint)
    cfg0 = cfg.replace(bc_steps=0)
    init0, _, _ = train.make_train_fns(cfg0, fetchq, train.fit_normalizer(expert))
    s0, s1 = init0((1,), expert), init((1,), expert)
    r0 = jax.device_get(ev(one(s0.params), one(s0.norm), held))["replay_success"].mean()
    r1 = jax.device_get(ev(one(s1.params), one(s1.norm), held))["replay_success"].mean()
    assert r0 == 0.0 and r1 > 0.0, (r0, r1)  # 12 held-out replays: untrained never succeeds
    # ``init.abstract`` with BC pre-training: the shapes of the state ``init`` (BC included) returns, without
    # running it
    got = init.abstract(cfg.seeds, expert)
    assert jax.tree.structure(got) == jax.tree.structure(s1)
    assert [(x.shape, x.dtype) for x in jax.tree.leaves(got)] == [(x.shape, x.dtype) for x in jax.tree.leaves(s1)]


def test_normaliser_std_floor(tiny_cfg, fetchq):
    from cogail_jax.algo.config import ConfigError

    expert = train.expert_arrays(data.load_demos(tiny_cfg.demos, fetchq), tiny_cfg.history)
    lo, hi = train.fit_normalizer(expert), train.fit_normalizer(expert, 0.5)
    assert lo["std"].min() >= 1e-2 and hi["std"].min() >= 0.5 and np.all(hi["std"] >= lo["std"])
    assert np.allclose(hi["mean"], lo["mean"]) and hi["num_demos"] == 12
    with pytest.raises(ConfigError, match="obs_std_floor"):
        tiny_cfg.replace(obs_std_floor=0.0).validate()


def test_pca_code_init_groups_demos_by_strategy(tiny_cfg, fetchq, setup):
    """The per-demonstration codes start from the demonstrations' principal components: demos that behave alike start with nearby codes (the nearest other demo's code is
    mostly one of the same strategy; a random layout gets ~1/4), each axis is spread evenly over
    (-0.9, 0.9), and the trainer's initial codes are those (plus a little noise)."""
    demos = data.load_demos(tiny_cfg.demos, fetchq)
    ns = train.fit_normalizer(train.expert_arrays(demos, tiny_cfg.history))
    c = train.demo_code_init(ns["features"], 2)
    st = np.asarray(demos.strategy)
    assert c.shape == (12, 2) and len(set(st.tolist())) >= 3
    d = ((c[:, None] - c[None]) ** 2).sum(-1)
    np.fill_diagonal(d, np.inf)
    assert (st[d.argmin(1)] == st).mean() >= 0.75
    for k in range(2):
        np.testing.assert_allclose(np.sort(c[:, k]), 0.9 * (2 * (np.arange(12) + 0.5) / 12 - 1), atol=1e-6)
    init, _, expert = setup
    state = init(tiny_cfg.seeds, expert)
    codes = np.tanh(np.asarray(state.params["codes"]))  # (seeds, demos, 2)
    assert codes.shape == (2, 12, 2) and np.abs(codes - c[None]).max() < 0.35
    assert np.abs(codes[0] - codes[1]).max() > 1e-4  # the noise differs per seed


@pytest.fixture(scope="module")
def ppo_only(tiny_cfg, fetchq, setup):
    """One seed, the separate L_a / L_r / L_z step off (only PPO moves the actor): the baseline the bc_coef and
    policy_cooldown tests compare against, compiled once."""
    _, _, expert = setup
    cfg = tiny_cfg.replace(seeds=(3,), lambda_r=0.0, lambda_a=0.0, lambda_z=0.0)
    init_c, chunk_c, nets = train.make_train_fns(cfg, fetchq, train.fit_normalizer(expert))
    return cfg, init_c, chunk_c, nets


def _max_diff(x, y):
    return max(float(np.abs(u - v).max()) for u, v in zip(jax.tree.leaves(x), jax.tree.leaves(y)))


def test_ppo_bc_term_pulls_the_co_policy_to_the_demonstrations(ppo_only, fetchq, setup):
    """bc_coef (PPO+BC): each PPO minibatch adds the co-policy's squared error on expert actions, so with a
    large weight the error on expert data ends lower than without it from the same start; the term is
    reported as ``ppo_bc``; a negative weight is refused."""
    from cogail_jax.algo import losses
    from cogail_jax.algo.config import ConfigError

    base, init0, chunk0, nets = ppo_only
    _, _, expert = setup
    norm = train.fit_normalizer(expert)
    n = 256
    err = {}
    for coef in (0.0, 20.0):
        if coef:
            init_c, chunk_c, _ = train.make_train_fns(base.replace(bc_coef=coef), fetchq, norm)
        else:
            init_c, chunk_c = init0, chunk0
        state = init_c(base.seeds, expert)
        for _ in range(3):
            state, m = chunk_c(state, expert)
        m = jax.device_get(m)
        assert ("ppo_bc" in m) == (coef > 0)
        if coef:
            assert np.all(np.isfinite(m["ppo_bc"])) and np.all(m["ppo_bc"] > 0)
        # the co-policy's error on expert data with psi's code, measured the same way for both runs
        p = jax.tree.map(lambda x: x[0], state.params)
        nz = lambda x: (x - norm["mean"]) / norm["std"]  # noqa: E731
        b = {"obs": nz(expert["obs"][:n]), "ah": expert["ah"][:n], "ar": expert["ar"][:n],
             "hist": nz(expert["hist"][:n]).reshape(n, -1), "prev_ah": expert["prev_ah"][:n]}
        la, lr = losses.behaviour_loss(nets["psi"].apply, nets["actor"].apply, p, b, fetchq.human_action_size)
        err[coef] = float(la + lr)
    assert err[20.0] < 0.8 * err[0.0], err
    with pytest.raises(ConfigError, match="bc_coef"):
        base.replace(bc_coef=-1.0).validate()


def test_disc_instance_noise_gives_expert_actions_the_policy_noise(tiny_cfg, fetchq, setup):
    """disc_instance_noise: the discriminator's expert actions get the policy's action noise and clip (so the
    noise level alone cannot tell them apart); it changes the discriminator's training, off leaves it as it was."""
    from cogail_jax.algo import losses

    a = np.zeros((20000, 3), np.float32)
    a[:, 2] = 1.0  # a gripper-like dim at its bound
    log_std = np.log(np.array([0.2, 0.05, 0.2], np.float32))
    out = np.asarray(losses.noisy_expert_actions(a, log_std, jax.random.PRNGKey(0)))
    assert np.allclose(out[:, :2].std(0), [0.2, 0.05], rtol=0.05)
    assert np.all(out <= 1.0) and np.all(out >= -1.0)
    assert 0.4 < np.mean(out[:, 2] == 1.0) < 0.6  # clipped like the policy's executed actions
    init, chunk, expert = setup  # off: the module's shared chunk
    off, _ = chunk(init(tiny_cfg.seeds, expert), expert)  # the chunk donates its input: a fresh (equal) start each
    _, chunk_on, _ = train.make_train_fns(tiny_cfg.replace(disc_instance_noise=True), fetchq,
                                          train.fit_normalizer(expert))
    on, _ = chunk_on(init(tiny_cfg.seeds, expert), expert)
    assert _max_diff(jax.device_get(off.params["disc"]), jax.device_get(on.params["disc"])) > 1e-6


def test_policy_cooldown_keeps_ppo_off_the_actor(ppo_only, fetchq, setup):
    """policy_cooldown: during a run's last N updates PPO trains the critic only. With N covering the whole
    run and the separate L_a / L_r / L_z step off, the actor ends where it started; without it, it moves."""
    from cogail_jax.algo.config import ConfigError

    base, init0, chunk0, _ = ppo_only
    _, _, expert = setup
    moved = {}
    for cool in (0, 6):
        assert base.num_updates == 6
        if cool:
            init_c, chunk_c, _ = train.make_train_fns(base.replace(policy_cooldown=cool), fetchq,
                                                      train.fit_normalizer(expert))
        else:
            init_c, chunk_c = init0, chunk0
        state = init_c(base.seeds, expert)
        a0, c0 = jax.device_get((state.params["actor"], state.params["critic"]))
        for _ in range(3):
            state, _ = chunk_c(state, expert)
        a1, c1 = jax.device_get((state.params["actor"], state.params["critic"]))
        moved[cool] = (_max_diff(a0, a1), _max_diff(c0, c1))
    assert moved[6][0] == 0.0 and moved[6][1] > 1e-6
    assert moved[0][0] > 1e-6
    with pytest.raises(ConfigError, match="policy_cooldown"):
        base.replace(policy_cooldown=-1).validate()


def test_gae_bootstraps_time_outs_and_cuts_at_every_episode_end():
    """GAE on a hand-made (T=3, N=2) rollout: env 0 times out after step 1 (bootstrapped with the critic's
    value of its final observation), env 1 fails after step 1 (terminal: no next value); both recursions stop
    there. Treating env 0's time-out as terminal gives another advantage."""
    from cogail_jax.algo import losses

    g, lam = 0.9, 0.8
    r = np.array([[1.0, 0.5], [2.0, -1.0], [0.5, 0.25]], np.float32)
    v = np.array([[0.3, 0.2], [0.7, 0.4], [0.1, 0.6]], np.float32)
    done = np.array([[0, 0], [1, 1], [0, 0]], np.float32)
    trunc = np.array([[0, 0], [1, 0], [0, 0]], np.float32)
    final = np.array([[0, 0], [5.0, 0], [0, 0]], np.float32)  # V(final obs) of the timed-out episode
    last = np.array([0.9, -0.3], np.float32)
    adv, ret = losses.gae(r, v, done, trunc, final, last, g, lam)
    a2 = r[2] + g * last - v[2]
    a1 = np.array([r[1, 0] + g * 5.0 - v[1, 0], r[1, 1] - v[1, 1]])  # time-out: bootstrapped; failure: not
    a0 = r[0] + g * v[1] - v[0] + g * lam * a1
    np.testing.assert_allclose(np.asarray(adv), np.stack([a0, a1, a2]), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(ret), np.stack([a0, a1, a2]) + v, rtol=1e-6)
    adv_t, _ = losses.gae(r, v, done, np.zeros_like(trunc), final, last, g, lam)  # the time-out as terminal
    assert abs(float(adv_t[1, 0]) - (r[1, 0] - v[1, 0])) < 1e-6 and abs(float(adv_t[1, 0] - adv[1, 0])) > 1.0
    np.testing.assert_array_equal(np.asarray(adv_t[:, 1]), np.asarray(adv[:, 1]))


def test_ppo_loss_stays_finite_when_the_policy_moved_many_stds():
    """With a 0.01 std (bc_std's floor) an action the behaviour policy found 211 nats less likely than the current
    one gives a log ratio of 211: exp() overflowed to inf, inf times a negative advantage won the surrogate's min
    and the gradient was NaN (seqmanip runs diverged so). The loss and its gradient stay finite; within the bound
    the surrogate is the textbook clipped one, on both of its branches."""
    from cogail_jax.algo import losses

    def actor(p, obs, z):
        return obs * p["w"], jnp.full(obs.shape, p["log_std"])

    def critic(p, obs, z):
        return obs[:, 0] * 0.0 + p["v"]

    obs, log_std = jnp.ones((4, 3)), jnp.log(jnp.float32(0.01))
    params = {"actor": {"w": jnp.float32(1.0), "log_std": log_std}, "critic": {"v": jnp.float32(0.0)}}
    logp_now = losses.gaussian_log_prob(obs, jnp.full(obs.shape, log_std), obs)  # the action at the current mean
    base = {"obs": obs, "z": jnp.zeros((4, 2)), "action": obs, "adv": jnp.array([1.0, -1.0, 2.0, -2.0]),
            "ret": jnp.zeros(4)}
    far = {**base, "logp": logp_now - 211.0}
    f = lambda p: losses.ppo_loss(actor, critic, p, far, 0.2, 0.5, 0.0)  # noqa: E731
    (total, m), grads = jax.value_and_grad(f, has_aux=True)(params)
    assert np.isfinite(float(total)) and np.isfinite(float(m["approx_kl"]))
    assert all(np.isfinite(np.asarray(g)).all() for g in jax.tree.leaves(grads))
    adv = (base["adv"] - base["adv"].mean()) / (base["adv"].std() + 1e-8)
    for d in (0.1, 0.3, -0.4):  # inside the clip range, past 1 + eps (positive advantages clipped), under 1 - eps
        _, m = losses.ppo_loss(actor, critic, params, {**base, "logp": logp_now - d}, 0.2, 0.5, 0.0)
        r = np.exp(d)
        want = -np.minimum(r * adv, np.clip(r, 0.8, 1.2) * adv).mean()
        np.testing.assert_allclose(float(m["policy_loss"]), float(want), rtol=1e-5)


def test_rollout_records_time_outs_with_the_value_of_the_final_observation(tiny_cfg, setup):
    """A time-out is a truncation: the rollout flags it and records the critic's value of the episode's final
    observation (what the auto-reset replaced), recomputed here by stepping the env that far; other steps
    carry no final value, and a terminal step none either."""
    import cogail_envs

    from cogail_jax.algo import rollout as ro
    from cogail_jax.algo.networks import normalize

    _, _, expert = setup
    env = cogail_envs.make_env("fetchq", max_episode_steps=5)
    cfg = tiny_cfg.replace(seeds=(3,), unroll_length=4)
    ctx = train.make_context(cfg, env)
    norm_stats = train.fit_normalizer(expert)
    norm = {"mean": norm_stats["mean"], "std": norm_stats["std"]}
    state = train.init_state(ctx, norm, np.zeros((12, 2), np.float32), jax.random.PRNGKey(0))
    run = jax.jit(lambda c, k: ro.rollout(cfg, env, ctx.nets.actor, ctx.nets.critic, state.params, norm, c, k))
    c1, tr1, _ = run(state.carry, jax.random.PRNGKey(1))  # steps 1..4 of the first episodes: no time-out yet
    assert float(tr1["truncation"].sum()) == 0 and float(np.abs(tr1["final_value"]).max()) == 0
    c2, tr2, last = run(c1, jax.random.PRNGKey(2))  # the first step of this unroll hits the 5-step limit
    np.testing.assert_array_equal(np.asarray(tr2["truncation"][0]), 1.0)
    np.testing.assert_array_equal(np.asarray(tr2["done"][0]), 1.0)
    assert float(tr2["truncation"][1:].sum()) == 0 and float(np.abs(tr2["final_value"][1:]).max()) == 0
    final = jax.vmap(env.step)(c1.env_state, tr2["act"][0])  # the episodes' final states, before the reset
    assert np.all(np.asarray(final.info["truncation"]) == 1.0)
    want = ctx.nets.critic(state.params["critic"], normalize(norm, final.obs), tr2["z"][0])
    np.testing.assert_allclose(np.asarray(tr2["final_value"][0]), np.asarray(want), rtol=1e-5, atol=1e-6)
    # the next step's value is that of the fresh episode, not of the final observation
    assert float(np.abs(np.asarray(tr2["value"][1]) - np.asarray(want)).max()) > 1e-4


def test_bc_std_sets_each_action_dims_std_to_the_cloned_residual(tiny_cfg, fetchq):
    """bc_std: after BC pre-training the co-policy's std per action dimension is the RMS of the cloned mean's residual on
    the demonstrations (measured here on every expert step, independently), within [0.01, exp(init_log_std)]; the
    moving average starts from it; without bc_std the std stays at init_log_std."""
    demos = data.load_demos(tiny_cfg.demos, fetchq)
    expert = train.expert_arrays(demos, tiny_cfg.history)
    norm = train.fit_normalizer(expert)
    cfg = tiny_cfg.replace(bc_steps=300, seeds=(1,), init_log_std=0.0, bc_std=True, policy_ema=0.9)
    init, _, nets = train.make_train_fns(cfg, fetchq, norm)
    p = jax.tree.map(lambda x: x[0], init((1,), expert).params)
    log_std = np.asarray(p["actor"]["params"]["log_std"])
    obs = (expert["obs"] - norm["mean"]) / norm["std"]
    z = np.tanh(np.asarray(p["codes"]))[np.asarray(expert["demo"])]
    mean, _ = nets["actor"].apply(p["actor"], obs, z)
    rms = np.sqrt(np.mean((np.asarray(mean) - np.concatenate([expert["ah"], expert["ar"]], -1)) ** 2, 0))
    want = np.clip(rms, 0.01, 1.0)
    np.testing.assert_allclose(np.exp(log_std), want, rtol=0.1)
    assert np.ptp(log_std) > 0.05, log_std  # one std per dimension, not one for all
    assert np.all(log_std < 0.0), log_std  # BC fits the demonstrations better than std 1
    np.testing.assert_array_equal(p["ema"]["actor"]["params"]["log_std"], log_std)
    init0, _, _ = train.make_train_fns(cfg.replace(bc_std=False), fetchq, norm)
    p0 = init0((1,), expert).params
    np.testing.assert_array_equal(np.asarray(p0["actor"]["params"]["log_std"]), 0.0)
    with pytest.raises(ConfigError, match="bc_steps"):
        cfg.replace(bc_steps=0).validate()


def test_motion_reads_the_change_since_the_last_step(tiny_cfg, fetchq):
    """``motion``: the normaliser holds the demonstrations' per-step change (none across two demonstrations), the
    actor reads it beside the observation (nothing at an episode's first step, whose history repeats it), and the
    replay protocol's robot acts on it; without ``motion`` the input is the observation alone."""
    from cogail_jax.algo import networks
    from cogail_jax.eval import rollouts

    expert = train.expert_arrays(data.load_demos(tiny_cfg.demos, fetchq), tiny_cfg.history)
    norm = train.fit_normalizer(expert, motion=True)
    n = int(train.expert_steps(expert))
    o, d = expert["obs"][:n], expert["demo"][:n]
    same = d[1:] == d[:-1]
    change = np.concatenate([np.zeros_like(o[:1]), np.where(same[:, None], o[1:] - o[:-1], 0.0)])
    np.testing.assert_allclose(norm["motion_std"], np.maximum(change.std(0), train.MOTION_STD_FLOOR), rtol=1e-5)
    assert np.any(o[1:][~same] != o[:-1][~same])  # the demonstrations' boundaries would have counted
    assert "motion_std" not in train.fit_normalizer(expert)
    D = fetchq.observation_size
    hist = jnp.asarray(expert["hist"][:n])
    x = networks.policy_input(norm, hist)
    assert x.shape == (n, 2 * D) and networks.policy_input({"mean": norm["mean"], "std": norm["std"]}, hist).shape == (n, D)
    change = (expert["hist"][:n, -1] - expert["hist"][:n, -2]) / norm["motion_std"]
    assert np.abs(change).max() > networks.MOTION_CLIP  # the clip below is exercised
    np.testing.assert_allclose(x[:, D:], np.clip(change, -networks.MOTION_CLIP, networks.MOTION_CLIP), rtol=1e-5)
    assert np.all(np.asarray(x[0, D:]) == 0)  # a first step: the history repeats the first observation
    cfg = tiny_cfg.replace(motion=True, bc_steps=0, seeds=(1,))
    init, _, nets = train.make_train_fns(cfg, fetchq, norm)
    s = init(cfg.seeds, expert)
    params, nrm = jax.tree.map(lambda a: a[0], (s.params, s.norm))
    _, robot_step = rollouts.make_robot_step(cfg, fetchq, nets)
    state = fetchq.reset(jax.random.PRNGKey(0))
    still = jnp.repeat(state.obs[None], cfg.history + 1, 0)
    moved = still.at[-2].add(0.05)
    a_h = jnp.zeros((fetchq.human_action_size,))
    _, _, _, ar_still = robot_step(params, nrm, state, still, a_h, a_h)
    _, _, _, ar_moved = robot_step(params, nrm, state, moved, a_h, a_h)
    assert not np.allclose(ar_still, ar_moved)
    with pytest.raises(ConfigError, match="history"):
        tiny_cfg.replace(motion=True, history=1).validate()


def test_separate_towers_keep_the_robot_s_actions_apart_from_the_human_s(tiny_cfg, fetchq):
    """``separate_towers``: the actor is a human and a robot network; changing the human one moves the human's actions
    and leaves the robot's; Co-GAIL's human tower still learns (only BC-GAIL's and PPO_BC's is frozen). Without it the
    actor is one network whose every weight moves both agents' actions."""
    from cogail_jax.algo import networks

    D, Ah = fetchq.observation_size, fetchq.human_action_size
    obs, z = jnp.ones((3, D)), jnp.zeros((3, tiny_cfg.code_dim))
    for towers in (True, False):
        cfg = tiny_cfg.replace(separate_towers=towers)
        assert cfg.two_towers is towers and not cfg.freeze_human
        actor = networks.make_networks(cfg, fetchq)["actor"]
        p = actor.init(jax.random.PRNGKey(0), obs, z)
        assert ({"human", "robot"} <= set(p["params"])) is towers
        first = "human" if towers else next(k for k in p["params"] if k.startswith("MLP"))
        moved = jax.tree.map(lambda x: x, p)
        moved["params"][first] = jax.tree.map(lambda x: x + 0.1, p["params"][first])
        (m0, _), (m1, _) = actor.apply(p, obs, z), actor.apply(moved, obs, z)
        assert not np.allclose(m0[:, :Ah], m1[:, :Ah])
        assert np.allclose(m0[:, Ah:], m1[:, Ah:]) is towers
    assert tiny_cfg.replace(method="bc_gail").two_towers
