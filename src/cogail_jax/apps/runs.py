"""A run: its set-up (environment, datasets, compiled programs), its directory and what is shared by the
training loop (:mod:`.train_loop`) and the evaluation loop (:mod:`.eval_runner`)."""
from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np

from ..runtime import checkpoint as ckpt
from ..data import io as data
from ..data import manifest, sets
from ..eval import rollouts
from ..algo import train
from ..algo.config import TrainConfig


class RunError(RuntimeError):
    """A problem with a run (directory, checkpoints, numerics) that the user must act on."""


@dataclass
class Setup:
    cfg: TrainConfig
    env: object
    expert: dict
    heldout: dict | None
    init: object
    chunk: object
    nets: dict
    train_metrics: dict | None = None
    validation: dict | None = None  # validation episodes (rollouts.heldout_arrays), for checkpoint selection
    files: dict | None = None  # split name (test, validation) -> the demonstration file it was read from
    task_env: object = None  # the task's env at its own time limit (its generated datasets'; ``env`` may differ)


def effective_updates_per_call(cfg: TrainConfig) -> int:
    return math.gcd(cfg.updates_per_call, cfg.checkpoint_every)


def total_updates(cfg: TrainConfig) -> int:
    upc = effective_updates_per_call(cfg)
    return int(math.ceil(cfg.num_updates / upc) * upc)


def build(cfg: TrainConfig, need_heldout: bool = True, need_validation: bool | None = None,
          run_dir: str | Path | None = None, need_demos: bool = True) -> Setup:
    """Environment, demonstrations and jitted programs of a config. The datasets are found, never made
    (:mod:`cogail_jax.data.sets`; ``cogail data`` makes them): a missing one raises ``MissingDataError``.
    ``need_heldout``: load the test split; ``need_validation`` (default: as ``need_heldout``): load the validation
    split. ``run_dir``: the run whose data manifest (RUN/data.json) the files are checked against (and recorded
    in, the first time). ``need_demos=False`` (play, video): no training file is read where the run's manifest
    records the training arrays' shapes (restoring a checkpoint needs only those)."""
    from cogail_envs import get_task

    cfg = cfg.validate()
    cfg = cfg.replace(updates_per_call=effective_updates_per_call(cfg))
    task = get_task(cfg.task)
    env = task_env = task.make_env()  # task_env: the task's own limit (the generated demos')
    if cfg.max_episode_steps and cfg.max_episode_steps != env.max_episode_steps:
        env = task.make_env(max_episode_steps=cfg.max_episode_steps)
    files: dict[str, Path] = {}
    expert = None if need_demos or run_dir is None else manifest.expert_struct(run_dir)
    train_metrics = None
    if expert is None:
        files["train"] = sets.split_path(cfg, sets.TRAIN, env=task_env)
        demos = data.load_demos(files["train"], env)
        expert, train_metrics = train.expert_arrays(demos, cfg.history, expert_capacity(cfg, task_env)), demos.metrics
    heldout, validation = None, None
    if need_heldout:
        files["test"] = sets.split_path(cfg, sets.TEST, env=task_env)
        heldout = rollouts.heldout_arrays(data.load_demos(files["test"], env, require_init=True))
    if need_heldout if need_validation is None else need_validation:
        files["validation"] = sets.split_path(cfg, sets.VALIDATION, env=task_env)
        validation = rollouts.heldout_arrays(data.load_demos(files["validation"], env, require_init=True))
    if run_dir is not None and files:
        manifest.check(run_dir, files, env.version)
    init, chunk, nets = train.make_train_fns(cfg, env, train.fit_normalizer(expert, cfg.obs_std_floor,
                                                                               train.unread_dims(cfg, env), cfg.motion))
    return Setup(cfg, env, expert, heldout, init, chunk, nets, train_metrics, validation,
                 {k: str(v) for k, v in files.items()}, task_env)


def expert_capacity(cfg: TrainConfig, task_env) -> int:
    """The rows of the training arrays (``train.expert_arrays``) as ``cfg`` fixes them before its datasets exist:
    every episode of the generated training set at the task's time limit; 0 (as many as the file's steps) for a
    training file of the user's."""
    n = sets.train_episodes(cfg)
    return 0 if n is None else n * int(task_env.max_episode_steps)


def compile_ahead(cfg: TrainConfig) -> None:
    """Compile the programs a fresh one-device ``cogail train`` of ``cfg`` starts with (the initial state, BC and the
    training chunk) for the shapes its training arrays will have, without its datasets (``cogail data`` runs this
    while it makes them): with the compilation cache on, the training command then loads them instead of compiling.
    A training file of the user's is read for its shapes. Only the training command's own results count: these
    programs take no data, so what they hold cannot differ from what it would compile."""
    from cogail_envs import get_task

    cfg = cfg.validate()
    cfg = cfg.replace(updates_per_call=effective_updates_per_call(cfg))
    task = get_task(cfg.task)
    env = task_env = task.make_env()
    if cfg.max_episode_steps and cfg.max_episode_steps != env.max_episode_steps:
        env = task.make_env(max_episode_steps=cfg.max_episode_steps)
    n = sets.train_episodes(cfg)
    if n is None:
        demos = data.load_demos(sets.split_path(cfg, sets.TRAIN, env=task_env), env)
        expert = train.expert_arrays(demos, cfg.history)
        n = int(demos.num)
    else:
        rows, d = expert_capacity(cfg, task_env), env.observation_size
        f32 = lambda *shape: jax.ShapeDtypeStruct((rows,) + shape, np.float32)  # noqa: E731
        expert = {"obs": f32(d), "ah": f32(env.human_action_size), "ar": f32(env.robot_action_size),
                  "hist": f32(cfg.history + 1, d), "prev_ah": f32(env.human_action_size),
                  "demo": jax.ShapeDtypeStruct((rows,), np.int32), "count": jax.ShapeDtypeStruct((), np.int32)}
    d = env.observation_size
    stats = {"mean": np.zeros(d, np.float32), "std": np.ones(d, np.float32), "num_demos": n}  # values unread
    if cfg.motion:
        stats["motion_std"] = np.ones(d, np.float32)
    init, chunk, _ = train.make_train_fns(cfg, env, stats)
    state = init.compile_ahead(cfg.seeds, expert)
    chunk.lower(state, expert).compile()


def run_metadata() -> dict:
    import importlib.metadata as md

    versions = {}
    for p in ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "brax", "mujoco", "mujoco-mjx", "numpy", "h5py"):
        try:
            versions[p] = md.version(p)
        except md.PackageNotFoundError:
            versions[p] = None
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                                cwd=Path(__file__).parent).stdout.strip() or None
        # uncommitted changes to the code (a run trained so is not the commit's)
        dirty = None if commit is None else bool(subprocess.run(
            ["git", "status", "--porcelain", "--", ":/src", ":/envs", ":/pyproject.toml"], capture_output=True,
            text=True, timeout=5, cwd=Path(__file__).parent).stdout.strip())
    except Exception:  # noqa: BLE001
        commit = dirty = None
    from ..runtime.xla import deterministic_ops

    return {"versions": versions, "git_commit": commit, "git_dirty": dirty, "python": sys.version.split()[0],
            "platform": platform.platform(), "devices": [str(d) for d in jax.devices()],
            "time": time.strftime("%Y-%m-%d %H:%M:%S"),
            # deterministic GPU kernels (on by default in the `cogail` CLI; off with --nondeterministic)
            "xla_gpu_deterministic_ops": deterministic_ops(), "xla_flags": os.environ.get("XLA_FLAGS", "")}


def holds_checkpoints(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds anything of a checkpoint: a training state, a delivered policy, or one set aside
    as damaged (anything at all in those folders, a checkpoint half written included). A folder that holds none
    never trained: its config.json is only what the command that made it was given."""
    return any((run_dir / d).is_dir() and any((run_dir / d).iterdir())
               for d in (ckpt.FULL, ckpt.POLICIES, "corrupt_checkpoints"))


PATH_FIELDS = ("demos", "heldout", "validation")


def _same(name: str, a, b) -> bool:
    if name in PATH_FIELDS and a and b:  # the same file, however written
        return a == b or os.path.abspath(a) == os.path.abspath(b)
    return a == b


def differences(saved: TrainConfig, cfg: TrainConfig, given=None) -> list[str]:
    """The fields among ``given`` (names; None: every field) whose values differ between the run's ``saved`` config
    and ``cfg``, in the config's order."""
    import dataclasses

    names = [f.name for f in dataclasses.fields(TrainConfig)]
    given = set(names if given is None else given)
    return [n for n in names if n in given and not _same(n, getattr(saved, n), getattr(cfg, n))]


def run_config(cfg: TrainConfig, run_dir: Path, resume: bool, given=None) -> tuple[TrainConfig, bool]:
    """The config a run in ``run_dir`` trains with, and whether the run folder is (re)written (a run that starts;
    False: a run continued as it was). Nothing is written here.

    Without ``resume``: ``cfg``; a folder that holds a checkpoint (``holds_checkpoints``) is refused.
    With ``resume``: the run's saved config.json, continued as it was. ``given``: the names of the fields the user
    gave (``cogail train``'s options, its --config file's and --set's fields, and a named budget's; never the
    task's defaults, which may have changed since the run was made); None (an API caller passing a whole config):
    every field. Where a given field differs from the saved run's, a run that has trained is refused with the
    fields named, and a folder that never trained (a command that failed or was stopped before its first
    checkpoint) starts afresh with ``cfg``: nothing of it is lost, and the options given now apply."""
    cfg_path = run_dir / "config.json"
    trained = holds_checkpoints(run_dir)
    if resume:
        if not cfg_path.exists():
            raise RunError(f"cannot resume: {run_dir} has no config.json; start a new run without --resume")
        saved = TrainConfig.load(cfg_path)
        diff = differences(saved, cfg, given)
        if not diff:
            return saved, not trained
        if trained:
            def show(c):
                return " and ".join(f"{n}={getattr(c, n)!r}" for n in diff)

            raise RunError(f"cannot resume: {run_dir} was trained with {show(saved)}, not the given {show(cfg)}: "
                           f"drop those options to continue the run as it was, or pass another --run to train a new "
                           f"one")
        print(f"{run_dir} holds no checkpoint: starting it afresh with the options given", flush=True)
        return cfg, True
    if trained:
        if cfg_path.exists():
            raise RunError(f"{run_dir} already holds a run: pass --resume to continue it or choose another --run")
        raise RunError(f"{run_dir} holds checkpoints but no config.json: put back the config.json it was trained "
                       f"with and pass --resume, or choose another --run")
    return cfg, True


def write_run_dir(cfg: TrainConfig, run_dir: Path) -> None:
    """Write a starting run's folder: config.json, run_info.json, and no data record of an earlier start that never
    trained (RUN/data.json; ``run_config`` has checked that the folder holds no checkpoint)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / manifest.NAME).unlink(missing_ok=True)
    (run_dir / "config.json").write_text(cfg.to_json())
    (run_dir / "run_info.json").write_text(json.dumps(run_metadata(), indent=2))


EVAL_PARAMS = ("actor", "psi")  # what evaluating a checkpoint reads of its parameters


def _eval_tree(state) -> dict:
    """The delivered policy's actor and psi (``train.policy_params``) and the observation normaliser of ``state``."""
    policy = train.policy_params(state.params)
    return {"params": {k: policy[k] for k in EVAL_PARAMS}, "norm": state.norm}


def eval_params(state) -> dict:
    """What evaluating a checkpoint reads of its state: the actor's and psi's parameters and the observation
    normaliser (seed axis first), on this process's first device, as ``checkpoint.restore`` puts them."""
    return jax.device_put(_eval_tree(state), jax.local_devices()[0])


class Policies:
    """A run's delivered policies, as evaluation, play and video read them: RUN/policies/ (one per checkpoint:
    ``_eval_tree``), or, for a run trained before policies were kept apart, its full training states. ``s``: the
    run's ``Setup`` (its state's shapes check and place what is read). ``steps()``: the checkpoints there are;
    ``load(step)``: ``eval_params`` of one; ``mgr``: the manager read (its ``failures`` name what did not
    restore)."""

    def __init__(self, run_dir: str | Path, s: Setup | None = None):
        self.run_dir, self.s = Path(run_dir), s
        self.mgr = ckpt.policy_manager(run_dir)
        self.full = self.mgr is None or not ckpt.steps(self.mgr)
        if self.full:
            self.mgr = ckpt.manager(run_dir)
        self._abstract = None

    def steps(self) -> list[int]:
        return ckpt.steps(self.mgr)

    def _expected(self):
        if self._abstract is None:
            state = self.s.init.abstract(self.s.cfg.seeds, self.s.expert)
            self._abstract = state if self.full else jax.eval_shape(_eval_tree, state)
        return self._abstract

    def load(self, step: int) -> dict:
        tree = ckpt.restore(self.mgr, step, self._expected())
        return eval_params(tree) if self.full else tree
