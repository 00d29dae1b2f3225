"""``cogail play`` on an Overcooked run, in headless Chromium: a tap of an arrow key moves the person's cook one cell,
Space interacts, and the trial is saved with one-hot actions in the project's format."""
from __future__ import annotations

import threading

import h5py
import jax
import numpy as np
import pytest

import cogail_envs
from cogail_jax.apps import play, train_loop
from cogail_jax.data import io as data
from cogail_jax.data import recorded
from test_play import _attr, _hold, _wait_status, browser  # noqa: F401  (the headless Chromium fixture)


@pytest.fixture(scope="module")
def oc_run(tiny_cfg, tmp_path_factory):
    """A one-seed overcooked run holding its initial checkpoint, from two test-split episodes of people."""
    d = tmp_path_factory.mktemp("oc-play")
    env = cogail_envs.make_env("overcooked")
    rec = cogail_envs.get_task("overcooked").recorded(env, "test")
    eps = recorded.episodes(rec)
    keep = eps._replace(**{k: getattr(eps, k)[:2, :60] if getattr(eps, k).ndim > 2 else getattr(eps, k)[:2]
                           for k in ("obs", "actions_human", "actions_robot", "length", "strategy", "executed",
                                     "success", "init")},
                        final_metrics={k: np.asarray(v)[:2] for k, v in eps.final_metrics.items()})
    keep = keep._replace(length=np.minimum(keep.length, 60))
    path = data.save_demos(d / "people.hdf5", env, keep)
    cfg = tiny_cfg.replace(task="overcooked", seeds=(3,), demos=str(path), heldout=str(path), validation=str(path),
                           train_varied=0, num_envs=2, unroll_length=8)
    run = d / "run"
    train_loop.train_run(cfg, run, progress=False, stop_after=0)
    return run


def test_play_overcooked_in_the_browser(oc_run, browser):  # noqa: F811
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    trials = oc_run.parent / "trials.hdf5"
    srv = play.open_study([oc_run], port=0, trials=trials, max_steps=40, log=lambda *a: None)
    assert srv.app.hz == 7.0  # the task's own pace (the people of the trials played about 6.7 steps a second)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    thread.start()
    try:
        browser.get(f"http://127.0.0.1:{srv.server_address[1]}/")
        _wait_status(browser, "ready")
        assert browser.find_element(By.ID, "task").text.startswith("overcooked")
        assert "Space: interact" in browser.find_element(By.ID, "help").text
        x0 = float(_attr(browser, "human", "data-x"))
        # the human's start cell: player 0's (1, 2), a free cell on its right, or player 1's (3, 1), one on its left
        key, dx, choice = (Keys.ARROW_RIGHT, 1, 2) if x0 == 1 else (Keys.ARROW_LEFT, -1, 3)
        _hold(browser, key, 0.05)  # a tap shorter than a step still moves the cook
        _wait_status(browser, "running")
        _hold(browser, Keys.SPACE, 0.4)  # held over steps: the interaction is recorded however loaded the machine
        browser.implicitly_wait(0)
        for _ in range(40):  # the page steps at 7 Hz: wait for the move to show
            if float(_attr(browser, "human", "data-x")) == x0 + dx:
                break
            browser.execute_script("return new Promise(r => setTimeout(r, 100))")
        assert float(_attr(browser, "human", "data-x")) == x0 + dx
        browser.find_element(By.ID, "end").click()
        _wait_status(browser, "failure", "success")
    finally:
        srv.shutdown()
        play.close(srv)
    with h5py.File(trials, "r") as f:
        assert f.attrs["task"] == "overcooked" and f.attrs["num_demos"] == 1
        d0 = f["data/demo_0"]
        ah, ar = d0["actions_human"][()], d0["actions_robot"][()]
        assert ah.shape[1] == ar.shape[1] == 6 and np.all(ah.sum(1) == 1) and np.all(ar.sum(1) == 1)
        choices = ah.argmax(1).tolist()
        assert choices[0] == choice and 5 in choices and set(choices) <= {choice, 4, 5}  # the move, interact, stay
        assert d0["init"].shape == (cogail_envs.make_env("overcooked").init_size,)
        assert d0.attrs["end"] == "ended" and "metric_soups" in d0.attrs


def test_discrete_key_mapping():
    keys = {"ArrowUp": 0, "ArrowRight": 2, "Space": 5}
    a, pressed = play.discrete_action(6, keys, 4, [])
    assert a.tolist() == [0, 0, 0, 0, 1, 0] and not pressed  # no key: stay
    a, pressed = play.discrete_action(6, keys, 4, ["ArrowUp", "Space"])
    assert a.argmax() == 5 and pressed  # the last mapped key
    a, _ = play.discrete_action(6, keys, 4, [], axes=[0.9, 0.1])  # a gamepad's stick to the right
    assert a.argmax() == 2
    a, _ = play.discrete_action(6, keys, 4, [], buttons=[True])  # its A button
    assert a.argmax() == 5


def test_crossplay_of_two_robots(oc_run):
    """The cross-play matrix: every ordered pair of robots in both seats; one run's robot under two labels gives
    the same figures in every cell (the same draws, the same policy in either slot), its reward the game's."""
    from cogail_jax.algo.config import TrainConfig
    from cogail_jax.apps.runs import Policies, build
    from cogail_jax.eval import field

    s = build(TrainConfig.load(oc_run / "config.json"), need_heldout=False, need_validation=False, run_dir=oc_run,
              need_demos=False)
    params = Policies(oc_run, s).load(0)
    m = field.crossplay(s.env, {"a": (s.cfg, s.nets, params), "b": (s.cfg, s.nets, params)}, 2)
    assert set(m) == {"a", "b"} and all(set(row) == {"a", "b"} for row in m.values())
    cells = [m[x][y] for x in "ab" for y in "ab"]
    assert all(c == cells[0] for c in cells) and cells[0]["episodes"] == 2 * 2  # 2 episodes x 2 seats (1 seed)
    assert cells[0]["reward"]["mean"] == 20 * cells[0]["score"]["mean"]
    assert "| a |" in "\n".join(field.crossplay_markdown(m))


def test_coplay_on_a_people_task_is_the_fields_protocol(oc_run):
    """`cogail eval` with co-play on a task learned from people runs the field's protocol in its place: H_proxy and
    the training pairs' clone with the robot in both seats, self-play, selection over every checkpoint, H_proxy's
    quality; no co-play of its own."""
    from cogail_jax.apps import eval_runner

    res = eval_runner.eval_run(oc_run, progress=False, coplay=True)
    assert "coplay" not in res
    f = res["field"]
    n = f["protocol"]["episodes_per_seed_and_seat"]
    for partner in ("h_proxy", "bc_train"):
        assert f[partner]["seat0"]["episodes"] == f[partner]["seat1"]["episodes"] == n  # one seed
        assert f[partner]["both"]["episodes"] == 2 * n
        assert f[partner]["both"]["reward"]["mean"] == 20 * f[partner]["both"]["score"]["mean"]
    assert f["self_play"]["episodes"] == 2 * n
    assert set(f["selected"]["validation_reward"]) == set(res["checkpoints"])  # every checkpoint played
    q = f["proxy_quality"]
    assert q["with_itself"]["episodes"] == q["with_copy"]["episodes"] == n  # two clones, no seed axis
    assert 0.0 <= q["accuracy_train_samples"] <= 1.0


def test_the_fields_plays_compiled_ahead_are_those_its_evaluation_plays(oc_run, monkeypatch):
    """While a run trains, its evaluation's preparation compiles the field's plays (``Field.lower_plays``): selection's
    batch, the robot with a BC model and self-play, lowered from the evaluation parameters' shapes, are the programs
    ``field.evaluate`` then runs (so it finds them in the compilation cache)."""
    from cogail_jax.algo.config import TrainConfig
    from cogail_jax.apps.runs import Policies, build
    from cogail_jax.eval import field

    s = build(TrainConfig.load(oc_run / "config.json"), run_dir=oc_run)
    params = Policies(oc_run, s).load(0)
    here = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])  # as the evaluation's preparation places them
    struct = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=here), params)
    ahead = [lowered.as_text() for lowered in field.Field(s).lower_plays(struct, 1)]
    played, make_play = [], field.make_play

    def spy(*args, **kw):
        fn = make_play(*args, **kw)

        def call(*a):
            played.append(fn.lower(*a).as_text())
            return fn(*a)
        return call

    monkeypatch.setattr(field, "make_play", spy)
    field.evaluate(s, lambda step: params, [0])
    assert len(ahead) == 3 and all(text in played for text in ahead)
