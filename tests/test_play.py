"""``cogail play``: the real page in headless Chromium (Debian's chromium + chromedriver, via selenium), driven
with key presses; the trials it records are read back and replay-evaluated; bad input ends in one sentence."""
from __future__ import annotations

import json
import shutil
import socket
import threading
import urllib.request

import h5py
import numpy as np
import pytest

from cogail_jax.apps import cli
from cogail_jax.apps import play
from cogail_jax.apps import train_loop

MAX_STEPS = 30


@pytest.fixture(scope="module")
def run_dir(tiny_cfg, tmp_path_factory):
    """A one-seed fetchq run holding only its initial checkpoint (no training: the page is under test), whose
    demonstration files are gone afterwards: play and video need none."""
    d = tmp_path_factory.mktemp("play")
    files = {k: shutil.copy(getattr(tiny_cfg, k), d / f"{k}.hdf5") for k in ("demos", "heldout", "validation")}
    run = d / "run"
    train_loop.train_run(tiny_cfg.replace(seeds=(3,), **{k: str(v) for k, v in files.items()}), run, progress=False,
                         stop_after=0)
    for f in files.values():  # set aside (the evaluation below puts them back)
        f.rename(f.with_suffix(".away"))
    return run


def test_video_of_a_run_needs_no_demonstrations(run_dir, tmp_path, capsys):
    import imageio.v2 as imageio

    out = tmp_path / "run.gif"
    assert cli.main(["video", "--run", str(run_dir), "--num", "2", "--steps", "6", "--out", str(out)]) == 0
    assert "no replay row" in capsys.readouterr().out  # the test split's humans are gone: interpolation only
    assert imageio.mimread(out)[0].shape == (256, 512, 3)


def test_video_of_a_run_of_another_task_is_refused(run_dir, tmp_path, capsys):
    assert cli.main(["video", "--task", "handover", "--run", str(run_dir), "--out", str(tmp_path / "v.gif")]) == 2
    err = capsys.readouterr().err
    assert "holds a fetchq checkpoint, not handover" in err and len(err.strip().splitlines()) == 1


@pytest.fixture(scope="module")
def server(run_dir):
    trials = run_dir.parent / "trials.hdf5"
    srv = play.open_study([run_dir], port=0, trials=trials, max_steps=MAX_STEPS, hz=20, log=lambda *a: None)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{srv.server_address[1]}/", trials
    srv.shutdown()
    play.close(srv)


def make_browser():
    """A headless Chromium driven by selenium (each has its own profile: its own localStorage)."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    if not (chromium and driver_path):
        pytest.fail("chromium and chromedriver are needed: `make test` installs them "
                    "(apt-get install chromium chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1200,800"):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(driver_path), options=opts)


@pytest.fixture(scope="module")
def browser():
    driver = make_browser()
    yield driver
    driver.quit()


def _attr(driver, elem, name):
    from selenium.webdriver.common.by import By

    return driver.find_element(By.ID, elem).get_attribute(name)


def _wait_status(driver, *states, timeout=60):
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(driver, timeout, poll_frequency=0.05).until(
        lambda d: _attr(d, "status", "data-status") in states)
    return _attr(driver, "status", "data-status")


def _hold(driver, key, seconds):
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(driver).key_down(key).pause(seconds).key_up(key).perform()


def test_play_fetchq_in_the_browser(server, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    url, trials = server
    browser.get(url)
    _wait_status(browser, "ready")
    assert browser.find_element(By.ID, "task").text.startswith("fetchq")
    assert browser.find_element(By.ID, "policy").text == "A"
    assert browser.find_element(By.ID, "frame").get_attribute("src").startswith("data:image/png;base64,")
    x0, y0 = float(_attr(browser, "human", "data-x")), float(_attr(browser, "human", "data-y"))

    # trial 1: hold the right arrow; the human agent moves right; the trial times out at MAX_STEPS
    _hold(browser, Keys.ARROW_RIGHT, 0.6)
    assert float(_attr(browser, "human", "data-x")) > x0 + 0.3
    z = json.loads(_attr(browser, "psi", "data-z"))
    assert len(z) == 2 and all(-1 <= v <= 1 for v in z)
    assert _wait_status(browser, "success", "failure") == "failure"
    assert browser.find_element(By.ID, "saved").text == "1"

    # trial 2 (Enter): hold W (up), then press "End trial"
    browser.find_element(By.TAG_NAME, "body").send_keys(Keys.ENTER)
    _wait_status(browser, "ready")
    assert browser.find_element(By.ID, "trial-n").text == "2"
    y1 = float(_attr(browser, "human", "data-y"))
    _hold(browser, "w", 0.3)
    browser.find_element(By.ID, "end").click()
    _wait_status(browser, "failure")
    assert float(_attr(browser, "human", "data-y")) > y1 + 0.1
    assert "Trial ended" in browser.find_element(By.ID, "status").text

    with h5py.File(trials, "r") as f:
        assert f.attrs["task"] == "fetchq" and f.attrs["num_demos"] == 2
        d0, d1 = f["data/demo_0"], f["data/demo_1"]
        assert d0["obs"].shape == (MAX_STEPS, 12)
        assert d0["actions_human"].shape == d0["actions_robot"].shape == (MAX_STEPS, 2)
        assert d0["init"].shape == (4,)
        assert np.any(np.all(d0["actions_human"][()] == [1.0, 0.0], axis=1))  # the right-arrow steps
        assert np.all(np.abs(d0["actions_robot"][()]) <= 1.0)
        assert 0 < d1["obs"].shape[0] < MAX_STEPS and np.any(np.all(d1["actions_human"][()] == [0.0, 1.0], axis=1))
        for d, end in ((d0, "timeout"), (d1, "ended")):
            a = d.attrs
            assert (a["method"], a["policy"], a["end"], int(a["success"])) == ("cogail", "A", end, 0)
            assert int(a["checkpoint"]) == 0 and int(a["seed"]) == 3 and a["run"].endswith("run")
            assert int(a["num_samples"]) == d["obs"].shape[0]


def test_eval_replays_the_trials(server, run_dir, capsys):
    url, trials = server
    if not trials.exists():  # the browser test did not run first: record one trial through the page's API
        post = lambda p, b: urllib.request.urlopen(urllib.request.Request(  # noqa: E731
            url + p, json.dumps(b).encode(), {"Content-Type": "application/json"})).read()
        post("api/step", {"keys": ["KeyD"], "start": True})
        post("api/end", {})
    for f in run_dir.parent.glob("*.away"):  # evaluation needs the run's test and validation splits
        f.rename(f.with_suffix(".hdf5"))
    assert cli.main(["eval", "--run", str(run_dir), "--replay-file", str(trials), "--no-progress",
                     "--no-robustness"]) == 0
    res = json.loads((run_dir / "replay-trials" / "results.json").read_text())
    assert set(res["replay_success"]["per_seed"]) == {"3"}
    with h5py.File(trials) as f:  # every recorded trial replayed, from that file
        assert res["episodes"] == len(f["data"]) > 0 and res["file"] == str(trials)
    assert "replay against" in capsys.readouterr().out


def test_human_action_mapping():
    assert play.human_action(2, ["ArrowRight", "KeyW"]).tolist() == [1.0, 1.0]
    assert play.human_action(2, ["ArrowLeft", "KeyD"]).tolist() == [0.0, 0.0]
    assert play.human_action(2, [], axes=[0.5, -0.5]).tolist() == [0.5, 0.5]  # stick up = +y
    a = play.human_action(7, ["KeyW", "KeyE", "KeyJ"], gripper=-1)
    assert a.tolist() == [0, 1, 1, 0, 0, 1, -1]


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("case", ["unknown run", "other task", "port in use", "port out of range", "hz", "seed",
                                  "trials are the run's test split", "trials are a folder"])
def test_bad_input_is_one_clear_sentence(case, run_dir, tmp_path, capsys):
    from cogail_jax.algo.config import TrainConfig

    holder = None
    if case == "unknown run":
        args, needle = ["--run", str(tmp_path / "nope")], "is not a run directory"
    elif case == "other task":
        other = tmp_path / "hrun"
        other.mkdir()
        (other / "config.json").write_text(TrainConfig(task="handover").to_json())
        args, needle = ["--task", "fetchq", "--run", str(other)], "holds a handover checkpoint, not fetchq"
    elif case == "hz":
        args, needle = ["--run", str(run_dir), "--hz", "-1"], "--hz -1 is not a usable number of steps per second"
    elif case == "seed":
        args, needle = ["--run", str(run_dir), "--seed", "-1"], "argument --seed: a seed is an integer from 0 to"
    elif case == "trials are the run's test split":  # people's trials appended to it would change the run's data
        split = run_dir.parent / "heldout.hdf5"
        args, needle = ["--run", str(run_dir), "--trials", str(split)], "is a dataset the run"
    elif case == "trials are a folder":
        args, needle = ["--run", str(run_dir), "--trials", str(tmp_path)], "is a folder: pass a file"
    elif case == "port out of range":
        args, needle = ["--run", str(run_dir), "--port", "70000"], "port 70000 is out of range: pass --port"
    else:
        holder = socket.socket()
        holder.bind(("127.0.0.1", _free_port()))
        holder.listen()
        port = holder.getsockname()[1]
        args, needle = ["--run", str(run_dir), "--port", str(port)], f"port {port} is in use: pass --port"
    try:
        try:
            code = cli.main(["play", *args])
        except SystemExit as e:  # a bad value argparse refuses: its usage, then one line
            code = e.code
        assert code == 2
    finally:
        if holder:
            holder.close()
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert needle in lines[-1] and "Traceback" not in err and (len(lines) == 1 or case == "seed"), err


def test_play_help(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["play", "--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and "usage: cogail play" in out and "--port" in out


def test_blind_order_cycles_through_the_policies(run_dir, tmp_path):
    srv = play.open_study([run_dir, run_dir], port=0, trials=tmp_path / "t.hdf5", seed=1, log=lambda *a: None)
    try:
        game = srv.app.game
        assert [p.label for p in game.policies] == ["A", "B"]
        seen = []
        for _ in range(4):  # two blocks: each holds every policy once
            seen.append(game.policy.label)
            game.new_trial()
        assert sorted(seen[:2]) == sorted(seen[2:]) == ["A", "B"]
        view = game.view()
        assert not {"method", "run", "checkpoint"} & set(view) and str(run_dir) not in json.dumps(view)
    finally:
        play.close(srv)
