"""The ``cogail`` command line: demos, train, eval, video, play, ..."""
from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
# JAX takes GPU memory as programs need it instead of 75 % of it up front: the first operation of a run starts
# 1.7 s sooner on an H100 and training runs at the same speed (BENCHMARKS.md). Set it to true to preallocate.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

from ..runtime.xla import DETERMINISTIC_FLAG, deterministic_ops, enable_compile_cache, set_deterministic  # noqa: F401
from .options import positive, seed, seeds


EXTRA_CURVES_HELP = ("replay the extra sets and varied humans at every checkpoint, not only at the reported ones: "
                     "each set's replay success per checkpoint in results.json (extra_sets.<name>.curve) and "
                     "RUN/robustness_curves.png; the evaluation takes several times longer, and on a GPU the figures "
                     "move at the rounding level (another batch)")


def _task_help() -> str:
    from cogail_envs import builtin_task_names

    return f"a task: {', '.join(builtin_task_names())}, or your own as my_pkg.my_module:TASK (docs/tasks.md)"


def _budget_help() -> str:
    from cogail_envs import builtin_task_names, get_task

    named = "; ".join(f"{n}: {', '.join(get_task(n).budgets)}" for n in builtin_task_names() if get_task(n).budgets)
    return f"the task's settings under a named budget: paper (default), or one the task names ({named})"


def _mix_help() -> str:
    from cogail_envs import builtin_task_names, get_task

    named = "; ".join(f"{n}: {', '.join(get_task(n).mixtures)}" for n in builtin_task_names() if get_task(n).mixtures)
    return f"strategy mixture of the default datasets: uniform (default) or one the task names ({named})"


def _add_config_args(t) -> None:
    """The options that make a run's config (``cogail train`` and ``cogail data``)."""
    from ..algo.config import METHODS

    t.add_argument("--task", default=None, help=_task_help() + "; its own settings are the defaults")
    t.add_argument("--budget", default="paper", help=_budget_help())
    t.add_argument("--method", default=None, choices=METHODS, help="method preset (default cogail)")
    t.add_argument("--seeds", type=seeds, default=None, help="comma-separated seeds (default 300,400,500)")
    t.add_argument("--config", default=None, help="JSON file of config fields, over the task's settings")
    t.add_argument("--total-steps", type=positive, default=None, help="env steps per seed")
    t.add_argument("--num-envs", type=positive, default=None, help="parallel environments per seed")
    t.add_argument("--env-shards", type=positive, default=None, metavar="N",
                   help="split each seed's envs into N shards that average their updates' gradients: one per device "
                        "with --devices (N devices train one policy on N x the envs of one), side by side on one")
    t.add_argument("--unroll-length", type=positive, default=None, help="rollout steps per env per update")
    t.add_argument("--checkpoint-every", type=positive, default=None, help="updates between checkpoints")
    t.add_argument("--bc-steps", type=int, default=None, help="behaviour-cloning pre-training steps (0 = off)")
    t.add_argument("--demos", default=None, help="training demonstrations (HDF5); default: the task's training set")
    t.add_argument("--heldout", default=None, help="test demonstrations for replay evaluation (default: the task's "
                                                   "test split)")
    t.add_argument("--validation", default=None,
                   help="validation demonstrations for checkpoint selection (default: the task's validation split)")
    t.add_argument("--mix", default=None, help=_mix_help())
    t.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override any config field, e.g. --set lambda_a=2.0 (repeatable)")


def _add_coplay_args(p, prefix: str) -> None:
    p.add_argument("--coplay", action=argparse.BooleanOptionalAction, default=True,
                   help=prefix + "also closed-loop co-play (default on): the robot at the reported checkpoints, and "
                        "the task's scripted robot as reference, with a reacting human (the task's scripted human "
                        "and its variations, seeing only the state; a human proxy behaviour-cloned on the test split); "
                        "results.json's coplay, RUN/coplay.png; on a task learned from people (Overcooked) the field's "
                        "protocol instead: H_proxy, a BC model of the test pairs, with the robot in both seats, "
                        "selection with the validation pairs' (docs/evaluation.md); results.json's field")
    p.add_argument("--coplay-episodes", type=positive, default=None, metavar="N",
                   help="co-play episodes per partner and robot (default 64 on an accelerator, 4 on a CPU)")


def _add_distributed_args(p) -> None:
    g = p.add_argument_group("several processes (one per host or per GPU; README, \"Several GPUs and hosts\")")
    g.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="process 0's address, where every process of the run meets")
    g.add_argument("--num-processes", type=positive, default=None, metavar="N", help="how many processes the run has")
    g.add_argument("--process-id", type=int, default=None, metavar="I", help="this process's index, 0..N-1 "
                   "(process 0 writes the run folder)")
    g.add_argument("--cluster", action="store_true",
                   help="take the three from the cluster scheduler's environment (SLURM, Open MPI, Kubernetes)")


def jax_process_index() -> int:
    import jax

    return jax.process_index()


def _keep_full(text: str) -> int | None:
    if text == "all":
        return None
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected a number of training states (1 or more) or 'all', got {text!r}")
    return int(text)


def build_parser() -> argparse.ArgumentParser:
    from ..algo.config import METHODS

    p = argparse.ArgumentParser(prog="cogail", description="Co-GAIL in JAX: learn human-robot collaboration "
                                "policies from human-human demonstrations.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    d = sub.add_parser("demos", help="generate scripted human-human demonstrations into an HDF5 file",
                       description="Generate scripted human-human demonstrations (one jitted, vmapped call) "
                                   "and write them in the project's HDF5 schema (docs/tasks.md, "
                                   "\"Demonstration files\").")
    d.add_argument("--task", required=True, help=_task_help())
    d.add_argument("--num", type=positive, default=60, help="number of demonstrations (default 60)")
    d.add_argument("--mix", default="uniform", help=_mix_help() + ", or comma-separated weights")
    d.add_argument("--seed", type=seed, default=0)
    d.add_argument("--out", required=True, help="output .hdf5 path, a new file (one that exists is kept)")

    da = sub.add_parser("data", help="make every dataset a run needs (train, validation, test, varied humans)",
                        description="Make the datasets of a run's config with the task's scripted team: the training "
                                    "set (with its varied humans where the config adds them), the validation and "
                                    "test splits and the varied humans the evaluation replays, in the data folder "
                                    "($COGAIL_DATA, else ./data). Sets already there and current are kept. Training, "
                                    "evaluation, play and video never make data: run this first (`make train` "
                                    "does), with the options you give `cogail train`.")
    _add_config_args(da)
    da.add_argument("--run", default=None, help="make the datasets of this run's config instead (its config.json)")
    da.add_argument("--robustness", action=argparse.BooleanOptionalAction, default=True,
                    help="also the varied humans of the robustness evaluation and, on a task learned from people, "
                         "the evaluation's BC models of them (default on)")
    da.add_argument("--programs", action=argparse.BooleanOptionalAction, default=True,
                    help="meanwhile compile the programs `cogail train` with the same options starts with (initial "
                         "state, BC, the training chunk) into the compilation cache, so that a first run does not "
                         "wait for them after the data (default on; off without the compilation cache)")

    t = sub.add_parser("train", help="train a method on a task (resumable)",
                       description="Train with Co-GAIL (or a baseline preset); every seed runs in one vmapped "
                                   "program. Checkpoints, config and TensorBoard logs go to --run, and "
                                   "RUN/speed.json gets the seconds of each phase (start, demos, bc, compile, train; "
                                   "eval and write with --eval or `cogail eval`), the env steps/s after "
                                   "compilation and the device; `cogail bench --phases RUN` tabulates them.")
    _add_config_args(t)
    t.add_argument("--run", required=True, help="run directory")
    t.add_argument("--resume", action="store_true",
                   help="continue the run in --run from its last valid checkpoint, with its own config (an option "
                        "that changes a field of it is refused: drop it, or pass another --run)")
    t.add_argument("--eval", action="store_true", help="evaluate every checkpoint when training ends")
    t.add_argument("--robustness", action=argparse.BooleanOptionalAction, default=True,
                   help="with --eval: also replay against varied humans (pace, pauses, path, noise, a change of "
                        "mind; made by `cogail data`), at the reported checkpoints; results in results.json's extra_sets "
                        "and RUN/robustness.png; on tasks with a patient human (the env's replay_hold) also the test split and "
                        "the varied humans replayed with a patient human (patient-*: handing an object over, it waits for the "
                        "robot to take the object)")
    t.add_argument("--extra-curves", action="store_true", help=EXTRA_CURVES_HELP)
    _add_coplay_args(t, "with --eval: ")
    t.add_argument("--devices", default=None,
                   help="spread the run over N devices or 'all' (one program): the env shards (--env-shards) and the "
                        "seeds (as many devices as split them evenly); with several processes every process's devices")
    _add_distributed_args(t)
    t.add_argument("--keep-full", type=_keep_full, default=1, metavar="N",
                   help="how many of the newest whole training states RUN/checkpoints/ keeps (default 1: the newest, "
                        "which --resume continues from), or 'all'; every checkpoint's delivered policy (what eval, "
                        "play and video read) goes to RUN/policies/ whatever N is (see --keep-policies)")
    t.add_argument("--keep-policies", choices=("reported", "all"), default="reported",
                   help="with --eval: after the evaluation, keep in RUN/policies/ the delivered policies of the "
                        "checkpoints results.json reports figures of (selected on validation, paper protocol, last, "
                        "each seed's best) and the newest (default: reported), or every checkpoint's (all: "
                        "`cogail eval` can then evaluate them all again); results.json keeps every checkpoint's "
                        "evaluation either way")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")

    e = sub.add_parser("eval", help="evaluate every checkpoint of a run (interpolation, replay, latent map)",
                       description="Interpolation and replay evaluation of every checkpoint and seed; writes "
                                   "results.json, results.md and figures into the run directory. Reported as the "
                                   "paper does (per column, the checkpoint with the best mean over seeds on test), "
                                   "beside the checkpoint selected on the validation set (reported on test) and "
                                   "the last checkpoint. The seconds spent go into RUN/speed.json (eval, write).")
    e.add_argument("--run", required=True, help="run directory")
    e.add_argument("--every", type=positive, default=1, help="evaluate every k-th checkpoint (default 1: all)")
    e.add_argument("--replay-file", action="append", default=[], metavar="FILE.hdf5",
                   help="an extra test set (e.g. the trials `cogail play` recorded, an imported file): replayed at "
                        "the checkpoint selected on validation and at the paper-protocol replay checkpoint; results "
                        "in results.json's extra_sets and in RUN/replay-<file name>/ (repeatable). An extra set's "
                        "replay lasts until the time limit or 20 %% of it past the end of each recording, whichever "
                        "is later (the test and validation splits: the limit)")
    e.add_argument("--robustness", action=argparse.BooleanOptionalAction, default=True,
                   help="also replay against varied humans (pace, pauses, path, noise, a change of mind; made by "
                        "`cogail data`), at the reported checkpoints: results.json's extra_sets robust-<variation>, "
                        "RUN/robustness.png; on tasks with a patient human (the env's replay_hold) also patient-test and "
                        "patient-robust-<variation>: the same humans waiting, as they hand an object over, for the robot")
    e.add_argument("--extra-curves", action="store_true", help=EXTRA_CURVES_HELP)
    _add_coplay_args(e, "")
    e.add_argument("--coplay-only", action="store_true",
                   help="run co-play alone at the checkpoints results.json reports (e.g. after a change of the "
                        "human proxy), keeping every other figure")
    e.add_argument("--extra-set", action="append", default=[], metavar="NAME=FILE.hdf5",
                   help="like --replay-file, under the name NAME (repeatable); a NAME starting with patient- is "
                        "replayed with a patient human where the task has one (the env's replay_hold)")
    e.add_argument("--reevaluate", action="store_true",
                   help="with extra sets: evaluate every checkpoint again even if RUN/results.json is up to date "
                        "(by default only the extra sets are replayed then)")
    e.add_argument("--ckpt-batch", type=positive, default=None, metavar="N",
                   help="evaluate N checkpoints in one device program (vmapped; more memory; on a GPU the batch "
                        "can move figures at the rounding level; default: every checkpoint on a GPU, halved while "
                        "the device runs out of memory; 1 on the CPU)")
    e.add_argument("--no-progress", action="store_true")

    pl = sub.add_parser("play", help="drive the human agent yourself in a local web page; the robot acts live",
                        description="Serve a local page (127.0.0.1) on which a person drives the human agent with "
                                    "the keyboard or a gamepad while the robot acts from pi_R with psi reading the "
                                    "live history. Several --run: trials cycle through them in a random, blind "
                                    "order (shown as policy A, B, ...). Every finished trial is appended to the "
                                    "trials file in the dataset schema (method, checkpoint, success recorded), "
                                    "ready for `cogail eval --run DIR --replay-file TRIALS`.")
    pl.add_argument("--task", default=None, help="task (default: the first run's)")
    pl.add_argument("--run", action="append", required=True, metavar="DIR",
                    help="training run whose robot plays (repeatable: several runs/methods, blind order)")
    pl.add_argument("--checkpoint", default="best",
                    help="best (best replay checkpoint of the best seed if evaluated, else latest), latest, or N")
    pl.add_argument("--port", type=int, default=8765, help="port on 127.0.0.1 (default 8765; 0: any free port)")
    pl.add_argument("--trials", default=None, metavar="FILE.hdf5",
                    help="where trials are appended (default: trials.hdf5 in the first --run)")
    pl.add_argument("--max-steps", type=positive, default=None,
                    help="end a trial after this many steps (default: the task's episode length)")
    pl.add_argument("--hz", type=float, default=None, help="steps per second the page asks for (default: the task's, "
                    "15 for most)")
    pl.add_argument("--seed", type=seed, default=0, help="seed of the blind order and the start states")

    co = sub.add_parser("collect", help="two people drive both agents of a task in a web page; every episode is recorded",
                        description="Serve a page on which two people drive the human agent and the robot agent (two "
                                    "browsers, or one page with two key sets or two gamepads). The environment steps "
                                    "at a fixed rate with both people's latest commands; every episode (success or "
                                    "not) is appended to a demonstration file in the dataset schema, ready for "
                                    "`cogail train --demos FILE` and `cogail eval --replay-file FILE`. See "
                                    "docs/collect.md.")
    co.add_argument("--task", required=True, help="task (a built-in name or my_pkg.my_module:TASK)")
    co.add_argument("--out", default=None, metavar="FILE.hdf5",
                    help="where episodes are appended (default: <data folder>/<task>_people.hdf5)")
    co.add_argument("--port", type=int, default=8766, help="port (default 8766; 0: any free port)")
    co.add_argument("--lan", action="store_true",
                    help="listen on the local network (default: this machine only); each seat is then taken with "
                         "the join code printed at start")
    co.add_argument("--hz", type=float, default=None, help="env steps per second (default: the task's, 15 for most)")
    co.add_argument("--max-steps", type=positive, default=None,
                    help="end an episode after this many steps (default: the task's episode length)")
    co.add_argument("--gap", type=float, default=2.0, help="seconds between an episode's end and the next (default 2)")
    co.add_argument("--hold", type=float, default=0.5,
                    help="seconds a person's last command is held without news before their agent holds still "
                         "(default 0.5)")
    co.add_argument("--leave", type=float, default=5.0,
                    help="seconds without news after which a seat is free again and the episode ends (default 5)")
    co.add_argument("--seed", type=seed, default=None, help="seed of the start states (default: a random one, recorded)")

    b = sub.add_parser("bench", help="throughput table: env-only, Co-GAIL train_step (1 and 3 seeds), brax PPO",
                       description="Env steps/s of the task alone (random actions), of the full Co-GAIL update "
                                   "with 1 and 3 vmapped seeds, and of brax's PPO on the same env and batch; "
                                   "prints a table and writes JSON. With --phases RUN [RUN ...]: no benchmark, "
                                   "the seconds of each phase of those runs (their speed.json) as a markdown table.")
    from .bench import add_arguments as _bench_args

    _bench_args(b)
    _add_distributed_args(b)

    v = sub.add_parser("video", help="render scripted demonstrations or a run's rollouts (interpolation and replay)",
                       description="Write a GIF/MP4 of episodes: scripted demos of --task, or, with --run, a grid "
                                   "whose top row is interpolation rollouts (codes spread over the code space, best "
                                   "interpolation checkpoint) and bottom row replays (the robot against held-out "
                                   "human trajectories, best replay checkpoint). MJX tasks use MuJoCo's offscreen "
                                   "renderer (no display needed).")
    v.add_argument("--task", default=None, help=_task_help() + " (with --run: the run's)")
    v.add_argument("--run", default=None, help="run directory (default: scripted demonstrations)")
    v.add_argument("--num", type=positive, default=4, help="episodes to render")
    v.add_argument("--out", required=True, help="output .gif or .mp4")
    v.add_argument("--steps", type=positive, default=None, help="render at most this many steps per episode")

    im = sub.add_parser("import", help="convert your own demonstrations (robomimic-style HDF5 or .npz) for a task",
                        formatter_class=argparse.RawDescriptionHelpFormatter,
                        description=(
                            "Convert demonstrations into the project's HDF5 schema and validate them against the task.\n\n"
                            "inputs: robomimic-style HDF5 with any key names, or a NumPy .npz (obs, actions or\n"
                            "actions_human + actions_robot, strategy; object arrays of per-demo arrays, or padded\n"
                            "(N, T, dim) arrays + length). Say where each FIELD is with --key FIELD=SOURCE or --map:\n"
                            "  obs, actions (one array, split into human | robot), actions_human, actions_robot,\n"
                            "  init, strategy (@NAME: a demo attribute; an integer: every demo), length (npz),\n"
                            "  group, demo_prefix (HDF5: where the demos are; default data/<all groups>).\n"
                            "SOURCEs joined with + are concatenated (e.g. obs=obs/pos+obs/flags).\n\n"
                            "examples (the files are in the repository's examples/ folder):\n"
                            "  cogail import --task TASK --in my_demos.npz --out data/mine.hdf5\n"
                            "  cogail import --task TASK --in my_robomimic.hdf5 --out data/mine.hdf5 --map my_map.json"))
    im.add_argument("--task", required=True, help=_task_help())
    im.add_argument("--in", dest="src", required=True, metavar="FILE", help="input .hdf5/.h5 or .npz file")
    im.add_argument("--out", required=True, metavar="FILE.hdf5",
                    help="output file in the project's schema, a new file (one that exists is kept)")
    im.add_argument("--map", default=None, metavar="MAPFILE", help='JSON key mapping, e.g. {"obs": "states"}')
    im.add_argument("--key", action="append", default=[], metavar="FIELD=SOURCE",
                    help="where a field is in the input, e.g. --key obs=observations (repeatable; wins over --map)")

    r = sub.add_parser("report", help="write one self-contained HTML page about a run",
                       description="Write an HTML report of a run directory: config, learning curves from "
                                   "TensorBoard logs, evaluation tables, figures and videos (all embedded).")
    r.add_argument("--run", required=True, help="run directory")
    r.add_argument("--out", default=None, metavar="FILE.html", help="output file (default RUN/report.html)")
    for sp in sub.choices.values():
        sp.add_argument("--nondeterministic", action="store_true",
                        help="allow nondeterministic GPU kernels (faster; by default XLA_FLAGS gets "
                             "--xla_gpu_deterministic_ops=true, recorded in run_info.json)")
        sp.add_argument("--no-compile-cache", action="store_true",
                        help="do not keep compiled programs between runs (by default they are kept in "
                             "$COGAIL_CACHE, else in a JAX_COMPILATION_CACHE_DIR of your own, else in "
                             "$XDG_CACHE_HOME/cogail/xla or ~/.cache/cogail/xla, with the traced programs in its "
                             "programs/ folder, and a second run loads them instead of tracing and compiling; "
                             "also COGAIL_NO_COMPILE_CACHE=1)")
    return p


def parse_field(name: str, value: str):
    """A config field's value from text (``--set FIELD=VALUE``): booleans true/false/1/0/yes/no/on/off, integers
    (also 1e6), floats, comma-separated seeds, none/null for optional files, else the text."""
    import dataclasses

    from ..algo.config import ConfigError, TrainConfig, unknown_fields

    fields = {f.name: f for f in dataclasses.fields(TrainConfig)}
    if name not in fields:
        raise unknown_fields([name], "--set: ")
    default = fields[name].default
    kind = type(default)
    v = value.strip()
    try:
        if kind is bool:
            low = v.lower()
            if low not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                raise ValueError
            return low in ("true", "1", "yes", "on")
        if kind is int:
            x = float(v)
            if x != int(x):
                raise ValueError
            return int(x)
        if kind is float:
            return float(v)
        if kind is tuple:
            return tuple(int(x) for x in v.split(",") if x.strip())
        if default is None and v.lower() in ("none", "null", ""):
            return None
        return v
    except ValueError:
        want = {bool: "true or false", int: "an integer", float: "a number",
                tuple: "comma-separated integers"}.get(kind, "text")
        raise ConfigError(f"--set {name}={value}: expected {want}")


def _config_from_args(a) -> "TrainConfig":  # noqa: F821
    """The run's config: the task's settings under ``--budget``, then ``--config``'s fields, then the flags."""
    return _config_and_given(a)[0]


def _config_and_given(a) -> tuple:
    """The run's config (``_config_from_args``) and the names of the fields the user gave: those of ``--config``'s
    file, of the flags given (``--task``, ``--method``, ``--seeds``, ``--total-steps``, ``--demos``, ...), of
    ``--set``, and those a named budget other than paper sets (``--budget quick``: the fields of the task's
    ``budgets["quick"]``). The task's own settings (``default_config()``, the paper budget) and the field defaults
    are not given: they may change between versions, and a run made under others is still continued by ``cogail
    train --run R --resume`` (or with the same --task/--budget/--method/--seeds, as ``make train`` gives them).
    ``cogail train --resume`` compares the given fields with the run's saved config (``runs.run_config``)."""
    from cogail_envs import UnknownTaskError, get_task

    from ..algo.config import REMOVED, ConfigError, TrainConfig, check_value, resolve, unknown_fields

    fields = {}
    if a.config:
        path = Path(a.config)
        if not path.exists():
            raise ConfigError(f"config file {path} does not exist: check the path (a JSON object of config fields, "
                              "e.g. a run's config.json)")
        try:
            given = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ConfigError(f"config file {path} is not valid JSON ({e.msg} at line {e.lineno}): fix it, or "
                              "start from a run's config.json")
        if not isinstance(given, dict):
            raise ConfigError(f"config file {path} holds a JSON {type(given).__name__}, not an object: write "
                              '{"FIELD": value, ...}')
        given.pop("_comment", None)
        known = TrainConfig.__dataclass_fields__
        if unknown := sorted(set(given) - set(known) - set(REMOVED)):
            raise unknown_fields(unknown, f"config file {path}: ")
        fields.update({k: check_value(k, v, f"config file {path}: ") if k in known else v for k, v in given.items()})
    for key in ("task", "method", "seeds", "total_steps", "num_envs", "env_shards", "unroll_length", "checkpoint_every",
                "bc_steps", "demos", "heldout", "validation", "mix"):
        val = getattr(a, key)
        if val is not None:
            fields[key] = val
    for item in a.set:
        if "=" not in item:
            raise ConfigError(f"--set needs FIELD=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        fields[k] = parse_field(k.strip(), v)
    given = set(fields) - set(REMOVED)
    task = fields.pop("task", None) or ""
    saved = Path(a.run) / "config.json" if getattr(a, "resume", False) and getattr(a, "run", None) else None
    if not task and saved is not None and saved.exists():  # `cogail train --run R --resume`: the run's own task
        saved_cfg = TrainConfig.load(saved)
        task = saved_cfg.task
        fields.setdefault("method", saved_cfg.method)
    cfg = resolve(task, a.budget, fields)
    if a.budget != "paper":  # (resolve has checked that the task has it)
        try:
            given |= set(get_task(cfg.task).budgets.get(a.budget, {})) & set(TrainConfig.__dataclass_fields__)
        except UnknownTaskError:
            pass
    return cfg, given


def _compile_ahead(cfg) -> threading.Thread:
    """A thread, started, that compiles ``cfg``'s first training programs (``runs.compile_ahead``); its
    ``seconds``, ``compiling`` (of them, its own compilations' seconds) and ``error`` (None, or what went wrong: it
    only costs the training command the time) once joined."""
    from .runs import compile_ahead

    def work():
        from ..runtime.timing import CompileLog

        t0, log = time.perf_counter(), CompileLog(this_thread=True)
        try:
            compile_ahead(cfg)
        except Exception as e:  # noqa: BLE001
            t.error = f"{type(e).__name__}: {e}"
        t.seconds = time.perf_counter() - t0
        t.compiling = sum(r["backend"] + r["trace"] for r in log.table().values())

    t = threading.Thread(target=work, name="compile-ahead", daemon=True)
    t.seconds, t.compiling, t.error = 0.0, 0.0, None
    t.start()
    return t


def main(argv=None) -> int:
    from ..runtime.timing import mark_process_start

    mark_process_start()  # speed.json's "start" phase counts from here
    args = build_parser().parse_args(argv)
    set_deterministic(not getattr(args, "nondeterministic", False))  # before JAX starts its backend
    enable_compile_cache(not getattr(args, "no_compile_cache", False))  # before anything compiles
    from cogail_envs import UnknownTaskError

    from ..runtime.checkpoint import CheckpointError
    from ..runtime.paths import OutputError
    from ..algo.config import ConfigError
    from ..data.io import DatasetError
    from .runs import RunError

    try:
        if hasattr(args, "coordinator"):  # before anything starts JAX's backend
            from ..runtime.distributed import join

            join(args.coordinator, args.num_processes, args.process_id, args.cluster)
        return _dispatch(args)
    except (ConfigError, DatasetError, RunError, CheckpointError, UnknownTaskError, OutputError) as e:
        print(f"cogail {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"cogail {args.command}: interrupted; a training run continues with --resume", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 -- only a device out of memory is answered here; the rest re-raises
        from ..runtime.devices import memory_error

        if (message := memory_error(e)) is None:
            raise
        print(f"cogail {args.command}: error: {message}", file=sys.stderr)
        return 2
    finally:
        mark_process_start(False)


def _dispatch(a) -> int:
    from ..algo.config import ConfigError
    from ..runtime.paths import output_dir, output_file

    if a.command == "demos":

        import cogail_envs

        from ..data import io as data
        from ..data import generate as demos

        env = cogail_envs.make_env(a.task)
        mix = a.mix
        if "," in mix:
            try:
                mix = tuple(float(x) for x in mix.split(","))
            except ValueError:
                raise ConfigError(f"--mix {a.mix}: weights are comma-separated numbers, one per strategy, e.g. "
                                  f"{','.join(['1'] * env.num_strategies)}") from None
        output_file(a.out, "--out", "demos.hdf5", keep=True)  # a dataset already there is the user's: kept
        try:
            t0 = time.time()
            eps = demos.generate(env, a.num, mix=mix, seed=a.seed)
            dt = time.time() - t0
        except ValueError as e:
            raise ConfigError(str(e))
        path = data.save_demos(a.out, env, eps, mixture=str(a.mix), seed=a.seed)
        import numpy as np

        counts = np.bincount(eps.strategy, minlength=env.num_strategies + 1)[1:]
        print(f"wrote {a.num} {env.name} demonstrations to {path} in {dt:.1f} s: success {eps.success.mean():.3f}, "
              f"mean length {eps.length.mean():.1f}, strategies {counts.tolist()}")
        return 0
    if a.command == "data":
        from ..algo.config import TrainConfig
        from ..data.sets import make_datasets

        from ..runtime.programs import program_dir
        from ..runtime.timing import CompileLog

        cfg = TrainConfig.load(Path(a.run) / "config.json") if a.run else _config_from_args(a)
        from ..data.io import data_dir

        output_dir(data_dir(), "the data folder", "set COGAIL_DATA to a folder you can write")
        t0, compiles = time.perf_counter(), CompileLog(this_thread=True)  # the datasets' own, not the programs'
        ahead = None
        if a.programs and program_dir() is not None:
            from ..data import sets

            if sets.train_episodes(cfg) is None:  # the programs' shapes are the training file's: made (or read) first
                sets.split_path(cfg, sets.TRAIN, make=True)
            ahead = _compile_ahead(cfg)
        for name, path in make_datasets(cfg, robustness=a.robustness).items():
            print(f"{name}: {path}")
        xla = sum(r["backend"] + r["trace"] for r in compiles.table().values())
        print(f"datasets ready in {time.perf_counter() - t0:.1f} s ({xla:.1f} s of it compiling)"
              + (" while the training programs compile beside them" if ahead is not None and ahead.is_alive() else ""),
              flush=True)
        if a.robustness:  # the evaluation's BC models of people (the field's protocol), while the programs compile
            from ..eval import field

            t1 = time.perf_counter()
            if (kept := field.prepare(cfg)) is not None:
                print(f"the field's BC models and H_proxy's quality ready in {time.perf_counter() - t1:.1f} s: {kept}",
                      flush=True)
        if ahead is not None:
            ahead.join()
            print(f"training programs compiled ahead in {ahead.seconds:.1f} s ({ahead.compiling:.1f} s of it "
                  "compiling)" if ahead.error is None else
                  f"warning: compiling the training programs ahead failed ({ahead.error}); `cogail train` compiles "
                  "them itself", flush=True)
        return 0
    if a.command == "train":
        from .eval_runner import EvalPrep, check_inputs, eval_run, prune_policies, was_pruned
        from .train_loop import train_run

        from ..runtime import distributed

        cfg, given = _config_and_given(a)
        evaluates = a.eval and distributed.primary()  # of several processes, process 0 evaluates
        # a finished run resumed (e.g. `make train` again) whose evaluation pruned its policies: its results stand
        evaluated = evaluates and a.resume and was_pruned(a.run)
        evaluates = evaluates and not evaluated
        kept = {}  # with --eval, each checkpoint's evaluation parameters kept in memory: none is read back
        prep = EvalPrep(a.run, a.robustness, a.extra_curves, coplay=a.coplay,
                        coplay_episodes=a.coplay_episodes) if evaluates else None  # made ready while training runs
        run = train_run(cfg, a.run, resume=a.resume, progress=not a.no_progress, devices=a.devices,
                        keep=kept if evaluates else None, on_compiled=prep.start if prep else None,
                        keep_full=a.keep_full, given=given,
                        # the evaluation's files too, before training (and before the run folder is written)
                        check=(lambda s: check_inputs(s, a.robustness)) if evaluates else None)
        if not distributed.primary():
            print(f"process {jax_process_index()}: trained; process 0 writes {run}", flush=True)
            distributed.barrier("done")  # until process 0 has written everything
            return 0
        print(f"trained: {run}")
        if evaluated:
            print(f"{run} was evaluated already and keeps the policies of the checkpoints it reports: its results "
                  f"stand ({Path(run) / 'results.json'})")
            print((Path(run) / "results.md").read_text())
        if evaluates:
            res = eval_run(run, progress=not a.no_progress, robustness=a.robustness, memory=kept,
                           extra_curves=a.extra_curves, prepared=prep, coplay=a.coplay,
                           coplay_episodes=a.coplay_episodes)
            print((Path(run) / "results.md").read_text())
            del res
            if a.keep_policies == "reported":
                gone = prune_policies(run)
                if gone:
                    print(f"kept the policies of the reported checkpoints in {Path(run) / 'policies'}; "
                          f"{len(gone)} others removed (--keep-policies all keeps every one)")
        distributed.barrier("done")
        return 0
    if a.command == "eval":
        from .eval_runner import eval_coplay, eval_extra_sets, eval_run, replay_results_dir, results_current

        sets = {}
        named = [(Path(f).stem, f, f"--replay-file {f}") for f in a.replay_file]
        for item in a.extra_set:
            if "=" not in item:
                raise ConfigError(f"--extra-set needs NAME=FILE, got {item!r}")
            name, f = item.split("=", 1)
            named.append((name, f, f"--extra-set {item}"))
        for name, f, given in named:  # each set's results go to a folder of its name
            if name in sets:
                first = next(g for n, _, g in named if n == name)
                raise ConfigError(f"{first} and {given} are both named {name!r}, and each set's results are written "
                                  f"under its name: name them apart with --extra-set NAME=FILE")
            sets[name] = f
        if a.coplay_only:
            eval_coplay(a.run, a.coplay_episodes)
        elif sets and not a.reevaluate and results_current(a.run, a.every):
            eval_extra_sets(a.run, sets)  # the checkpoints are chosen already: replay the extra sets only
        else:
            eval_run(a.run, progress=not a.no_progress, every=a.every, extra_sets=sets, ckpt_batch=a.ckpt_batch,
                     robustness=a.robustness, extra_curves=a.extra_curves, coplay=a.coplay,
                     coplay_episodes=a.coplay_episodes)
        print((Path(a.run) / "results.md").read_text())
        for name, f in sets.items():
            out = replay_results_dir(a.run, name)
            print((out / "results.md").read_text() + f"(replay against {f}; files in {out})")
        return 0
    if a.command == "play":
        from .play import serve

        return serve(a.run, task=a.task, port=a.port, trials=a.trials, checkpoint=a.checkpoint,
                     max_steps=a.max_steps, hz=a.hz, seed=a.seed)
    if a.command == "collect":
        from .collect import serve as collect

        return collect(a.task, out=a.out, port=a.port, lan=a.lan, hz=a.hz, max_steps=a.max_steps, gap=a.gap,
                       hold=a.hold, leave=a.leave, seed=a.seed)
    if a.command == "bench":
        from .bench import run_from_args

        run_from_args(a)
        return 0
    if a.command == "video":
        from .video import write_video

        if not a.task and not a.run:
            raise ConfigError("cogail video needs --run RUN (a run's rollouts) or --task TASK (scripted demonstrations)")
        path = write_video(a.task, a.out, run=a.run, num=a.num, steps=a.steps)
        print(f"wrote {path}")
        return 0
    if a.command == "import":
        from ..data.importer import import_demos, load_mapping, parse_keys

        mapping = {**(load_mapping(a.map) if a.map else {}), **parse_keys(a.key)}
        if not (Path(a.out).exists() and Path(a.out).resolve() == Path(a.src).resolve()):  # import_demos says so
            output_file(a.out, "--out", "mine.hdf5", keep=True)  # a dataset already there is the user's: kept
        print(import_demos(a.src, a.out, a.task, mapping).describe(a.task))
        return 0
    if a.command == "report":
        from .report import build_report

        if a.out is not None:
            output_file(a.out, "--out", "report.html")
        print(f"wrote {build_report(a.run, a.out)}")
        return 0
    return 1


if __name__ == "__main__":
    sys.exit(main())
