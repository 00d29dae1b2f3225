"""Data is an explicit step: `cogail data` makes a run's sets, nothing else does; a run records its data in
RUN/data.json, and evaluating it against changed data stops with one sentence."""
from __future__ import annotations

import json

import pytest
from cogail_envs import get_task

from cogail_jax.apps import cli
from cogail_jax.data import io as data
from cogail_jax.data import generate as demos

# the fields of conftest.TINY with seeds 3, 5 (the task's other settings set back to the defaults that TINY keeps): the
# same programs as the other tiny fetchq runs of the suite, found in its compilation cache
TINY = ["--task", "fetchq", "--seeds", "3,5", "--set", "train_varied=0", "--set", "num_envs=4", "--set",
        "unroll_length=16", "--set", "updates_per_call=2", "--set", "checkpoint_every=2", "--set", "total_steps=384",
        "--set", "ppo_epochs=2", "--set", "num_minibatches=2", "--set", "inner_updates=2", "--set", "inner_batch=32",
        "--set", "bc_steps=0", "--set", "eval_codes=4", "--set", "scan_unroll=1", "--set", "aux_lr_decay=false"]


@pytest.fixture()
def small_splits(tmp_path, monkeypatch):
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "data"))
    for split, n in (("train", 12), ("validation", 4), ("test", 4)):
        monkeypatch.setitem(get_task("fetchq").splits, split, n)
    return tmp_path


def test_data_is_made_by_its_own_step_and_checked_against_the_run(small_splits, fetchq, capsys):
    tmp = small_splits
    run = tmp / "run"
    # nothing makes data on the side: training without `cogail data` stops in one sentence naming it
    assert cli.main(["train", *TINY, "--run", str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cogail data" in err and err.strip().count("\n") == 0 and not (tmp / "data").exists()
    assert cli.main(["data", *TINY, "--no-robustness"]) == 0
    made = sorted(p.name for p in (tmp / "data").glob("*.hdf5"))
    assert made == ["fetchq_uniform_test.hdf5", "fetchq_uniform_train.hdf5", "fetchq_uniform_validation.hdf5"]
    mtimes = {p: p.stat().st_mtime_ns for p in (tmp / "data").glob("*.hdf5")}
    assert cli.main(["data", *TINY, "--no-robustness"]) == 0  # current sets are kept as they are
    assert {p: p.stat().st_mtime_ns for p in mtimes} == mtimes
    assert cli.main(["train", *TINY, "--run", str(run), "--no-progress", "--eval", "--no-robustness",
                     "--keep-policies", "all"]) == 0  # evaluated again below
    man = json.loads((run / "data.json").read_text())
    assert set(man["sets"]) == {"train", "validation", "test"} and man["expert"]
    assert man["sets"]["test"]["env_version"] == fetchq.version
    capsys.readouterr()
    # the test split made again with other episodes (as after a change of physics): evaluation stops, never regenerates
    test = tmp / "data" / "fetchq_uniform_test.hdf5"
    data.save_demos(test, fetchq, demos.generate(fetchq, 4, seed=9), seed=9, generated=4)
    before = test.read_bytes()
    assert cli.main(["eval", "--run", str(run), "--no-progress", "--no-robustness"]) == 2
    err = capsys.readouterr().err
    assert str(test) in err and "has changed" in err and err.strip().count("\n") == 0
    assert test.read_bytes() == before
    # a missing split of a run: one sentence naming `cogail data`
    test.unlink()
    assert cli.main(["eval", "--run", str(run), "--no-progress", "--no-robustness"]) == 2
    assert "cogail data" in capsys.readouterr().err


def test_data_compiles_the_first_training_programs_before_the_data_exist(small_splits, monkeypatch, capsys):
    """`cogail data` compiles the programs `cogail train` with the same options starts with (the initial state and the
    training chunk; BC where the config has it) while it makes the datasets, for the shapes the config fixes: the
    training command then finds every one of them and traces none of its own."""
    from cogail_jax.runtime import programs

    folder = small_splits / "programs"  # no program of the suite's: every one here is this test's
    monkeypatch.setattr(programs, "program_dir", lambda: folder)
    assert cli.main(["data", *TINY, "--no-robustness", "--no-programs"]) == 0
    assert not folder.exists() and "compiled ahead" not in capsys.readouterr().out
    for p in (small_splits / "data").glob("*.hdf5"):  # made again below, with the programs compiled meanwhile
        p.unlink()
    assert cli.main(["data", *TINY, "--no-robustness"]) == 0
    assert "training programs compiled ahead in" in capsys.readouterr().out
    ahead = {p.name for p in folder.glob("*.jaxprog")}
    assert sorted(n.split("-")[0] for n in ahead) == ["chunk", "init"]
    assert cli.main(["train", *TINY, "--run", str(small_splits / "run"), "--no-progress"]) == 0
    assert {p.name for p in folder.glob("*.jaxprog")} == ahead


def test_data_reads_a_training_file_of_people_before_compiling_for_its_shapes(tmp_path, monkeypatch, capsys):
    """On a task learned from recordings the training arrays' shapes are the training file's: `cogail data` makes that
    split before it starts compiling the training programs (which read it), not beside it, so that a first run's
    programs are compiled ahead instead of failing for a file not yet written."""
    import threading

    from cogail_jax.algo.config import resolve
    from cogail_jax.data import sets
    from cogail_jax.runtime import programs

    pytest.importorskip("pandas")
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "data"))
    monkeypatch.setattr(programs, "program_dir", lambda: tmp_path / "programs")
    seen = []

    def fake_ahead(cfg):  # what the compiling thread would read first
        seen.append(sets.split_path(cfg, sets.TRAIN).is_file())
        t = threading.Thread(target=lambda: None)
        t.seconds, t.compiling, t.error = 0.0, 0.0, None
        t.start()
        return t

    monkeypatch.setattr(cli, "_compile_ahead", fake_ahead)
    assert cli.main(["data", "--task", "overcooked_forced_coordination", "--no-robustness"]) == 0
    assert seen == [True] and "training programs compiled ahead in" in capsys.readouterr().out
    cfg = resolve("overcooked_forced_coordination", "paper", {})
    assert all(sets.split_path(cfg, s).is_file() for s in (sets.VALIDATION, sets.TEST))
