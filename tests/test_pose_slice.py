"""The held-out pose and place slice (``variations.POSE_HELDOUT``) and the object-centric observation features:
every episode a run trains, validates or is tested on lies in the teams' training ranges, every episode of the
``pose_heldout`` set lies outside them, and ``obs_frame`` chooses which features the networks read."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import cogail_envs
from cogail_envs import get_task
from cogail_envs.variations import FOLLOWING_PARTNER, POSE_HELDOUT, VARIATIONS

from cogail_jax.algo import train
from cogail_jax.algo.config import TrainConfig
from cogail_jax.data.varied import protocol_variations, variation_seed

HELD_TASKS = [t for t in ("handover", "seqmanip") if get_task(t).team.held_out]


_INIT = {}


def _draws(task: str, variation: int, n: int = 2000):
    """The teams' draws of ``n`` episodes (no physics; one compiled program per task, the variation traced): yaw
    and the hand-over heights."""
    if task not in _INIT:
        env, team = cogail_envs.make_env(task), get_task(task).team
        _INIT[task] = jax.jit(jax.vmap(lambda k, v: team.init(env, k, env.uniform_mix(), v)))
    keys = jax.random.split(jax.random.PRNGKey(variation), n)
    ts, _ = _INIT[task](keys, jnp.full((n,), variation, jnp.int32))
    mod = __import__(f"cogail_envs.{task}.team", fromlist=["x"])
    z = {"handover": lambda: [(ts.spot[:, 2], mod.Z_RANGE, mod.Z_HELD)],
         "seqmanip": lambda: [(ts.spot[:, 2], (mod.SPOT_LO[2], mod.SPOT_HI[2]), mod.SPOT_Z_HELD),
                              (ts.wait_pt[:, 0, 2], (mod.WAIT_LO[2], mod.WAIT_HI[2]), mod.WAIT_Z_HELD)]}[task]()
    return np.abs(np.asarray(ts.yaw)), mod, [(np.asarray(v), lo, hi) for v, lo, hi in z]


@pytest.mark.parametrize("task", HELD_TASKS)
def test_training_draws_stay_in_range_and_the_slice_outside(task):
    """Default, varied (and following-partner) episodes: yaw and heights in the training range; the held-out
    slice: each episode has its yaw or its height beyond it, and the two kinds each cover their band."""
    for v in [0, *range(1, len(VARIATIONS) + 1), 6 | FOLLOWING_PARTNER]:
        yaw, mod, heights = _draws(task, v)
        assert yaw.max() <= mod.YAW_RANGE[1] + 1e-6, (task, v)
        for h, (lo, hi), _ in heights:
            assert h.min() >= lo - 1e-6 and h.max() <= hi + 1e-6, (task, v)
    yaw, mod, heights = _draws(task, POSE_HELDOUT)
    out_yaw = yaw > mod.YAW_RANGE[1]
    out_z = np.zeros_like(out_yaw)
    for h, (lo, hi), (hlo, hhi) in heights:
        assert h.max() <= hhi + 1e-6
        out_z |= h > hi
    assert np.all(out_yaw ^ out_z)  # exactly one of the two outside the training range
    assert 0.35 < out_yaw.mean() < 0.65 and yaw[out_yaw].max() > mod.YAW_HELD[1] - 0.05
    assert yaw.max() <= mod.YAW_HELD[1] + 1e-6


def test_slice_is_an_evaluation_set_with_its_own_seeds():
    """The slice is evaluated (the protocol's varied humans) but never trained on: its generator seeds differ from
    every split's and every variation's, and the training set's varied humans are the VARIATIONS only."""
    for task in HELD_TASKS:
        env = cogail_envs.make_env(task)
        assert protocol_variations(env)[-1] == "pose_heldout" and "pose_heldout" not in VARIATIONS
    assert protocol_variations(cogail_envs.make_env("fetchq")) == tuple(VARIATIONS)
    seeds = {variation_seed(v, s) for v in VARIATIONS for s in ("test", "validation", "train")} | {0, 1, 2}
    held = {variation_seed("pose_heldout", s) for s in ("test", "validation", "train")}
    assert not held & seeds


def test_the_validation_slice_is_as_large_as_the_validation_split(monkeypatch):
    """A run's sets ask for the validation split's held-out slice at the validation split's size (settings are chosen
    on it beside the validation replay) and for the test's varied humans at the test split's size."""
    from cogail_jax.data import io, sets, varied

    asked = []
    monkeypatch.setattr(varied, "ensure_robustness_sets", lambda env, mix, split="test", num=0, variations=(),
                        **kw: asked.append((split, num, tuple(variations))) or {})
    for task in HELD_TASKS:
        asked.clear()
        sets.robustness_paths(TrainConfig(task=task), env=cogail_envs.make_env(task))
        val, test = io.default_count(task, "validation"), io.default_count(task, "test")
        assert val > test
        assert asked == [("test", 0, protocol_variations(cogail_envs.make_env(task))),
                         ("validation", val, ("pose_heldout",))], (task, asked)


@pytest.mark.parametrize("task", HELD_TASKS)
def test_object_frame_features(task):
    """The features are the env's last 22 dims; ``obs_frame="world"`` normalises them (only them) to 0, "object" the
    absolute orientations (only them), "both" none."""
    env = cogail_envs.make_env(task)
    dims = np.asarray(env.object_frame_dims)
    assert len(dims) == 22 and dims[-1] == env.observation_size - 1
    s = jax.jit(env.reset_from)(env.sample_init(jax.random.PRNGKey(3)))
    obs = np.asarray(s.obs)[None].repeat(4, 0)
    expert = {"obs": obs + np.arange(4)[:, None], "demo": np.array([0, 0, 1, 1])}
    x = jnp.asarray(expert["obs"])

    def normalised(frame):
        norm = train.fit_normalizer(expert, 0.1, train.unread_dims(TrainConfig(task=task, obs_frame=frame), env))
        return np.asarray((x - norm["mean"]) / norm["std"])

    both, world, obj = normalised("both"), normalised("world"), normalised("object")
    rot = np.asarray(env.orientation_dims)
    assert len(rot) == 18 and not set(rot) & set(dims)
    for unread, n in ((dims, world), (rot, obj)):
        assert np.all(n[:, unread] == 0) and np.any(both[:, unread] != 0)
        keep = np.setdiff1d(np.arange(env.observation_size), unread)
        np.testing.assert_array_equal(both[:, keep], n[:, keep])


PROMPT_TASKS = [t for t in ("handover", "seqmanip") if get_task(t).team.prompt_robot]


@pytest.mark.parametrize("task", PROMPT_TASKS)
def test_prompt_robot_changes_the_robot_only(task):
    """``variation | PROMPT_ROBOT`` (the training split's): the robot at the top of its speed, acceleration and gain
    ranges and at its shortest reaction, above every plain draw (on seqmanip also starting early towards the drop);
    every human field and every other draw as without the flag (the same episodes otherwise). The test and validation splits are made without it."""
    from cogail_envs.variations import PROMPT_ROBOT

    from cogail_jax.data.generate import training_flags

    env, team = cogail_envs.make_env(task), get_task(task).team
    init = jax.jit(jax.vmap(lambda k, v: team.init(env, k, env.uniform_mix(), v), in_axes=(0, None)))
    keys = jax.random.split(jax.random.PRNGKey(0), 200)
    for v in (0, 5):  # none, and a varied human (noise)
        plain, s0 = init(keys, jnp.int32(v))
        fast, s1 = init(keys, jnp.int32(v | PROMPT_ROBOT))
        np.testing.assert_array_equal(np.asarray(s0), np.asarray(s1))
        robot = ("vmax", "amax", "gain", "delay", "react")
        for name in plain._fields:
            a, b = np.asarray(getattr(plain, name)), np.asarray(getattr(fast, name))
            if name == "early":  # seqmanip: the prompt robot alone starts towards the drop while the drawer opens
                assert not a.any() and b.all(), name
            elif name in robot:
                np.testing.assert_array_equal(a[:, 0], b[:, 0])  # the human's
                top = b[:, 1]
                assert np.all(top == top[0]), name
                assert (top[0] >= a[:, 1].max() if name != "delay" and name != "react" else top[0] <= a[:, 1].min())
                assert np.any(a[:, 1] != top[0]), name  # the plain robot varies
            else:
                np.testing.assert_array_equal(a, b, err_msg=name)
    assert training_flags(env) == PROMPT_ROBOT
    assert training_flags(cogail_envs.make_env("fetchq")) == 0


TRAIN_ENV_TASKS = [t for t in ("handover", "seqmanip") if get_task(t).train_env]


@pytest.mark.parametrize("task", TRAIN_ENV_TASKS)
def test_training_env_changes_the_robot_start_only(task, tmp_path, monkeypatch):
    """The training split's env (the task's ``train_env``) draws the robot gripper's start yaw and height from its
    wider ranges and every other part of the start as the plain env does from the same key; ``reset_from`` puts the
    gripper there (joint and command); only the training split is made in it, under its own dataset version."""
    from cogail_jax.data import generate, io

    env = cogail_envs.make_env(task)
    tenv = generate.training_env(env)
    opts = get_task(task).train_env
    keys = jax.random.split(jax.random.PRNGKey(0), 4000)
    plain, wide = (np.asarray(jax.vmap(e.sample_init)(keys)) for e in (env, tenv))
    np.testing.assert_array_equal(plain[:, :8], wide[:, :8])  # the object's and the human's start, the robot's x, y
    assert np.abs(plain[:, 9]).max() == 0 and np.abs(plain[:, 8]).max() <= 0.03
    yaw, z = np.abs(wide[:, 9]).max(), np.abs(wide[:, 8]).max()
    assert 0.95 * opts["robot_start_yaw"] < yaw <= opts["robot_start_yaw"]
    assert 0.95 * opts["robot_start_z"] < z <= opts["robot_start_z"]
    assert tenv.version != env.version and generate.training_env(tenv).version == tenv.version
    x = plain[0].copy()
    x[8], x[9] = -0.07, 0.4
    d = jax.jit(env.reset_from)(jnp.asarray(x)).pipeline_state
    r = env.robot
    np.testing.assert_allclose(np.asarray(d.qpos)[[r.qpos[2], r.qpos[5]]], [-0.07, 0.4], atol=1e-6)
    np.testing.assert_allclose(np.asarray(d.ctrl)[[r.act + 2, r.act + 5]], [-0.07, 0.4], atol=1e-6)

    made = {}

    class Stop(Exception):
        pass

    def fake(env_, num, **kw):
        made[num] = env_.version
        raise Stop

    monkeypatch.setenv("COGAIL_DATA", str(tmp_path))
    monkeypatch.setattr(generate, "generate", fake)
    for split, num in (("train", 3), ("validation", 0), ("test", 0)):
        with pytest.raises(Stop):
            io.ensure_default_demos(env, split, num=num, verbose=False)
        assert made.pop(num if num else io.default_count(task, split)) == (tenv.version if split == "train"
                                                                           else env.version), split
