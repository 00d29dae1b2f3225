"""Each method preset builds, runs one tiny train_step, and has exactly its distinguishing terms."""
import jax
import numpy as np
import pytest

from cogail_jax import data, train
from cogail_jax.config import METHODS

EXPECT = {
    # method: (keys that must be in the metrics, keys that must not)
    "cogail": ({"disc_loss", "loss_z", "loss_a", "loss_r", "policy_loss"}, {"loss_q", "bc_loss"}),
    "ma_infogail": ({"disc_loss", "loss_z", "policy_loss"}, {"loss_a", "loss_q", "bc_loss"}),
    "ma_gail": ({"disc_loss", "policy_loss"}, {"loss_z", "loss_a", "loss_q", "bc_loss"}),
    "bc_gail": ({"disc_loss", "policy_loss"}, {"loss_z", "loss_a", "loss_q", "bc_loss"}),
    "diayn": ({"disc_loss", "loss_q", "policy_loss"}, {"loss_z", "loss_a", "bc_loss"}),
    "bc_single": ({"bc_loss"}, {"disc_loss", "policy_loss", "loss_z", "loss_a", "episode_success"}),
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
    else:
        assert not disc_same
    if method in ("ma_gail", "bc_gail", "bc_single"):
        assert np.all(np.asarray(after.z) == 0)
    else:
        assert np.any(np.asarray(after.z) != 0)
    if method == "bc_gail":  # the BC-trained human tower is frozen during GAIL
        h0, h1 = before.params["actor"]["params"]["human"], after.params["actor"]["params"]["human"]
        assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(h0), jax.tree.leaves(h1)))
        r0, r1 = before.params["actor"]["params"]["robot"], after.params["actor"]["params"]["robot"]
        assert not all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(r0), jax.tree.leaves(r1)))
