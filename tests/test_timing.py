"""RUN/speed.json (cogail_jax.runtime.timing), `cogail bench --phases` and the persistent compilation cache (no training
here: tests/test_train.py checks the speed.json of a real run)."""
import json
import time

import pytest

from cogail_jax.apps import cli
from cogail_jax.runtime import timing
from cogail_jax.runtime import xla


def _clock(**seconds):
    clock = timing.Phases()
    for name, s in seconds.items():
        clock.add(name, s)
    return clock


def test_phases_add_up_and_never_go_negative():
    clock = _clock(bc=2.0)
    with clock("bc"):
        time.sleep(0.05)
    clock.add("compile", -1.0)
    assert clock.seconds["bc"] >= 2.05 and clock.seconds["compile"] == 0.0
    assert clock.elapsed() >= 0


@pytest.mark.parametrize("calls,want", [([], 0.0), ([5.0], 5.0), ([5.0, 1.0, 2.0, 1.0], 4.0), ([1.0, 3.0], 0.0)])
def test_compile_estimate_is_the_first_call_over_a_steady_one(calls, want):
    assert timing.compile_estimate(calls) == want


def test_call_parts_split_the_calls_excess_between_checkpoints_and_the_rest():
    parts = timing.call_parts([9.0, 1.0, 1.0, 3.0, 1.0, 2.5, 1.0], {3, 4})
    assert parts == {"calls": 6, "median_call": 1.0, "checkpoint_excess": 2.0, "other_excess": 1.5}
    assert timing.call_parts([9.0], {0})["calls"] == 0 and timing.call_parts([], set())["median_call"] == 0.0


def test_a_resumed_training_adds_up_and_an_evaluation_replaces():
    first = timing.merge_train({}, _clock(demos=1, bc=2, compile=3, train=4), 100, 2.0, False,
                               {"bc_run": 1.5, "calls": 3}, task="fetchq")
    assert set(first["phases"]) == set(timing.PHASES) and first["phases"]["eval"] == 0.0
    assert first["train_parts"] == {**dict.fromkeys(timing.TRAIN_PARTS, 0.0), "bc_run": 1.5, "calls": 3}
    assert first["env_steps_per_s"] == 50.0 and first["task"] == "fetchq"
    ev = timing.merge_eval(first, _clock(eval=5, write=1), _clock(setup=1, checkpoints=3.5, extra_sets=0.5))
    assert ev["eval_parts"] == {"setup": 1, "checkpoints": 3.5, "extra_sets": 0.5, "prepared": 0.0}
    again = timing.merge_eval(ev, _clock(eval=6, write=2))
    assert again["eval_parts"] == dict.fromkeys(timing.EVAL_PARTS, 0.0)  # replaced with the new evaluation's
    assert again["phases"]["eval"] == 6 and again["phases"]["write"] == 2 and again["phases"]["train"] == 4
    resumed = timing.merge_train(again, _clock(demos=1, compile=3, train=4), 300, 2.0, True)
    assert resumed["phases"]["train"] == 8 and resumed["phases"]["bc"] == 2 and resumed["phases"]["eval"] == 6
    assert resumed["train_env_steps"] == 400 and resumed["env_steps_per_s"] == 100.0
    assert resumed["total"] == pytest.approx(sum(resumed["wall"].values()))
    fresh = timing.merge_train(again, _clock(train=1), 0, 0.0, False)
    assert fresh["phases"]["eval"] == 0.0 and fresh["env_steps_per_s"] is None


def test_bench_phases_prints_a_table_of_runs(tmp_path, capsys):
    rec = timing.merge_eval(timing.merge_train({}, _clock(demos=1.5, bc=2, compile=3, train=40), 1000, 10.0,
                                               False, task="handover"), _clock(eval=7, write=0.5))
    run = tmp_path / "run"
    run.mkdir()
    (run / "speed.json").write_text(json.dumps(rec))
    old = tmp_path / "old"  # a speed.json from before the phases
    old.mkdir()
    (old / "speed.json").write_text(json.dumps({"env_steps_per_s": 2e5}))
    assert cli.main(["bench", "--phases", str(run), str(old)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "| run | task | start | demos | bc | compile | train | eval | write | total | env steps/s |"
    assert lines[2].startswith(f"| {run} | handover | 0.0 | 1.5 | 2.0 | 3.0 | 40.0 | 7.0 | 0.5 | ")
    assert lines[2].endswith(" | 100 |")
    assert lines[3] == f"| {old} | - | - | - | - | - | - | - | - | - | 2e+05 |"
    assert lines[5].startswith("| run | bc_run | chunk_compile | compile_wait | calls | median_call |")
    assert lines[7] == f"| {run} | 0.0 | 0.0 | 0.0 | 0 | 0.000 | 0.0 | 0.0 | 0.0 | 0.0 | 0.0 | 0.0 |"
    assert lines[8] == f"| {old} | " + " | ".join(["-"] * 11) + " |"

    assert cli.main(["bench", "--phases", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no readable speed.json" in err[0]


def test_the_start_phase_counts_from_the_command_start_once():
    import time

    timing.mark_process_start()
    time.sleep(0.05)
    clock = timing.Phases()
    clock.take_process_start()
    assert clock.seconds["start"] >= 0.05 and clock.elapsed() >= 0.05  # the origin moved back to the command's start
    again = timing.Phases()
    again.take_process_start()  # taken already: a second run in the same process starts from its own call
    assert "start" not in again.seconds and again.elapsed() < 0.05
    rec = timing.merge_train({}, clock, 0, 0.0, False)
    assert rec["phases"]["start"] >= 0.05 and rec["total"] >= rec["phases"]["start"]

def test_compile_cache_folder():
    home = {"XDG_CACHE_HOME": "/x"}
    assert str(xla.compile_cache_dir(home)) == "/x/cogail/xla"
    assert str(xla.compile_cache_dir({**home, "COGAIL_CACHE": "/c"}, jax_dir="/j")) == "/c"
    assert str(xla.compile_cache_dir(home, jax_dir="/j")) == "/j"  # JAX_COMPILATION_CACHE_DIR of one's own
    assert xla.compile_cache_dir({"HOME": "/h"}).parts[-3:] == (".cache", "cogail", "xla")
    assert xla.compile_cache_dir({**home, "COGAIL_CACHE": "/c", "COGAIL_NO_COMPILE_CACHE": "1"}) is None


def test_compile_cache_is_set_when_on_and_left_alone_when_off(tmp_path, monkeypatch):
    import jax

    before = jax.config.jax_compilation_cache_dir
    monkeypatch.setenv("COGAIL_CACHE", str(tmp_path / "xla"))
    assert xla.enable_compile_cache(False) is None
    assert jax.config.jax_compilation_cache_dir == before
    monkeypatch.setenv("COGAIL_NO_COMPILE_CACHE", "1")
    assert xla.enable_compile_cache(True) is None
    assert jax.config.jax_compilation_cache_dir == before
    monkeypatch.delenv("COGAIL_NO_COMPILE_CACHE")
    try:
        assert xla.enable_compile_cache(True) == tmp_path / "xla" and (tmp_path / "xla").is_dir()
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
        assert jax.config.jax_persistent_cache_min_compile_time_secs == xla.MIN_COMPILE_SECONDS
    finally:  # back to the suite's cache (tests/conftest.py)
        jax.config.update("jax_compilation_cache_dir", before)


@pytest.mark.parametrize("extra,want", [([], True), (["--no-compile-cache"], False)])
def test_every_command_sets_up_the_cache_unless_told_not_to(extra, want, tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(cli, "enable_compile_cache", calls.append)
    monkeypatch.setenv("XLA_FLAGS", "")
    for cmd in (["report", "--run", str(tmp_path / "none")], ["eval", "--run", str(tmp_path / "none")]):
        assert cli.main([*cmd, *extra]) == 2  # parses, sets up, then fails: not a run
    assert calls == [want, want]


def test_a_compile_log_of_one_thread_leaves_out_the_compilations_beside_it():
    """``CompileLog(this_thread=True)`` (`cogail data`'s datasets, while the training programs compile in a thread
    beside them): only the compilations of the thread that made it, so that its seconds are part of that thread's
    wall time; a plain log counts every thread's."""
    import threading

    import jax
    import jax.numpy as jnp

    def beside_probe(x):
        return x * 11.0 - 2.0

    def here_probe(x):
        return x * 13.0 + 5.0

    every, mine = timing.CompileLog(), timing.CompileLog(this_thread=True)
    t = threading.Thread(target=lambda: jax.block_until_ready(jax.jit(beside_probe)(jnp.ones(3))))
    t.start()
    t.join()
    jax.jit(here_probe)(jnp.ones(3))
    assert {"beside_probe", "here_probe"} <= set(every.table())
    assert "here_probe" in mine.table() and "beside_probe" not in mine.table()


def test_compile_log_counts_each_program_once_and_merges_into_the_record():
    import jax
    import jax.numpy as jnp

    from cogail_jax.runtime import programs

    log = timing.CompileLog()
    f = programs.stored(lambda x: jnp.cos(x) + 3.0, "timing_probe", "test_timing")
    f(jnp.ones(5))
    f(jnp.ones(5))  # the same program: no second compilation
    jax.jit(lambda x: x * 7.0)(jnp.ones(2))
    table = log.table()
    probe = table["timing_probe"]  # its tracing and its compilation in one row
    assert probe["count"] == 1 and probe["backend"] > 0 and probe["trace"] > 0
    assert timing.CompileLog().table() == {}  # a new log reads only what happens after it
    rec = timing.merge_train({}, _clock(train=1.0), 10, 1.0, False, compiles=table)
    rec = timing.merge_eval(rec, _clock(eval=1.0), compiles={"timing_probe": {"count": 2, "backend": 1.0,
                                                                                "trace": 0.5}})
    assert rec["compiles"]["timing_probe"]["count"] == 3  # the evaluation's compilations add to the training's
    md = timing.compiles_table([("a", rec)])
    assert "`timing_probe` | 3 / " in md and md.splitlines()[-1].startswith("| all ")
