"""A task from outside the package (examples/table_carry): `cogail data`, `cogail train --eval` in a fresh process,
then evaluation, play and video of its run, with nothing under src/ or envs/ naming it."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
TASK = "examples.table_carry:TASK"
TINY = ["--task", TASK, "--seeds", "3", "--set", "num_envs=8", "--set", "unroll_length=16", "--set",
        "updates_per_call=2", "--set", "checkpoint_every=2", "--set", "total_steps=512", "--set", "bc_steps=50",
        "--set", "ppo_epochs=2", "--set", "num_minibatches=2", "--set", "inner_updates=2", "--set", "inner_batch=32",
        "--set", "eval_codes=4"]


def cogail(*args, env):
    return subprocess.run([sys.executable, "-m", "cogail_jax.apps.cli", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=900)


@pytest.fixture(scope="module")
def example_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("example")
    env = {**os.environ, "COGAIL_DATA": str(tmp / "data"), "JAX_PLATFORMS": "cpu"}
    r = cogail("data", *TINY, env=env)
    assert r.returncode == 0, r.stderr
    run = tmp / "run"
    r = cogail("train", *TINY, "--run", str(run), "--eval", "--no-progress", env=env)
    assert r.returncode == 0, r.stderr
    return run


def test_the_example_task_trains_and_evaluates_from_a_fresh_process(example_run):
    res = json.loads((example_run / "results.json").read_text())
    cfg = json.loads((example_run / "config.json").read_text())
    assert cfg["task"] == TASK and res["task"] == TASK
    assert res["checkpoints"] == [2, 4] and set(res["splits"]) == {"test", "validation"}
    assert res["splits"]["test"]["episodes"] == 20 and res["splits"]["validation"]["episodes"] == 20
    for column in ("replay", "interpolation"):
        assert 0.0 <= res["selected"][column]["mean"] <= 1.0
    assert set(res["strategy_distribution"]) == {"human-leads", "robot-leads"}
    assert set(json.loads((example_run / "data.json").read_text())["sets"]) == {"train", "validation", "test"}


def test_the_example_task_plays_and_renders_its_run(example_run, tmp_path, monkeypatch):
    import numpy as np

    from cogail_jax.apps import cli, play

    monkeypatch.chdir(ROOT)  # examples/ importable, as for the commands above
    srv = play.open_study([example_run], port=0, trials=tmp_path / "trials.hdf5", max_steps=5, hz=20,
                          log=lambda *a: None)
    try:
        game = srv.app.game
        assert game.env.name == "table_carry" and len(game.policies) == 1
        frame = play.render_frame(game.env, game.state)
        assert frame.ndim == 3 and frame.dtype == np.uint8
    finally:
        play.close(srv)
    out = tmp_path / "table.gif"
    assert cli.main(["video", "--run", str(example_run), "--num", "2", "--steps", "6", "--out", str(out)]) == 0
    import imageio.v2 as imageio

    frames = imageio.mimread(out)  # the run's rollouts, drawn: frames that show something and move
    assert len(frames) > 1 and frames[0].std() > 5 and not np.array_equal(frames[0], frames[-1])


def test_the_example_task_makes_and_imports_demonstrations(tmp_path, monkeypatch, capsys):
    from cogail_jax.apps import cli

    monkeypatch.chdir(ROOT)
    demos = tmp_path / "table.hdf5"
    assert cli.main(["demos", "--task", TASK, "--num", "6", "--out", str(demos)]) == 0
    assert "wrote 6 table_carry demonstrations" in capsys.readouterr().out
    assert cli.main(["import", "--task", TASK, "--in", str(demos), "--out", str(tmp_path / "mine.hdf5")]) == 0
    import numpy as np
    from cogail_envs import make_env
    from cogail_jax.data import io as data

    env = make_env(TASK)
    made, mine = data.load_demos(demos, env), data.load_demos(tmp_path / "mine.hdf5", env)  # the same episodes
    assert len(mine.length) == 6
    for field in ("obs", "actions_human", "actions_robot", "length", "strategy"):
        np.testing.assert_array_equal(getattr(mine, field), getattr(made, field))
    assert cli.main(["import", "--task", "fetchq", "--in", str(demos), "--out", str(tmp_path / "x.hdf5")]) == 2
    assert "not 'fetchq'" in capsys.readouterr().err
