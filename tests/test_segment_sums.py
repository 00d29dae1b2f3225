"""MJX's sums over the kinematic tree, traced as gathers (cogail_envs.segment_sums)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cogail_envs.segment_sums import gathered_segment_sums, static_segment_sum


@pytest.mark.parametrize("ids, n", [(np.array([0, 0, 1, 3, 1, 0]), 4), (np.array([2]), 3), (np.arange(5), 5)])
def test_static_segment_sum_is_jax_segment_sum(ids, n):
    x = jax.random.normal(jax.random.PRNGKey(0), (ids.size, 3, 2))
    want = jax.ops.segment_sum(x, ids, n)
    got = static_segment_sum(x, ids, n)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
    # integers sum exactly; an empty segment is zero
    xi = jnp.arange(ids.size * 2).reshape(ids.size, 2)
    np.testing.assert_array_equal(static_segment_sum(xi, ids, n), jax.ops.segment_sum(xi, ids, n))


def test_members_are_added_in_the_order_of_their_ids():
    # float32: (1 + 1e8) - 1e8 == 0, whereas (1e8 - 1e8) + 1 == 1
    ids = np.zeros(3, np.int64)
    assert float(static_segment_sum(jnp.array([1.0, 1e8, -1e8], jnp.float32), ids, 1)[0]) == 0.0
    assert float(static_segment_sum(jnp.array([1e8, -1e8, 1.0], jnp.float32), ids, 1)[0]) == 1.0


def test_only_static_ids_are_routed_and_jax_is_restored():
    original = jax.ops.segment_sum
    x = jnp.ones((4, 2))
    traced_ids = jnp.array([0, 1, 1, 0])

    def f(x, ids):
        with gathered_segment_sums():
            a = jax.ops.segment_sum(x, np.array([0, 1, 1, 0]), 2)
            b = jax.ops.segment_sum(x, ids, 2)  # traced ids: JAX's own scatter
            c = jax.ops.segment_sum(x, np.array([0, 5, 1, 0]), 2)  # out of range (dropped): JAX's own
        return a, b, c

    jaxpr = jax.make_jaxpr(f)(x, traced_ids)
    assert [e.primitive.name for e in jaxpr.eqns].count("scatter-add") == 2
    a, b, c = jax.jit(f)(x, traced_ids)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(c, [[2.0, 2.0], [1.0, 1.0]])
    assert jax.ops.segment_sum is original


def _segment_sum_scatters(jaxpr) -> int:
    """Scatter-adds traced from ``jax.ops.segment_sum`` in a jaxpr and its sub-jaxprs."""
    n = 0
    for e in jaxpr.eqns:
        if e.primitive.name == "scatter-add" and e.source_info.traceback is not None:
            n += any(f.function_name == "segment_sum" for f in e.source_info.traceback.frames)
        for p in e.params.values():
            for q in p if isinstance(p, (tuple, list)) else [p]:
                inner = getattr(q, "jaxpr", q)
                if hasattr(inner, "eqns"):
                    n += _segment_sum_scatters(inner)
    return n


def test_the_handover_physics_step_sums_over_its_tree_without_scatters():
    import cogail_envs
    from cogail_envs import mjx_common as mc

    env = cogail_envs.make_env("handover")
    state = env.reset(jax.random.PRNGKey(0))
    action = jnp.zeros(env.human_action_size + env.robot_action_size)
    assert _segment_sum_scatters(jax.make_jaxpr(env.step)(state, action).jaxpr) == 0
    # the same MJX step traced without the gathers does scatter (the check sees them)
    d = state.pipeline_state
    with jax.default_matmul_precision("highest"):
        plain = jax.make_jaxpr(lambda d: mc.mjx.step(env.mx, d))(d)
    assert _segment_sum_scatters(plain.jaxpr) > 10


def test_mjx_forward_is_traced_once_for_reset_step_and_later_programs(monkeypatch):
    """``mjx_common.shared_forward``: one trace per matmul precision (reset: the default; step: highest), reused by
    every later program of the process, whatever vmap it is under."""
    import cogail_envs
    from cogail_envs import mjx_common as mc

    env = cogail_envs.make_env("handover")  # a model of its own: a shared forward of its own
    real, traces = mc.mjx.forward, []
    monkeypatch.setattr(mc.mjx, "forward", lambda m, d: traces.append(m) or real(m, d))
    action = jnp.zeros(env.human_action_size + env.robot_action_size)

    def program(key):
        return env.step(env.reset(key), action)

    jax.make_jaxpr(jax.vmap(program))(jax.random.split(jax.random.PRNGKey(0), 2))
    assert len(traces) == 2 and all(m is env.mx for m in traces)
    jax.make_jaxpr(program)(jax.random.PRNGKey(1))  # another program, no vmap: nothing traced again
    assert len(traces) == 2
