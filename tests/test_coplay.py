"""Closed-loop co-play (cogail_jax.eval.coplay): the scripted human sees only the state, the proxy learns from the
test split alone, the scripted pair succeeds in co-play, and results.json carries the co-play entries."""
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from cogail_envs import get_task, make_env
from cogail_envs.variations import CHANGE_OF_MIND

from cogail_jax.eval import coplay

LATER = 15  # robot B reacts this many steps later than robot A (or, where it has speeds, moves at half speed)
# The human-sees-only-the-state worlds' time limit: seqmanip's robots part ways after ~105 of its 600 steps, so 240
# steps show the parting and the human's actions well after it (the program's run time scales with the steps).
STEPS = {"seqmanip": 240}


def _other_plan(ts):
    """The robot's team state with another internal plan: half its speed, else LATER more steps of delay."""
    if "speed" in ts._fields:
        return ts._replace(speed=ts.speed.at[1].multiply(0.5))
    return ts._replace(delay=ts.delay.at[1].add(LATER))


def _same_state(a, b):
    leaves = jax.tree.leaves(jax.tree.map(lambda x, y: jnp.array_equal(x, y), (a.pipeline_state, a.info),
                                          (b.pipeline_state, b.info)))
    return jnp.all(jnp.stack(leaves))


def _scramble(ts_h, ts_other):
    """The human's team state with every per-agent entry of the robot (index 1 of each (2, ...) field) and the
    co-play robot's own fields taken from another robot's team state."""
    def mix(name, x, y):
        if name in ("seen", "still", "guess"):
            return y
        return x.at[1].set(y[1]) if x.ndim and x.shape[0] == 2 else x

    return ts_h._replace(**{f: mix(f, getattr(ts_h, f), getattr(ts_other, f)) for f in ts_h._fields})


@pytest.fixture(scope="module")
def two_robots():
    """jitted ``f(task) -> (human actions (T, 3, Ah), states equal (T, 3))``: one scripted human (change of mind)
    in three worlds, all from the same start and the same per-step keys, vmapped (the same code for each): 0
    against the scripted robot A; 1 against robot B, the same robot with another internal plan
    (``_other_plan``); 2 against robot A, with the robot's fields of the human's own team state scrambled at every
    step. ``equal[t, w]``: world w's state at step t equals world 0's."""
    fns = {}

    def get(name):
        if name not in fns:
            env = make_env(name, **({"max_episode_steps": STEPS[name]} if name in STEPS else {}))
            team = get_task(name).team

            def run(key):
                k_init, k_team, k_run = jax.random.split(key, 3)
                state = env.reset_from(env.sample_init(k_init))
                ts_h, _ = team.init(env, k_team, env.uniform_mix(), CHANGE_OF_MIND)
                ts_a, _ = team.init(env, jax.random.fold_in(key, 1), env.uniform_mix(), 0)
                other, _ = team.init(env, jax.random.fold_in(key, 2), env.uniform_mix(), 0)
                stack = lambda *xs: jax.tree.map(lambda *v: jnp.stack(v), *xs)  # noqa: E731
                lane = jnp.arange(3)

                def step(s, h, r, k, w):
                    kh, kr = jax.random.split(k)
                    h = jax.tree.map(lambda x, y: jnp.where(w == 2, y, x), h, _scramble(h, other))
                    h, a_h = team.human_act(env, h, s, kh)
                    r, a_r = team.robot_act(env, r, s, kr)
                    return env.step(s, jnp.concatenate([a_h, a_r])), h, r, a_h

                def body(c, k):
                    s, h, r = c
                    equal = jax.vmap(lambda x: _same_state(jax.tree.map(lambda v: v[0], s), x))(s)
                    s, h, r, a_h = jax.vmap(step, in_axes=(0, 0, 0, None, 0))(s, h, r, k, lane)
                    return (s, h, r), (a_h, equal)

                c = (stack(state, state, state), stack(ts_h, ts_h, ts_h), stack(ts_a, _other_plan(ts_a), ts_a))
                _, out = jax.lax.scan(body, c, jax.random.split(k_run, env.max_episode_steps))
                return out

            fns[name] = jax.jit(run)
        return fns[name]

    return get


@pytest.mark.parametrize("task", ["fetchq", "seqmanip"])
def test_coplay_human_sees_only_the_state(two_robots, task):
    """(a) The co-play human's actions do not change with the robot's internal state: against two robots that
    differ in their plan only, they are identical up to the first step where the physical state differs; and
    with the robot's fields of its own team state scrambled, identical at every step (and so is the world)."""
    a_h, equal = jax.device_get(two_robots(task)(jax.random.PRNGKey(7)))
    first_diff = int(np.argmin(equal[:, 1])) if not equal[:, 1].all() else len(equal)
    assert 3 <= first_diff < len(equal)  # the robots' plans did show, but only after a while
    np.testing.assert_array_equal(a_h[:first_diff + 1, 0], a_h[:first_diff + 1, 1])  # a_h[t] reads the state at t
    np.testing.assert_array_equal(a_h[:, 0], a_h[:, 2])
    assert equal[:, 2].all()


@pytest.fixture(scope="module")
def scripted_coplay():
    """The co-play program of a task without a learned robot (scripted robot, scripted human), one per task."""
    fns = {}

    def get(name):
        if name not in fns:
            fns[name] = (make_env(name), None)
            fns[name] = (fns[name][0], coplay.make_coplay_fn(fns[name][0]))
        return fns[name]

    return get


@pytest.mark.parametrize("task", ["fetchq", "handover", "seqmanip"])
def test_scripted_pair_succeeds_in_coplay(scripted_coplay, task):
    """(c) The scripted human and the scripted robot, each on observables only, with their own team states
    (the robot's drawn from its own key), still succeed."""
    env, run = scripted_coplay(task)
    assert coplay.partners(env)[0] == coplay.SCRIPTED and coplay.has_scripted_robot(env)
    batch = coplay.episode_batch(env, [coplay.SCRIPTED], 6, ("scripted",), first=6)  # both seqmanip strategies
    out = jax.device_get(run(None, None, None, batch))
    assert out["success"].shape == (1, 6)
    assert out["success"].mean() >= 5 / 6, out
    if task == "seqmanip":
        assert set(out["strategy"][0].tolist()) == {1, 2}, out


@pytest.mark.parametrize("task", ["examples.table_carry:TASK", "fetchq", "handover"])
def test_results_md_describes_only_the_partners_and_robots_it_shows(task):
    """results.md's co-play footnote: the scripted human, its variations, its held-out pose slices and the scripted
    robot each described where the task has them (the partners coplay.partners gives it), never otherwise."""
    env = make_env(task)
    names, scripted = coplay.partners(env), coplay.has_scripted_robot(env)
    proxy = {"hidden": [256, 256], "split": "test", "episodes": 20, "samples": 900, "steps": 500, "loss": 0.01}
    one = {"mean": 0.5, "std": 0.1}
    c = {"partners": names, "episodes": 4, "proxy_episodes": 16, "scripted_robot_copies": 1 if scripted else 0,
         "learned": {"selected": {"checkpoint": 3, "success": {n: one for n in names}}},
         "scripted_robot": {n: 0.5 for n in names} if scripted else None, "proxy": proxy}
    note = coplay.markdown(c)[-1]
    assert ("scripted human" in note) == (coplay.SCRIPTED in names), note
    assert ("change_of_mind" in note) == ("change_of_mind" in names), note
    assert ("pose_heldout" in note) == any(n.startswith("pose_heldout") for n in names), note
    assert ("The scripted robot" in note) == scripted and "proxy: an MLP (256, 256)" in note, note
    if task.startswith("examples"):  # a proxy alone: nothing of a scripted human or robot
        assert names == [coplay.PROXY] and not scripted and "scripted" not in note, note


def test_each_held_out_pose_slice_is_a_partner_where_the_team_draws_them():
    """Where the team draws held-out pose slices, each (``pose_heldout_<axis>``) is a co-play partner: its episodes
    carry that slice's variation id (the scripted human presents the object there) and start as the other partners'
    do."""
    from cogail_envs.variations import pose_slice, slice_names

    for task in ("fetchq", "handover", "seqmanip"):
        env = make_env(task)
        names = coplay.partners(env)
        held = slice_names(get_task(task).team.held_out_slices) if task != "fetchq" else ()
        assert tuple(n for n in names if n.startswith("pose_heldout")) == held and names[-1] == coplay.PROXY, task
    env = make_env("handover")
    batch = coplay.episode_batch(env, [coplay.SCRIPTED, "pose_heldout_roll", "pose_heldout_x"], 3, ("learned",))
    for axis in ("roll", "x"):
        held = batch["partner"] == f"pose_heldout_{axis}"
        assert (batch["variation"][held] == pose_slice(axis)).all()
        assert (batch["key"][held] == batch["key"][batch["partner"] == coplay.SCRIPTED]).all()  # the same starts
    assert (batch["variation"][batch["partner"] == coplay.SCRIPTED] == 0).all()


def test_the_proxy_plays_more_episodes_from_the_same_starts(fetchq):
    """The proxy's rare successes get PROXY_EPISODES times the episodes; its first ones start where every other
    partner's do, with each robot."""
    b = coplay.episode_batch(fetchq, [coplay.SCRIPTED, coplay.PROXY], 3, ("learned", "scripted"))
    for robot in ("learned", "scripted"):
        keys = {n: b["key"][(b["partner"] == n) & (b["robot"] == robot)] for n in (coplay.SCRIPTED, coplay.PROXY)}
        assert len(keys[coplay.SCRIPTED]) == 3 and len(keys[coplay.PROXY]) == 3 * coplay.PROXY_EPISODES > 3
        np.testing.assert_array_equal(keys[coplay.PROXY][:3], keys[coplay.SCRIPTED])
        assert len(np.unique(keys[coplay.PROXY], axis=0)) == len(keys[coplay.PROXY])
    assert b["proxy"].sum() == 2 * 3 * coplay.PROXY_EPISODES


def test_the_scripted_robot_plays_other_episodes_in_each_copy(fetchq):
    """In each copy of the program (one per seed of the learned robot) the learned robot's episodes start from the
    same keys, and the scripted robot's from other keys in every copy after the first, none of them an episode of the
    first copy: its reference rate rests on as many episodes as the learned robot's mean over seeds."""
    b = coplay.episode_batch(fetchq, [coplay.SCRIPTED, coplay.PROXY], 3, ("learned", "scripted"))
    keys = np.asarray(coplay.episode_keys(b["index"], b["scripted_robot"], 3))
    assert keys.shape == (3, len(b["index"]), 2)
    np.testing.assert_array_equal(keys[0], b["key"])
    learned = ~b["scripted_robot"]
    for p in (1, 2):
        np.testing.assert_array_equal(keys[p][learned], keys[0][learned])
    for name in (coplay.SCRIPTED, coplay.PROXY):  # per partner, no episode of the scripted robot repeats
        sel = b["scripted_robot"] & (b["partner"] == name)
        ref = keys[:, sel].reshape(-1, 2)
        assert len(ref) == 3 * sel.sum() and len(np.unique(ref, axis=0)) == len(ref)
    assert not {tuple(k) for k in keys[1:, b["scripted_robot"]].reshape(-1, 2)} & {tuple(k) for k in keys[0]}


def test_proxy_trains_on_the_test_split_only(demo_files, fetchq):
    """(b) The proxy refuses any split but the test one, learns deterministically, and records what it learned
    from (the test data's digest)."""
    from cogail_jax.data import io as data
    from cogail_jax.eval import rollouts

    test = rollouts.heldout_arrays(data.load_demos(demo_files[1], fetchq, require_init=True))
    with pytest.raises(coplay.CoplayError, match="test split"):
        coplay.train_proxy(test, "validation", steps=5)
    p1, info = coplay.train_proxy(test, "test", steps=50, file=demo_files[1])
    p2, _ = coplay.train_proxy(test, "test", steps=50)
    assert info["split"] == "test" and info["file"] == str(demo_files[1])
    assert info["digest"] == coplay.data_digest(test["obs"], test["ah"], test["length"])
    assert info["samples"] == int(np.sum(test["length"])) and info["loss"] < info["loss_curve"][0]
    for a, b in zip(jax.tree.leaves(p1), jax.tree.leaves(p2)):
        np.testing.assert_array_equal(a, b)
    a_h = coplay.proxy_action(p1, jnp.asarray(test["obs"][0, :3 * 4]).reshape(3, 4, -1))
    assert a_h.shape == (3, fetchq.human_action_size) and np.all(np.abs(np.asarray(a_h)) <= 1)


def test_a_proxy_study_variant_does_not_read_its_unread_features(demo_files, fetchq):
    """experiments/proxy_study.py: a proxy variant that does not read some observation indices acts the same
    whatever they hold (in the newest observation and in its history), and moves with a feature it reads."""
    import importlib.util
    from pathlib import Path

    from cogail_jax.data import io as data
    from cogail_jax.eval import rollouts

    found = importlib.util.spec_from_file_location("proxy_study",
                                                   Path(__file__).parents[1] / "experiments" / "proxy_study.py")
    study = importlib.util.module_from_spec(found)
    found.loader.exec_module(study)
    test = rollouts.heldout_arrays(data.load_demos(demo_files[1], fetchq, require_init=True))
    D = test["obs"].shape[-1]
    proxy, info = study.train_variant(test, (0, D - 1), key=0, steps=20)
    assert info["samples"] == int(np.sum(test["length"]))
    hist = jnp.asarray(test["obs"][0, :12]).reshape(3, 4, -1)
    moved = hist.at[..., jnp.array([0, D - 1])].add(jax.random.normal(jax.random.PRNGKey(1), hist[..., :2].shape) * 5)
    np.testing.assert_array_equal(coplay.proxy_action(proxy, hist), coplay.proxy_action(proxy, moved))
    assert not np.array_equal(coplay.proxy_action(proxy, hist), coplay.proxy_action(proxy, hist.at[..., 1].add(5.0)))


def test_eval_run_reports_coplay(tiny_cfg, demo_files, fetchq, tmp_path, caplog):
    """(d) results.json / results.md carry co-play per partner for the learned robot at the selected and the
    paper-protocol checkpoints and for the scripted robot, the proxy's record (trained on the test split: its
    digest is the test file's), and RUN/coplay.png is drawn. Co-play's proxy and program were made while training
    ran (``EvalPrep``: nothing of it compiles in the evaluation), and ``cogail eval --coplay-only``, which makes them
    from nothing, gives the same figures."""
    import logging

    from cogail_jax.apps import eval_runner, train_loop
    from cogail_jax.data import io as data
    from cogail_jax.eval import rollouts

    run = tmp_path / "run"
    prep = eval_runner.EvalPrep(run, robustness=False, coplay=True, coplay_episodes=1)
    train_loop.train_run(tiny_cfg.replace(bc_steps=3000), run, progress=False, on_compiled=prep.start)
    caplog.set_level(logging.WARNING)

    def seen(x):  # a program compiled for sure: the log below does show compilations
        return x + 1

    with jax.log_compiles(True):
        eval_runner.eval_run(run, progress=False, coplay=True, coplay_episodes=1, prepared=prep)
        jax.jit(seen)(np.float32(1))
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(")]
    assert any(m.startswith("Compiling jit(seen)") for m in compiled)
    assert not [m for m in compiled if m.startswith(("Compiling jit(coplay)", "Compiling jit(fit)"))]
    res = json.loads((run / "results.json").read_text())
    c = res["coplay"]
    names = ["scripted", "slow", "fast", "pauses", "detour", "noise", "change_of_mind", "proxy"]
    assert c["partners"] == names and c["episodes"] == 1 and c["scripted_robot_copies"] == 2  # seeds 3, 5
    assert c["learned"]["selected"]["checkpoint"] == res["selected"]["checkpoint"]
    assert c["learned"]["paper_protocol"]["checkpoint"] == res["paper_protocol"]["replay"]["checkpoint"]
    for key in ("selected", "paper_protocol"):
        succ = c["learned"][key]["success"]
        assert list(succ) == names
        assert all(set(e["per_seed"]) == {"3", "5"} and 0 <= e["mean"] <= 1 for e in succ.values())
    assert list(c["scripted_robot"]) == names and c["scripted_robot"]["scripted"] == 1.0
    # the robot (BC first) succeeds with some partners: `--coplay-only`'s equality below compares figures, not zeros
    assert sum(e["mean"] for e in c["learned"]["selected"]["success"].values()) > 0
    test = rollouts.heldout_arrays(data.load_demos(demo_files[1], fetchq, require_init=True))
    val = rollouts.heldout_arrays(data.load_demos(demo_files[2], fetchq, require_init=True))
    p = c["proxy"]
    assert p["split"] == "test" and p["file"] == res["splits"]["test"]["file"] == str(demo_files[1])
    assert p["digest"] == coplay.data_digest(test["obs"], test["ah"], test["length"])
    assert p["digest"] != coplay.data_digest(val["obs"], val["ah"], val["length"])
    assert p["success_with_scripted_robot"] == c["scripted_robot"]["proxy"] and p["loss"] > 0
    md = (run / "results.md").read_text()
    assert "Closed-loop co-play" in md and "| change_of_mind |" in md and "| proxy |" in md
    assert (run / "coplay.png").stat().st_size > 0
    # `cogail eval --coplay-only`: co-play again at the reported checkpoints, the other figures kept as they were
    (run / "coplay.png").unlink()
    again = eval_runner.eval_coplay(run, episodes=1)
    assert again["coplay"] == json.loads(json.dumps(c)) and again["selected"] == res["selected"]
    assert json.loads((run / "results.json").read_text()) == json.loads(json.dumps(again))
    assert (run / "coplay.png").stat().st_size > 0
