"""Runs survive kills, bad files and numerical blow-ups without losing work."""
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cogail_jax.runtime import checkpoint as ckpt
from cogail_jax.data import io as data
from cogail_jax.algo import train
from cogail_jax.apps import runs, train_loop




def _params(run_dir, cfg):
    s = runs.build(cfg, need_heldout=False)
    mgr = ckpt.manager(run_dir)
    abstract = jax.eval_shape(lambda: s.init(cfg.seeds, s.expert))
    out = {}
    for step in ckpt.steps(mgr):  # every listed checkpoint must be readable
        out[step] = jax.tree.leaves(jax.device_get(ckpt.restore(mgr, step, abstract).params))
    return out


@pytest.fixture(scope="module")
def kill_cfg(tiny_cfg):
    return tiny_cfg.replace(seeds=(7,), total_steps=4 * 16 * 24, checkpoint_every=2, updates_per_call=2)


@pytest.fixture(scope="module")
def reference(kill_cfg, tmp_path_factory):
    run = tmp_path_factory.mktemp("ref") / "run"
    train_loop.train_run(kill_cfg, run, progress=False)
    return _params(run, kill_cfg)


def _start(cfg_file, run, resume, stdout=subprocess.DEVNULL):
    args = [sys.executable, "-m", "cogail_jax.apps.cli", "train", "--config", str(cfg_file), "--run", str(run), "--no-progress"]
    return subprocess.Popen(args + (["--resume"] if resume else []), stdout=stdout, stderr=subprocess.PIPE,
                            start_new_session=True)


def _wait_for_step(run, step, proc, timeout=120):
    t0 = time.time()
    while time.time() - t0 < timeout and proc.poll() is None:
        d = Path(run) / "checkpoints"
        if d.exists() and any(p.name.isdigit() and int(p.name) >= step for p in d.iterdir()):
            return True
        time.sleep(0.05)
    return False


def test_kill_9_then_resume_matches_uninterrupted(kill_cfg, reference, tmp_path):
    cfg_file = tmp_path / "cfg.json"
    cfg_file.write_text(kill_cfg.to_json())
    run = tmp_path / "run"
    rng = random.Random(0)
    kills = 0
    # kill 1: at a random moment of start-up / compilation; kills 2-3: at random moments of training
    for target in (None, 4, 12):
        proc = _start(cfg_file, run, resume=(run / "config.json").exists())
        if target is None:
            time.sleep(rng.uniform(1.0, 6.0))
        else:
            assert _wait_for_step(run, target, proc), proc.stderr.read().decode()[-2000:]
            time.sleep(rng.uniform(0.0, 0.3))
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            kills += 1
        proc.wait()
    assert kills >= 2
    proc = _start(cfg_file, run, resume=True, stdout=subprocess.PIPE)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err.decode()[-2000:]
    # the work done before the kills is kept: training continues from a checkpoint at or after update 12
    import re

    m = re.search(r"resuming .* from update (\d+)", out.decode())
    assert m and int(m.group(1)) >= 12, out.decode()[-500:]
    got = _params(run, kill_cfg)  # every checkpoint left behind is readable
    last = max(reference)
    assert max(got) == last
    for a, b in zip(reference[last], got[last]):
        np.testing.assert_array_equal(a, b)


def test_corrupt_latest_checkpoint_is_skipped(kill_cfg, reference, tmp_path, capsys):
    run = tmp_path / "run"  # every training state kept (--keep-full all): a damaged newest one has a predecessor
    train_loop.train_run(kill_cfg, run, progress=False, stop_after=6, keep_full=None)
    latest = Path(run) / "checkpoints" / "6"
    for f in latest.rglob("*"):
        if f.is_file() and f.stat().st_size > 0:
            f.write_bytes(b"\0garbage" * 3)
    train_loop.train_run(kill_cfg, run, resume=True, progress=False, keep_full=None)
    out = capsys.readouterr().out
    assert "checkpoint 6" in out and "unreadable" in out and "resuming" in out
    assert any((Path(run) / "corrupt_checkpoints").iterdir())  # moved aside, not deleted
    got = _params(run, kill_cfg)
    last = max(reference)
    for a, b in zip(reference[last], got[last]):
        np.testing.assert_array_equal(a, b)


def test_nonfinite_stops_and_keeps_last_good_checkpoint(kill_cfg, tmp_path, monkeypatch):
    real = train.fit_normalizer

    def broken(expert, *args, **kwargs):
        stats = real(expert, *args, **kwargs)
        return {**stats, "std": np.zeros_like(stats["std"])}  # 0/0 in the observations -> NaN

    monkeypatch.setattr(train, "fit_normalizer", broken)
    run = tmp_path / "run"
    with pytest.raises(runs.RunError, match=r"diverged at update \d+"):
        train_loop.train_run(kill_cfg, run, progress=False)
    assert ckpt.steps(ckpt.manager(run)) == [0]


def test_same_seed_same_metrics(tiny_cfg, fetchq):
    demos = data.load_demos(tiny_cfg.demos, fetchq)
    expert = train.expert_arrays(demos, tiny_cfg.history)
    init, chunk, _ = train.make_train_fns(tiny_cfg, fetchq, train.fit_normalizer(expert))
    runs = []
    for _ in range(2):
        s = init(tiny_cfg.seeds, expert)
        s, m = chunk(s, expert)
        runs.append(jax.device_get(m))
    for k in runs[0]:
        np.testing.assert_array_equal(runs[0][k], runs[1][k])


def test_config_errors(tiny_cfg):
    from cogail_jax.algo.config import ConfigError

    for bad, why in ((dict(task="nope"), "unknown task 'nope'"), (dict(method="nope"), "unknown method 'nope'"),
                     (dict(total_steps=0), "total-steps must be positive"), (dict(num_envs=-1), "num-envs must be"),
                     (dict(checkpoint_every=0), "checkpoint-every must be positive"), (dict(seeds=()), "no seeds")):
        with pytest.raises(ConfigError, match=why):
            tiny_cfg.replace(**bad).validate()


def test_a_removed_field_at_its_old_value_still_loads_and_another_value_stops(tiny_cfg, tmp_path):
    """A run's config.json from before a field was removed (``config.REMOVED``) loads where the field holds the value
    every run had; another value stops with a ConfigError naming the field."""
    from cogail_jax.algo.config import REMOVED, ConfigError, TrainConfig

    d = json.loads(tiny_cfg.to_json())
    path = tmp_path / "config.json"
    path.write_text(json.dumps({**d, **REMOVED}))
    assert TrainConfig.load(path) == tiny_cfg
    for key in REMOVED:
        path.write_text(json.dumps({**d, key: "psi"}))
        with pytest.raises(ConfigError, match=key):
            TrainConfig.load(path)
    with pytest.raises(ConfigError, match="unknown config field .no_such_field."):
        TrainConfig.from_dict({**d, "no_such_field": 1})


def test_max_episode_steps_sets_the_time_limit_of_training_and_evaluation(tiny_cfg):
    """``max_episode_steps`` builds the task with that time limit (training and evaluation use ``Setup.env``);
    0 keeps the task's own; a negative value is a config error."""
    from cogail_jax.algo.config import ConfigError

    assert runs.build(tiny_cfg, need_heldout=False).env.max_episode_steps == 300  # fetchq's own
    s = runs.build(tiny_cfg.replace(max_episode_steps=40), need_heldout=False)
    assert s.env.max_episode_steps == 40
    state = s.env.reset(jax.random.PRNGKey(0))
    for _ in range(40):
        assert float(state.done) == 0.0 and float(state.info["truncation"]) == 0.0
        state = s.env.step(state, np.zeros(s.env.action_size, np.float32))
    assert float(state.done) == 1.0 and int(state.info["t"]) == 40
    assert float(state.info["truncation"]) == 1.0  # a time-out, not a terminal state: bootstrapped in GAE
    with pytest.raises(ConfigError, match="max_episode_steps"):
        tiny_cfg.replace(max_episode_steps=-1).validate()


def test_resume_into_run_of_another_task(tiny_cfg, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({**json.loads(tiny_cfg.to_json()), "task": "handover"}))
    (run / "checkpoints" / "2").mkdir(parents=True)  # it trained (a stand-in: only the folder's content is read)
    with pytest.raises(runs.RunError, match="was trained with task='handover', not the given task='fetchq'"):
        train_loop.train_run(tiny_cfg, run, resume=True, progress=False)
    assert sorted(p.name for p in run.iterdir()) == ["checkpoints", "config.json"]


# ---------------------------------------------------------------- property-based: demonstration files
FAULTS = [None, "drop", "obs_dim", "act_dim", "nan", "inf", "dtype", "ndim", "empty", "length_mismatch"]
_demo = st.fixed_dictionaries({
    "T": st.integers(1, 6),
    "fault": st.sampled_from(FAULTS),
    "key": st.sampled_from(["obs", "actions_human", "actions_robot"]),
    "bad_dim": st.sampled_from([0, 1, 3, 12, 14]),
})


def _write_demo(g, i, d):
    dg = g.create_group(f"demo_{i}")
    dims = {"obs": 12, "actions_human": 2, "actions_robot": 2}
    for key, dim in dims.items():
        fault = d["fault"] if key == d["key"] else None
        if fault == "drop":
            continue
        T = 0 if fault == "empty" else d["T"] + (1 if fault == "length_mismatch" else 0)
        if fault in ("obs_dim", "act_dim"):
            dim = d["bad_dim"] if d["bad_dim"] != dim else dim + 1
        shape = (T,) if fault == "ndim" else (T, dim)
        arr = np.full(shape, b"abc") if fault == "dtype" else np.ones(shape, np.float32)
        if fault == "nan":
            arr.flat[0] = np.nan
        if fault == "inf":
            arr.flat[-1] = np.inf
        dg.create_dataset(key, data=arr)
    if d["fault"] == "empty":  # every array empty
        for key in dims:
            if key in dg:
                del dg[key]
            dg.create_dataset(key, data=np.zeros((0, dims[key]), np.float32))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(demos=st.lists(_demo, min_size=0, max_size=3), task=st.sampled_from(["fetchq", "fetchq", "handover", None]))
def test_loader_never_crashes_on_bad_files(demos, task, fetchq, tmp_path_factory):
    """Any mix of faults (missing keys, wrong dims, NaN/inf, wrong dtype or rank, empty demos, mismatched
    lengths, another task): the file loads only when nothing is wrong, else one DatasetError naming it."""
    path = tmp_path_factory.mktemp("h") / "f.hdf5"
    with h5py.File(path, "w") as f:
        if task:
            f.attrs["task"] = task
        g = f.create_group("data")
        for i, d in enumerate(demos):
            _write_demo(g, i, d)
    valid = bool(demos) and task in ("fetchq", None) and all(d["fault"] is None for d in demos)
    if valid:
        assert data.load_demos(path, fetchq).num == len(demos)
    else:
        with pytest.raises(data.DatasetError) as e:
            data.load_demos(path, fetchq)
        assert str(path) in str(e.value) and "\n" not in str(e.value)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(blob=st.binary(min_size=0, max_size=2048))
def test_loader_rejects_garbage_bytes(blob, fetchq, tmp_path_factory):
    path = tmp_path_factory.mktemp("g") / "junk.hdf5"
    path.write_bytes(blob)
    with pytest.raises(data.DatasetError, match="junk.hdf5"):
        data.load_demos(path, fetchq)


def test_background_saver_queues_in_order_and_reports_errors(tmp_path, monkeypatch):
    """Checkpoints submitted while training goes on are written in submission order, at most MAX_PENDING copies
    wait, and a failed write surfaces (at the next submit or at wait) instead of being lost."""
    written, gate = [], threading.Event()

    def slow_save(mgr, step, state):
        gate.wait(5)
        if step == 3:
            raise OSError("disk full")
        written.append((step, float(state["x"][0])))

    monkeypatch.setattr(ckpt, "save", slow_save)
    saver = ckpt.BackgroundSaver(None)
    state = {"x": jax.numpy.ones(2)}
    saver.submit(1, saver.copy(state))
    saver.submit(2, saver.copy({"x": state["x"] * 2}))
    assert len(saver._pending) == ckpt.BackgroundSaver.MAX_PENDING == 2 and not written  # queued, caller not blocked
    threading.Timer(0.3, gate.set).start()
    t0 = time.perf_counter()
    saver.submit(4, saver.copy({"x": state["x"] * 4}))  # a third waits until the oldest is written
    assert time.perf_counter() - t0 >= 0.25 and written[:1] == [(1, 1.0)]
    saver.wait()
    assert written == [(1, 1.0), (2, 2.0), (4, 4.0)]
    saver.submit(3, saver.copy(state))
    while not saver._pending[0].done():
        time.sleep(0.01)
    with pytest.raises(OSError, match="disk full"):  # the failed write surfaces at the next submit
        saver.submit(5, saver.copy(state))
    saver.submit(3, saver.copy(state))
    with pytest.raises(OSError, match="disk full"):  # or at wait
        saver.wait()
    saver.close()


def test_a_failed_restore_s_pending_reads_print_nothing(capsys):
    """What TensorStore reads left pending by a failed restore print when they end, from their own threads and in
    pieces ("Traceback ...", asyncio's frames, "RuntimeError: Event loop is closed"), is dropped; another
    thread's own lines and the main thread's output pass, whole and in order."""
    import threading

    from cogail_jax.runtime import checkpoint as ckpt

    import sys

    real = sys.stderr
    quiet = ckpt._QuietStderr(real)
    noise = ["Traceback (most recent call last):\n", '  File "/usr/lib/python3.11/asyncio/base_events.py", line 806, ',
             "in call_soon_threadsafe\n", "    self._check_closed()\n",
             '  File "/usr/lib/python3.11/asyncio/base_events.py", line 519, in _check_closed\n',
             "    raise RuntimeError('Event loop is closed')\n", "RuntimeError: Event loop is closed\n"]

    def pending_read():
        for piece in noise:
            quiet.write(piece)

    def other():
        quiet.write("warning: ")
        quiet.write("something else\n")
        quiet.write("no newline yet")
        quiet.flush()

    threads = [threading.Thread(target=pending_read) for _ in range(4)] + [threading.Thread(target=other)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    quiet.write("eval: 50%\r")  # the main thread's progress bar: straight through
    quiet.flush()
    err = capsys.readouterr().err
    assert err == "warning: something else\nno newline yeteval: 50%\r", repr(err)
