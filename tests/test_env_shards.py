"""Env shards (``env_shards``, algo/shards.py): each seed's envs split into shards whose gradients and metrics are
averaged over the named axis "envs". Two shards side by side on one device (``jax.vmap`` with that axis name) and
one shard per device (2 forced CPU devices, ``shard_map``) train alike; one shard is the unchanged one-device
program (no collectives); the shards really split the batch; the code counter counts every shard's episodes.

Compilations (CPU compile time dominates): the 1-shard and 2-shard chunks in this process, the 2-device chunk in a
subprocess started first, so that it compiles while this process does."""
from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from cogail_jax.algo import shards, train
from cogail_jax.algo.config import ConfigError, TrainConfig

CALLS = 2  # chunk calls of every run (updates_per_call updates each)
# the training arrays' step count became an argument of the program (it was their length): a new digest
# the rollout also carries the task's reward and the update reads task_reward (the field's presets; the fetchq
# state after training is the same to the bit, measured on the CPU): a new digest
# the actor, critic and discriminator read what ``networks.policy_input`` gives (the observation taken from the
# history; ``motion`` off: the same values, fetchq's parameters after BC and three chunk calls the same to the bit,
# measured on the CPU): a new digest
ONE_SHARD_DIGEST = "f54ab80e729fad60b1fd9d42956130009fef2231e2d9b9dfcb3c562ae158f0e5"
# the collective primitives (JAX's names; also the ones a variant such as psum_invariant starts with)
COLLECTIVES = ("all_gather", "psum", "pmax", "pmin", "ppermute", "all_to_all", "axis_index", "reduce_scatter")


@pytest.fixture(scope="module")
def cfgs(tiny_cfg):
    """The 1-shard and the 2-shard config (tiny fetchq, 4 envs: 2 a shard). A time limit of 10 steps ends every
    env's episode within each 16-step rollout, so that the code counter moves."""
    one = tiny_cfg.replace(max_episode_steps=10, env_shards=1).validate()
    return one, one.replace(env_shards=2).validate()


# the 2-device run: one env shard per device; what it found comes back as JSON (placements, compilations) and an
# .npz (parameters, code counters, episode counts)
DEVICE_SCRIPT = textwrap.dedent("""
    import json, os, sys
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2 " + os.environ.get("XLA_FLAGS", "")
    import jax, numpy as np
    from cogail_jax.apps import runs, train_loop
    from cogail_jax.algo.config import TrainConfig
    assert len(jax.devices()) == 2
    cfg = TrainConfig.from_dict(json.loads(sys.argv[1]))
    s = runs.build(cfg, need_heldout=False)
    st, ex = train_loop.place_on_devices(s.init(cfg.seeds, s.expert), s.expert, "all", len(cfg.seeds),
                                         cfg.env_shards)
    sig = lambda t: [(x.sharding, x.shape, x.dtype, x.weak_type) for x in jax.tree.leaves(t)]
    pspec = lambda x: [None if a is None else str(a) for a in x.sharding.spec]
    before = sig(st)
    out = {"mesh": dict(st.env_state.obs.sharding.mesh.shape),
           "env_specs": {k: pspec(getattr(st, k)) for k in ("ret_acc", "z", "hist", "prev_ah")}
                        | {"env_state.obs": pspec(st.env_state.obs)},
           "env_devices": len(st.env_state.obs.sharding.device_set),
           "params_replicated": all(x.sharding.is_fully_replicated for x in jax.tree.leaves(st.params)),
           "params_devices": len(jax.tree.leaves(st.params)[0].sharding.device_set)}
    counters, episodes = [np.asarray(st.code_counter)], []
    for _ in range(int(sys.argv[2])):
        st, m = s.chunk(st, ex)
        counters.append(np.asarray(st.code_counter))
        episodes.append(np.asarray(m["episodes"]))
    out["placement_kept"] = sig(st) == before
    # every leaf without an env axis (parameters, optimizer states, return moments, code counter, keys) is held by
    # each device as its shard computed it (shard_map's out_specs take it as replicated): the same bits on both
    from cogail_jax.algo.train import env_leaves
    flags, named = jax.tree.leaves(env_leaves(st)), jax.tree_util.tree_leaves_with_path(st)
    out["shards_differ"] = [jax.tree_util.keystr(k) for f, (k, x) in zip(flags, named) if not f and x.size
                            and not all(np.array_equal(np.asarray(a.data), np.asarray(x.addressable_shards[0].data))
                                        for a in x.addressable_shards)]
    out["compilations"] = s.chunk._cache_size()
    leaves = jax.tree.leaves(jax.device_get(st.params))
    np.savez("two_devices.npz", counters=np.stack(counters), episodes=np.stack(episodes),
             **{f"p{i}": np.asarray(x) for i, x in enumerate(leaves)})
    # zero-size leaves (MJX's unused fields) stay outside the program over both devices, and inside each device sees
    # its block's shape of them: a toy chunk over a state with an empty env leaf and an empty seed leaf
    import jax.numpy as jnp
    from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
    from cogail_jax.runtime.parallel import SeedChunk
    seen = {}
    def toy(st, ex):
        seen.update(env=st["e"].shape, seed=st["s"].shape)
        return {"x": st["x"] + ex, "e": st["e"], "s": st["s"]}, {"m": jnp.zeros((1, st["x"].shape[0]))}
    mesh = Mesh(np.asarray(jax.devices()[:2]).reshape(1, 2), ("seeds", "envs"))
    toy_state = {"x": jax.device_put(jnp.ones((1, 4, 3)), NamedSharding(mesh, P(None, "envs"))),
                 "e": jax.device_put(jnp.zeros((1, 4, 0)), NamedSharding(mesh, P())),
                 "s": jax.device_put(jnp.zeros((1, 0)), NamedSharding(mesh, P()))}
    chunk = SeedChunk(toy, env_fn=toy, env_leaves=lambda st: {"x": True, "e": True, "s": False})
    lowered = chunk.lower(toy_state, jnp.float32(1.0))
    new, _ = chunk(toy_state, jnp.float32(1.0))
    out["toy"] = {"blocks": {k: list(v) for k, v in seen.items()},
                  "args": [list(a.shape) for a in jax.tree.leaves(lowered.args_info)],
                  "empties_kept": new["e"] is toy_state["e"] and new["s"] is toy_state["s"],
                  "x": float(np.asarray(new["x"]).sum())}
    print("RESULT " + json.dumps(out))
""")


class DeviceRun:
    def __init__(self, cfg, tmp):
        self.tmp = tmp
        self.proc = subprocess.Popen([sys.executable, "-c", DEVICE_SCRIPT, cfg.to_json(), str(CALLS)], cwd=tmp,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self._result = None

    def result(self):
        if self._result is None:
            out, err = self.proc.communicate(timeout=600)
            line = [x for x in out.splitlines() if x.startswith("RESULT ")]
            assert self.proc.returncode == 0 and line, err[-3000:]
            self._result = json.loads(line[0][len("RESULT "):]), dict(np.load(self.tmp / "two_devices.npz"))
        return self._result


@pytest.fixture(scope="module")
def two_devices(cfgs, tmp_path_factory):
    run = DeviceRun(cfgs[1], tmp_path_factory.mktemp("two_devices"))
    yield run
    if run.proc.poll() is None:
        run.proc.kill()
        run.proc.wait()


def _run_here(cfg):
    """``CALLS`` chunk calls of ``cfg`` on this process's one device: the final state, the metrics of every call,
    the code counter before and after every call, and the state's shapes (for tracing the chunk)."""
    from cogail_jax.apps import runs

    s = runs.build(cfg, need_heldout=False)
    st = s.init(cfg.seeds, s.expert)
    shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), st)
    counters, metrics = [np.asarray(st.code_counter)], []
    for _ in range(CALLS):
        st, m = s.chunk(st, s.expert)  # (the chunk donates its input state)
        counters.append(np.asarray(st.code_counter))
        metrics.append(jax.device_get(m))
    return dict(setup=s, state=st, metrics=metrics, counters=np.stack(counters), shapes=shapes,
                compilations=s.chunk._cache_size())


@pytest.fixture(scope="module")
def here(cfgs, two_devices):  # (two_devices first: the subprocess compiles meanwhile)
    return {c.env_shards: _run_here(c) for c in cfgs}


def _leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(jax.device_get(tree))]


def _primitives(jaxpr) -> set[str]:
    """The names of every primitive in ``jaxpr`` and in the jaxprs of its equations (scan, cond, pjit, ...)."""
    names = set()

    def walk(j):
        for e in j.eqns:
            names.add(e.primitive.name)
            for p in e.params.values():
                for sub in p if isinstance(p, (tuple, list)) else (p,):
                    sub = getattr(sub, "jaxpr", sub)
                    if hasattr(sub, "eqns"):
                        walk(sub)

    walk(jaxpr.jaxpr)
    return names


def _collectives(names) -> set[str]:
    return {n for n in names if n.startswith(COLLECTIVES)}


# ------------------------------------------------------------------------------------------------ layouts agree
def test_two_devices_match_shards_side_by_side(cfgs, here, two_devices):
    """2 shards side by side on one device == 1 shard per device on 2 devices: the same arithmetic (per-shard keys,
    gradients gathered and averaged in shard order), compiled as two different programs."""
    out, arrs = two_devices.result()
    # placement: the env leaves split over both devices along "envs", everything else (params) replicated
    assert out["mesh"] == {"seeds": 1, "envs": 2}, out
    for name, pspec in out["env_specs"].items():
        assert "envs" in pspec, (name, pspec)
    assert out["env_devices"] == 2 and out["params_devices"] == 2 and out["params_replicated"], out
    # the output state is placed as the input was, and the chunk compiled once over both calls (outputs placed
    # otherwise than the inputs made the second call compile the whole chunk again)
    assert out["placement_kept"] and out["compilations"] == 1, out
    # every shard holds the same parameters (and optimizer states, code counter, ...) bit for bit: the averages
    # are gathered and summed in shard order on every device
    assert out["shards_differ"] == [], out["shards_differ"]
    # zero-size leaves: outside the program (they crash XLA's GPU compiler there), each device's block inside
    assert out["toy"]["blocks"] == {"env": [1, 2, 0], "seed": [1, 0]}, out["toy"]
    assert all(0 not in a for a in out["toy"]["args"]) and out["toy"]["empties_kept"], out["toy"]
    assert out["toy"]["x"] == 24.0, out["toy"]  # (1 + 1) x 12 elements: the toy update ran on both blocks
    side = here[2]
    assert side["compilations"] == 1
    # Tolerance: the two programs are compiled differently (the shard axis vmapped in one program vs shard_map
    # over two devices), so XLA fuses and orders the sums differently and the results differ in the last bits,
    # which Adam's updates then carry on. After CALLS x updates_per_call = 4 updates the largest difference
    # measured was 1.7e-7 (parameters up to 1.6; ~1e-6 with 8 envs): atol 2e-6 / rtol 2e-5 (as test_sharding.py)
    # leaves ~10x room for another XLA version's fusion choices, and stays 50x below the 1e-4 by which a real
    # change of the arithmetic (other keys, an un-averaged gradient: 5e-3 in the next test) moves them.
    mine = _leaves(side["state"].params)
    assert len(mine) == sum(k.startswith("p") for k in arrs)
    for i, a in enumerate(mine):
        np.testing.assert_allclose(arrs[f"p{i}"], a, rtol=2e-5, atol=2e-6)
    # the episodes (and so the code counter) agree exactly: the rollouts ended the same episodes
    np.testing.assert_array_equal(arrs["episodes"], np.stack([m["episodes"] for m in side["metrics"]]))
    np.testing.assert_array_equal(arrs["counters"], side["counters"])


# ------------------------------------------------------------------------------------------------ shards average
def test_shards_split_the_batch_and_both_train(cfgs, here):
    one, two = here[1], here[2]
    n_seeds = len(cfgs[0].seeds)
    for r in (one, two):
        assert all(np.isfinite(x).all() for x in _leaves(r["state"].params))
        for m in r["metrics"]:
            for k, v in m.items():
                assert v.shape == (cfgs[0].updates_per_call, n_seeds), (k, v.shape)
            assert np.isfinite(m["disc_loss"]).all() and not m["nonfinite"].any()
        assert r["compilations"] == 1
    # the same envs, seeds and init, but each shard draws its own actions and minibatches (its own keys): a
    # different run, not the 1-shard program under another name (measured: 5e-3 apart after 4 updates; 1e-4 is
    # 50x the layouts' tolerance in the test above)
    diffs = [np.abs(a - b).max() for a, b in zip(_leaves(one["state"].params), _leaves(two["state"].params))]
    assert max(diffs) > 1e-4, diffs
    # the env state keeps its full (seeds, num_envs) layout after the side-by-side shards are joined again
    assert two["state"].env_state.obs.shape[:2] == (n_seeds, cfgs[1].num_envs)
    assert two["state"].z.shape == one["state"].z.shape


def test_one_shard_program_has_no_collectives(cfgs, here):
    """With one shard every shards.* function is the identity: the one-device chunk has no collective (the
    program of runs without env shards is unchanged); the 2-shard per-shard chunk (``env_fn``, what shard_map
    runs on each device) gathers over "envs" and reads its shard index."""
    s1, s2 = here[1]["setup"], here[2]["setup"]
    expert = jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), np.asarray(x).dtype), s1.expert)
    hyper = s1.chunk.extra  # the update's hyperparameters, the program's third argument
    jaxpr1 = jax.make_jaxpr(s1.chunk.fn)(here[1]["shapes"], expert, hyper)
    p1 = _primitives(jaxpr1)
    assert not _collectives(p1), _collectives(p1)
    # bit for bit the program of the trainer before env shards existed (commit 75a9e65; since the update's
    # hyperparameters became the program's argument, its jaxpr reads them from there, with the same results): the
    # same jaxpr, so the same compiled program and results. Traced with a fixed number of expert steps (the generated demonstrations' total
    # length could differ on another CPU). A deliberate change of the update changes this digest: replace it then.
    fixed = jax.tree.map(lambda x: jax.ShapeDtypeStruct((1000,) + x.shape[1:], x.dtype) if x.shape else x, expert)
    digest = hashlib.sha256(str(jax.make_jaxpr(s1.chunk.fn)(here[1]["shapes"], fixed, hyper)).encode()).hexdigest()
    assert digest == ONE_SHARD_DIGEST, digest
    # one shard's part of the state (its envs), traced with the axis bound as shard_map binds it
    full = here[2]["shapes"]
    local = jax.tree.map(lambda f, x: jax.ShapeDtypeStruct(x.shape[:1] + (x.shape[1] // 2,) + x.shape[2:], x.dtype)
                         if f else x, train.env_leaves(full), full)
    p2 = _primitives(jax.make_jaxpr(s2.chunk.env_fn, axis_env=[(shards.AXIS, 2)])(local, expert, hyper))
    assert {"all_gather", "axis_index"} <= _collectives(p2), _collectives(p2)


# ------------------------------------------------------------------------------------------------ code counter
def test_code_counter_counts_every_shards_episodes(cfgs, here):
    """After each rollout the seed's code counter (one per seed, the same on every shard: the state joined from
    the shards keeps shard 0's) has moved by all shards' new episodes together: the sum of the updates'
    ``episodes`` (gathered over the shards). With 2 envs a shard and a 10-step limit, every update ends some."""
    for r in here.values():
        steps = np.diff(r["counters"], axis=0)  # (calls, seeds)
        eps = np.stack([m["episodes"].sum(0) for m in r["metrics"]])
        assert (eps > 0).all(), eps
        np.testing.assert_array_equal(steps, eps.astype(steps.dtype))
    # 4 envs over 16 steps with a 10-step limit: both layouts end every env's episode at least once per update
    # (so the 2-shard count is both shards' episodes, not one shard's)
    assert (np.stack([m["episodes"] for m in here[2]["metrics"]]) >= cfgs[1].num_envs).all()


# ------------------------------------------------------------------------------------------------ config errors
@pytest.mark.parametrize("kw", [dict(env_shards=3),  # does not divide num_envs (4)
                                dict(env_shards=2, inner_batch=33),  # does not divide inner_batch
                                dict(env_shards=0),
                                dict(env_shards=4, num_minibatches=32)])  # 16 steps a shard: not 32 minibatches
def test_env_shards_config_errors(tiny_cfg, kw):
    tiny_cfg.replace(**{k: v for k, v in kw.items() if k != "env_shards"}).validate()  # valid with one shard
    with pytest.raises(ConfigError, match="env.shards"):
        tiny_cfg.replace(**kw).validate()
