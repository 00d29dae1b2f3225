"""Bring your own demonstrations: convert robomimic-style HDF5 or NumPy ``.npz`` files into the project's schema.

``import_demos(src, out, task, mapping)`` reads ``src``, renames its keys with ``mapping``, checks every
demo against the task (keys present, dimensions, lengths, finite values, strategy ids, the file's task),
writes ``out`` in the schema of :mod:`cogail_jax.data.io` and validates it with ``data.load_demos``.

The mapping (``--key FIELD=SOURCE`` on the command line, or a JSON object ``{"FIELD": "SOURCE", ...}`` in
a file given with ``--map``; command-line keys win) names where each field of the schema lives::

    obs            the states, (T, obs_dim)
    actions        one concatenated action array (T, human + robot dims), split into human | robot
    actions_human  the human's actions (T, human_action_dim)     } use these two or ``actions``
    actions_robot  the robot's actions (T, robot_action_dim)     }
    init           the reset parameters (init_dim,) [optional; replay evaluation needs them]
    strategy       the strategy id (0 = unknown, 1..S) [optional, default 0]
    length         npz only: the number of valid steps per demo of padded arrays [optional]
    group          HDF5 only: the group holding the demos (default ``data``; ``/`` for the file's root)
    demo_prefix    HDF5 only: only child groups whose name starts with this are demos (default: all)

A SOURCE is a dataset path inside the demo group (HDF5: ``states``, ``obs/agent_pos``) or an array name
(npz); several joined with ``+`` are concatenated along the last axis (``obs/pos+obs/flags``). For
``strategy``, ``@name`` reads the demo group's attribute ``name`` and an integer gives every demo that id.

Defaults, when a field is not mapped: ``obs``; ``actions_human`` + ``actions_robot`` if present, else
``actions`` split; ``init`` if present; ``strategy`` from the attribute or dataset of that name, else 0;
``length`` / ``lengths`` (npz) if present.

npz files hold one entry per field, either an object array of per-demo arrays (N,) of (T_i, dim), or a
padded array (N, T_max, dim) with ``length`` (N,) (without it every demo has T_max steps); a single
(T, dim) array is one demo. ``strategy`` is (N,), ``init`` is (N, init_dim). An observation array with
one more step than the actions (the final state included) is cut to the actions' length.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..algo.config import ConfigError
from .io import SCHEMA_VERSION, DatasetError, Demos, load_demos

ARRAY_FIELDS = ("obs", "actions", "actions_human", "actions_robot", "init", "strategy", "length")
STRUCT_FIELDS = ("group", "demo_prefix")
FIELDS = ARRAY_FIELDS + STRUCT_FIELDS
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
ZIP_MAGIC = b"PK\x03\x04"


# ----------------------------------------------------------------------------------------------- mapping
def parse_keys(items, where: str = "--key") -> dict[str, str]:
    """``["obs=states", "actions=acts"]`` -> ``{"obs": "states", "actions": "acts"}``."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise ConfigError(f"{where} needs FIELD=SOURCE (e.g. obs=observations), got {item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        out[k] = v
    return check_mapping(out, where)


def check_mapping(mapping: dict, where: str) -> dict[str, str]:
    mapping = {k: v for k, v in mapping.items() if not k.startswith("_")}  # "_comment" and friends
    unknown = sorted(set(mapping) - set(FIELDS))
    if unknown:
        raise ConfigError(f"{where}: unknown field {unknown[0]!r}; map one of {', '.join(FIELDS)}")
    for k, v in mapping.items():
        if not isinstance(v, (str, int)) or isinstance(v, bool) or (isinstance(v, str) and not v.strip()
                                                                  and k != "demo_prefix"):
            raise ConfigError(f"{where}: field {k!r} must map to a key name (a non-empty string), got {v!r}")
    mapping = {k: str(v) for k, v in mapping.items()}
    both = [k for k in ("actions_human", "actions_robot") if k in mapping]
    if both and "actions" in mapping:
        raise ConfigError(f"{where}: map either 'actions' (one array, split into human | robot) or "
                          f"'actions_human' and 'actions_robot', not both")
    return mapping


def load_mapping(path: str | os.PathLike) -> dict[str, str]:
    """Read a key-mapping JSON file: ``{"obs": "states", "actions": "actions", "strategy": "@label"}``."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"key-mapping file {path} does not exist: give a JSON file like examples/fetchq_robomimic_map.json")
    try:
        mapping = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"key-mapping file {path} is not valid JSON ({getattr(e, 'msg', e)}): "
                          f"write an object like {{\"obs\": \"states\", \"actions\": \"acts\"}}")
    if not isinstance(mapping, dict):
        raise ConfigError(f"key-mapping file {path} must hold a JSON object like {{\"obs\": \"states\"}}")
    return check_mapping(mapping, f"key-mapping file {path}")


# ----------------------------------------------------------------------------------------------- demos
@dataclass
class _Demo:
    name: str
    obs: np.ndarray
    ah: np.ndarray
    ar: np.ndarray
    init: np.ndarray | None
    strategy: int
    src: dict = field(default_factory=dict)  # field -> source key (for messages)


@dataclass
class ImportSummary:
    src: str
    out: str
    kind: str  # "hdf5" | "npz"
    num: int
    mean_length: float
    strategies: list[int]  # count per id 0..S
    with_init: int
    trimmed_obs: int  # demos whose final observation was dropped

    def describe(self, task: str) -> str:
        notes = []
        if self.trimmed_obs:
            notes.append(f"dropped the final observation of {self.trimmed_obs} demos (one more state than actions)")
        if self.strategies and self.strategies[0] == self.num:
            notes.append("no strategy labels found, so every demo has strategy 0 (unknown); if the file has them, "
                         "map them with --key strategy=NAME (a dataset or array) or strategy=@NAME (an attribute)")
        if self.with_init < self.num:
            notes.append(f"{self.num - self.with_init} demos have no 'init', so the file can train but not serve as "
                         f"--heldout for replay evaluation")
        s = (f"imported {self.num} {task} demonstrations from {self.src} ({self.kind}) to {self.out}: "
             f"mean length {self.mean_length:.1f}, strategies (0 = unknown, 1..) {self.strategies}")
        return s + "".join(f"\nnote: {n}" for n in notes)


def _file_kind(path: Path) -> str:
    if not path.exists():
        raise DatasetError(f"input file {path} does not exist: check the --in path")
    if not path.is_file():
        raise DatasetError(f"input {path} is not a file: give an HDF5 (.hdf5/.h5) or NumPy .npz file")
    with open(path, "rb") as f:
        head = f.read(8)
    if head == HDF5_MAGIC:
        return "hdf5"
    if head[:4] == ZIP_MAGIC:
        return "npz"
    import h5py

    if h5py.is_hdf5(str(path)):  # HDF5 with a user block
        return "hdf5"
    raise DatasetError(f"input file {path} is neither HDF5 nor a NumPy .npz archive: convert it to one of the two "
                       f"(e.g. np.savez(path, obs=..., actions=..., strategy=...))")


def _listing(names, limit: int = 12) -> str:
    names = list(names)
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more if names else "nothing"


def _as_2d(a: np.ndarray, T: int | None = None) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 1:
        a = a[:, None]
    elif a.ndim > 2:
        a = a.reshape(a.shape[0], -1)
    return a


def _strategy_value(v, env, at: str, src: str) -> int:
    v = np.asarray(v)
    if v.dtype.kind in "SUO":
        flat = [x.decode() if isinstance(x, bytes) else str(x) for x in v.reshape(-1)]
        if len(set(flat)) > 1:
            raise DatasetError(f"{at}: strategy ({src}) changes within the demo: give one id per demo")
        name = flat[0] if flat else ""
        names = list(env.strategy_names)
        if name in names:
            return names.index(name) + 1
        if name.strip().lstrip("-").isdigit():
            v = np.asarray(int(name))
        else:
            raise DatasetError(f"{at}: strategy ({src}) is {name!r}, which is neither an id nor one of "
                               f"{env.name}'s strategy names ({', '.join(names)})")
    if v.dtype.kind not in "fiub" or v.size == 0:
        raise DatasetError(f"{at}: strategy ({src}) is not a number")
    vals = np.unique(v.reshape(-1))
    if len(vals) > 1:
        raise DatasetError(f"{at}: strategy ({src}) changes within the demo ({vals[:4].tolist()}): give one id per demo")
    x = float(vals[0])
    S = env.num_strategies
    if not np.isfinite(x) or x != int(x) or not 0 <= int(x) <= S:
        raise DatasetError(f"{at}: strategy ({src}) is {x:g}, but {env.name}'s strategy ids are 1..{S} "
                           f"({', '.join(env.strategy_names)}) and 0 means unknown: relabel it or map strategy=0")
    return int(x)


def _check_demo(d: _Demo, env, at: str) -> int:
    """Validate one demo in place (shapes, lengths, finite values); returns 1 if the final obs was dropped."""
    Ah, Ar, D = env.human_action_size, env.robot_action_size, env.observation_size
    trimmed = 0
    for key, a, dim in (("obs", d.obs, D), ("actions_human", d.ah, Ah), ("actions_robot", d.ar, Ar)):
        if a.dtype.kind not in "fiub":
            raise DatasetError(f"{at}: {key} ({d.src.get(key, key)}) is not a numeric array (dtype {a.dtype})")
        if a.ndim != 2 or a.shape[1] != dim:
            hint = ("the task's action is concat(human, robot): map actions_human and actions_robot, or one "
                    f"'actions' of {Ah + Ar} columns" if key != "obs" else "check the mapping of obs or --task")
            src = d.src.get(key, key)
            raise DatasetError(f"{at}: {key} ({src}) has shape {tuple(a.shape)}, but task {env.name} needs (T, {dim}): {hint}")
    T = d.ah.shape[0]
    if d.ar.shape[0] != T:
        raise DatasetError(f"{at}: actions_human has {T} steps but actions_robot has {d.ar.shape[0]}")
    if d.obs.shape[0] == T + 1:
        d.obs, trimmed = d.obs[:T], 1
    if d.obs.shape[0] != T:
        raise DatasetError(f"{at}: obs ({d.src.get('obs', 'obs')}) has {d.obs.shape[0]} steps but the actions have {T}: "
                           f"each step needs the state before it and both agents' actions")
    if T == 0:
        raise DatasetError(f"{at} has zero steps: remove it")
    for key, a in (("obs", d.obs), ("actions_human", d.ah), ("actions_robot", d.ar)):
        if not np.all(np.isfinite(a)):
            raise DatasetError(f"{at}: {key} ({d.src.get(key, key)}) contains NaN or infinite values: clean or drop this demo")
    if d.init is not None:
        init = np.asarray(d.init).reshape(-1)
        if init.dtype.kind not in "fiub" or init.shape != (env.init_size,) or not np.all(np.isfinite(init)):
            raise DatasetError(f"{at}: init ({d.src.get('init', 'init')}) must be {env.init_size} finite numbers for task "
                               f"{env.name}, got shape {tuple(np.shape(d.init))}")
        d.init = init
    return trimmed


# ----------------------------------------------------------------------------------------------- HDF5
def _read_hdf5(path: Path, env, mapping: dict) -> list[_Demo]:
    import h5py

    where = f"input file {path}"
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise DatasetError(f"{where} cannot be read as HDF5 ({e}): check that the file is complete")
    demos = []
    with f:
        task = f.attrs.get("task")
        if isinstance(task, bytes):
            task = task.decode()
        if task is not None and str(task) != env.name:
            raise DatasetError(f"{where} holds demonstrations of task {str(task)!r}, not {env.name!r}: "
                               f"pass --task {task} or use a {env.name} file")
        gname = mapping.get("group", "data")
        if gname in ("/", ""):
            root = f
        else:
            if gname not in f or not isinstance(f[gname], h5py.Group):
                raise DatasetError(f"{where} has no group {gname!r} holding the demos (its top level holds "
                                   f"{_listing(f.keys())}): name the group with --key group=NAME")
            root = f[gname]
        prefix = mapping.get("demo_prefix", "")
        names = [k for k in root.keys() if k.startswith(prefix) and isinstance(root[k], h5py.Group)]
        names.sort(key=lambda n: (int(n.rsplit("_", 1)[-1]) if n.rsplit("_", 1)[-1].isdigit() else 1 << 30, n))
        if not names:
            what = f"groups whose name starts with {prefix!r}" if prefix else "demo groups"
            raise DatasetError(f"{where}: group {gname!r} holds no {what} (it holds {_listing(root.keys())}): "
                               f"set --key group=... / --key demo_prefix=... to where the demos are")
        for name in names:
            g = root[name]
            at = f"{where}, demo {name}"
            keys = []
            g.visit(lambda k: keys.append(k) if isinstance(g[k], h5py.Dataset) else None)

            def get(fieldname, src, required=True):
                parts = [p.strip() for p in src.split("+")]
                arrays = []
                for p in parts:
                    if p not in g:
                        if not required:
                            return None
                        raise DatasetError(f"{at} has no dataset {p!r} (for {fieldname}); it holds {_listing(keys)}: "
                                           f"map {fieldname} to one of them, e.g. --key {fieldname}=NAME")
                    obj = g[p]
                    if isinstance(obj, h5py.Group):
                        sub = [f"{p}/{k}" for k in obj.keys()]
                        raise DatasetError(f"{at}: {p!r} (for {fieldname}) is a group of {_listing(sub)}, not an array: "
                                           f"map {fieldname} to its datasets joined with '+' in the order of the task's "
                                           f"layout, e.g. --key {fieldname}={'+'.join(sub[:3])}")
                    arrays.append(obj[()])
                if len(arrays) == 1:
                    return np.asarray(arrays[0])
                try:
                    return np.concatenate([_as_2d(a) for a in arrays], -1)
                except ValueError:
                    shapes = ", ".join(f"{p} {np.shape(a)}" for p, a in zip(parts, arrays))
                    raise DatasetError(f"{at}: cannot join {src!r} for {fieldname}: the parts have different numbers "
                                       f"of steps ({shapes})")

            has = lambda k: all(p.strip() in g for p in k.split("+"))  # noqa: E731
            ak = _action_keys(at, mapping, has, _listing(keys))
            if ak[0] == "actions":
                ah, ar, src = _split(at, env, get("actions", ak[1]), ak[1])
            else:
                ah, ar = _as_2d(get("actions_human", ak[1])), _as_2d(get("actions_robot", ak[2]))
                src = {"actions_human": repr(ak[1]), "actions_robot": repr(ak[2])}
            d = _Demo(name=name, obs=np.zeros((0, 0)), ah=ah, ar=ar, init=None, strategy=0, src=src)
            obs = get("obs", mapping.get("obs", "obs"))
            d.obs = _as_2d(obs)
            d.src["obs"] = repr(mapping.get("obs", "obs"))
            if "init" in mapping:
                d.init = get("init", mapping["init"])
                d.src["init"] = repr(mapping["init"])
            elif "init" in g:
                d.init = g["init"][()]
            s = mapping.get("strategy")
            if s is None:
                if "strategy" in g.attrs:
                    d.strategy = _strategy_value(g.attrs["strategy"], env, at, "attribute 'strategy'")
                elif "strategy" in g and isinstance(g["strategy"], h5py.Dataset):
                    d.strategy = _strategy_value(g["strategy"][()], env, at, "dataset 'strategy'")
            elif s.lstrip("-").isdigit():
                d.strategy = _strategy_value(int(s), env, at, f"strategy={s}")
            elif s.startswith("@"):
                if s[1:] not in g.attrs:
                    raise DatasetError(f"{at} has no attribute {s[1:]!r} (for strategy); its attributes are "
                                       f"{_listing(g.attrs.keys())}: fix --key strategy=@NAME")
                d.strategy = _strategy_value(g.attrs[s[1:]], env, at, f"attribute {s[1:]!r}")
            else:
                d.strategy = _strategy_value(get("strategy", s), env, at, f"dataset {s!r}")
            demos.append(d)
    return demos


def _action_keys(at: str, mapping: dict, has, holds: str) -> tuple[str, ...]:
    """Where the actions are: ``("actions", key)`` (one array to split) or ``("pair", human_key, robot_key)``."""
    explicit = [k for k in ("actions", "actions_human", "actions_robot") if k in mapping]
    kh, kr = mapping.get("actions_human", "actions_human"), mapping.get("actions_robot", "actions_robot")
    if "actions" in explicit:
        return ("actions", mapping["actions"])
    if explicit or (has(kh) and has(kr)):
        return ("pair", kh, kr)
    if has("actions"):
        return ("actions", "actions")
    missing = " and ".join(repr(k) for k in (kh, kr) if not has(k))
    raise DatasetError(f"{at} has no actions (no 'actions', no {missing}; it holds {holds}): map actions_human and "
                       f"actions_robot, or one concatenated array (human | robot) with --key actions=NAME")


def _split(at: str, env, a: np.ndarray, key: str):
    Ah, Ar = env.human_action_size, env.robot_action_size
    a = _as_2d(a)
    if a.shape[1] != Ah + Ar:
        raise DatasetError(f"{at}: actions ({key!r}) has shape {tuple(a.shape)}, but task {env.name} needs "
                           f"(T, {Ah + Ar}) = {Ah} human then {Ar} robot columns: check the mapping or --task")
    return a[:, :Ah], a[:, Ah:], {"actions_human": f"{key!r}[:, :{Ah}]", "actions_robot": f"{key!r}[:, {Ah}:]"}


# ----------------------------------------------------------------------------------------------- npz
def _read_npz(path: Path, env, mapping: dict) -> list[_Demo]:
    where = f"input file {path}"
    for key in STRUCT_FIELDS:
        if key in mapping:
            raise ConfigError(f"--key {key}=... only applies to HDF5 files; {path} is an .npz archive")
    try:
        z = np.load(path, allow_pickle=False)
        arrays = {}
        for k in z.files:
            try:
                arrays[k] = z[k]
            except ValueError:  # an object array (per-demo arrays of different lengths): needs pickle
                arrays[k] = np.load(path, allow_pickle=True)[k]
    except Exception as e:  # noqa: BLE001 - a damaged archive raises many kinds of errors
        raise DatasetError(f"{where} cannot be read as a NumPy .npz archive ({type(e).__name__}: {e}): "
                           f"write it with np.savez")
    if "task" in arrays:
        task = str(np.asarray(arrays["task"]).reshape(-1)[0])
        if task != env.name:
            raise DatasetError(f"{where} holds demonstrations of task {task!r}, not {env.name!r}: "
                               f"pass --task {task} or use a {env.name} file")

    def has(src):
        return all(p.strip() in arrays for p in src.split("+"))

    def per_demo(fieldname, src, series=True):
        """-> list of per-demo arrays (series: time-major (T, dim); else per-demo values)."""
        parts = [p.strip() for p in src.split("+")]
        for p in parts:
            if p not in arrays:
                raise DatasetError(f"{where} has no array {p!r} (for {fieldname}); it holds {_listing(arrays)}: "
                                   f"map {fieldname} to one of them, e.g. --key {fieldname}=NAME")
        lists = []
        for p in parts:
            a = arrays[p]
            if a.dtype == object:
                items = [np.asarray(x) for x in a.reshape(-1)]
                if any(x.dtype == object for x in items):
                    raise DatasetError(f"{where}: {p!r} (for {fieldname}) holds nested objects, not numeric arrays")
            elif series and a.ndim == 2:
                items = [a]  # one demo (T, dim)
            elif series and a.ndim == 3:
                items = list(a)  # padded (N, T_max, dim)
            elif series:
                raise DatasetError(f"{where}: {p!r} (for {fieldname}) has shape {a.shape}: give an object array of "
                                   f"per-demo (T, dim) arrays, or a padded (N, T_max, dim) array with 'length'")
            else:
                items = [a] if a.ndim == 0 else list(a.reshape(a.shape[0], -1)) if a.size else [x for x in a]
            lists.append(items)
        n = {len(x) for x in lists}
        if len(n) > 1:
            raise DatasetError(f"{where}: the parts of {src!r} hold different numbers of demos "
                               f"({', '.join(f'{p} {len(x)}' for p, x in zip(parts, lists))})")
        if len(lists) == 1:
            return lists[0]
        out = []
        for i, xs in enumerate(zip(*lists)):
            try:
                out.append(np.concatenate([_as_2d(x) if series else np.reshape(x, -1) for x in xs], -1))
            except ValueError:
                raise DatasetError(f"{where}, demo {i}: cannot join {src!r} for {fieldname}: the parts have "
                                   f"different numbers of steps ({', '.join(str(np.shape(x)) for x in xs)})")
        return out

    cache = {}

    def get(fieldname, src):
        if src not in cache:
            cache[src] = per_demo(fieldname, src)
        return cache[src]

    obs_key = mapping.get("obs", "obs")
    obs = get("obs", obs_key)
    N = len(obs)
    ak = _action_keys(where, mapping, has, _listing(arrays))
    use_split = ak[0] == "actions"
    if use_split:
        sources = {"actions": (ak[1], get("actions", ak[1]))}
    else:
        sources = {"actions_human": (ak[1], get("actions_human", ak[1])),
                   "actions_robot": (ak[2], get("actions_robot", ak[2]))}
    for k, (src, xs) in sources.items():
        if len(xs) != N:
            raise DatasetError(f"{where}: {k} ({src!r}) holds {len(xs)} demos but obs ({obs_key!r}) holds {N}")
    lengths = None
    lkey = mapping.get("length") or next((k for k in ("length", "lengths", "num_samples") if k in arrays), None)
    if lkey is not None:
        if lkey not in arrays:
            raise DatasetError(f"{where} has no array {lkey!r} (for length); it holds {_listing(arrays)}")
        lengths = np.asarray(arrays[lkey]).reshape(-1)
        if lengths.shape != (N,) or lengths.dtype.kind not in "iuf":
            raise DatasetError(f"{where}: length ({lkey!r}) must hold one step count per demo ({N}), got shape "
                               f"{np.asarray(arrays[lkey]).shape}")
    strategies = None
    skey = mapping.get("strategy")
    if skey is not None and skey.lstrip("-").isdigit():
        strategies = [int(skey)] * N
    elif skey is not None or "strategy" in arrays:
        skey = skey or "strategy"
        if skey.startswith("@"):
            raise ConfigError(f"--key strategy=@NAME reads an HDF5 attribute; in an .npz give the array's name")
        strategies = per_demo("strategy", skey, series=False)
        if len(strategies) != N:
            raise DatasetError(f"{where}: strategy ({skey!r}) holds {len(strategies)} values but there are {N} demos")
    inits = None
    ikey = mapping.get("init") or ("init" if "init" in arrays else None)
    if ikey is not None:
        inits = per_demo("init", ikey, series=False)
        if len(inits) != N:
            raise DatasetError(f"{where}: init ({ikey!r}) holds {len(inits)} rows but there are {N} demos")

    demos = []
    for i in range(N):
        at = f"{where}, demo {i}"

        def cut(a, src):
            a = _as_2d(a)
            if lengths is None:
                return a
            n = int(lengths[i])
            if n < 0 or n > a.shape[0]:
                raise DatasetError(f"{at}: length ({lkey!r}) is {n} but {src!r} has only {a.shape[0]} steps")
            return a[:n]

        if use_split:
            ka, acts = sources["actions"]
            ah, ar, src = _split(at, env, cut(acts[i], ka), ka)
        else:
            (kh, xh), (kr, xr) = sources["actions_human"], sources["actions_robot"]
            ah, ar = cut(xh[i], kh), cut(xr[i], kr)
            src = {"actions_human": repr(kh), "actions_robot": repr(kr)}
        o = cut(obs[i], obs_key)
        src["obs"] = repr(obs_key)
        d = _Demo(name=str(i), obs=o, ah=ah, ar=ar, init=None, strategy=0, src=src)
        if strategies is not None:
            d.strategy = _strategy_value(strategies[i], env, at, f"array {skey!r}")
        if inits is not None:
            d.init, d.src["init"] = inits[i], repr(ikey)
        demos.append(d)
    return demos


# ----------------------------------------------------------------------------------------------- entry
def make_task_env(task: str):
    import cogail_envs

    try:
        return cogail_envs.make_env(task)
    except ImportError:
        raise ConfigError(f"task {task!r} is not built yet in this version: import demonstrations for "
                          f"{', '.join(t for t in cogail_envs.TASKS if t != task)} instead")


def _write_checked(path: Path, src: Path, env, demos: list) -> Demos:
    """Write ``demos`` to ``path`` in the project's schema and read them back through the loader's checks."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs.update(task=env.name, schema_version=SCHEMA_VERSION, obs_dim=env.observation_size,
                       human_action_dim=env.human_action_size, robot_action_dim=env.robot_action_size,
                       init_dim=env.init_size, num_demos=len(demos), mixture="imported", seed=0,
                       source=str(src))
        data = f.create_group("data")
        for i, d in enumerate(demos):
            g = data.create_group(f"demo_{i}")
            g.create_dataset("obs", data=d.obs.astype(np.float32))
            g.create_dataset("actions_human", data=d.ah.astype(np.float32))
            g.create_dataset("actions_robot", data=d.ar.astype(np.float32))
            if d.init is not None:
                g.create_dataset("init", data=np.asarray(d.init, np.float32))
            g.attrs["strategy"] = int(d.strategy)
            g.attrs["num_samples"] = int(d.obs.shape[0])
            g.attrs["source_demo"] = d.name
    return load_demos(path, env)


def import_demos(src: str | os.PathLike, out: str | os.PathLike, task: str, mapping: dict | None = None,
                 env=None) -> ImportSummary:
    """Convert ``src`` (HDF5 or .npz) into the project's schema at ``out``; validate it against ``task``."""
    src, out = Path(src), Path(out)
    mapping = check_mapping(dict(mapping or {}), "the key mapping")
    env = env or make_task_env(task)
    kind = _file_kind(src)
    if out.exists() and out.resolve() == src.resolve():
        raise ConfigError(f"--out {out} is the input file: write the converted file somewhere else")
    if kind == "npz" and out.suffix == ".npz":
        raise ConfigError(f"--out {out} should be an .hdf5 file (the project's format), not .npz")
    demos = _read_hdf5(src, env, mapping) if kind == "hdf5" else _read_npz(src, env, mapping)
    if not demos:
        raise DatasetError(f"input file {src} holds no demonstrations: give a file with at least one (or, if it "
                           "has them elsewhere, say where with --key or --map)")
    trimmed = 0
    for d in demos:
        at = f"input file {src}, demo {d.name}"
        d.obs, d.ah, d.ar = (np.asarray(x) for x in (d.obs, d.ah, d.ar))
        trimmed += _check_demo(d, env, at)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f"{out.name}.{os.getpid()}.tmp")
    try:
        loaded = _write_checked(tmp, src, env, demos)
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)  # a failed write or check leaves nothing behind
    counts = np.bincount(loaded.strategy, minlength=env.num_strategies + 1).tolist()
    return ImportSummary(src=str(src), out=str(out), kind=kind, num=loaded.num,
                         mean_length=float(loaded.length.mean()), strategies=counts,
                         with_init=sum(d.init is not None for d in demos), trimmed_obs=trimmed)


__all__ = ["import_demos", "parse_keys", "load_mapping", "check_mapping", "ImportSummary", "FIELDS"]
