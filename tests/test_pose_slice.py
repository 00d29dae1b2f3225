"""The held-out pose and place slices (``variations.POSE_HELDOUT``, one per degree of freedom) and the object-centric
observation features: every episode a run trains, validates or is tested on lies in the teams' training ranges, every
episode of a ``pose_heldout_<axis>`` set lies outside that axis' range alone, and ``obs_frame`` chooses which features
the networks read."""
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


_ENV, _INIT, _RESET = {}, {}, {}  # per task, for the whole module: one env, its team's draws and reset_from, compiled once


def _env(task: str):
    if task not in _ENV:
        _ENV[task] = cogail_envs.make_env(task)
    return _ENV[task]


def _init(task: str):
    """The team's draws, jitted: ``f(keys (n, 2), variation (n,)) -> (team states, strategies)``."""
    if task not in _INIT:
        env, team = _env(task), get_task(task).team
        _INIT[task] = jax.jit(jax.vmap(lambda k, v: team.init(env, k, env.uniform_mix(), v)))
    return _INIT[task]


def _reset(task: str):
    if task not in _RESET:
        _RESET[task] = jax.jit(_env(task).reset_from)
    return _RESET[task]


def _axes(task: str, ts) -> dict:
    """Per degree of freedom of the team's draws: ``[(values, training range)]`` (the bar's turn as magnitudes)."""
    mod = __import__(f"cogail_envs.{task}.team", fromlist=["x"])
    a = lambda x: np.abs(np.asarray(x))  # noqa: E731
    turn = {"roll": [(a(ts.roll), mod.TILT_RANGE)], "pitch": [(a(ts.pitch), mod.TILT_RANGE)],
            "yaw": [(a(ts.yaw), mod.YAW_RANGE)]}
    if task == "handover":
        return {**turn, "x": [(a(ts.spot[:, 0]), (0.0, mod.REGIONS_X[2, 1]))],
                "y": [(np.asarray(ts.spot[:, 1]), mod.SPOT_Y)], "z": [(np.asarray(ts.spot[:, 2]), mod.Z_RANGE)]}
    spot, wait, drop = (np.asarray(x) for x in (ts.spot, ts.wait_pt[:, 0], ts.drop))
    rng = lambda lo, hi, i: (lo[i], hi[i])  # noqa: E731
    return {**turn, **{k: [(spot[:, i], rng(mod.SPOT_LO, mod.SPOT_HI, i)), (wait[:, i], rng(mod.WAIT_LO, mod.WAIT_HI, i))]
                       for i, k in enumerate("xyz")},
            "place": [(drop[:, 0], rng(mod.DROP_LO, mod.DROP_HI, 0)), (a(drop[:, 1]), (0.0, mod.DROP_HI[1]))]}


def _draws(task: str, variation: int, n: int = 1000):
    """The teams' draws of ``n`` episodes (no physics; one compiled program per task, the variation traced): per
    axis, whether each episode's value lies beyond the training range (any of its places, for the place axes) and
    how far (m or rad) at most."""
    keys = jax.random.split(jax.random.PRNGKey(variation), n)
    ts, _ = _init(task)(keys, jnp.full((n,), variation, jnp.int32))
    out, beyond = {}, {}
    for axis, parts in _axes(task, ts).items():
        off = np.max([np.maximum(lo - v, v - hi) for v, (lo, hi) in parts], 0)
        out[axis], beyond[axis] = off > 0, off.max()  # float32, as drawn: a slice starts at its range's end
    return out, beyond


@pytest.mark.parametrize("task", HELD_TASKS)
def test_training_draws_stay_in_range_and_each_slice_outside_its_own(task):
    """Default, varied (and following-partner) episodes: every degree of freedom in its training range; each axis'
    held-out slice (``pose_slice(axis)``): that axis beyond its range in every episode, by at most a few cm or 0.35
    rad, and every other axis in range; ``POSE_HELDOUT`` alone: exactly one axis beyond, each of the team's drawn."""
    from cogail_envs.variations import PROMPT_ROBOT, pose_slice

    slices = get_task(task).team.held_out_slices
    assert set(slices) >= {"roll", "pitch", "yaw", "x", "y", "z"}
    for v in [0, *range(1, len(VARIATIONS) + 1), 6 | FOLLOWING_PARTNER, PROMPT_ROBOT]:
        out, _ = _draws(task, v)  # (as many episodes as below: the same compiled program)
        assert not any(o.any() for o in out.values()), (task, v)
    for axis in slices:
        out, beyond = _draws(task, pose_slice(axis))
        assert out[axis].all(), (task, axis)
        assert beyond[axis] <= (0.35 if axis in ("roll", "pitch", "yaw") else 0.06), (task, axis, beyond[axis])
        assert not any(out[a].any() for a in slices if a != axis), (task, axis)
    out, _ = _draws(task, POSE_HELDOUT)
    count = np.sum([out[a] for a in slices], 0)
    assert np.all(count == 1) and all(out[a].mean() > 0.5 / len(slices) for a in slices)


def test_slices_are_evaluation_sets_with_their_own_seeds():
    """The slices are evaluated (the protocol's varied humans, one set per axis) but never trained on: their
    generator seeds differ from every split's, every variation's and each other's, and the training set's varied
    humans are the VARIATIONS only."""
    from cogail_envs.variations import slice_names, variation_id

    held = set()
    for task in HELD_TASKS:
        env = cogail_envs.make_env(task)
        names = slice_names(get_task(task).team.held_out_slices)
        assert protocol_variations(env) == tuple(VARIATIONS) + names
        assert all(variation_id(n) & POSE_HELDOUT for n in names) and not set(names) & set(VARIATIONS)
        held |= {variation_seed(n, s) for n in names for s in ("test", "validation", "train")}
        assert len({variation_seed(n, "test") for n in names}) == len(names)
    assert protocol_variations(cogail_envs.make_env("fetchq")) == tuple(VARIATIONS)
    seeds = {variation_seed(v, s) for v in VARIATIONS for s in ("test", "validation", "train")} | {0, 1, 2}
    assert not held & seeds
    with pytest.raises(ValueError, match="pose_heldout_<axis>"):
        variation_id("pose_heldout_spin")


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
        names = protocol_variations(cogail_envs.make_env(task))
        assert asked == [("test", 0, names), ("validation", val, names[len(VARIATIONS):])], (task, asked)


@pytest.mark.parametrize("task", HELD_TASKS)
def test_object_frame_features(task):
    """The features are the env's last 34 dims; ``obs_frame="world"`` normalises them (only them) to 0, "object" the
    absolute orientations (only them), "both" none."""
    env = _env(task)
    dims = np.asarray(env.object_frame_dims)
    assert len(dims) == 34 and dims[-1] == env.observation_size - 1
    s = _reset(task)(env.sample_init(jax.random.PRNGKey(3)))
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

    env = _env(task)
    keys = jax.random.split(jax.random.PRNGKey(0), 1000)  # (the draws' program of the test above: its batch size)
    init = lambda keys, v: _init(task)(keys, jnp.full((len(keys),), v, jnp.int32))  # noqa: E731
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

    env = _env(task)
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
    d = _reset(task)(jnp.asarray(x)).pipeline_state
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
