"""The task's one generator program: every set (default splits, varied humans, their validation) is made by the
same compiled program, whatever the counts, and an episode depends on its key alone (not on the chunk or the
other sets it shares a call with)."""
import jax
import numpy as np

from cogail_jax.data import generate, varied


def _same(a: dict, b: dict):
    for k in a:
        if isinstance(a[k], dict):
            _same(a[k], b[k])
        else:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_one_compiled_program_makes_every_set():
    import cogail_envs

    fetchq = cogail_envs.make_env("fetchq")  # its own env object: the programs kept on the shared one are counted here
    w = generate.resolve_mix(fetchq, "uniform")
    f = generate.generator_fn(fetchq)
    keys = jax.random.split(jax.random.PRNGKey(5), 11)
    whole = generate.run_episodes(fetchq, keys, w)  # two chunks of 8, the second padded
    # three requests in the same calls: plain, a varied human that is validated, a fixed robot
    a, b, c = generate.run_requests(fetchq, [generate.Request(keys[:3], w),
                                             generate.Request(keys[3:], w, variation=2, validate=True),
                                             generate.Request(keys[:2], w, robot_strategy=1)])
    _same(a, jax.tree.map(lambda x: x[:3], whole))  # the same episodes, whatever chunk they were made in
    assert not np.array_equal(b["actions_human"], whole["actions_human"][3:])  # the variation acts
    np.testing.assert_array_equal(b["init"], whole["init"][3:])  # ... on the same starts
    # the validation (the same program, stepping the recorded actions) agrees with the separate replay program
    rep = varied.validate_episodes(fetchq, b["init"], b["actions_human"], b["actions_robot"])
    np.testing.assert_array_equal(b["valid_success"], rep["success"])
    np.testing.assert_array_equal(b["valid_executed"], rep["executed"])
    assert "valid_success" not in a
    assert np.all(c["strategy"] >= 1) and np.array_equal(c["init"], whole["init"][:2])
    # a robot kept to strategy 1 whatever its human does: these two humans go for other strategies, which their
    # own teams carry out and which fail with it
    assert 1 not in whole["strategy"][:2] and np.array_equal(whole["executed"][:2], whole["strategy"][:2])
    assert np.all(c["executed"] == 0)
    # sets of other sizes (and the varied-human sets) reuse the one compilation
    generate.generate(fetchq, 3, seed=11)
    varied.generate_varied(fetchq, "slow", 2, seed=99)
    assert f._cache_size() == 1


def test_generated_sets_are_deterministic(fetchq):
    one = generate.generate(fetchq, 5, seed=21)
    two = generate.generate(fetchq, 5, seed=21)
    _same(one._asdict(), two._asdict())
    eps, stats = varied.generate_varied(fetchq, "pauses", 3, seed=77)
    again, _ = varied.generate_varied(fetchq, "pauses", 3, seed=77)
    _same(eps._asdict(), again._asdict())
    assert stats["kept"] == 3 and stats["attempted"] >= 3 and list(eps.gen_index) == sorted(eps.gen_index)
