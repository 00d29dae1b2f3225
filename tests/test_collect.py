"""``cogail collect``: two headless Chromium pages drive both agents of every built-in task from the task's scripted
team (or, without one, seeded choices), through the page; the recorded episodes replay to the recorded states, the file
trains and replays; bad input from clients gets a clear refusal or a clean end of the episode, and nothing recorded is
lost (plain HTTP clients, no browser)."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import h5py
import numpy as np
import pytest

from cogail_jax.apps import cli, collect
from test_play import make_browser

ROOT = Path(__file__).parents[1]
HZ, MAX_STEPS, EPISODES = 25, 10, 20
# the scripted clients' controller: the action of the team's script for the step the page shows (window.S is set per
# episode by the test, from the episode's init as the page shows it)
CONTROLLER = ("window.cogailController = (seat, v) => (window.S && window.S.episode === v.episode) ? "
              "window.S.actions[Math.min(v.t, window.S.actions.length - 1)] : null;")


def _serve(task, out, **kw):
    srv = collect.open_table(task, out=out, port=0, log=lambda *a: None, **kw)
    threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    return srv, f"http://127.0.0.1:{srv.server_address[1]}"


def _wait(cond, what, timeout=60.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if r := cond():
            return r
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def _view(page):
    return page.execute_script("return window.cogailView || null")


def _hold(page, keys, seconds):
    from selenium.webdriver.common.action_chains import ActionChains

    chain = ActionChains(page)
    for k in keys:
        chain.key_down(k)
    chain.pause(seconds)
    for k in keys:
        chain.key_up(k)
    chain.perform()


def _click(page, elem):
    """Click a button as a person would; where the page's text reflowed between locating it and clicking (another
    element took the point: the status lines change every frame), locate it again, as a person would look again."""
    from selenium.common.exceptions import ElementClickInterceptedException
    from selenium.webdriver.common.by import By

    for attempt in range(10):
        try:
            return page.find_element(By.ID, elem).click()
        except ElementClickInterceptedException:
            if attempt == 9:
                raise
            time.sleep(0.1)


def _replayed_obs(c, init, ah, ar):
    """The states the env goes through from ``reset_from(init)`` under the recorded actions (the server's own
    compiled step)."""
    import jax.numpy as jnp

    state, obs = c._reset(jnp.asarray(init)), []
    for a, b in zip(ah, ar):
        obs.append(np.asarray(state.obs))
        state = c._step(state, jnp.concatenate([jnp.asarray(a), jnp.asarray(b)]))
    return np.stack(obs)


def _lags(rec, script, idle):
    """Per recorded step t: how many steps behind the script's action it was (t - the last k <= t with
    script[k] == rec[t]); -1 for the seat's idle action (its first command had not arrived); None if it matches no
    script row at all."""
    out = []
    for t, a in enumerate(rec):
        ks = [k for k in range(min(t, len(script) - 1) + 1) if np.array_equal(script[k], a)]
        out.append(t - ks[-1] if ks else (-1 if np.array_equal(a, idle) else None))
    return out


def _record_scripted(pages, srv, n, sync=None):
    """Both pages drive ``n`` episodes, each from the task's scripted team's actions for the episode's start (as the
    page shows it); returns {episode: (human script, robot script)}. ``sync``: a list that gets (t, t) pairs of the
    two pages' views read at the same moment."""
    from selenium.webdriver.common.keys import Keys

    c = srv.collector
    for p in pages:
        p.execute_script(CONTROLLER)
    scripts, start = {}, c.recorded
    for k in range(n):
        def ready():
            t0 = time.monotonic()
            vs = [_view(p) for p in pages]
            took = time.monotonic() - t0  # the pages are read one after the other: steps may pass in between
            if sync is not None and all(vs) and vs[0]["episode"] == vs[1]["episode"] and vs[0]["status"] == "running":
                sync.append((vs[0]["t"], vs[1]["t"], took))
            ok = all(v and v["status"] == "ready" and all(v["taken"].values()) for v in vs)
            return vs[0] if ok and vs[0]["episode"] == vs[1]["episode"] and vs[0]["episode"] not in scripts else None

        v = _wait(ready, f"episode {k} ready on both pages")
        ah, ar = collect.scripted_actions(c.env, np.asarray(v["init"], np.float32), seed=k, steps=c.settings.max_steps,
                                          step_fn=c._step)
        for page, acts in zip(pages, (ah, ar)):
            page.execute_script("window.S = arguments[0]", {"episode": v["episode"], "actions": acts.tolist()})
        scripts[v["episode"]] = (ah, ar)
        pages[0].find_element("tag name", "body").send_keys(Keys.ENTER)  # start (the team may wait at first)
    _wait(lambda: c.recorded >= start + n, f"{n} episodes recorded")
    for p in pages:
        p.execute_script("window.cogailController = null; window.S = null;")
    return scripts


def _check_replays(c, out, scripts):
    """Every scripted episode of the file: its actions came from the script through the page, in order and in step,
    and replaying them from its init gives the recorded states, bit for bit."""
    idle = {s: c.idle(c.seats[s]) for s in collect.SEATS}
    lags = []
    with h5py.File(out, "r") as f:
        demos = {int(g.attrs["episode"]): g for g in f["data"].values()}
        for ep, (sh, sr) in scripts.items():
            g = demos[ep]
            obs, ah, ar = g["obs"][()], g["actions_human"][()], g["actions_robot"][()]
            assert g["init"].shape == (c.env.init_size,) and len(obs) == g.attrs["num_samples"] > 0
            np.testing.assert_array_equal(_replayed_obs(c, g["init"][()], ah, ar), obs)
            for rec, script, seat in ((ah, sh, "human"), (ar, sr, "robot")):
                lag = _lags(rec, script, idle[seat])
                assert None not in lag, f"episode {ep}: the {seat}'s recorded actions are not its script's"
                lags += [x for x in lag if x >= 0]
            assert g.attrs["human_input"] == "controller" and g.attrs["robot_input"] in ("controller", "")
    return lags


# ---------------------------------------------------------------------------------------------- fetchq, end to end
@pytest.fixture(scope="module")
def pages():
    a, b = make_browser(), make_browser()
    yield a, b
    a.quit()
    b.quit()


@pytest.fixture(scope="module")
def fetchq_session(pages, tmp_path_factory):
    """One fetchq table: a page with both seats (two key sets), then two pages, one per seat, driven by keys and
    then by the scripted team for 20 episodes. Returns what the tests check."""
    from selenium.webdriver.common.keys import Keys

    out = tmp_path_factory.mktemp("collect") / "people.hdf5"
    srv, url = _serve("fetchq", out, hz=HZ, max_steps=MAX_STEPS, gap=0.0, seed=0)
    c = srv.collector
    a, b = pages
    info = {"srv": srv, "out": out, "url": url}
    try:
        # one page, both seats: WASD drives the human agent, the arrows the robot
        a.get(url + "/?seat=both")
        _wait(lambda: (v := _view(a)) and v["status"] == "ready" and all(v["taken"].values()), "both seats")
        _hold(a, ["w", Keys.ARROW_LEFT], 0.3)
        _click(a, "end")
        _wait(lambda: c.recorded == 1, "the one-page episode")
        # two pages: each takes its seat; a key press on each shows on both (an ended episode stays on screen 1 s)
        c.settings.gap = 1.0
        a.get(url + "/?seat=human")  # leaving the page frees both seats (pagehide)
        b.get(url + "/?seat=robot")
        _wait(lambda: (v := _view(b)) and v["status"] == "ready" and all(v["taken"].values()), "two pages")
        other = threading.Thread(target=_hold, args=(b, [Keys.ARROW_UP], 0.25))
        other.start()
        _hold(a, [Keys.ARROW_RIGHT], 0.25)
        other.join()
        info["same_frame"] = _wait(lambda: (va := _view(a)) and (vb := _view(b)) and va["frame_id"] == vb["frame_id"]
                                   and va["t"] > 0 and (va, vb), "the same frame on both pages")
        info["latency"] = {p: a.find_element("id", "lat").get_attribute(f"data-{p}") for p in ("n", "median", "p95")}
        _click(b, "end")
        _wait(lambda: c.recorded == 2 and c.status == "ready", "the key-driven episode")
        c.settings.gap = 0.0
        sync = []
        t0 = time.monotonic()
        info["scripts"] = _record_scripted(pages, srv, EPISODES, sync)
        info["seconds"], info["sync"] = time.monotonic() - t0, sync
        info["drivers"] = [_view(p)["drivers"] for p in pages]
    finally:
        srv.shutdown()
        collect.close(srv)
    # 2 key-driven episodes and the scripted ones (checked by episode number), and whatever ran when it stopped
    info["recorded"] = c.recorded
    assert c.recorded >= EPISODES + 2
    yield info


def test_one_page_two_key_sets_drive_both_agents(fetchq_session):
    with h5py.File(fetchq_session["out"], "r") as f:
        g = f["data/demo_0"]
        assert g.attrs["end"] in ("ended", "timeout") and g.attrs["human_input"] == g.attrs["robot_input"] == "keyboard"
        ah, ar = g["actions_human"][()], g["actions_robot"][()]
        assert np.any(np.all(ah == [0.0, 1.0], axis=1)) and not np.any(ah[:, 0])  # W: up, never sideways
        assert np.any(np.all(ar == [-1.0, 0.0], axis=1)) and not np.any(ar[:, 1])  # left arrow: left, never up
        assert g.attrs["human_id"] != g.attrs["robot_id"]  # one page, two anonymous drivers


def test_two_pages_stay_in_step_and_show_a_key_press(fetchq_session):
    va, vb = fetchq_session["same_frame"]
    assert va["t"] == vb["t"] and va["episode"] == vb["episode"] and va["you"] == "human" and vb["you"] == "robot"
    assert va["human"] == vb["human"] and va["drivers"] == vb["drivers"]  # the same scene on both pages
    lat = fetchq_session["latency"]
    assert int(lat["n"]) >= 1 and 0 < float(lat["median"]) < 1000  # the page measured press -> frame
    print(f"press-to-frame in Chromium at {HZ} Hz: median {lat['median']} ms, p95 {lat['p95']} ms ({lat['n']} presses)")
    sync = fetchq_session["sync"]
    # both pages within two steps whenever read together, beside the steps that passed between the two reads
    assert sync and all(abs(x - y) <= 2 + math.ceil(took * HZ) for x, y, took in sync), sync
    with h5py.File(fetchq_session["out"], "r") as f:
        g = f["data/demo_1"]
        assert g.attrs["human_input"] == g.attrs["robot_input"] == "keyboard"
        assert np.any(np.all(g["actions_human"][()] == [1.0, 0.0], axis=1))
        assert np.any(np.all(g["actions_robot"][()] == [0.0, 1.0], axis=1))
        drivers = fetchq_session["drivers"][0]
        assert (g.attrs["human_id"], g.attrs["robot_id"]) == (drivers["human"], drivers["robot"])


def test_scripted_pages_record_episodes_that_replay_to_the_recorded_states(fetchq_session):
    srv, out, scripts = fetchq_session["srv"], fetchq_session["out"], fetchq_session["scripts"]
    lags = _check_replays(srv.collector, out, scripts)
    assert len(scripts) == EPISODES and np.median(lags) <= 1  # the commands of the step shown, mostly in time
    with h5py.File(out, "r") as f:
        assert f.attrs["task"] == "fetchq" and f.attrs["num_demos"] == fetchq_session["recorded"]
        for g in f["data"].values():
            settings = json.loads(g.attrs["settings"])
            assert settings["hz"] == HZ and settings["max_steps"] == MAX_STEPS and settings["lan"] is False
            assert g.attrs["time"][:4].isdigit() and g.attrs["collector"] == "cogail collect"
            assert g.attrs["strategy"] == int(srv.collector._classify({k[7:]: np.float32(v) for k, v in
                                                                        g.attrs.items() if k.startswith("metric_")}))
            assert 0 < g.attrs["num_samples"] <= MAX_STEPS
    print(f"20 scripted episodes of {MAX_STEPS} steps at {HZ} Hz through two pages: {fetchq_session['seconds']:.1f} s")


def test_the_recorded_file_trains_and_replays(fetchq_session, tiny_cfg, tmp_path, capsys):
    out, run = fetchq_session["out"], tmp_path / "run"
    tiny = ["--num-envs", "4", "--unroll-length", "16", "--total-steps", "128", "--checkpoint-every", "2",
            "--bc-steps", "0"] + [x for kv in ("updates_per_call=2", "ppo_epochs=2", "num_minibatches=2",
                                              "inner_updates=2", "inner_batch=32", "eval_codes=4")
                                  for x in ("--set", kv)]
    assert cli.main(["train", "--task", "fetchq", "--demos", str(out), "--heldout", tiny_cfg.heldout, "--validation",
                     tiny_cfg.validation, "--seeds", "3", "--run", str(run), "--no-progress", *tiny]) == 0
    assert cli.main(["eval", "--run", str(run), "--replay-file", str(out), "--no-progress", "--no-robustness",
                     "--no-coplay"]) == 0
    res = json.loads((run / f"replay-{out.stem}" / "results.json").read_text())
    with h5py.File(out, "r") as f:
        ends = [(g.attrs["episode"], g.attrs["end"], g.attrs["human_input"], g.attrs["robot_input"], len(g["obs"]))
                for g in f["data"].values()]
    assert res["episodes"] == len(ends) == fetchq_session["recorded"] and res["file"] == str(out), sorted(ends)
    assert json.loads((run / "config.json").read_text())["demos"] == str(out)


# ---------------------------------------------------------------------------------------------- every other task
@pytest.mark.parametrize("task", ["overcooked", "handover", "seqmanip"])
def test_scripted_pages_record_each_builtin_task(task, pages, tmp_path):
    out = tmp_path / f"{task}.hdf5"
    srv, url = _serve(task, out, hz=10, max_steps=4, gap=0.0, seed=1)
    try:
        pages[0].get(url + "/?seat=human")
        pages[1].get(url + "/?seat=robot")
        scripts = _record_scripted(pages, srv, 1)
        _check_replays(srv.collector, out, scripts)
    finally:
        srv.shutdown()
        collect.close(srv)
    with h5py.File(out, "r") as f:
        assert f.attrs["task"] == task and f.attrs["num_demos"] == 1


# ---------------------------------------------------------------------------------------------- bad input
@pytest.fixture(scope="module")
def lan_table(tmp_path_factory):
    """A fetchq table open to the network (join codes), quick to notice a silent seat."""
    out = tmp_path_factory.mktemp("collect-lan") / "people.hdf5"
    srv = collect.open_table("fetchq", out=out, port=0, lan=True, hz=40, max_steps=200, gap=0.0, leave=0.6,
                             seed=2, log=lambda *a: None)
    threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    yield srv, f"http://127.0.0.1:{srv.server_address[1]}", out
    srv.shutdown()
    collect.close(srv)


def _seated(lan_table):
    srv, url, _ = lan_table
    _wait(lambda: not any(s.token for s in srv.collector.seats.values()) and srv.collector.status != "running",
          "free seats", 5)
    h, r = collect.Client(url), collect.Client(url)
    h.join("human", srv.collector.seats["human"].code)
    r.join("robot", srv.collector.seats["robot"].code.lower())  # codes are read case-blind
    return h, r


def _running(srv, h, steps=3):
    v = h.view()
    while v["status"] != "running" or v["t"] < steps:
        h.send(["KeyD"])
        v = h.view(v["frame_id"])
    return v


class _KeepAlive:
    """A client that keeps sending (an idle command) every 0.1 s, as an open page does."""

    def __init__(self, client):
        self.client, self.stop = client, threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self.stop.wait(0.1):
            try:
                self.client.send([])
            except collect.Refused:
                return

    def __enter__(self):
        self.thread.start()
        return self.client

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()


def _demos(out):
    if not out.exists():
        return []
    with h5py.File(out, "r") as f:
        return [dict(g.attrs) | {"steps": len(g["obs"])} for g in f["data"].values()]


def test_a_seat_needs_its_join_code_on_the_network(lan_table):
    srv, url, _ = lan_table
    links = collect.links(srv)
    codes = {s: srv.collector.seats[s].code for s in collect.SEATS}
    assert all(f"code={codes[s]}" in links[s] for s in codes) and "both" not in links
    assert srv.server_address[0] == "0.0.0.0" and codes["human"] != codes["robot"]
    for code, needle in ((None, "needs its join code"), ("WRONG1", "wrong join code"),
                         (codes["robot"], "wrong join code")):  # the other seat's code does not open this one
        with pytest.raises(collect.Refused) as e:
            collect.Client(url).join("human", code)
        assert e.value.status == 403 and needle in str(e.value)
    assert not srv.collector.seats["human"].token


def test_two_clients_claiming_one_agent(lan_table):
    srv, url, _ = lan_table
    h, r = _seated(lan_table)
    try:
        with pytest.raises(collect.Refused) as e:
            collect.Client(url).join("robot", srv.collector.seats["robot"].code)
        assert e.value.status == 409 and "the robot seat is taken" in str(e.value)
        r.send(["KeyW"])  # the first claimant still drives it
        assert h.view()["taken"] == {"human": True, "robot": True}
    finally:
        h.leave()
        r.leave()


def test_malformed_and_hostile_messages_are_refused(lan_table):
    srv, url, out = lan_table
    h, r = _seated(lan_table)
    try:
        with _KeepAlive(r):
            _malformed(srv, url, out, h)
    finally:
        h.leave()
        r.leave()


def _malformed(srv, url, out, h):
    v = _running(srv, h)
    before = h.seq

    def raw(path, data: bytes, headers=None):
        req = urllib.request.Request(url + path, data, headers or {"Content-Type": "application/json"})
        try:
            urllib.request.urlopen(req, timeout=5)
            return 200, {}
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read())

    tok = h.token
    cases = [
        (b"{not json", 400, "not JSON"),
        (b"[1, 2]", 400, "JSON object"),
        (json.dumps({"token": tok, "seq": 99, "keys": "KeyD"}).encode(), 400, "'keys'"),
        (json.dumps({"token": tok, "seq": 99, "keys": ["K" * 40]}).encode(), 400, "'keys'"),
        (json.dumps({"token": tok, "seq": -1}).encode(), 400, "'seq'"),
        (b'{"token": "%s", "seq": 99, "axes": [NaN]}' % tok.encode(), 400, "not finite"),
        (json.dumps({"token": tok, "seq": 99, "action": [1.0, 0.0, 0.0]}).encode(), 400, "'action' must hold 2"),
        (json.dumps({"token": tok, "seq": 99, "device": "<script>"}).encode(), 400, "'device'"),
        (json.dumps({"token": "forged", "seq": 99, "keys": ["KeyA"]}).encode(), 403, "not (or no longer) valid"),
        (json.dumps({"seq": 99, "keys": ["KeyA"]}).encode(), 403, "join a seat first"),
        (json.dumps({"token": tok, "seq": 99, "episode": "last"}).encode(), 400, "'episode'"),
        (b"x" * (collect.MAX_BODY + 1), 413, "at most"),
    ]
    for body, status, needle in cases:
        code, ans = raw("/api/input", body)
        assert (code, needle in ans.get("error", "")) == (status, True), (body[:60], code, ans)
    assert raw("/api/nope", b"{}")[0] == 404
    assert raw("/api/join", json.dumps({"seat": "referee"}).encode())[0] == 400
    with pytest.raises(collect.Refused) as e:
        h._call("GET", "/api/view?token=forged")
    assert e.value.status == 403
    # none of it reached the agent or stopped the table: the episode runs on with the seat's own commands
    assert srv.collector.seats["human"].seq == before
    v2 = h.view(v["frame_id"] + 2)
    assert v2["status"] == "running" and v2["t"] > v["t"] and v2["episode"] == v["episode"]
    stale = h.seq
    h.seq = 1  # an old message overtaken by newer ones changes nothing
    h.send(["KeyA"])
    assert srv.collector.seats["human"].seq == stale
    h.seq = stale
    h.send(["KeyA"], episode=v["episode"] - 1)  # a command meant for an episode that is over is dropped
    assert srv.collector.seats["human"].seq == stale
    n = len(_demos(out))
    h.end()
    _wait(lambda: len(_demos(out)) == n + 1, "the ended episode")
    assert _demos(out)[-1]["end"] == "ended"


@pytest.mark.parametrize("how", ["closed", "silent"])
def test_a_partner_who_leaves_mid_episode_ends_it_and_it_is_kept(how, lan_table):
    srv, url, out = lan_table
    h, r = _seated(lan_table)
    n = len(_demos(out))
    with _KeepAlive(r):
        v = _running(srv, h, steps=5)
    if how == "closed":
        r.leave()  # what the page sends when its tab is closed
    else:  # the robot's client stops talking (a crash, a cable pulled): after `leave` seconds its seat is free
        t_end = time.monotonic() + 0.6 * 3
        while time.monotonic() < t_end and h.view(v["frame_id"])["status"] == "running":
            h.send(["KeyD"])
    # the file, not the page, is waited on: with no gap the next episode may already show
    _wait(lambda: len(_demos(out)) > n, "the episode to end and be recorded")
    assert srv.collector.seats["human"].token and not srv.collector.seats["robot"].token  # the robot's seat is free
    demos = _demos(out)
    assert len(demos) == n + 1 and demos[-1]["end"] == "left" and demos[-1]["steps"] >= 5
    assert demos[-1]["human_id"] == h.view()["drivers"]["human"]
    h.leave()


# ---------------------------------------------------------------------------------------------- the command
def test_a_killed_collect_keeps_every_finished_episode_of_a_user_task(tmp_path):
    """`cogail collect` on the example task (the task API), killed mid-episode: the file holds every finished
    episode, readable, and the running one is the only loss."""
    out = tmp_path / "carry.hdf5"
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    proc = subprocess.Popen([sys.executable, "-m", "cogail_jax.apps.cli", "collect", "--task",
                             "examples.table_carry:TASK", "--port", "0", "--out", str(out), "--hz", "40",
                             "--max-steps", "12", "--gap", "0", "--seed", "5"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        while not any("?seat=human" in x for x in lines):
            lines.append(proc.stdout.readline())
            assert lines[-1] or proc.poll() is None, "".join(lines)
        url = next(x for x in lines if "?seat=human" in x).split()[-1].split("/?")[0]
        assert "table_carry" in "".join(lines) and str(out) in "".join(lines)
        h, r = collect.Client(url), collect.Client(url)
        h.join("human")
        r.join("robot")
        done = 0
        v = h.view()
        while done < 2 or v["t"] < 3:  # two whole episodes, then kill the server 3 steps into the third
            h.send(action=[0.0, 1.0])
            r.send(action=[0.0, 1.0])
            nv = h.view(v["frame_id"])
            done += nv["episode"] > v["episode"]
            v = nv
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    with h5py.File(out, "r") as f:
        assert f.attrs["task"] == "table_carry" and f.attrs["num_demos"] == 2
        for g in f["data"].values():
            assert len(g["obs"]) == 12 and g["init"].shape == (4,) and g.attrs["end"] == "timeout"
            # the server steps at its own rate: a step before the client's first action of an episode arrives is
            # recorded with the idle action (zeros), so a loaded machine may record a few; every other step holds
            # the action the client sent
            a = g["actions_human"][()]
            sent, idle = np.all(a == [0.0, 1.0], axis=1), np.all(a == 0.0, axis=1)
            assert np.all(sent | idle) and sent.any(), a


def test_collect_help_and_bad_options(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["collect", "--help"])
    assert e.value.code == 0 and "usage: cogail collect" in capsys.readouterr().out
    other = tmp_path / "other.hdf5"
    with h5py.File(other, "w") as f:
        f.attrs["task"] = "handover"
    for args, needle in ((["--out", str(other)], "holds demonstrations of task 'handover', not 'fetchq'"),
                         (["--hz", "0"], "--hz 0.0 is not a usable number"),
                         (["--leave", "0"], "--leave 0.0 is not a usable number of seconds: pass a positive one"),
                         (["--gap", "-1"], "--gap -1.0 is not a usable number of seconds: pass 0 or more"),
                         (["--task", "nope"], "unknown task 'nope'")):
        argv = ["collect", "--task", "fetchq", "--port", "0", *args]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_the_scripted_partner_keeps_its_seat_while_it_plans_and_ends_in_one_sentence(tmp_path, monkeypatch, capsys):
    """examples/collect_partner.py: while the team's plan is computed (its first compile takes seconds on a busy
    CPU: longer than the table waits for a silent seat) the partner keeps its seat; a table that stops answering
    ends it in one sentence, no traceback."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("collect_partner", ROOT / "examples" / "collect_partner.py")
    partner = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(partner)
    srv, url = _serve("fetchq", tmp_path / "people.hdf5", hz=40, leave=1.0)
    planned = threading.Event()

    def slow_plan(env, init, seed, steps, step_fn=None):  # 2.5 times as long as the table waits
        time.sleep(2.5)
        planned.set()
        return (np.zeros((steps, env.human_action_size), np.float32),
                np.zeros((steps, env.robot_action_size), np.float32))

    monkeypatch.setattr(collect, "scripted_actions", slow_plan)
    code = []
    t = threading.Thread(target=lambda: code.append(partner.main(["--url", url, "--task", "fetchq"])), daemon=True)
    t.start()
    _wait(planned.is_set, "the partner's plan")
    assert srv.collector.seats["robot"].token, "the table dropped the partner's seat while it planned"
    srv.shutdown()
    collect.close(srv)
    t.join(30)
    err = capsys.readouterr().err
    assert code == [2] and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"the table at {url} stopped answering" in err, err
