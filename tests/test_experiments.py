"""The experiment scripts' options: a bad one ends in one sentence naming it and the fix, before anything runs."""
import importlib.util
import sys
from pathlib import Path

import pytest

EXPERIMENTS = Path(__file__).parents[1] / "experiments"

# A stand-in for JaxMARL's baselines/IPPO/ippo_ff_overcooked.py and its config (the script reads nothing more
# before it runs): what bench_jaxmarl_ippo.py checks --layout and --total-steps against.
STUB = "overcooked_layouts = {'cramped_room': None}\n\ndef make_train(config):\n    raise AssertionError('ran')\n"
STUB_CONFIG = '"NUM_ENVS": 16\n"NUM_STEPS": 128\n"ENV_KWARGS":\n  "layout": "coord_ring"\n'


@pytest.mark.parametrize("script,args,needle", [
    ("multi_gpu.py", ["--envs", "0"], "argument --envs: expected a positive integer, got '0'"),
    ("multi_gpu.py", ["--task", "nope"], "--task: unknown task 'nope'"),
    ("multi_gpu.py", ["--envs", "3", "--unroll", "3"], "--envs 3 --unroll 3 --updates-per-call 4: num-envs x"),
    ("multi_gpu.py", ["--out", "{dir}"], "argument --out: {dir} is a folder: pass a file name"),
    ("pose_slices.py", ["--task", "handover", "--batch", "-3"], "argument --batch: expected a positive integer"),
    ("pose_slices.py", ["--task", "overcooked"], "--task overcooked: the task has no scripted team"),
    ("pose_slices.py", ["--task", "handover", "--slices", "x,place"],
     "--slices: 'place' is not one of handover's held-out slices"),
    ("pose_slices.py", ["--task", "fetchq", "--out", "{file}/x.json"],
     "argument --out: {file}/x.json lies under {file}, a file"),
    ("proxy_study.py", ["--episodes", "0"], "argument --episodes: expected a positive integer"),
    ("proxy_study.py", ["--tasks", "seqmanip,overcooked"], "--tasks: overcooked has no scripted robot"),
    ("proxy_study.py", ["--keys", "0,a"], "--keys 0,a: give comma-separated integers"),
    ("proxy_study.py", ["--out", "{file}"], "argument --out: {file} is a file: pass a folder"),
    ("collect_latency.py", ["--every", "0"], "argument --every: expected a positive integer"),
    ("collect_latency.py", ["--task", "nope"], "--task: unknown task 'nope'"),
    ("collect_latency.py", ["--url", "http://127.0.0.1:1", "--hz", "5"], "--hz: the table at --url"),
    ("collect_latency.py", ["--out", "{dir}"], "argument --out: {dir} is a folder: pass a file name"),
    ("bench_jaxmarl_ippo.py", ["--script", "{missing}.py"], "--script {missing}.py is not a Python file"),
    ("bench_jaxmarl_ippo.py", ["--script", "{stub}", "--seeds", "0"], "argument --seeds: expected a positive integer"),
    ("bench_jaxmarl_ippo.py", ["--script", "{stub}", "--total-steps", "100"],
     "--total-steps 100: give at least one update's steps, 2048"),
    ("bench_jaxmarl_ippo.py", ["--script", "{stub}", "--layout", "nope"], "--layout nope: no such kitchen"),
])
def test_bad_options_end_in_one_sentence_before_anything_runs(script, args, needle, tmp_path, monkeypatch, capsys):
    """Each script's ``main`` in this process (a script's start-up would cost a Python and JAX each time), as
    ``python experiments/SCRIPT ARGS`` runs it: argparse's exit 2 with the one line last."""
    (tmp_path / "DIR").mkdir()
    (tmp_path / "FILE").write_text("")
    (tmp_path / "ippo.py").write_text(STUB)
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "ippo_ff_overcooked.yaml").write_text(STUB_CONFIG)
    paths = {"dir": tmp_path / "DIR", "file": tmp_path / "FILE", "missing": tmp_path / "missing",
             "stub": tmp_path / "ippo.py"}
    args, needle = [x.format(**paths) for x in args], needle.format(**paths)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path / "data"))
    monkeypatch.setattr(sys, "argv", [str(EXPERIMENTS / script), *args])  # argparse names the script from it
    before = sorted(tmp_path.rglob("*"))
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        _script(script).main(args)
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert e.value.code == 2 and last.startswith(f"{script}: error: ") and needle in last, err
    assert sorted(tmp_path.rglob("*")) == before  # checked first: no data made, nothing compiled or started


_SCRIPTS = {}


def _script(name: str):
    """The experiment script ``name``, imported once per process."""
    if name not in _SCRIPTS:
        spec = importlib.util.spec_from_file_location(f"experiments_{name[:-3]}", EXPERIMENTS / name)
        _SCRIPTS[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(_SCRIPTS[name])
    return _SCRIPTS[name]
