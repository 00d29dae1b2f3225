"""Demonstration datasets: HDF5 files in the robomimic layout, their validation, and the default cache.

Schema (version 1)::

    file attrs:  task (str), schema_version (int), obs_dim, human_action_dim, robot_action_dim, init_dim,
                 num_demos, mixture (str), seed (int)
    data/demo_<i>/obs            float32 (T, obs_dim)            state before each step
    data/demo_<i>/actions_human  float32 (T, human_action_dim)   the human's action at each step
    data/demo_<i>/actions_robot  float32 (T, robot_action_dim)   the robot's action at each step
    data/demo_<i>/init           float32 (init_dim,)             reset parameters (env.reset_from) [optional]
    data/demo_<i> attrs:         strategy (int, 1..S; 0 = unknown), num_samples (int, = T)

Trials recorded by ``cogail play`` (:func:`append_demo`) follow the same schema (file attr mixture =
"recorded") and add demo attrs method, run, seed, checkpoint, policy (the blind label), success (0/1),
end (success / timeout / ended), time and the final ``metric_<name>`` values.

The full action the environment takes is ``concat(actions_human, actions_robot)``. ``init`` is only
needed for replay evaluation (held-out sets); training files may omit it.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SCHEMA_VERSION = 1

# The default datasets of a task: three disjoint splits, each from its own generator seed (distinct random
# streams, so no episode of one split is an episode of another).
#   train       the paper's training set sizes
#   validation  our addition: checkpoint selection (the "selected" figures of results.json) is done on it,
#               so that nothing is tuned on the test set
#   test        the paper's 60 held-out demonstrations for replay evaluation (the config field ``heldout``
#               names a test file; "heldout" is accepted as another name of this split)
# Their sizes are the task's (``Task.splits``).
SPLITS = ("train", "validation", "test")
SPLIT_SEEDS = {"train": 0, "test": 1, "validation": 2}


class DatasetError(ValueError):
    """A demonstration file that cannot be used; the message names the file, the demo and the problem."""


@dataclass
class Demos:
    """Demonstrations padded to a common length (arrays have a leading demo axis)."""

    obs: np.ndarray  # (N, T, obs_dim)
    actions_human: np.ndarray  # (N, T, Ah)
    actions_robot: np.ndarray  # (N, T, Ar)
    length: np.ndarray  # (N,)
    strategy: np.ndarray  # (N,)
    init: np.ndarray | None  # (N, init_dim) or None
    task: str
    path: str = ""
    metrics: dict | None = None  # name -> (N,) final episode metrics recorded by the generator (optional)

    @property
    def num(self) -> int:
        return int(self.obs.shape[0])


def save_demos(path: str | os.PathLike, env, episodes, mixture: str = "uniform", seed: int = 0,
               generated: int = 0) -> Path:
    """Write episodes (``demos.Episodes``) to an HDF5 file in the project's schema; ``generated`` (optional) records
    how many episodes the generator was asked for (failed ones are not kept)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f"{path.suffix}.{os.getpid()}.tmp")  # per process: concurrent writers never share it
    try:
        _write_episodes(tmp, env, episodes, mixture, seed, generated)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)  # a failed write leaves nothing behind
    return path


def _write_episodes(tmp: Path, env, episodes, mixture: str, seed: int, generated: int) -> None:
    import h5py

    with h5py.File(tmp, "w") as f:
        f.attrs.update(task=env.name, schema_version=SCHEMA_VERSION, obs_dim=env.observation_size,
                       human_action_dim=env.human_action_size, robot_action_dim=env.robot_action_size,
                       init_dim=env.init_size, num_demos=len(episodes.length), mixture=str(mixture), seed=int(seed),
                       env_version=env.version)
        if generated:
            f.attrs["generated"] = int(generated)
        data = f.create_group("data")
        for i in range(len(episodes.length)):
            n = int(episodes.length[i])
            g = data.create_group(f"demo_{i}")
            g.create_dataset("obs", data=np.asarray(episodes.obs[i, :n], np.float32))
            g.create_dataset("actions_human", data=np.asarray(episodes.actions_human[i, :n], np.float32))
            g.create_dataset("actions_robot", data=np.asarray(episodes.actions_robot[i, :n], np.float32))
            g.create_dataset("init", data=np.asarray(episodes.init[i], np.float32))
            g.attrs["strategy"] = int(episodes.strategy[i])
            g.attrs["num_samples"] = n
            for k, v in (episodes.final_metrics or {}).items():  # e.g. the handover spot
                g.attrs[f"metric_{k}"] = float(np.asarray(v)[i])


def append_demo(path: str | os.PathLike, env, obs, actions_human, actions_robot, init, strategy: int = 0,
                attrs: dict | None = None) -> int:
    """Append one episode to a file in the project's schema (created if missing); returns its demo index.

    ``attrs`` become attributes of the demo's group (e.g. ``cogail play`` records method, checkpoint, success).
    The file is rewritten through a temporary copy, so an interrupted write leaves the old file intact."""
    import shutil

    import h5py

    path = Path(path)
    obs, ah, ar = (np.asarray(x, np.float32) for x in (obs, actions_human, actions_robot))
    for name, a, dim in (("obs", obs, env.observation_size), ("actions_human", ah, env.human_action_size),
                         ("actions_robot", ar, env.robot_action_size)):
        if a.ndim != 2 or a.shape[1] != dim or a.shape[0] != obs.shape[0] or a.shape[0] == 0:
            raise DatasetError(f"cannot append to {path}: '{name}' has shape {a.shape}, expected "
                               f"({obs.shape[0] or 'T>0'}, {dim}) for task {env.name}")
    check_appendable(path, env)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f"{path.suffix}.{os.getpid()}.tmp")  # per process: concurrent writers never share it
    if path.exists():
        shutil.copyfile(path, tmp)
    with h5py.File(tmp, "a") as f:
        if "data" not in f:
            f.attrs.update(task=env.name, schema_version=SCHEMA_VERSION, obs_dim=env.observation_size,
                           human_action_dim=env.human_action_size, robot_action_dim=env.robot_action_size,
                           init_dim=env.init_size, num_demos=0, mixture="recorded", seed=0)
            f.create_group("data")
        i = max([int(k[5:]) for k in f["data"] if k.startswith("demo_") and k[5:].isdigit()], default=-1) + 1
        g = f["data"].create_group(f"demo_{i}")
        g.create_dataset("obs", data=obs)
        g.create_dataset("actions_human", data=ah)
        g.create_dataset("actions_robot", data=ar)
        g.create_dataset("init", data=np.asarray(init, np.float32).reshape(-1))
        g.attrs["strategy"] = int(strategy)
        g.attrs["num_samples"] = int(obs.shape[0])
        for k, v in (attrs or {}).items():
            g.attrs[k] = v
        f.attrs["num_demos"] = len(f["data"])
    os.replace(tmp, path)
    return i


def check_appendable(path: str | os.PathLike, env) -> None:
    """Raise ``DatasetError`` unless ``path`` is missing or a file in the project's schema for ``env``'s task."""
    import h5py

    path = Path(path)
    if not path.exists():
        return
    try:
        with h5py.File(path, "r") as f:
            task = f.attrs.get("task")
    except OSError:
        raise DatasetError(f"{path} exists and is not an HDF5 file: pass another file")
    task = task.decode() if isinstance(task, bytes) else task
    if task != env.name:
        raise DatasetError(f"{path} holds demonstrations of task {task!r}, not {env.name!r}: pass another file")


def _demo_key(name: str) -> tuple[int, str]:
    tail = name.rsplit("_", 1)[-1]
    return (int(tail), name) if tail.isdigit() else (1 << 30, name)


def check_demos(path: str | os.PathLike, env, require_init: bool = False) -> None:
    """``load_demos``'s checks of a file's layout, without reading its arrays: what it holds (task, demos, their
    datasets' shapes, strategies, ``init`` where ``require_init``), so that a command can find a bad file before it
    works, in milliseconds; its values (NaN, infinities) are checked where it is read."""
    load_demos(path, env, require_init, read=False)


def load_demos(path: str | os.PathLike, env, require_init: bool = False, read: bool = True) -> Demos | None:
    """Read and validate a demonstration file against ``env``; raise ``DatasetError`` on any problem. ``read=False``:
    ``check_demos``."""
    import h5py

    path = Path(path)
    where = f"demonstration file {path}"
    if not path.exists():
        raise DatasetError(f"{where} does not exist: check the path or make one with `cogail demos`")
    try:
        f = h5py.File(path, "r")
    except OSError as e:  # not HDF5, or unreadable (h5py's reason: a truncated file, a lock held elsewhere)
        raise DatasetError(f"{where} could not be read as an HDF5 file ({e}): give a file written by `cogail demos` "
                           "or `cogail import`")
    with f:
        task = f.attrs.get("task")
        if isinstance(task, bytes):
            task = task.decode()
        if task is not None and task != env.name:
            raise DatasetError(f"{where} holds demonstrations of task {task!r}, not {env.name!r}: use a {env.name} file")
        if "data" not in f or not isinstance(f["data"], h5py.Group):
            raise DatasetError(f"{where} has no 'data' group: it does not follow the robomimic layout (data/demo_<i>/...)")
        names = sorted((k for k in f["data"].keys() if k.startswith("demo")), key=_demo_key)
        if not names:
            if not (others := sorted(f["data"].keys(), key=_demo_key)):
                raise DatasetError(f"{where} is empty: its 'data' group holds no demo_<i> groups")
            kind = "groups" if all(isinstance(f["data"][k], h5py.Group) for k in others) else "entries"
            shown = ", ".join(others[:3]) + (", ..." if len(others) > 3 else "")
            raise DatasetError(f"{where} is not in the project's schema: its 'data' group holds {len(others)} {kind} "
                               f"named {shown}, not demo_<i>; convert it with `cogail import --task {env.name} --in "
                               f"{path} --out FILE.hdf5` (--key or --map say where each field is)")
        dims = {"obs": env.observation_size, "actions_human": env.human_action_size,
                "actions_robot": env.robot_action_size}
        arrays: dict[str, list[np.ndarray]] = {k: [] for k in dims}
        inits, strategies, lengths, metrics = [], [], [], []
        for name in names:
            g = f["data"][name]
            at = f"{where}, demo {name}"
            if not isinstance(g, h5py.Group):
                raise DatasetError(f"{at} is not a group: each demo must be a group with obs and actions datasets")
            T = None
            for key, dim in dims.items():
                if key not in g:
                    raise DatasetError(f"{at} has no '{key}' dataset: each demo needs {', '.join(dims)}")
                a = g[key]
                if not isinstance(a, h5py.Dataset) or a.dtype.kind not in "fiu":
                    raise DatasetError(f"{at}: '{key}' is not a numeric array")
                shape = tuple(a.shape)
                if len(shape) != 2 or shape[1] != dim:
                    raise DatasetError(f"{at}: '{key}' has shape {shape}, expected (T, {dim}) for task {env.name}")
                if T is None:
                    T = shape[0]
                elif shape[0] != T:
                    raise DatasetError(f"{at}: '{key}' has {shape[0]} steps but 'obs' has {T}")
                if not read:
                    continue
                a = np.asarray(a[()], np.float32)
                if not np.all(np.isfinite(a)):
                    raise DatasetError(f"{at}: '{key}' contains NaN or infinite values")
                arrays[key].append(a)
            if T == 0:
                raise DatasetError(f"{at} has zero steps")
            n = g.attrs.get("num_samples", T)
            if int(n) != T:
                raise DatasetError(f"{at}: attr num_samples={int(n)} but the arrays have {T} steps")
            lengths.append(T)
            strategy = g.attrs.get("strategy", 0)
            S = env.num_strategies
            if np.ndim(strategy) or float(strategy) != int(strategy) or not 0 <= int(strategy) <= S:
                raise DatasetError(f"{at}: strategy {strategy} is not one of {env.name}'s ids, 1..{S} "
                                   f"({', '.join(env.strategy_names)}), or 0 for unknown: relabel it, e.g. with "
                                   "`cogail import --key strategy=...`")
            strategies.append(int(strategy))
            metrics.append({k[7:]: float(v) for k, v in g.attrs.items() if k.startswith("metric_")})
            if "init" in g:
                init = np.asarray(g["init"][()], np.float32).reshape(-1)
                if init.shape != (env.init_size,) or not np.all(np.isfinite(init)):
                    raise DatasetError(f"{at}: 'init' must be {env.init_size} finite numbers, got shape {init.shape}")
                inits.append(init)
            elif require_init:
                raise DatasetError(f"{at} has no 'init' dataset, which replay evaluation needs to restart the episode")
    if not read:
        return None
    N, Tmax = len(names), max(lengths)

    def pad(xs, dim):
        out = np.zeros((N, Tmax, dim), np.float32)
        for i, x in enumerate(xs):
            out[i, : len(x)] = x
        return out

    return Demos(
        obs=pad(arrays["obs"], env.observation_size),
        actions_human=pad(arrays["actions_human"], env.human_action_size),
        actions_robot=pad(arrays["actions_robot"], env.robot_action_size),
        length=np.asarray(lengths, np.int32),
        strategy=np.asarray(strategies, np.int32),
        init=np.stack(inits) if len(inits) == N else None,
        task=env.name,
        path=str(path),
        metrics={k: np.asarray([m.get(k, np.nan) for m in metrics]) for k in metrics[0]} if metrics[0] else None,
    )


def data_dir() -> Path:
    """Where default datasets are cached: $COGAIL_DATA, else ./data."""
    return Path(os.environ.get("COGAIL_DATA", "data"))


def split_name(split: str) -> str:
    """The canonical name of a default split: train, validation or test ("heldout" is the test split)."""
    split = "test" if split == "heldout" else split
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}: use one of {', '.join(SPLITS)}")
    return split


def default_count(task: str, split: str) -> int:
    """The number of demonstrations of a task's default split (``Task.splits``)."""
    from cogail_envs import get_task

    return get_task(task).split_size(split_name(split))


class MissingDataError(DatasetError):
    """A dataset a command needs is not on disk (or was made for another version of the task): ``cogail data``
    makes it; nothing else generates data."""


def missing(path, what: str, why: str = "is missing") -> MissingDataError:
    return MissingDataError(f"{what} {path} {why}: make the run's datasets first with `cogail data` and the same "
                            "--task / --budget / --config / --set / --mix options (`make train` does)")


def default_demo_path(task: str, split: str, mix: str = "uniform", num: int = 0) -> Path:
    """The cached default dataset; ``num`` > 0 (other than the task's default count) gets a file of its own."""
    split = split_name(split)
    count = f"_{num}" if num and num != default_count(task, split) else ""
    return data_dir() / f"{task}_{mix}_{split}{count}.hdf5"


def _stored_version(path: Path) -> str | None:
    return _stored_attrs(path)[0]


def _stored_attrs(path: Path) -> tuple[str | None, int]:
    """The task version a cached file was made by and the number of episodes asked of the generator (older files:
    the number they hold)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            v = f.attrs.get("env_version")
            n = int(f.attrs.get("generated", f.attrs.get("num_demos", 0)))
            return (None if v is None else str(v.decode() if isinstance(v, bytes) else v)), n
    except OSError:
        return None, 0


def ensure_default_demos(env, split: str = "train", mix: str = "uniform", verbose: bool = True, num: int = 0,
                         make: bool = True) -> Path:
    """Path of the default dataset of a task (``train``, ``validation`` or ``test``, also called ``heldout``),
    generated from the split's own generator seed (``SPLIT_SEEDS``) when missing or made by another version of the
    task; ``num`` > 0 asks for that many scripted demonstrations instead of the task's default count. With
    ``make=False`` a missing or stale file raises ``MissingDataError`` instead (only ``cogail data`` makes data)."""
    from . import generate as demos

    path = default_demo_path(env.name, split, mix, num)
    split = split_name(split)
    num = num or default_count(env.name, split)
    if split == "train":  # the task's training env (e.g. a robot that starts from more poses)
        env = demos.training_env(env)
    if path.exists():
        version, generated = _stored_attrs(path)
        if version == env.version and generated == num:
            return path
        if not make:
            raise missing(path, f"the {split} split", "was made by another version of the task or for another size")
        if verbose:
            why = ("another version of the task (physics, observation or team)" if version != env.version
                   else f"{generated} generated episodes, not {num}")
            print(f"{path} was made with {why}: regenerating it", flush=True)
    if not make:
        raise missing(path, f"the {split} split")
    seed = SPLIT_SEEDS[split]  # one generator seed per split: the splits are disjoint
    if verbose:
        print(f"making {num} {split} demonstrations for {env.name} (mixture {mix}) -> {path}", flush=True)
    eps = demos.generate(env, num, mix=mix, seed=seed, variation=demos.training_flags(env) if split == "train" else 0)
    ok = eps.success > 0
    if not ok.all():  # keep successful demonstrations only
        eps = demos.select(eps, ok)
    return save_demos(path, env, eps, mixture=mix, seed=seed, generated=num)
