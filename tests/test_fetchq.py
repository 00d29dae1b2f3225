import jax
import jax.numpy as jnp
import numpy as np
from cogail_envs import get_task
import pytest

from cogail_jax.data import generate as demos

TEAM = get_task("fetchq").team


@pytest.fixture(scope="module")
def episodes(fetchq):
    return demos.generate(fetchq, 1000, seed=0)


def test_reset_step_shapes(fetchq):
    s = fetchq.reset(jax.random.PRNGKey(0))
    assert s.obs.shape == (fetchq.observation_size,)
    assert fetchq.action_size == 4
    s2 = jax.jit(fetchq.step)(s, jnp.ones(4) * 5.0)  # actions are clipped to [-1, 1]
    moved = np.abs(np.asarray(s2.pipeline_state["pos"] - s.pipeline_state["pos"]))
    assert moved.max() <= 0.23 + 1e-6 and moved.max() > 0.1
    assert set(s2.metrics) >= {"success", "human_room", "robot_room", "first"}
    assert int(s2.info["t"]) == 1


def test_step_keeps_the_state_types_of_reset(fetchq):
    """Same tree, dtypes and weak types after a step as after reset: a jitted consumer (brax's evaluator, a
    user's scan) fed both would otherwise compile twice (human_room / robot_room came out weak-typed)."""
    s = jax.jit(fetchq.reset)(jax.random.PRNGKey(0))
    s2 = jax.jit(fetchq.step)(s, jnp.zeros(fetchq.action_size))
    sig = lambda st: jax.tree.map(lambda a: (a.shape, a.dtype, a.weak_type), st)  # noqa: E731
    assert jax.tree.structure(s) == jax.tree.structure(s2) and sig(s) == sig(s2)


def test_doors_block_until_button_held(fetchq):
    # an agent walking straight into the left room from its door is blocked while nobody holds the button
    s = fetchq.reset_from(jnp.array([3.0, 6.75, 4.0, 1.0]))
    step = jax.jit(fetchq.step)
    for _ in range(10):
        s = step(s, jnp.array([-1.0, 0.0, 0.0, 0.0]))
    assert float(s.pipeline_state["pos"][0, 0]) >= 2.5
    # robot stands on the left button: the door opens and the human gets in
    s = fetchq.reset_from(jnp.array([3.0, 6.75, 0.9, 3.8]))
    for _ in range(10):
        s = step(s, jnp.array([-1.0, 0.0, 0.0, 0.0]))
    assert float(s.pipeline_state["pos"][0, 0]) < 2.5


def test_scripted_team_succeeds_and_is_classified(episodes):
    assert episodes.success.mean() == 1.0
    assert np.array_equal(episodes.strategy, episodes.executed)
    assert set(np.unique(episodes.strategy)) == {1, 2, 3, 4}
    assert 120 < episodes.length.mean() < 175  # ~145 steps like the paper's demonstrations


def test_robot_ignoring_human_fails(fetchq, episodes):
    ignore = demos.generate(fetchq, 400, seed=3, robot_strategy=1)
    assert ignore.success.mean() < 0.5 * episodes.success.mean()
    # it only succeeds when the human happened to follow strategy 1
    assert np.all(ignore.strategy[ignore.success > 0] == 1)


def test_robot_watches_the_human(fetchq):
    """The robot does not know the strategy at step 0: it stands still (exactly) until the human's heading
    has shown it, and then follows the human's strategy."""
    n, steps = 16, 40

    def roll(key):
        k_init, k_team, k_run = jax.random.split(key, 3)
        state = fetchq.reset_from(fetchq.sample_init(k_init))
        ts, strategy = TEAM.init(fetchq, k_team, fetchq.uniform_mix())

        def body(carry, k):
            state, ts = carry
            ts, a = TEAM.act(fetchq, ts, state, k)
            return (fetchq.step(state, a), ts), (a[2:], ts.strategy[1])

        _, (a_robot, known) = jax.lax.scan(body, (state, ts), jax.random.split(k_run, steps))
        return ts.strategy[1], strategy, a_robot, known

    keys = jax.random.split(jax.random.PRNGKey(0), n)
    at_reset, strategy, a_robot, known = map(np.asarray, jax.jit(jax.vmap(roll))(keys))
    assert np.all(at_reset == 0) and np.all(known[:, 0] == 0)  # the human has not moved yet at step 0
    assert np.all(a_robot[known == 0] == 0) and np.all(np.abs(a_robot[known != 0]).sum(-1) > 0)
    assert np.median(np.argmax(known > 0, axis=1)) >= 3  # it takes the human a few steps to show its heading
    assert np.mean(known[:, -1] == strategy) >= 15 / 16


@pytest.mark.parametrize("name", ["D1", "D2"])
def test_mixture_proportions(fetchq, name):
    w = demos.resolve_mix(fetchq, name)
    n = 6000
    _, strat = jax.vmap(lambda k, m: TEAM.init(fetchq, k, m), in_axes=(0, None))(jax.random.split(jax.random.PRNGKey(1), n), w)
    freq = np.bincount(np.asarray(strat), minlength=5)[1:] / n
    expected = np.asarray(get_task("fetchq").mixtures[name])
    assert np.all(np.abs(freq - expected) < 4 * np.sqrt(expected * (1 - expected) / n))


def test_reset_does_not_reveal_strategy(fetchq):
    # the initial state comes from sample_init alone: team strategies do not enter reset
    eps = demos.generate(fetchq, 400, seed=5)
    first = eps.obs[:, 0]
    for k in (1, 2, 3, 4):
        m = first[eps.strategy == k].mean(0)
        assert np.allclose(m[:4], first.mean(0)[:4], atol=0.03)



