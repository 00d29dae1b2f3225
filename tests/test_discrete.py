"""Discrete actions: the categorical head's distribution functions, and every preset training on a discrete task
(tests/discrete_task.py) with its own terms, its losses being log-likelihoods."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import discrete_task  # noqa: F401  (registers the task line_meet)
from cogail_jax.algo import actions, losses, train
from cogail_jax.algo.config import METHODS
from cogail_jax.data import generate as demos
from cogail_jax.data import io as data
from test_presets import EXPECT

SPEC = actions.ActionSpec(3, 2, True, False)  # a discrete human, a continuous robot


def test_log_prob_entropy_mode_of_a_mixed_action():
    logits = jnp.log(jnp.array([0.5, 0.3, 0.2]))
    mean = jnp.concatenate([logits, jnp.array([0.1, -0.4])])
    log_std = jnp.full((5,), -1.0)
    a = jnp.array([0.0, 1.0, 0.0, 0.3, -0.2])
    want = np.log(0.3) + float(losses.gaussian_log_prob(mean[3:], log_std[3:], a[3:]))
    assert np.isclose(float(actions.log_prob(SPEC, mean, log_std, a)), want, atol=1e-5)
    h = -(0.5 * np.log(0.5) + 0.3 * np.log(0.3) + 0.2 * np.log(0.2))
    assert np.isclose(float(actions.entropy(SPEC, mean, log_std)), h + float(losses.gaussian_entropy(log_std[3:])),
                      atol=1e-5)
    np.testing.assert_allclose(np.asarray(actions.mode(SPEC, mean)), [1, 0, 0, 0.1, -0.4], atol=1e-6)
    # the cross-entropy of an expert choice, and the squared error of a continuous one
    assert np.isclose(float(actions.agent_error(True, logits, jnp.array([0.0, 0.0, 1.0]))), -np.log(0.2), atol=1e-5)
    assert np.isclose(float(actions.agent_error(False, mean[3:], jnp.zeros(2))), 0.17, atol=1e-6)


def test_sampled_choices_follow_the_categorical():
    mean = jnp.broadcast_to(jnp.concatenate([jnp.log(jnp.array([0.6, 0.3, 0.1])), jnp.zeros(2)]), (4000, 5))
    a, act = actions.sample(SPEC, mean, jnp.full(mean.shape, -1.0), jax.random.PRNGKey(0))
    a, act = np.asarray(a), np.asarray(act)
    assert np.all(a[:, :3].sum(1) == 1) and set(np.unique(a[:, :3])) == {0.0, 1.0}  # one-hot
    np.testing.assert_allclose(a[:, :3].mean(0), [0.6, 0.3, 0.1], atol=0.03)
    assert np.all(np.abs(act[:, 3:]) <= 1) and np.array_equal(a[:, :3], act[:, :3])
    assert a[:, 3:].std() > 0.3  # the Gaussian part is sampled with its std


@pytest.fixture(scope="module")
def line():
    env = discrete_task.TASK.make_env()
    eps = demos.generate(env, 12, seed=0)
    return env, eps


@pytest.fixture(scope="module")
def line_expert(line, tmp_path_factory, tiny_cfg):
    env, eps = line
    path = data.save_demos(tmp_path_factory.mktemp("line") / "train.hdf5", env, eps)
    return path, train.expert_arrays(data.load_demos(path, env), tiny_cfg.history)


def test_demonstrations_hold_one_hot_actions(line):
    env, eps = line
    assert eps.success.all() and set(eps.executed) == {1, 2}
    for a in (eps.actions_human, eps.actions_robot):
        valid = a[np.arange(a.shape[1])[None] < eps.length[:, None]]
        assert np.all(valid.sum(-1) == 1) and set(np.unique(valid)) == {0.0, 1.0}


@pytest.mark.parametrize("method", METHODS)
def test_preset_trains_on_a_discrete_task(method, line, line_expert, tiny_cfg, monkeypatch):
    env, _ = line
    path, expert = line_expert
    fitted = []  # (discrete?) of every fitting error the trainer traces: all cross-entropies on this task
    agent_error, joint_error = actions.agent_error, actions.joint_error
    monkeypatch.setattr(actions, "agent_error", lambda d, *a: fitted.append(bool(d)) or agent_error(d, *a))
    monkeypatch.setattr(actions, "joint_error", lambda s, *a: fitted.append(not s.continuous) or joint_error(s, *a))
    cfg = tiny_cfg.replace(task="line_meet", method=method, demos=str(path), seeds=(1,), updates_per_call=1,
                           num_envs=4, unroll_length=14, bc_steps=2, entropy_coef=0.01)
    init, chunk, _ = train.make_train_fns(cfg, env, train.fit_normalizer(expert))
    s0 = init(cfg.seeds, expert)
    s1, m = chunk(s0, expert)
    must, must_not = EXPECT[method]
    assert must <= set(m) and not (must_not & set(m)), (method, set(m))
    assert all(np.all(np.isfinite(np.asarray(v))) for v in m.values())
    # L_a / L_r / BC are negative log-likelihoods of the expert's choices: >= 0, at most log(3) from a uniform start
    for k in ("loss_a", "loss_r", "bc_loss"):
        if k in m:
            assert 0 <= float(np.mean(m[k])) < 3 * np.log(3), (k, m[k])
    assert fitted and all(fitted), fitted  # none fitted as a squared error of the logits
    if "entropy" in m:  # two categorical heads of 3 choices each
        assert 0 < float(np.mean(m["entropy"])) <= 2 * np.log(3) + 1e-5
    if method != "bc_single":
        # the rollout's executed human action, psi's previous-action input, is one-hot
        prev = np.asarray(s1.prev_ah)
        assert prev.shape[-1] == 3 and np.all((prev.sum(-1) == 1) | (prev.sum(-1) == 0))
