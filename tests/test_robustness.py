"""Robustness sets (varied scripted humans): validated episodes, the intended differences, the blind robot.

fetchq carries most checks (one compiled rollout and one compiled replay serve all six variations); the MJX
tasks get one tiny set each (seqmanip's with 600-step episodes).
"""
from __future__ import annotations

import contextlib
import os

import h5py
import numpy as np
import pytest

from cogail_jax.data import varied as rb
from cogail_jax.eval import robustness as rfig
from cogail_jax.data.io import load_demos

NUM = 16  # fetchq episodes per variation (every set made by the task's one generator program)


@contextlib.contextmanager
def _data_dir(path):
    old = os.environ.get("COGAIL_DATA")
    os.environ["COGAIL_DATA"] = str(path)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("COGAIL_DATA", None)
        else:
            os.environ["COGAIL_DATA"] = old


# Episodes per MJX generator call (``generate.generator_batch``; 8 on a CPU): each call rolls out every lane for the
# whole time limit, so the lanes beyond the episodes tried are pure cost. seqmanip tries 5 episodes in each of its
# sets below (one call at this width, one program for both of its tests); handover tries 3.
MJX_BATCH = {"handover": 3, "seqmanip": 5}


@pytest.fixture(scope="module")
def mjx_env():
    """``get(task)``: one env object per MJX task for this module: the task's generator program is kept on it
    (``generate.generator_fn``), so the tests of one task trace and compile it once."""
    import cogail_envs

    envs = {}

    def get(task):
        if task not in envs:
            envs[task] = cogail_envs.make_env(task)
        return envs[task]

    return get


@pytest.fixture(scope="module")
def fq_sets(fetchq, tmp_path_factory):
    with _data_dir(tmp_path_factory.mktemp("robust")):
        return rb.ensure_robustness_sets(fetchq, num=NUM, verbose=False)


@pytest.fixture(scope="module")
def fq_twins(fetchq, fq_sets):
    return {v: rb.twin_episodes(fetchq, fq_sets[rb.PREFIX + v]) for v in rb.VARIATIONS}


def _human(fetchq, path):
    d = load_demos(path, fetchq, require_init=True)
    return d, [d.actions_human[i, : d.length[i]] for i in range(d.num)]


def test_files_follow_the_schema_and_validate_by_resimulation(fetchq, fq_sets):
    assert set(fq_sets) == {rb.PREFIX + v for v in rb.VARIATIONS}
    seeds = set()
    for v in rb.VARIATIONS:
        path = fq_sets[rb.PREFIX + v]
        assert path.name == f"fetchq_uniform_robust-{v}_{NUM}.hdf5"
        with h5py.File(path, "r") as f:
            assert f.attrs["variation"] == v and int(f.attrs["num_demos"]) == NUM
            assert 0.75 <= float(f.attrs["yield"]) <= 1.0
            seeds.add(int(f.attrs["seed"]))
        d = load_demos(path, fetchq, require_init=True)
        # an independent open-loop re-simulation of both agents' recorded actions
        r = rb.validate_episodes(fetchq, d.init, d.actions_human, d.actions_robot)
        assert np.all(r["success"] > 0) and np.array_equal(r["executed"], d.strategy)
        assert np.array_equal(r["length"], d.length)
    assert len(seeds) == 6 and not seeds & {0, 1, 2}  # generator seeds distinct from train / test / validation


def test_cached_sets_are_reused(fetchq, fq_sets):
    path = fq_sets[rb.PREFIX + "slow"]
    mtime = path.stat().st_mtime_ns
    with _data_dir(path.parent):
        again = rb.ensure_robustness_sets(fetchq, num=NUM, variations=("slow",), verbose=False)
    assert again[rb.PREFIX + "slow"] == path and path.stat().st_mtime_ns == mtime


def test_twins_are_the_unvaried_episodes(fetchq, fq_twins):
    for v, tw in fq_twins.items():
        assert np.all(tw["success"] > 0), v  # the default team: all succeed


def test_pace(fetchq, fq_sets, fq_twins):
    slow, _ = _human(fetchq, fq_sets["robust-slow"])
    fast, hf = _human(fetchq, fq_sets["robust-fast"])
    assert slow.length.mean() > 1.15 * fq_twins["slow"]["length"].mean()
    assert fast.length.mean() < fq_twins["fast"]["length"].mean()
    tw = fq_twins["fast"]
    speed = lambda acts: np.mean([np.linalg.norm(a, axis=-1).mean() for a in acts])  # noqa: E731
    assert speed(hf) > 1.05 * speed([tw["actions_human"][i, : tw["length"][i]] for i in range(len(tw["length"]))])


def _longest_still(a: np.ndarray) -> int:
    still = np.all(np.abs(a) < 1e-6, axis=-1)
    best = run = 0
    for s in still:
        run = run + 1 if s else 0
        best = max(best, run)
    return best


def test_pauses_are_runs_of_zero_human_actions(fetchq, fq_sets, fq_twins):
    d, hp = _human(fetchq, fq_sets["robust-pauses"])
    tw = fq_twins["pauses"]
    runs = np.array([_longest_still(a) for a in hp])
    twin_runs = np.array([_longest_still(tw["actions_human"][i, : tw["length"][i]]) for i in range(d.num)])
    assert np.mean(runs >= 20) >= 0.9 and twin_runs.max() < 20
    assert d.length.mean() > tw["length"].mean() + 20


def _path_length(obs: np.ndarray, n: int) -> float:
    pos = obs[:n, 0:2] * 8.0  # the human's xy (obs / MAP)
    return float(np.linalg.norm(np.diff(pos, axis=0), axis=-1).sum())


def test_detour_takes_longer_paths(fetchq, fq_sets, fq_twins):
    d = load_demos(fq_sets["robust-detour"], fetchq)
    tw = fq_twins["detour"]
    varied = np.mean([_path_length(d.obs[i], d.length[i]) for i in range(d.num)])
    twin = np.mean([_path_length(tw["obs"][i], tw["length"][i]) for i in range(d.num)])
    assert varied > 1.1 * twin


def test_noise_is_larger(fetchq, fq_sets, fq_twins):
    _, hn = _human(fetchq, fq_sets["robust-noise"])
    tw = fq_twins["noise"]
    jitter = lambda acts: np.mean([np.abs(np.diff(a, axis=0)).mean() for a in acts])  # noqa: E731
    assert jitter(hn) > 2.0 * jitter([tw["actions_human"][i, : tw["length"][i]] for i in range(len(tw["length"]))])


def test_change_of_mind_heads_elsewhere_first(fetchq, fq_sets, fq_twins):
    from cogail_envs.fetchq.team import first_target

    d = load_demos(fq_sets["robust-change_of_mind"], fetchq)
    tw = fq_twins["change_of_mind"]

    def cos_to_own(obs, s):  # heading of the human's first 15 steps vs. the direction to its own first target
        start, later = obs[0, 0:2] * 8.0, obs[15, 0:2] * 8.0
        goal = np.asarray(first_target(np.int32(s), 0))
        u, w = later - start, goal - start
        return float(u @ w / (np.linalg.norm(u) * np.linalg.norm(w) + 1e-9))

    varied = np.array([cos_to_own(d.obs[i], d.strategy[i]) for i in range(d.num)])
    twin = np.array([cos_to_own(tw["obs"][i], d.strategy[i]) for i in range(d.num)])
    assert twin.mean() > 0.8 and varied.mean() < twin.mean() - 0.3


def test_blind_robot_parts_ways_with_the_human_follower(fetchq, fq_sets):
    """The team's robot follows the human and succeeds on every varied episode (by construction); the recorded
    robot of the unvaried twin, replayed blind, drops under variation compared with an in-distribution human."""
    res = {v: rb.blind_robot_success(fetchq, fq_sets[rb.PREFIX + v]) for v in rb.VARIATIONS}
    for v in ("slow", "pauses", "change_of_mind"):
        assert res[v]["varied"] < res[v]["in_distribution"] - 0.15, (v, res[v])
    assert np.mean([r["varied"] for r in res.values()]) < np.mean([r["in_distribution"] for r in res.values()])
    assert set(res["slow"]["by_strategy"]) <= set(fetchq.strategy_names)


def test_figure(tmp_path):
    results = {  # the shape of eval_run's results.json
        "selected": {"replay": {"mean": 0.6, "std": 0.05}},
        "replay_by_strategy": {"a": 0.5, "b": 0.7},
        "extra_sets": {"robust-slow": {"selected": {"mean": 0.3, "std": 0.1, "by_strategy": {"a": 0.2, "b": 0.4}}},
                       "robust-noise": {"selected": {"mean": 0.5, "std": 0.0, "by_strategy": {"a": 0.5}}},
                       "other": {"selected": {"mean": 0.1, "std": 0.0}}},
    }
    rows = rfig.parse_results(results)
    assert list(rows) == ["in-distribution", "slow", "noise"] and rows["slow"]["by_strategy"]["b"] == 0.4
    out = rfig.robustness_figure(results, tmp_path / "robust.png", blind={"slow": {"varied": 0.1, "in_distribution": 0.8}})
    assert out.exists() and out.stat().st_size > 1000
    flat = rfig.robustness_figure({"in_distribution": 0.6, "pauses": 0.2}, tmp_path / "flat.png")
    assert flat.exists()
    assert rfig.robustness_curve_figure(results, tmp_path / "none.png") is None  # no per-checkpoint curves
    curves = {**results, "checkpoints": [10, 20], "curves": {"replay_success": [[0.5, 0.7], [0.6, 0.8]]},
              "extra_sets": {"robust-slow": {"curve": [[0.1, 0.3], [0.2, 0.4]]}, "other": {"curve": [[0, 0]]}}}
    out = rfig.robustness_curve_figure(curves, tmp_path / "curves.png")
    assert out.exists() and out.stat().st_size > 1000


@pytest.mark.parametrize("task", ["handover", "seqmanip"])
def test_mjx_sets_validate(task, tmp_path, mjx_env):
    """Tiny MJX sets: 2 varied episodes, validated by open-loop re-simulation, with the human's pauses in them."""
    env = mjx_env(task)
    eps, stats = rb.generate_varied(env, "pauses", 2, max_attempts=MJX_BATCH[task], batch=MJX_BATCH[task])
    assert stats["kept"] == 2 and stats["validated"] >= 2
    path = rb.write_robust_file(tmp_path / f"{task}.hdf5", env, eps, "pauses", "uniform", 102, "test", 2, stats)
    d = load_demos(path, env, require_init=True)
    assert np.all(d.strategy == eps.executed)
    runs = [_longest_still(d.actions_human[i, : d.length[i], :6]) for i in range(d.num)]
    assert min(runs) >= 20


def test_varied_training_set_adds_validated_varied_humans_to_the_team(fetchq, fq_sets, tmp_path):
    """``train_varied``: the default training set, then per_variation validated varied-human episodes of each
    variation, from generator seeds of their own (none is one of the test split's varied humans); cached."""
    from cogail_jax.algo.config import ConfigError, TrainConfig

    k = 2
    with _data_dir(tmp_path):
        path = rb.ensure_varied_training_set(fetchq, per_variation=k, verbose=False)
        team = load_demos(tmp_path / "fetchq_uniform_train.hdf5", fetchq, require_init=True)
        stamp = path.stat().st_mtime_ns
        assert rb.ensure_varied_training_set(fetchq, per_variation=k, verbose=False) == path
        assert path.stat().st_mtime_ns == stamp  # cached, not made again
    d = load_demos(path, fetchq, require_init=True)
    n = team.num
    assert d.num == n + k * len(rb.VARIATIONS)
    with h5py.File(path, "r") as f:
        assert int(f.attrs["team_demos"]) == n and int(f.attrs["varied_per_variation"]) == k
    assert np.array_equal(d.length[:n], team.length) and np.allclose(d.obs[:n, : team.obs.shape[1]], team.obs)
    added = slice(n, None)
    rep = rb.validate_episodes(fetchq, d.init[added], d.actions_human[added], d.actions_robot[added])
    assert np.all(rep["success"] > 0)
    test_inits = np.concatenate([load_demos(p, fetchq, require_init=True).init for p in fq_sets.values()])
    assert not any(np.any(np.all(np.isclose(test_inits, x), axis=1)) for x in d.init[added])
    with h5py.File(path, "r") as f:
        assert not bool(f.attrs["following_partner"])  # fetchq's scripted robot has no following mode
    with pytest.raises(ValueError, match="following mode"):
        rb.generate_varied(fetchq, "change_of_mind", 1, following_partner=True)
    with pytest.raises(ConfigError, match="train_varied"):
        TrainConfig(task="fetchq", train_varied=-1).validate()
    with pytest.raises(ConfigError, match="--demos"):
        TrainConfig(task="fetchq", train_varied=2, demos="mine.hdf5").validate()


def test_following_partner_guesses_then_recovers(tmp_path, mjx_env):
    """seqmanip's training change of mind: the same humans (same draws), a robot that starts on the strategy the
    human's first leg suggests -- its actions part from the plan-reading robot's before the human's do -- and
    episodes that still succeed with the human's strategy and validate by re-simulation (the generator's own
    open-loop replay, which keeps an episode only where the replay succeeds with the strategy drawn;
    ``validate_episodes``' separate replay program is checked against it on fetchq above)."""
    env = mjx_env("seqmanip")  # the generator program test_mjx_sets_validate[seqmanip] compiled
    B = MJX_BATCH["seqmanip"]
    plan, _ = rb.generate_varied(env, "change_of_mind", 4, split="train", max_attempts=B, batch=B)
    follow, stats = rb.generate_varied(env, "change_of_mind", 4, split="train", max_attempts=B, batch=B,
                                       following_partner=True)
    assert stats["kept"] == 4 and stats["validated"] >= 4 and np.array_equal(plan.gen_index, follow.gen_index)
    assert np.array_equal(plan.strategy, follow.strategy) and np.array_equal(follow.executed, follow.strategy)
    early = 0
    for i in range(4):
        d_r = np.abs(plan.actions_robot[i] - follow.actions_robot[i]).max(-1) > 1e-6
        d_h = np.abs(plan.actions_human[i] - follow.actions_human[i]).max(-1) > 1e-6
        early += bool(d_r.any() and (not d_h.any() or np.argmax(d_r) < np.argmax(d_h)))
    assert early >= 3
    assert np.all(follow.success > 0)
