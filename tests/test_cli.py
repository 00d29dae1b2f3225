import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from cogail_envs import get_task

from cogail_jax.apps import cli


@pytest.mark.parametrize("cmd", [[], ["demos"], ["train"], ["eval"], ["video"], ["bench"]])
def test_help(cmd, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main([*cmd, "--help"])
    assert e.value.code == 0
    assert "usage: cogail" in capsys.readouterr().out



def test_demos_help_points_to_the_page_that_describes_the_schema(capsys):
    """``cogail demos --help`` names the file and section that describe the schema it writes, and they exist."""
    with pytest.raises(SystemExit):
        cli.main(["demos", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert 'docs/tasks.md, "Demonstration files"' in text and "see README" not in text, text
    page = Path(__file__).parents[1] / "docs" / "tasks.md"
    assert "\n## Demonstration files\n" in page.read_text()

def run(*args):
    return subprocess.run([sys.executable, "-m", "cogail_jax.apps.cli", *args], capture_output=True, text=True, timeout=300)


def test_demos_command(tmp_path):
    out = tmp_path / "d.hdf5"
    r = run("demos", "--task", "fetchq", "--num", "8", "--mix", "D1", "--seed", "0", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "wrote 8 fetchq demonstrations" in r.stdout
    import cogail_envs
    from cogail_jax.data import io as data

    demos = data.load_demos(out, cogail_envs.make_env("fetchq"))
    assert demos.num == 8
    with h5py.File(out) as f:
        assert f.attrs["mixture"] == "D1"


@pytest.mark.parametrize("args,needle", [
    (["train", "--task", "fetchq", "--run", "RUN", "--demos", "MISSING.hdf5", "--total-steps", "100"], "does not exist"),
    (["train", "--task", "fetchq", "--run", "RUN", "--resume"], "cannot resume"),
    (["eval", "--run", "RUN"], "not a run directory"),
    (["video", "--run", "RUN", "--out", "MISSING.gif"], "not a run directory"),
    (["video", "--task", "fetchq", "--out", "MISSING.txt"], "a video is written as .gif or .mp4"),
    (["video", "--task", "fetchq", "--out", "DIR.gif"], "is a folder: pass a file name"),
    (["train", "--task", "fetchq", "--run", "RUN", "--config", "MISSING.json"], "config file"),
    (["train", "--task", "fetchq", "--run", "RUN", "--set", "nope=1"], "unknown config field"),
    (["train", "--task", "fetchq", "--run", "RUN", "--set", "lrr=1"], "did you mean 'lr'?"),
    (["train", "--task", "fetchq", "--run", "RUN", "--set", "multi_device=mesh"], "multi_device must be auto, shard_map or per_device"),
])
def test_user_errors_are_one_clear_line(args, needle, tmp_path, capsys):
    args = [a.replace("RUN", str(tmp_path / "run")).replace("MISSING", str(tmp_path / "missing")) for a in args]
    (tmp_path / "DIR.gif").mkdir()
    args = [str(tmp_path / a) if a == "DIR.gif" else a for a in args]
    code, err = in_process(args, capsys)  # the command's own process: test_the_command_answers_in_one_line
    assert code == 2
    assert needle in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()  # a run that cannot start leaves no folder for --resume to pick up


@pytest.mark.parametrize("text,needle", [
    ("[1, 2]", "holds a JSON list, not an object"),
    ('{"lr": "abc"}', 'lr is "abc", expected a number'),
    ('{"seeds": [1, "a"]}', "expected a list of integers"),
    ('{"reward_norm": 1}', "expected true or false"),
    ('{"num_envs": 2.5}', "expected an integer"),
    ('{"lrr": 0.1}', "unknown config field 'lrr': did you mean 'lr'?"),
    ("{bad", "is not valid JSON"),
])
def test_a_config_file_is_checked_field_by_field(text, needle, tmp_path, capsys):
    """``--config``'s file: a JSON object whose fields exist and have their defaults' types, or one sentence naming
    the field and the fix before anything runs (no run folder is made)."""
    f = tmp_path / "c.json"
    f.write_text(text)
    code, err = in_process(["train", "--task", "fetchq", "--run", str(tmp_path / "run"), "--config", str(f)], capsys)
    assert code == 2 and needle in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


RUN_CONFIGS = {"not JSON": ("{bad", "cannot be read as JSON"),
               "a list": ("[1, 2]", "holds a JSON list, not a config's object of fields"),
               "a field of the wrong type": ('{"task": "fetchq", "num_envs": "four"}', 'num_envs is "four", expected an integer'),
               "an unknown field": ('{"task": "fetchq", "bogus": 1}', "unknown config field 'bogus'")}


@pytest.mark.parametrize("damage", list(RUN_CONFIGS))
def test_a_damaged_run_config_is_one_sentence_in_every_command(damage, tmp_path, capsys):
    """A run whose config.json is damaged: every command that reads it (eval, video, data --run, train --resume)
    ends in one sentence naming the file, before anything runs; so does data --run of a folder that is no run."""
    text, needle = RUN_CONFIGS[damage]
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(text)
    for args in (["eval", "--run", str(run_dir)], ["video", "--run", str(run_dir), "--out", str(tmp_path / "v.gif")],
                 ["data", "--run", str(run_dir)], ["train", "--run", str(run_dir), "--resume"]):
        code, err = in_process(args, capsys)
        assert code == 2 and needle in err and str(run_dir / "config.json") in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in run_dir.iterdir()) == ["config.json"]  # nothing made, nothing changed
    code, err = in_process(["data", "--run", str(tmp_path)], capsys)
    assert code == 2 and "is not a run directory (no config.json)" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("command", ["demos", "import", "report", "bench", "data"])
@pytest.mark.parametrize("where", ["a folder", "under a file"])
def test_an_output_that_cannot_be_written_ends_before_the_work(command, where, tmp_path, capsys, monkeypatch):
    """Each command that writes a file (or, for ``cogail data``, the data folder) checks the path before it works:
    one sentence naming it, nothing made (no temporary file left)."""
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("mine")
    out = tmp_path / "folder" if where == "a folder" else tmp_path / "file" / "x.out"
    run_dir = tmp_path / "run"  # report's run: a config.json is all it needs to start
    run_dir.mkdir()
    (run_dir / "config.json").write_text('{"task": "fetchq"}')
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "data"))
    args = {"demos": ["demos", "--task", "fetchq", "--num", "2", "--out", str(out)],
            "import": ["import", "--task", "fetchq", "--in", str(tmp_path / "file"), "--out", str(out)],
            "report": ["report", "--run", str(run_dir), "--out", str(out)],
            "bench": ["bench", "fetchq", str(out)]}
    if command == "data":
        monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "file" if where == "a folder" else out))
        args["data"] = ["data", "--task", "fetchq", "--no-robustness", "--no-programs"]
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    code, err = in_process(args[command], capsys)
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert ("is a folder: pass a file name" in err if where == "a folder" and command != "data" else
            "a file: " in err and (" is a file" in err or "lies under" in err)), err
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before and (tmp_path / "file").read_text() == "mine"


@pytest.mark.parametrize("command", ["demos", "import"])
def test_a_dataset_that_exists_is_never_overwritten(command, tmp_path, capsys):
    """``cogail demos --out`` and ``cogail import --out`` refuse a file that is there (a user's dataset), in one
    sentence naming it and the fix, before any work."""
    out = tmp_path / "mine.hdf5"
    out.write_text("mine")
    src = tmp_path / "src.hdf5"
    src.write_text("not read")
    args = {"demos": ["demos", "--task", "fetchq", "--num", "2", "--out", str(out)],
            "import": ["import", "--task", "fetchq", "--in", str(src), "--out", str(out)]}[command]
    code, err = in_process(args, capsys)
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"--out {out} exists: remove it or pass another file name" in err, err
    assert out.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["mine.hdf5", "src.hdf5"]


@pytest.mark.parametrize("command", ["video", "report", "bench"])
def test_an_output_made_from_a_run_is_replaced_when_run_again(command, tmp_path, capsys, monkeypatch):
    """What a command derives (a video, a report, a bench table) is written again over the file of an earlier
    call; a file that cannot be written is one sentence."""
    from cogail_jax.apps import bench

    out = tmp_path / {"video": "v.gif", "report": "r.html", "bench": "b.json"}[command]
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text('{"task": "fetchq"}')
    monkeypatch.setattr(bench, "main", lambda task, sizes, out, *rest: Path(out).write_text("[]"))  # no benchmark
    args = {"video": ["video", "--task", "fetchq", "--num", "1", "--steps", "2", "--out", str(out)],
            "report": ["report", "--run", str(run_dir), "--out", str(out)],
            "bench": ["bench", "fetchq", str(out)]}[command]
    out.write_text("earlier")
    code, err = in_process(args, capsys)
    assert code == 0 and out.read_bytes() != b"earlier", err
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: str(p) != str(out) and real_access(p, mode, **kw))  # as if read-only
    out.write_text("earlier")
    code, err = in_process(args, capsys)
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"{out} exists and cannot be written: make it writable or pass another file name" in err, err
    assert out.read_text() == "earlier"


@pytest.mark.parametrize("args,needle", [
    (["demos", "--task", "fetchq", "--mix", "a,b", "--out", "OUT"], "--mix a,b: weights are comma-separated numbers"),
    (["demos", "--task", "fetchq", "--mix", "1,0.5", "--out", "OUT"], "needs 4 non-negative weights, e.g. 1,1,1,1, got 1,0.5"),
    (["demos", "--task", "fetchq", "--seed", str(2 ** 64), "--out", "OUT"], "a seed is an integer from 0 to 4294967295"),
    (["data", "--task", "fetchq", "--mix", "D9"], "unknown mixture 'D9' for fetchq: choose one of uniform, D1, D2"),
    (["train", "--task", "fetchq", "--run", "OUT", "--seeds", "1,4294967296"], "a seed is an integer from 0"),
    (["train", "--task", "fetchq", "--run", "OUT", "--set", "seeds=-1"], "a seed is an integer from 0"),
    (["train", "--task", "fetchq", "--run", "OUT", "--total-steps", "inf"], "expected a positive integer, got 'inf'"),
    (["train", "--task", "fetchq", "--run", "OUT", "--total-steps", "2.5"], "expected a positive integer, got '2.5'"),
    (["bench", "fetchq", "--sizes", "a"], "--sizes: expected comma-separated positive integers"),
    (["bench", "fetchq", "--sizes", "-4"], "--sizes: expected comma-separated positive integers"),
    (["bench", "fetchq", "--env-shards", "0"], "--env-shards: expected a positive integer"),
    (["eval", "--run", "OUT", "--replay-file", "a/t.hdf5", "--replay-file", "b/t.hdf5"], "are both named 't'"),
    (["eval", "--run", "OUT", "--replay-file", "a/t.hdf5", "--extra-set", "t=c.hdf5"], "are both named 't'"),
])
def test_bad_values_end_before_anything_runs(args, needle, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "data"))
    code, err = in_process([a.replace("OUT", str(tmp_path / "out")) for a in args], capsys)
    assert code == 2 and needle in err and "Traceback" not in err, err
    assert err.strip().splitlines()[-1].startswith(f"cogail {args[0]}: error:")
    assert not any(tmp_path.iterdir())  # no data, no run, no output


def _saved_run(tmp_path, trained=True, **changes):
    """A run folder whose config.json is fetchq's settings with ``changes`` (e.g. made when the task's defaults were
    others), holding a checkpoint where ``trained`` (a stand-in: the folder's content is all that is looked at)."""
    from cogail_jax.algo.config import resolve

    run = tmp_path / "run"
    run.mkdir()
    saved = resolve("fetchq", "paper", {}).replace(**changes)
    (run / "config.json").write_text(saved.to_json())
    if trained:
        (run / "checkpoints" / "40").mkdir(parents=True)
    return run, saved


@pytest.mark.parametrize("extra,saved_text,given_text", [
    (["--total-steps", "40960"], "total_steps=6016000", "total_steps=40960"),
    (["--set", "lambda_a=7"], "lambda_a=", "lambda_a=7.0"),
    (["--seeds", "300,400"], "seeds=(300, 400, 500)", "seeds=(300, 400)"),
    (["--demos", "mine.hdf5"], "demos=None", "demos='mine.hdf5'"),
    (["--budget", "quick"], "total_steps=6016000", "total_steps=902400"),
    (["--method", "ma_gail"], "method='cogail'", "method='ma_gail'"),
    (["--seeds", "300,400", "--set", "lr=1e-3"], "seeds=(300, 400, 500) and lr=0.0003", "seeds=(300, 400) and lr=0.001"),
])
def test_resume_with_other_settings_is_refused_naming_them(extra, saved_text, given_text, tmp_path, capsys):
    """`cogail train --resume` with an option that changes the run's config (its fields, --set, --seeds, --demos, a
    named budget's, the method) ends in one sentence naming each field as saved and as given and the fix, before
    anything runs: the run is neither trained with the saved config as if the option had been taken, nor changed."""
    run, _ = _saved_run(tmp_path)
    before = (run / "config.json").read_bytes()
    code, err = in_process(["train", "--task", "fetchq", "--run", str(run), "--resume", "--no-progress", *extra], capsys)
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"cannot resume: {run} was trained with {saved_text}" in err and f"not the given {given_text}" in err, err
    assert "drop those options to continue the run as it was, or pass another --run" in err
    assert (run / "config.json").read_bytes() == before and sorted(p.name for p in run.iterdir()) == [
        "checkpoints", "config.json"]


@pytest.mark.parametrize("args", [
    [],  # the run's own task
    ["--task", "fetchq"],
    ["--task", "fetchq", "--budget", "paper", "--method", "cogail", "--seeds", "300,400,500"],  # as `make train`
    ["--task", "fetchq", "--total-steps", "1234", "--eval", "--keep-policies", "all", "--no-progress"],
    ["--config", "RUN/config.json"],
])
def test_resume_continues_a_run_made_under_other_defaults(args, tmp_path):
    """Only what the user gives is compared with the run's config, never the task's current settings: a run made
    when fetchq's defaults were others (here lr, num_envs and total_steps) is continued with its own config by a plain
    --resume, by the options `make train` always gives when they equal the run's, and with options that change no
    field (or equal the run's)."""
    from cogail_jax.apps import runs

    run, saved = _saved_run(tmp_path, lr=1e-3, num_envs=32, total_steps=1234)
    a = cli.build_parser().parse_args(["train", "--run", str(run), "--resume",
                                       *[x.replace("RUN", str(run)) for x in args]])
    cfg, given = cli._config_and_given(a)
    assert cfg != saved or "--config" in args  # today's defaults
    assert runs.run_config(cfg, run, True, given) == (saved, False)  # the run's own, and its folder as it is


def test_a_run_folder_that_never_trained_starts_afresh(tmp_path, capsys):
    """A folder a command left without a checkpoint (it failed or was stopped before its first one) holds no run:
    resumed with other options it starts afresh with those (a plain --resume keeps its config), its stale data
    record dropped; a folder holding checkpoints is never started over, config.json or not."""
    from cogail_jax.apps import runs

    run, saved = _saved_run(tmp_path, trained=False, demos=str(tmp_path / "missing.hdf5"), train_varied=0)
    (run / "data.json").write_text('{"sets": {"train": {"path": "missing.hdf5", "content_hash": "x"}}}')
    a = cli.build_parser().parse_args(["train", "--task", "fetchq", "--run", str(run), "--resume", "--demos", "d.hdf5",
                                       "--set", "train_varied=0"])
    cfg, given = cli._config_and_given(a)
    assert runs.run_config(saved, run, True, set()) == (saved, True)
    assert runs.run_config(cfg, run, True, given) == (cfg, True)
    assert "holds no checkpoint: starting it afresh with the options given" in capsys.readouterr().out
    runs.write_run_dir(cfg, run)
    assert json.loads((run / "config.json").read_text())["demos"] == "d.hdf5" and not (run / "data.json").exists()
    (run / "policies" / "2").mkdir(parents=True)  # a run that trained: refused either way, nothing written
    with pytest.raises(runs.RunError, match="cannot resume"):
        runs.run_config(saved, run, True, {"demos"})
    (run / "config.json").unlink()
    with pytest.raises(runs.RunError, match="holds checkpoints but no config.json"):
        runs.run_config(cfg, run, False)


def in_process(args, capsys):
    """``cli.main(args)`` in this process (a user error or a bad flag costs no start of a Python): (exit code,
    stderr)."""
    capsys.readouterr()
    try:
        code = cli.main(list(args))
    except SystemExit as e:  # argparse's own exit
        code = e.code
    return code, capsys.readouterr().err


def test_the_command_answers_in_one_line(tmp_path):
    """The installed command (its own process, ``python -m cogail_jax.apps.cli``): a user error and a bad flag each
    end with exit status 2 and one line on stderr, nothing else (no warning of a library at start-up); the other
    cases of both kinds are run in this process (test_user_errors_are_one_clear_line, test_bad_flags)."""
    r = run("train", "--task", "fetchq", "--run", str(tmp_path / "run"), "--resume")
    assert r.returncode == 2 and "cannot resume" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = run("train", "--task", "fetchq", "--run", "x", "--num-envs", "0")
    assert r.returncode == 2 and "Traceback" not in r.stderr and "expected a positive integer, got '0'" in r.stderr


@pytest.mark.parametrize("error,answered", [
    ("INTERNAL: Failed to get configs for: 14 out of 14 instructions. BlasLt is unavailable", True),
    ("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 123456 bytes.", True),
    ("INTERNAL: something else went wrong in the kernel", False),
])
def test_a_device_out_of_memory_is_one_clear_line(error, answered, monkeypatch, capsys):
    import jax

    def fail(args):
        raise jax.errors.JaxRuntimeError(error)

    monkeypatch.setattr(cli, "_dispatch", fail)
    if not answered:  # any other device error keeps its traceback
        with pytest.raises(jax.errors.JaxRuntimeError):
            cli.main(["train", "--run", "x"])
        return
    assert cli.main(["train", "--run", "x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "XLA_PYTHON_CLIENT_MEM_FRACTION" in err[0] and "--resume" in err[0]


@pytest.mark.parametrize("args, why", [
    (["--method", "nope"], "invalid choice: 'nope'"),
    (["--seeds", "a,b"], "--seeds must be comma-separated integers"),
    (["--num-envs", "0"], "expected a positive integer, got '0'"),
])
def test_bad_flags(args, why, capsys):
    """A bad flag value stops argparse with its own message (a run that is otherwise valid: a task given)."""
    code, err = in_process(["train", "--task", "fetchq", "--run", "x", *args], capsys)
    assert code == 2 and "Traceback" not in err and why in err, err


def test_bench_tiny_writes_json(tmp_path, monkeypatch):
    import json

    from cogail_jax.apps import bench
    from cogail_jax.data import io as data

    monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "data"))
    for split in ("train", "validation", "test"):
        monkeypatch.setitem(get_task("fetchq").splits, split, 4)
    with pytest.raises(data.MissingDataError, match="cogail data"):  # benchmarks make no data
        bench.main("fetchq", (4,), str(tmp_path / "x.json"), steps=4, unroll=8, calls=1, peer=False)
    assert cli.main(["data", "--task", "fetchq", "--set", "train_varied=0", "--no-robustness", "--no-programs"]) == 0
    out = tmp_path / "bench.json"
    assert cli.main(["bench", "fetchq", str(out), "--sizes", "4", "--steps", "4", "--unroll", "8", "--calls", "1"]) == 0
    rows = json.loads(out.read_text())["rows"]
    kinds = [r["kind"] for r in rows]
    assert kinds == ["env-only", "co-gail train_step", "co-gail train_step", "brax ppo (peer)"]
    assert [r.get("seeds", 1) for r in rows] == [1, 1, 3, 1]
    assert all(r["env_steps_per_s"] > 0 and r["compile_s"] >= 0 for r in rows)
    del bench


def test_video_of_scripted_demos(tmp_path):
    import imageio.v2 as imageio

    out = tmp_path / "demo.gif"
    assert cli.main(["video", "--task", "fetchq", "--num", "2", "--out", str(out)]) == 0
    frames = imageio.mimread(out)
    assert len(frames) > 20 and frames[0].shape == (256, 512, 3)


def test_video_of_a_run_has_interpolation_and_replay_rows(tiny_cfg, tmp_path):
    import imageio.v2 as imageio

    from cogail_jax.apps import runs, train_loop

    run = tmp_path / "run"
    train_loop.train_run(tiny_cfg.replace(seeds=(3,)), run, progress=False, stop_after=0)
    out = tmp_path / "run.gif"
    assert cli.main(["video", "--task", "fetchq", "--run", str(run), "--num", "2", "--steps", "6", "--out", str(out)]) == 0
    frames = imageio.mimread(out)
    assert len(frames) == 3 and frames[0].shape == (512, 512, 3)  # 2 rows (interp, replay) x 2 episodes
    assert not np.array_equal(frames[0], frames[-1])  # the agents move


def test_video_of_an_mjx_task_renders_offscreen(tmp_path):
    import imageio.v2 as imageio

    out = tmp_path / "handover.mp4"
    assert cli.main(["video", "--task", "handover", "--num", "1", "--steps", "8", "--out", str(out)]) == 0
    frames = imageio.mimread(out)
    assert len(frames) == 4 and frames[0].ndim == 3 and frames[0].shape[2] == 3
    assert frames[0].std() > 5  # a rendered scene, not a blank frame


def test_brax_shim_places_like_pmap_so_the_epoch_compiles_once():
    """brax's PPO replicates its state with jax.device_put_replicated (our shim on new jax) and feeds each
    epoch's output to the next: the second and third calls must reuse the first call's compilation (a
    recompile inside the timed epoch made brax's figure ~100x too low)."""
    import jax
    import jax.numpy as jnp

    from cogail_jax.apps import bench

    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, *a, **k: compiles.append(name) if "backend_compile" in name else None)
    epoch = jax.pmap(lambda t: jax.tree.map(lambda a: a * 2, t), axis_name="i", donate_argnums=0)
    state = bench._replicate_for_pmap({"w": jnp.ones(3), "n": jnp.zeros((2, 2))}, jax.local_devices()[:1])
    assert state["w"].shape == (1, 3) and state["n"].shape == (1, 2, 2)
    state = jax.block_until_ready(epoch(state))
    before = len(compiles)
    assert before >= 1  # the listener sees compilations (else the check below could not fail)
    state = jax.block_until_ready(epoch(epoch(state)))
    assert len(compiles) == before
    assert float(state["w"][0, 0]) == 8.0


@pytest.mark.parametrize("text,value", [("false", False), ("False", False), ("0", False), ("no", False),
                                        ("off", False), ("true", True), ("1", True), ("yes", True)])
def test_set_parses_booleans(text, value):
    a = cli.build_parser().parse_args(["train", "--task", "fetchq", "--run", "x", "--set", f"disc_instance_noise={text}",
                                       "--set", "reward_norm=" + text])
    cfg = cli._config_from_args(a)
    assert cfg.disc_instance_noise is value and cfg.reward_norm is value


def test_keep_full_counts_training_states():
    parse = lambda v: cli.build_parser().parse_args(["train", "--task", "fetchq", "--run", "x", "--keep-full", v])  # noqa: E731
    assert parse("all").keep_full is None and parse("3").keep_full == 3
    assert cli.build_parser().parse_args(["train", "--task", "fetchq", "--run", "x"]).keep_full == 1  # the newest
    for bad in ("0", "-1", "some"):
        with pytest.raises(SystemExit):
            parse(bad)


def test_set_parses_numbers_seeds_and_optional_files():
    from cogail_jax.algo.config import ConfigError

    a = cli.build_parser().parse_args(["train", "--task", "fetchq", "--run", "x", "--set", "total_steps=1e6", "--set", "lr=2e-4",
                                       "--set", "seeds=1,2", "--set", "validation=v.hdf5", "--set", "heldout=none"])
    cfg = cli._config_from_args(a)
    assert (cfg.total_steps, cfg.lr, cfg.seeds, cfg.validation, cfg.heldout) == (1_000_000, 2e-4, (1, 2), "v.hdf5",
                                                                                 None)
    for bad, needle in (("reward_norm=maybe", "true or false"), ("num_envs=2.5", "an integer"),
                        ("lr=fast", "a number"), ("nope=1", "unknown config field")):
        with pytest.raises(ConfigError, match=needle):
            cli._config_from_args(cli.build_parser().parse_args(["train", "--task", "fetchq", "--run", "x", "--set", bad]))


@pytest.mark.parametrize("extra,want", [([], True), (["--nondeterministic"], False)])
def test_the_cli_makes_gpu_execution_deterministic_by_default(extra, want, tmp_path, monkeypatch):
    """Every command sets XLA_FLAGS (appending to what is there) before JAX starts; --nondeterministic
    removes the flag; run_info.json records the setting."""
    from cogail_jax.apps import runs, train_loop

    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/nowhere --xla_gpu_deterministic_ops=true")
    assert cli.main(["report", "--run", str(tmp_path / "none"), *extra]) == 2  # parses, sets, then fails
    flags = __import__("os").environ["XLA_FLAGS"].split()
    assert flags[0] == "--xla_dump_to=/tmp/nowhere"
    assert ("--xla_gpu_deterministic_ops=true" in flags) is want and cli.deterministic_ops() is want
    assert runs.run_metadata()["xla_gpu_deterministic_ops"] is want
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/nowhere")
    assert cli.main(["report", "--run", str(tmp_path / "none"), *extra]) == 2
    assert __import__("os").environ["XLA_FLAGS"] == "--xla_dump_to=/tmp/nowhere" + (
        " --xla_gpu_deterministic_ops=true" if want else "")
    monkeypatch.delenv("XLA_FLAGS")
    assert cli.main(["report", "--run", str(tmp_path / "none"), *extra]) == 2
    assert ("XLA_FLAGS" in __import__("os").environ) is want


def test_the_installed_command_sets_the_flag_before_jax_starts():
    code = ("import os, sys; from cogail_jax.apps import cli; cli.main(sys.argv[1:]); "
            "import jax; print('FLAGS', os.environ.get('XLA_FLAGS'), jax.devices()[0].platform)")
    r = subprocess.run([sys.executable, "-c", code, "report", "--run", "/nonexistent"], capture_output=True,
                       text=True, timeout=120, env={**__import__("os").environ, "XLA_FLAGS": ""})
    assert "FLAGS --xla_gpu_deterministic_ops=true cpu" in r.stdout, r.stderr


def _tiny_train_eval(run, train, held, validation) -> int:
    return cli.main(["train", "--task", "fetchq", "--run", str(run), "--demos", str(train), "--heldout", str(held),
                     "--validation", str(validation), "--num-envs", "4", "--unroll-length", "16", "--total-steps",
                     "256", "--checkpoint-every", "2", "--bc-steps", "0", "--seeds", "3", "--no-robustness", "--eval",
                     "--no-progress", "--set", "updates_per_call=2", "--set", "ppo_epochs=2", "--set",
                     "num_minibatches=2", "--set", "inner_updates=2", "--set", "inner_batch=32", "--set",
                     "eval_codes=4", "--no-coplay"])


def test_train_with_eval_prepares_the_evaluation_while_training(demo_files, fetchq, tmp_path, capsys, monkeypatch):
    """`cogail train --eval`: the evaluation's sets and programs are made ready in the background during training
    (speed.json's eval_parts.prepared), the evaluation reports every checkpoint, and then the policies of the
    checkpoints it reports no figure of are pruned (``--keep-policies reported``, the default)."""
    from cogail_jax.apps import eval_runner
    from cogail_jax.data import io as data
    from cogail_jax.data import generate as demos

    pruned = []
    real = eval_runner.prune_policies
    monkeypatch.setattr(eval_runner, "prune_policies", lambda r: pruned.append(r) or real(r))
    train, held, _ = demo_files
    val = data.save_demos(tmp_path / "val.hdf5", fetchq, demos.generate(fetchq, 4, seed=2), seed=2)
    run = tmp_path / "run"
    assert _tiny_train_eval(run, train, held, val) == 0
    assert [str(r) for r in pruned] == [str(run)]
    rec = json.loads((run / "speed.json").read_text())
    assert rec["eval_parts"]["prepared"] > 0 and rec["phases"]["eval"] > 0
    assert json.loads((run / "results.json").read_text())["checkpoints"] == [2, 4]
    assert "selected on validation" in capsys.readouterr().out


@pytest.mark.parametrize("case,needle", [
    ("no test split", "is missing: make the run's datasets first with `cogail data`"),
    ("test file without init", "demo demo_0 has no 'init' dataset, which replay evaluation needs"),
    ("validation file not HDF5", "could not be read as an HDF5 file"),
    ("no varied humans", "is missing: make the run's datasets first with `cogail data`"),
])
def test_train_eval_checks_the_evaluation_files_before_training(case, needle, demo_files, tmp_path, capsys,
                                                                monkeypatch):
    """`cogail train --eval` checks its evaluation's files before it trains: a missing split or set of varied humans,
    a test file without the start states replay needs or a file that is no HDF5 ends the command in one sentence
    before any training, and leaves no run folder."""
    import shutil

    from cogail_jax.apps import train_loop

    def trains(*args, **kw):
        raise AssertionError("training started")

    monkeypatch.setattr(train_loop, "_start_state", trains)
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "empty"))
    train, held, val = demo_files
    run = tmp_path / "run"
    files = ["--heldout", str(held), "--validation", str(val)]
    if case == "no test split":
        files = ["--validation", str(val)]
    elif case == "test file without init":
        bad = shutil.copy(held, tmp_path / "noinit.hdf5")
        with h5py.File(bad, "a") as f:
            del f["data/demo_0/init"]
        files = ["--heldout", str(bad), "--validation", str(val)]
    elif case == "validation file not HDF5":
        (tmp_path / "bad.hdf5").write_text("not hdf5")
        files = ["--heldout", str(held), "--validation", str(tmp_path / "bad.hdf5")]
    code, err = in_process(["train", "--task", "fetchq", "--run", str(run), "--demos", str(train), *files,
                            "--set", "train_varied=0", "--eval", "--no-progress", "--no-coplay",
                            *([] if case == "no varied humans" else ["--no-robustness"])], capsys)
    assert code == 2 and needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not run.exists()
