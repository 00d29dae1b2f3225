"""The reporting protocol (protocol.summarize) on made-up curves with a known answer, the disjoint default
splits, and one tiny evaluation with a validation set and an extra test set."""
import json
import time

import numpy as np
import pytest
from cogail_envs import get_task

from cogail_jax.eval import rollouts
from cogail_jax.eval import protocol

SEEDS = (1, 2, 3)
STEPS = (10, 20, 30, 40)
# success rates, (seeds, checkpoints); 4 episodes / codes each, so every rate is a multiple of 1/4
TEST_REPLAY = [[0.25, 1.0, 0.5, 0.5],
               [0.5, 0.25, 0.75, 0.5],
               [0.75, 0.25, 0.5, 0.5]]  # seed means 0.5, 0.5, 0.583, 0.5: paper protocol -> 30
VAL_REPLAY = [[0.0, 0.5, 0.5, 0.5],
              [0.0, 0.5, 0.25, 0.75],
              [0.0, 0.5, 0.75, 0.25]]  # seed means 0, 0.5, 0.5, 0.5: a three-way tie -> the later, 40
INTERP = [[0.0, 0.5, 1.0, 0.25],
          [0.0, 0.75, 0.5, 0.25],
          [0.0, 0.25, 0.75, 0.25]]  # seed means 0, 0.5, 0.75, 0.25: paper protocol -> 30


def _episodes(rate, n=4):
    k = int(round(rate * n))
    return np.array([1.0] * k + [0.0] * (n - k))


def _per_ckpt(validation=True, val_interp=None):
    out = {}
    for c, step in enumerate(STEPS):
        strat = np.array([[c % 4 + 1, 1, 2, 3]] * len(SEEDS))  # executed strategy of each interpolation rollout
        r = {"replay_success": np.stack([_episodes(TEST_REPLAY[i][c]) for i in range(3)]),
             "interp_success": np.stack([_episodes(INTERP[i][c]) for i in range(3)]),
             "interp_strategy": strat}
        if validation:
            r["val_replay_success"] = np.stack([_episodes(VAL_REPLAY[i][c]) for i in range(3)])
        if val_interp is not None:  # the validation rollouts: their own rates, strategies in reverse order
            r["val_interp_success"] = np.stack([_episodes(val_interp[i][c]) for i in range(3)])
            r["val_interp_strategy"] = strat[:, ::-1]
        out[step] = r
    return out


def _stat(values):
    return {"mean": pytest.approx(np.mean(values)), "std": pytest.approx(np.std(values)),
            "per_seed": {str(s): pytest.approx(v) for s, v in zip(SEEDS, values)}}


def test_paper_protocol_selected_last_and_per_seed_best():
    res = protocol.summarize("fetchq", "cogail", SEEDS, _per_ckpt(), ("s1", "s2", "s3", "s4"), None)
    rep, val, itp = (np.array(x) for x in (TEST_REPLAY, VAL_REPLAY, INTERP))
    pp = res["paper_protocol"]
    # the paper: the checkpoint maximising the seed MEAN, mean +- std over seeds there, per column
    assert pp["replay"]["checkpoint"] == 30 and pp["interpolation"]["checkpoint"] == 30
    assert {k: pp["replay"][k] for k in ("mean", "std", "per_seed")} == _stat(rep[:, 2])
    assert pp["replay"]["mean"] == pytest.approx(7 / 12)
    assert {k: pp["interpolation"][k] for k in ("mean", "std", "per_seed")} == _stat(itp[:, 2])
    # selected on validation (tie 20 / 30 / 40 -> the later), reported on test
    sel = res["selected"]
    assert sel["checkpoint"] == 40
    assert sel["validation_replay"] == _stat(val[:, 3])
    assert sel["replay"] == _stat(rep[:, 3]) and sel["replay"]["std"] == 0.0
    assert sel["interpolation"] == _stat(itp[:, 3])
    assert res["last"]["checkpoint"] == 40 and res["last"]["replay"] == _stat(rep[:, 3])
    # each seed's own best: 1.0 (20), 0.75 (30), 0.75 (10): inflated above the paper protocol
    psb = res["per_seed_best"]
    assert psb["replay"]["mean"] == pytest.approx(2.5 / 3) and psb["replay"]["mean"] > pp["replay"]["mean"]
    assert psb["replay"]["checkpoint"] == {"1": 20, "2": 30, "3": 10}
    assert psb["interpolation"]["checkpoint"] == {"1": 30, "2": 20, "3": 30}
    assert "best_checkpoint" not in res and "replay_success" not in res  # no per-seed best at the top
    # the breakdowns are at the selected checkpoint; Fig. 3's paper-protocol distribution at 30
    assert res["breakdowns_at"] == {"checkpoint": 40, "basis": "selected on validation"}
    # at 40 (c = 3) the successful rollout (the first, 1 of 4) executed strategy 4
    assert res["strategy_distribution"] == {"s1": 0.0, "s2": 0.0, "s3": 0.0, "s4": 1.0}
    # at 30 (c = 2): seed 1 all four succeed (3, 1, 2, 3), seed 2 two (3, 1), seed 3 three (3, 1, 2): 9 in all
    assert pp["interpolation"]["strategy_distribution"] == pytest.approx(
        {"s1": 3 / 9, "s2": 2 / 9, "s3": 4 / 9, "s4": 0.0})
    assert np.array_equal(res["curves"]["replay_success"], rep)
    assert np.array_equal(res["curves"]["validation_replay_success"], val)
    assert np.array_equal(res["curves"]["interpolation_success"], itp)
    json.dumps(res)  # results.json is plain JSON
    md = protocol.results_markdown(res)
    assert md.index("selected on validation") < md.index("paper protocol") < md.index("| last |")
    assert "**50.0 +- 0.0**" in md and "58.3 +- 11.8" in md and "inflated" in md


def test_the_robot_to_show_is_the_selected_checkpoint_and_its_best_validation_seed():
    res = protocol.summarize("fetchq", "cogail", SEEDS, _per_ckpt(), ("a", "b", "c", "d"), None)
    assert protocol.selected_checkpoint(res) == (2, 40)  # validation at 40: 0.5, 0.75, 0.25
    res = protocol.summarize("fetchq", "cogail", SEEDS, _per_ckpt(validation=False), ("a", "b", "c", "d"), None)
    assert protocol.selected_checkpoint(res) == (2, 30)  # no validation: paper protocol, best test seed there
    assert protocol.selected_checkpoint({"best_checkpoint": {"5": {"replay": 7, "interpolation": 3}}}) == (5, 7)
    assert protocol.selected_checkpoint({}) == (None, None)


def test_ties_go_to_the_later_checkpoint_whatever_the_rounding():
    thirds = np.array([[0.1 + 0.2, 0.3], [1 / 3, 1 / 3]])  # equal means, up to float rounding
    assert protocol.argmax_seed_mean(thirds) == 1
    assert protocol.argmax_seed_mean(np.array([[0.2, 0.1, 0.2]])) == 2
    assert protocol.argmax_seed_mean(np.array([[0.9, 0.1, 0.2]])) == 0


def test_without_validation_there_is_no_selected_checkpoint():
    res = protocol.summarize("fetchq", "cogail", SEEDS, _per_ckpt(validation=False), ("a", "b", "c", "d"), None)
    assert res["selected"] is None and "validation_replay_success" not in res["curves"]
    assert res["breakdowns_at"]["checkpoint"] == 40 and res["paper_protocol"]["replay"]["checkpoint"] == 30
    assert "no selected checkpoint" in protocol.results_markdown(res)


def test_stack_sets_and_extra_set_summary():
    a = {"init": np.ones((2, 3)), "ah": np.ones((2, 5, 2)), "length": np.array([5, 4]), "obs": np.ones((2, 5, 6)),
         "prev_ah": np.ones((2, 5, 2)), "strategy": np.array([1, 2])}
    b = {"init": np.zeros((3, 3)), "ah": np.ones((3, 7, 2)), "length": np.array([7, 1, 2]),
         "obs": np.ones((3, 7, 6)), "prev_ah": np.ones((3, 7, 2)), "strategy": np.array([1, 1, 1])}
    batch, part = rollouts.stack_sets({"test": a, "validation": b})
    assert part == {"test": slice(0, 2), "validation": slice(2, 5)} and "strategy" not in batch
    assert batch["ah"].shape == (5, 7, 2) and batch["ah"][:2, 5:].sum() == 0 and batch["obs"].shape == (5, 7, 6)
    np.testing.assert_array_equal(batch["length"], [5, 4, 7, 1, 2])
    padded, _ = rollouts.stack_sets({"test": a, "validation": b}, steps=9)  # shapes fixed by the episode limit
    assert padded["ah"].shape == (5, 9, 2) and padded["obs"].shape == (5, 9, 6)
    np.testing.assert_array_equal(padded["ah"][:, :7], batch["ah"])
    succ = {"selected": np.array([[1, 0, 1, 1], [0, 0, 1, 1]]), "paper_protocol": np.ones((2, 4))}
    e = protocol.summarize_extra_set(succ, np.array([1, 1, 2, 2]), (7, 8), ("x", "y"),
                                     {"selected": 40, "paper_protocol": 30}, file="f.hdf5")
    assert e["episodes"] == 4 and e["selected"]["checkpoint"] == 40
    assert e["selected"]["mean"] == pytest.approx(0.625) and e["selected"]["per_seed"] == {"7": 0.75, "8": 0.5}
    assert e["selected"]["by_strategy"] == {"x": 0.25, "y": 1.0} and e["paper_protocol"]["mean"] == 1.0


def test_default_splits_are_disjoint(fetchq, tmp_path, monkeypatch):
    """train, validation and test default files come from distinct generator seeds: no episode of one is an
    episode of another (no shared start state, no shared human action sequence)."""
    from cogail_jax.data import io as data

    monkeypatch.setenv("COGAIL_DATA", str(tmp_path))
    monkeypatch.setitem(get_task("fetchq").splits, "train", 12)
    monkeypatch.setitem(get_task("fetchq").splits, "validation", 12)
    monkeypatch.setitem(get_task("fetchq").splits, "test", 12)
    files = {sp: data.ensure_default_demos(fetchq, sp, verbose=False) for sp in data.SPLITS}
    assert data.ensure_default_demos(fetchq, "heldout", verbose=False) == files["test"]  # another name of test
    assert len({p.name for p in files.values()}) == 3
    d = {sp: data.load_demos(p, fetchq, require_init=True) for sp, p in files.items()}
    for sp, x in d.items():
        assert x.num >= 10, sp
    for a, b in (("train", "validation"), ("train", "test"), ("validation", "test")):
        inits = {tuple(np.round(v, 6)) for v in d[a].init}
        assert not inits & {tuple(np.round(v, 6)) for v in d[b].init}, (a, b)
        acts = {d[a].actions_human[i, : d[a].length[i]].tobytes() for i in range(d[a].num)}
        assert not acts & {d[b].actions_human[i, : d[b].length[i]].tobytes() for i in range(d[b].num)}, (a, b)
    with pytest.raises(ValueError, match="unknown split"):
        data.default_demo_path("fetchq", "dev")


def test_eval_run_reports_validation_test_and_extra_sets(tiny_cfg, demo_files, fetchq, tmp_path, monkeypatch,
                                                          capsys, caplog):
    """A tiny run: every checkpoint on test and validation, the protocol's keys, and an extra set. The extra
    set is the test file itself, so its replay figures must equal the test replay figures at the same
    checkpoints (the replay-only program and the stacked test + validation program agree). The first evaluation
    was prepared while training ran (``EvalPrep``); the later ones, made from nothing, give the same figures."""
    import jax

    from cogail_jax.data import io as data
    from cogail_jax.data import generate as demos
    from cogail_jax.apps import eval_runner, runs, train_loop

    val = data.save_demos(tmp_path / "val.hdf5", fetchq, demos.generate(fetchq, 6, seed=2), seed=2)
    cfg = tiny_cfg.replace(seeds=(3, 5), validation=str(val), bc_steps=3000)  # BC: episodes that succeed
    run = tmp_path / "run"
    kept = {}
    prep = eval_runner.EvalPrep(run, robustness=False, extra_sets={"again": demo_files[1]})  # made while training runs
    train_loop.train_run(cfg, run, progress=False, keep=kept, on_compiled=prep.start)
    assert sorted(kept) == [2, 4, 6]  # every checkpoint the training wrote (update 0 is not evaluated)
    from cogail_jax.apps.report import read_scalars  # TensorBoard: every metric of every update, one file per seed

    sc = read_scalars(run / "tb")
    assert set(sc) == {"3", "5"} and set(sc["3"]) == set(sc["5"]) and "train/episode_success" in sc["3"]
    spu = cfg.steps_per_update
    for tag, (st, x) in sc["5"].items():
        assert st.tolist() == [u * spu for u in range(1, 7)] and np.all(np.isfinite(x)), tag
    assert np.all(sc["3"]["train/nonfinite"][1] == 0)
    import logging

    caplog.set_level(logging.WARNING)
    def seen(x):  # a program compiled for sure: the log below does show compilations
        return x + 1

    with jax.log_compiles(True):  # its programs were compiled in the background: nothing compiles now
        res = eval_runner.eval_run(run, progress=False, extra_sets={"again": demo_files[1]}, memory=kept,
                               prepared=prep)
        jax.jit(seen)(np.float32(1))
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(")]
    assert any(m.startswith("Compiling jit(seen)") for m in compiled)
    assert not [m for m in compiled if m.startswith(("Compiling jit(evaluate)", "Compiling jit(replay)"))]
    assert json.loads((run / "speed.json").read_text())["eval_parts"]["prepared"] > 0

    class Late:  # a preparation still at work when the evaluation starts: its wait is the eval phase's set-up
        def result(self):
            time.sleep(0.5)

    eval_runner.eval_run(run, progress=False, extra_sets={"again": demo_files[1]}, memory=kept, prepared=Late())
    assert json.loads((run / "speed.json").read_text())["eval_parts"]["setup"] >= 0.5
    assert res["checkpoints"] == [2, 4, 6]
    # episodes succeed (BC above), so the equalities below compare figures, not zeros
    assert all(np.asarray(res["curves"][k]).sum() > 0 for k in ("replay_success", "validation_replay_success"))
    assert res["splits"]["validation"] == {"file": str(val), "episodes": 6}
    assert res["splits"]["test"]["episodes"] == 4
    assert np.asarray(res["curves"]["validation_replay_success"]).shape == (2, 3)
    sel, pp = res["selected"], res["paper_protocol"]
    assert sel["checkpoint"] in (2, 4, 6) and res["latent_map"]["checkpoint"] == sel["checkpoint"]
    e = res["extra_sets"]["again"]
    assert e["episodes"] == 4 and e["selected"]["checkpoint"] == sel["checkpoint"]
    assert e["selected"]["per_seed"] == sel["replay"]["per_seed"]
    assert e["paper_protocol"]["checkpoint"] == pp["replay"]["checkpoint"]
    assert e["paper_protocol"]["per_seed"] == pp["replay"]["per_seed"]
    assert "curve" not in e  # replayed at the reported checkpoints only (the default)
    saved = json.loads((run / "results.json").read_text())
    assert list(saved)[:4] == ["task", "method", "seeds", "checkpoints"] and "extra_sets" in saved
    own = json.loads((run / "replay-again" / "results.json").read_text())
    assert own["replay_success"]["per_seed"] == sel["replay"]["per_seed"]
    # adding a set later (`cogail eval --extra-set`, the run evaluated already) replays it at the same checkpoints
    # only (eval_runner.eval_extra_sets); the earlier set is kept
    from cogail_jax.apps import cli

    assert eval_runner.results_current(run)
    calls = []
    monkeypatch.setattr(eval_runner, "eval_run", lambda *a, **k: calls.append(a))  # must not be needed
    assert cli.main(["eval", "--run", str(run), "--extra-set", f"val-again={val}", "--no-progress"]) == 0
    assert not calls and "replay against" in capsys.readouterr().out
    res2 = json.loads((run / "results.json").read_text())
    assert set(res2["extra_sets"]) == {"again", "val-again"}
    # (a set added later is counted in float64, the evaluation's sets in float32: the same figure to 1e-7)
    assert res2["extra_sets"]["val-again"]["selected"]["per_seed"] == pytest.approx(
        sel["validation_replay"]["per_seed"])
    assert "val-again" in (run / "results.md").read_text()
    monkeypatch.undo()
    # checkpoints two at a time in one device program (vmapped over stacked parameters; the second group padded):
    # the same figures as one checkpoint at a time
    # with extra_curves the extra sets ride in that program's batch at every checkpoint: a curve per set, and the
    # reported figures those of the default evaluation (the extra sets' too)
    again = eval_runner.eval_run(run, progress=False, ckpt_batch=2, extra_curves=True)
    for key in ("replay_success", "validation_replay_success", "interpolation_success"):
        assert again["curves"][key] == res["curves"][key], key
    assert again["selected"] == sel and again["paper_protocol"] == pp
    assert again["extra_sets"]["again"]["curve"] == res["curves"]["replay_success"]  # every checkpoint and seed
    for key in ("selected", "paper_protocol"):
        assert again["extra_sets"]["again"][key] == res["extra_sets"]["again"][key], key
    np.testing.assert_allclose(again["latent_map"]["codes"], res["latent_map"]["codes"], rtol=1e-5, atol=1e-6)
    assert set(again["extra_sets"]) == {"again", "val-again"}  # earlier extra sets are evaluated again
    # ... stacked into one replay batch (4 and 6 episodes, padded to the episode limit): each set's figures are
    # still those of its own episodes
    assert again["extra_sets"]["again"]["selected"]["per_seed"] == sel["replay"]["per_seed"]
    assert again["extra_sets"]["val-again"]["selected"]["per_seed"] == pytest.approx(
        sel["validation_replay"]["per_seed"])
    # the checkpoints kept in memory by the training loop, all in one program: no checkpoint read from disk, and
    # the same results as reading each one back
    monkeypatch.setattr(runs.ckpt, "restore", lambda *a, **k: pytest.fail("a checkpoint was read from disk"))
    mem = eval_runner.eval_run(run, progress=False, ckpt_batch=3, memory=kept)
    monkeypatch.undo()
    for key in ("replay_success", "validation_replay_success", "interpolation_success"):
        assert mem["curves"][key] == res["curves"][key], key
    assert mem["selected"] == sel and mem["paper_protocol"] == pp and mem["last"] == res["last"]
    np.testing.assert_allclose(mem["latent_map"]["codes"], res["latent_map"]["codes"], rtol=1e-5, atol=1e-6)
    assert mem["extra_sets"]["again"]["selected"] == again["extra_sets"]["again"]["selected"]
    # a device that runs out of memory with 3 checkpoints per program: the evaluation goes on with fewer, the
    # same results, and a warning says which --ckpt-batch fits
    from cogail_jax.eval import rollouts as ev
    from cogail_jax.eval import protocol

    real = ev.make_eval_fn

    def small_device(*a, **k):
        fn = real(*a, **k)

        def call(params, norm, held):
            if jax.tree.leaves(params)[0].shape[0] > 1:
                raise RuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 1.00GiB.")
            return fn(params, norm, held)
        return call

    monkeypatch.setattr(ev, "make_eval_fn", small_device)
    capsys.readouterr()
    oom = eval_runner.eval_run(run, progress=False, ckpt_batch=3, memory=kept)
    monkeypatch.undo()
    out = capsys.readouterr().out
    assert "give --ckpt-batch 1 next time" in out and "compare runs evaluated with the same batch" in out
    assert oom["curves"] == mem["curves"] and oom["selected"] == sel


def test_checkpoints_per_evaluation_program_default_by_backend(monkeypatch):
    """None (the CLI's default): 1 checkpoint per program on the CPU; on an accelerator every checkpoint of the
    run in one program (up to a cap)."""
    from cogail_jax.apps import eval_runner, runs, train_loop

    monkeypatch.setattr(runs.jax, "default_backend", lambda: "cpu")
    assert eval_runner.default_ckpt_batch(34) == 1
    monkeypatch.setattr(runs.jax, "default_backend", lambda: "gpu")
    assert eval_runner.default_ckpt_batch(34) == 34
    assert eval_runner.default_ckpt_batch(1000) == eval_runner.MAX_CKPT_BATCH


def test_eval_program_matches_a_step_by_step_reference(tiny_cfg, demo_files, fetchq):
    """The one-batch evaluation program (interpolation and replay episodes side by side, the physics on one flat
    axis) against each protocol written out one episode and one step at a time: the replay robot of
    ``make_robot_step`` (what `cogail play` drives) and the co-policy acting for both agents with a code."""
    import jax
    import jax.numpy as jnp

    from cogail_jax.data import io as data
    from cogail_jax.algo import train

    cfg = tiny_cfg.replace(bc_steps=3000, eval_codes=4)
    expert = train.expert_arrays(data.load_demos(cfg.demos, fetchq), cfg.history)
    init, _, nets = train.make_train_fns(cfg, fetchq, train.fit_normalizer(expert))
    state = init(cfg.seeds, expert)
    held = rollouts.heldout_arrays(data.load_demos(demo_files[1], fetchq, require_init=True))
    held = {k: v for k, v in held.items() if k != "strategy"}
    E = held["length"].shape[0]
    one = lambda t: jax.tree.map(lambda x: x[None], t)  # noqa: E731  (one checkpoint)
    out = jax.device_get(rollouts.make_eval_fn(cfg, fetchq, nets)(one(state.params), one(state.norm), held))
    assert out["replay_success"].shape == (1, 2, E) and out["interp_success"].shape == (1, 2, 4)

    _, robot_step = rollouts.make_robot_step(cfg, fetchq, nets)
    robot_step, env_step = jax.jit(robot_step), jax.jit(fetchq.step)
    actor = jax.jit(nets["actor"].apply)
    codes = rollouts.interpolation_codes(cfg.eval_codes)
    keys = {name: jax.random.split(jax.random.PRNGKey(seed), cfg.eval_codes)
            for name, seed in (("interp", rollouts.EVAL_SEED), ("val_interp", rollouts.VALIDATION_EVAL_SEED))}
    Ah, ref = fetchq.human_action_size, {"replay": [], "interp": [], "val_interp": []}
    for i in range(len(cfg.seeds)):
        params, norm = jax.tree.map(lambda x: x[i], (state.params, state.norm))
        for e in range(E):  # replay: the recorded human, the robot from pi_R(s, psi(h))
            s = fetchq.reset_from(jnp.asarray(held["init"][e]))
            hist, prev = jnp.repeat(s.obs[None], cfg.history + 1, 0), jnp.zeros(Ah)
            for t in range(fetchq.max_episode_steps):
                a_h = jnp.asarray(held["ah"][e][t] if t < held["length"][e] else np.zeros(Ah, np.float32))
                s, hist, _, _ = robot_step(params, norm, s, hist, prev, a_h)
                prev = a_h
                if s.done:
                    break
            ref["replay"].append(s.metrics)
        for name, k in ((name, k) for name in keys for k in range(cfg.eval_codes)):  # the co-policy with code k
            s = fetchq.reset(keys[name][k])  # from the reported and from the validation initial states
            for t in range(fetchq.max_episode_steps):
                mean, _ = actor(params["actor"], (s.obs - norm["mean"]) / norm["std"], codes[k])
                s = env_step(s, jnp.clip(mean, -1, 1))
                if s.done:
                    break
            ref[name].append(s.metrics)
    for name, got in (("replay", out["replay_metrics"]), ("interp", out["interp_metrics"])):
        for m, v in got.items():  # every final metric: success, events, positions
            assert np.allclose(np.asarray(v).reshape(-1), [float(r[m]) for r in ref[name]], atol=1e-5), (name, m)
    assert out["val_interp_success"].shape == (1, 2, 4)
    assert np.array_equal(out["val_interp_success"].reshape(-1), [float(r["success"]) for r in ref["val_interp"]])
    assert np.array_equal(out["val_interp_strategy"].reshape(-1),
                          [int(fetchq.classify_strategy(r)) for r in ref["val_interp"]])
    assert out["replay_success"].sum() + out["interp_success"].sum() > 0  # some episode succeeds: a real check


def test_validation_interpolation_is_reported_beside_the_test_figures_and_chooses_nothing():
    """The validation interpolation rollouts give their own figure at the selected and the last checkpoint, their
    curve and strategy shares; the selected checkpoint stays the validation replay's, and the test figures are the
    same as without them."""
    v_itp = np.array(INTERP)[::-1]  # the seeds' rows swapped: best at 30 on its own, but nothing is chosen on it
    res = protocol.summarize("fetchq", "cogail", SEEDS, _per_ckpt(val_interp=v_itp), ("s1", "s2", "s3", "s4"), None)
    plain = protocol.summarize("fetchq", "cogail", SEEDS, _per_ckpt(), ("s1", "s2", "s3", "s4"), None)
    sel = res["selected"]
    assert sel["checkpoint"] == 40 and sel["validation_interpolation"] == _stat(v_itp[:, 3])
    assert res["last"]["validation_interpolation"] == _stat(v_itp[:, 3])
    assert np.array_equal(res["curves"]["validation_interpolation_success"], v_itp)
    # at 40, one rollout per seed succeeds, the first, which executed strategy 3 there (reversed order: 3, 2, 1, 4)
    assert res["validation_strategy_distribution"] == {"s1": 0.0, "s2": 0.0, "s3": 1.0, "s4": 0.0}
    for key in ("paper_protocol", "per_seed_best", "strategy_distribution"):
        assert res[key] == plain[key]
    assert "validation_interpolation" not in plain["selected"] and "validation_strategy_distribution" not in plain
    md = protocol.results_markdown(res)
    assert f"(validation replay {protocol._f(sel['validation_replay'])}, interpolation " in md
    assert "| s3 | 0.0 | 44.4 | 100.0 |" in md  # test share, paper-protocol share, validation share


def test_robustness_sets_of_a_run_trained_on_varied_humans_are_flagged():
    """A run whose training set held varied humans (train_varied) says so next to its varied-human figures."""
    res = protocol.summarize("fetchq", "cogail", SEEDS, _per_ckpt(), ("a", "b", "c", "d"), None)
    e = {"episodes": 4, "selected": {"checkpoint": 40, "mean": 0.5, "std": 0.0, "per_seed": {}},
         "paper_protocol": None}
    assert "recording" not in protocol.results_markdown(res)
    res["extra_sets"] = {"robust-detour": e}
    assert "trained on" not in protocol.results_markdown(res)
    assert "20 % of it after the end of the human's recording" in protocol.results_markdown(res)  # the margin said
    res["train_varied"] = 10
    assert "10 varied-human episodes of each variation" in protocol.results_markdown(res)
    assert "patient human" not in protocol.results_markdown(res)
    res["extra_sets"]["patient-robust-detour"] = e  # the patient replay of a set is said what it is
    assert "| patient-robust-detour |" in protocol.results_markdown(res)
    assert "patient human" in protocol.results_markdown(res)


def test_a_patient_human_waits_then_goes_on_with_its_recording(tiny_cfg, demo_files, fetchq):
    """Patient replay (a task's ``replay_hold``): a human that waits W steps and then replays its recording from where
    it stopped ends exactly as the plain replay of that recording with the W waiting steps put in front of it;
    episodes not flagged patient never wait; fetchq itself defines no patient human."""
    import jax
    import jax.numpy as jnp

    from cogail_jax.data import io as data
    from cogail_jax.algo import train

    W = 7

    class Waits(type(fetchq)):  # waits W steps (moving by 0.5); its final metrics hold the human's position
        def replay_hold(self, state, a_h):
            return state.info["t"] < W, jnp.full_like(a_h, 0.5)

        def _where(self, s):
            return s.replace(metrics={**s.metrics, "human_x": s.obs[0], "human_y": s.obs[1]})

        def reset_from(self, init):
            return self._where(super().reset_from(init))

        def step(self, state, action):
            return self._where(super().step(state, action))

    env = Waits(fetchq.max_episode_steps)
    assert env.has_patient_replay and not fetchq.has_patient_replay
    cfg = tiny_cfg.replace(bc_steps=300, seeds=(3,))
    expert = train.expert_arrays(data.load_demos(cfg.demos, env), cfg.history)
    init, _, nets = train.make_train_fns(cfg, env, train.fit_normalizer(expert))
    state = init(cfg.seeds, expert)
    held = rollouts.heldout_arrays(data.load_demos(demo_files[1], env, require_init=True))
    shifted = dict(held, ah=np.concatenate([np.full((len(held["ah"]), W, held["ah"].shape[2]), 0.5, np.float32),
                                            held["ah"]], 1), length=held["length"] + W)
    batch, part = rollouts.stack_sets({"plain": held, "patient": dict(held, patient=np.ones_like(held["patient"])),
                                       "shifted": shifted}, steps=env.max_episode_steps + W)
    replay = rollouts.make_replay_fn(cfg, env, nets)
    m = jax.device_get(replay(state.params, state.norm, {k: batch[k] for k in ("init", "ah", "length", "patient")}))
    plain = jax.device_get(rollouts.make_replay_fn(cfg, fetchq, nets)(
        state.params, state.norm, {k: batch[k][part["plain"]] for k in ("init", "ah", "length")}))
    for k, v in m.items():
        np.testing.assert_array_equal(v[:, part["patient"]], v[:, part["shifted"]], err_msg=k)
        if k in plain:  # not flagged patient: the same as the task without a patient human
            np.testing.assert_array_equal(v[:, part["plain"]], plain[k], err_msg=k)
    assert not np.array_equal(m["human_x"][:, part["patient"]], m["human_x"][:, part["plain"]])


def test_a_replay_runs_the_margin_past_a_late_recording(tiny_cfg, demo_files, fetchq):
    """A human from outside the splits (``margin``) is replayed until the time limit, or ``replay_margin`` steps
    after its recording ends where that is later; the splits' humans and the interpolation episodes end at the
    limit, as in the paper."""
    import jax
    import jax.numpy as jnp

    from cogail_jax.data import io as data
    from cogail_jax.algo import train

    T = 40

    class Clocked(type(fetchq)):  # its final metrics hold the step count at which the episode was frozen
        def _where(self, s):
            return s.replace(metrics={**s.metrics, "t": s.info["t"].astype(jnp.float32)})

        def reset_from(self, init):
            return self._where(super().reset_from(init))

        def step(self, state, action):
            return self._where(super().step(state, action))

    env = Clocked(T)
    margin = rollouts.replay_margin(env)
    assert margin == round(rollouts.REPLAY_MARGIN * T) > 0
    cfg = tiny_cfg.replace(bc_steps=300, seeds=(3,), eval_codes=4)
    expert = train.expert_arrays(data.load_demos(cfg.demos, fetchq), cfg.history)
    init, _, nets = train.make_train_fns(cfg, env, train.fit_normalizer(expert))
    state = init(cfg.seeds, expert)
    held = rollouts.heldout_arrays(data.load_demos(demo_files[1], fetchq, require_init=True))
    lengths = np.array([3, T - margin, T - 2, T + 5])[: len(held["length"])]
    held = dict(held, length=lengths, ah=held["ah"][:, :T + 5], margin=np.ones(len(lengths), bool))
    split = dict(held, margin=np.zeros(len(lengths), bool))
    assert rollouts.replay_steps(env, lengths, split["margin"]) == T
    batch, part = rollouts.stack_sets({"test": split, "extra": held}, steps=rollouts.replay_steps(env, lengths))
    assert batch["ah"].shape[1] == T + 5 + margin == rollouts.replay_steps(env, lengths)
    keys = ("init", "ah", "length", "patient", "margin")
    m = jax.device_get(rollouts.make_replay_fn(cfg, env, nets)(state.params, state.norm, {k: held[k] for k in keys}))
    horizon = np.maximum(T, lengths + margin)
    ended = m["t"][0]
    won = m["success"][0] > 0
    assert np.all(ended[~won] == horizon[~won]) and np.all(ended[won] <= horizon[won]), (ended, horizon)
    assert not won[2:].all()  # an untrained robot: the late recordings run to their pushed-back limit
    one = lambda t: jax.tree.map(lambda x: x[None], t)  # noqa: E731
    out = jax.device_get(rollouts.make_eval_fn(cfg, env, nets)(one(state.params), one(state.norm),
                                                               {k: batch[k] for k in batch}))
    np.testing.assert_array_equal(out["replay_metrics"]["t"][0, 0, part["extra"]], ended)  # the same in a batch
    plain_t, plain_won = out["replay_metrics"]["t"][0, 0, part["test"]], out["replay_success"][0, 0, part["test"]] > 0
    assert np.all(plain_t[~plain_won] == T) and np.all(plain_t <= T)  # the splits: the paper's time limit
    interp_t, interp_won = out["interp_metrics"]["t"][0, 0], out["interp_success"][0, 0] > 0
    assert np.all(interp_t[~interp_won] == T) and np.all(interp_t <= T)


def test_pruned_policies_keep_the_reported_checkpoints_and_refuse_a_full_reevaluation(tmp_path, monkeypatch):
    """After an evaluation only the policies of the checkpoints results.json reports figures of are kept (and the
    newest); results.json keeps every checkpoint's evaluation, extra sets still need no re-evaluation, and evaluating
    every checkpoint again ends in one sentence naming --keep-policies all."""
    from cogail_jax.apps import eval_runner
    from cogail_jax.apps.runs import RunError
    from cogail_jax.runtime import checkpoint as ckpt

    run = tmp_path / "run"
    mgr = ckpt.manager(run, folder=ckpt.POLICIES)
    for st in range(1, 8):
        ckpt.save(mgr, st, {"w": np.full((2,), st, np.float32)})
    res = {"checkpoints": list(range(1, 8)), "selected": {"checkpoint": 3}, "last": {"checkpoint": 6},
           "paper_protocol": {"replay": {"checkpoint": 4}, "interpolation": {"checkpoint": 4}},
           "per_seed_best": {"replay": {"checkpoint": {"1": 2, "2": 4}}, "interpolation": {"checkpoint": {"1": 4}}}}
    (run / "results.json").write_text(json.dumps(res))
    (run / "config.json").write_text("{}")
    assert protocol.reported_checkpoints(res) == [2, 3, 4, 6]
    assert eval_runner.results_current(run) and not eval_runner.was_pruned(run)
    assert eval_runner.prune_policies(run) == [1, 5]  # 7: the newest
    assert eval_runner.was_pruned(run)
    assert ckpt.steps(ckpt.policy_manager(run)) == [2, 3, 4, 6, 7]
    saved = json.loads((run / "results.json").read_text())
    assert saved["policies_kept"] == [2, 3, 4, 6, 7] and saved["checkpoints"] == res["checkpoints"]
    assert eval_runner.results_current(run) and not eval_runner.results_current(run, every=2)
    with pytest.raises(RunError, match="--keep-policies all") as e:
        eval_runner.eval_run(run, progress=False)
    assert str(e.value).count("\n") == 0
    assert eval_runner.prune_policies(run) == []
    # stopped before deleting: results.json names what is kept, every policy is still there, nothing is refused, and
    # the next prune ends the job
    run2 = tmp_path / "run2"
    mgr = ckpt.manager(run2, folder=ckpt.POLICIES)
    for st in range(1, 8):
        ckpt.save(mgr, st, {"w": np.full((2,), st, np.float32)})
    (run2 / "results.json").write_text(json.dumps(res))
    (run2 / "config.json").write_text("{}")

    def stopped(*_):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(ckpt, "prune", stopped)
        with pytest.raises(KeyboardInterrupt):
            eval_runner.prune_policies(run2)
    assert json.loads((run2 / "results.json").read_text())["policies_kept"] == [2, 3, 4, 6, 7]
    assert ckpt.steps(ckpt.policy_manager(run2)) == list(range(1, 8))
    eval_runner._refuse_pruned(run2, eval_runner.Policies(run2))  # every checkpoint can still be evaluated
    assert eval_runner.prune_policies(run2) == [1, 5]
