"""The task API: what defines a collaboration task, and the registry the rest of the code asks.

A task is one :class:`Task` value: its environment (a :class:`~cogail_envs.base.CollabEnv`, i.e. brax's
``Env`` plus the collaboration extras), its scripted human-human team (optional: a task without one trains
and is evaluated from demonstration files), its per-task settings (``default_config()``: any
``TrainConfig`` field, the task's paper settings; ``budgets``: named overrides of them), the sizes of its
default dataset splits, and what ``cogail play`` / ``cogail video`` need to show it. ``docs/tasks.md``
states the contract in full.

Where tasks come from, in the order :func:`get_task` looks:

* tasks registered in this process with :func:`register_task` (a notebook, a test, a plugin's import);
* the built-in tasks: every subpackage of ``cogail_envs`` that defines ``TASK`` (found by scanning the
  package, so that nothing here names one), and the tasks of its ``VARIANTS`` (a tuple of more ``Task`` values,
  e.g. the other kitchens of one game, each under its own name);
* the ``cogail.tasks`` entry-point group of installed distributions (``name = "my_pkg.my_module:TASK"``);
* a reference ``"my_pkg.my_module:attr"`` (or ``"path/to/file.py:attr"``), whose attribute is a ``Task``
  or a function returning one; the current directory is importable for it, as for ``python -m``.

A run records the reference it was trained with (``TrainConfig.task``), so evaluation, play and video find
the same task again.
"""
from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import os
import pkgutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

ENTRY_POINT_GROUP = "cogail.tasks"
DEFAULT_SPLITS = {"train": 60, "validation": 100, "test": 60}


class UnknownTaskError(ValueError):
    """A task name or reference that does not resolve; the message says what to pass instead."""


@dataclass(frozen=True)
class Team:
    """A scripted human-human team, pure JAX and vmappable (one episode per call; the generator vmaps it).

    ``init(env, rng, mix, variation) -> (team_state, strategy)``: draw an episode's plan; ``mix`` is a vector of
    strategy probabilities (``len(env.strategy_names)``), ``strategy`` the drawn id (1..S). ``variation`` (an
    int32, possibly traced) varies the HUMAN only (:mod:`cogail_envs.variations`); a team that does not
    implement variations sets ``variations=False`` and ignores it.
    ``act(env, team_state, state, rng) -> (team_state, action)``: both agents' action ``concat(a_H, a_R)``.
    ``partner_can_follow``: ``init`` also takes ``variation | variations.FOLLOWING_PARTNER`` (a robot that
    follows the human's apparent strategy under a change of mind, for the training sets' varied humans).
    ``held_out``: ``init`` also takes ``variation | variations.POSE_HELDOUT``, an episode whose object pose or
    place lies in the team's held-out slice (outside every training, validation and test episode's range), and
    ``variation | variations.pose_slice(axis)`` for each axis of ``held_out_slices`` (``variations.POSE_AXES``):
    that one degree of freedom beyond its range, the others in range (the ``pose_heldout_<axis>`` evaluation sets). ``prompt_robot``: ``init`` also takes ``variation | variations.PROMPT_ROBOT``,
    a robot at the prompt end of its ranges; the training split's demonstrations are made so.

    Closed-loop co-play (:mod:`cogail_jax.eval.coplay`) takes each agent of the team alone, against a partner
    that is not its scripted teammate; both are optional (a task without them has no scripted co-play partner):

    * ``human_act(env, team_state, state, rng) -> (team_state, a_H)``: the scripted human (and its variation),
      seeing only what a person at the table sees: the physics state and its own plan and memory in
      ``team_state``, never the robot's plan or phase;
    * ``robot_act(env, team_state, state, rng) -> (team_state, a_R)``: the scripted robot, reading only the
      physics state and its own fields: it infers from the state what the human does (has lifted, holds still,
      has gone) and which strategy the human's moves show, never the human's phase or the shared plan.

    Co-play gives each agent its own team state, from ``init`` with independent keys, so the robot's never holds
    the human's plan."""

    init: Callable
    act: Callable
    variations: bool = False
    partner_can_follow: bool = False
    held_out: bool = False
    held_out_slices: tuple = ()
    prompt_robot: bool = False
    human_act: Callable | None = None
    robot_act: Callable | None = None


@dataclass(frozen=True)
class Task:
    """One collaboration task (see the module docstring and ``docs/tasks.md``).

    ``env(**kwargs)`` builds the environment (``max_episode_steps=`` must be accepted). ``default_config()``
    returns ``TrainConfig`` fields: the task's own settings, used whenever the task is trained. ``budgets``
    names overrides of them (``cogail train --budget NAME``; ``paper`` is always the defaults alone).
    ``splits``: the number of episodes of each default dataset split the team generates. ``mixtures``: named
    strategy mixtures (``--mix NAME``) besides ``uniform``. ``paper``: the paper's figures for the task
    (``{"replay": {method: (mean, std)}, "interpolation": {...}}``), where it has them. ``cameras``: the
    render cameras ``cogail play`` shows side by side (``()``: the env's default view). ``legend``: what
    the play page's colours mean, ``((css colour, label), ...)``. ``spots``: three ``State.metrics`` names, the
    x, y, z of where an episode's strategy happened (e.g. a handover), drawn for successful interpolation
    rollouts (RUN/<task>_spots.png, the paper's Fig. 4a). ``cpu_steps_per_s``: env steps per second
    and core of a training update on a CPU, for the warning before a long CPU run (0: no warning). ``train_env``:
    env options (``env(**train_env)``) the training split's demonstrations are made with, e.g. a wider range of
    starts; validation, test, the evaluation sets and the training rollouts use the plain env. ``recorded``: a task
    whose datasets are people's recordings, not its team's: ``recorded(env, split) -> dict`` returns the split's
    episodes (``obs``, ``actions_human``, ``actions_robot`` padded (N, T, .); ``length``, ``strategy``, ``init``,
    ``final_metrics`` as the generator's; ``source``: attrs naming where they came from, e.g. the file and its
    hash), and ``cogail data`` writes them as the split's file. ``play_keys`` / ``play_idle`` / ``play_help``: for a
    discrete human, the keys of ``cogail play`` (``KeyboardEvent.code`` -> choice), its choice when no key is pressed,
    and the page's help line; ``play_hz``: the steps per second ``cogail play`` runs at by default."""

    name: str
    env: Callable[..., Any]
    team: Team | None = None
    default_config: Callable[[], dict] = dict
    budgets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    splits: Mapping[str, int] = field(default_factory=lambda: dict(DEFAULT_SPLITS))
    mixtures: Mapping[str, tuple] = field(default_factory=dict)
    paper: Mapping[str, Any] = field(default_factory=dict)
    cameras: tuple = ()
    spots: tuple = ()
    legend: tuple = (("#f07828", "you (human)"), ("#28a0e6", "robot"))
    cpu_steps_per_s: float = 0.0
    description: str = ""
    train_env: Mapping[str, Any] = field(default_factory=dict)
    recorded: Callable[..., Mapping[str, Any]] | None = None
    play_keys: Mapping[str, int] = field(default_factory=dict)
    play_idle: int = 0
    play_help: str = ""
    play_hz: float = 15.0


    def make_env(self, **kwargs):
        env = self.env(**kwargs)
        if getattr(env, "name", None) != self.name:
            raise UnknownTaskError(f"task {self.name!r} builds an env named {getattr(env, 'name', None)!r}: set the env "
                                   f"class's name to {self.name!r}")
        return env

    def make_training_env(self, **kwargs):
        """The env the training split's demonstrations are made in: ``make_env`` with ``train_env``'s options."""
        return self.make_env(**{**dict(self.train_env), **kwargs})

    def config(self, budget: str = "paper") -> dict:
        """The task's settings under a budget: ``default_config()`` updated with ``budgets[budget]``."""
        if budget != "paper" and budget not in self.budgets:
            names = ", ".join(["paper", *self.budgets])
            raise UnknownTaskError(f"task {self.name} has no budget {budget!r}: choose one of {names}")
        return {**self.default_config(), **dict(self.budgets.get(budget, {}))}

    def split_size(self, split: str) -> int:
        return int({**DEFAULT_SPLITS, **dict(self.splits)}[split])

    @property
    def has_team(self) -> bool:
        return self.team is not None


_REGISTRY: dict[str, Task] = {}
_BUILTIN: dict[str, str] | None = None  # task name -> module, found by scanning cogail_envs


def register_task(task: Task, replace: bool = False) -> Task:
    """Make ``task`` known by its name in this process (``get_task(task.name)``); returns it."""
    if not isinstance(task, Task):
        raise TypeError(f"register_task takes a cogail_envs.Task, got {type(task).__name__}")
    old = _REGISTRY.get(task.name)
    if old is not None and old is not task and not replace:
        raise UnknownTaskError(f"a task named {task.name!r} is registered already: give yours another name")
    _REGISTRY[task.name] = task
    return task


def _builtin_modules() -> dict[str, str]:
    global _BUILTIN
    if _BUILTIN is None:
        pkg = importlib.import_module(__package__)
        _BUILTIN = {m.name: f"{__package__}.{m.name}" for m in pkgutil.iter_modules(pkg.__path__) if m.ispkg}
    return _BUILTIN


def _entry_points() -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _builtin_tasks() -> dict[str, Task]:
    """Every built-in task by name: each subpackage's ``TASK`` and its ``VARIANTS``."""
    out = {}
    for mod in _builtin_modules().values():
        if (task := _module_task(mod)) is not None:
            out[task.name] = task
            for v in getattr(importlib.import_module(mod), "VARIANTS", ()):
                out[v.name] = v
    return out


def builtin_task_names() -> tuple[str, ...]:
    """The built-in tasks (the subpackages of ``cogail_envs`` that define ``TASK``, and their ``VARIANTS``), sorted."""
    return tuple(sorted(_builtin_tasks()))


def task_names() -> tuple[str, ...]:
    """Every task known by name: registered, built-in and entry points."""
    return tuple(sorted({*_REGISTRY, *builtin_task_names(), *_entry_points()}))


def _module_task(module: str) -> Task | None:
    mod = importlib.import_module(module)
    task = getattr(mod, "TASK", None)
    return task if isinstance(task, Task) else None


def _import_module(ref: str, module: str):
    if module.endswith(".py") or os.sep in module or "/" in module:
        path = Path(module)
        if not path.exists():
            raise UnknownTaskError(f"task {ref!r}: file {path} does not exist: pass an existing file or module")
        package = path.is_dir() or path.name == "__init__.py"  # a package: its relative imports must work
        if path.is_dir():
            path = path / "__init__.py"
        name = f"cogail_user_task_{abs(hash(str(path.resolve())))}"
        if name in sys.modules:
            return sys.modules[name]
        found = importlib.util.spec_from_file_location(
            name, path, submodule_search_locations=[str(path.parent)] if package else None)
        mod = importlib.util.module_from_spec(found)
        sys.modules[name] = mod
        found.loader.exec_module(mod)
        return mod
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.append(os.getcwd())  # as `python -m` does: a package in the current directory is importable
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        raise UnknownTaskError(f"task {ref!r}: module {module!r} cannot be imported ({e}): install your package or "
                               "run from the directory that holds it")


def _resolve(obj, ref: str) -> Task:
    if callable(obj) and not isinstance(obj, Task):
        obj = obj()
    if not isinstance(obj, Task):
        raise UnknownTaskError(f"task {ref!r} is a {type(obj).__name__}, not a cogail_envs.Task: point it at a Task "
                               "or at a function returning one")
    return obj


def get_task(ref: str | Task) -> Task:
    """The task named ``ref`` (registered, built-in or entry point), or loaded from a ``"module:attr"``
    reference (then also registered under its name)."""
    if isinstance(ref, Task):
        return ref
    if ref in _REGISTRY:
        return _REGISTRY[ref]
    if ":" in ref:
        module, _, attr = ref.rpartition(":")
        mod = _import_module(ref, module)
        if not hasattr(mod, attr):
            raise UnknownTaskError(f"task {ref!r}: module {module!r} has no attribute {attr!r}: name the Task in it")
        task = _resolve(getattr(mod, attr), ref)
        existing = _REGISTRY.get(task.name)
        if existing is None or existing is not task:
            _REGISTRY[task.name] = task
        return task
    builtin = _builtin_modules()
    if ref in builtin and (task := _module_task(builtin[ref])) is not None:
        return task
    if (task := _builtin_tasks().get(ref)) is not None:
        return task
    eps = _entry_points()
    if ref in eps:
        return register_task(_resolve(eps[ref].load(), ref), replace=True)
    raise UnknownTaskError(f"unknown task {ref!r}: choose one of {', '.join(task_names())}, or give your own as "
                           "my_pkg.my_module:TASK")


def make_env(ref: str | Task, **kwargs):
    """Build the environment of a task (a name or a reference, see :func:`get_task`)."""
    return get_task(ref).make_env(**kwargs)


def team_of(env) -> Team:
    """The scripted team of ``env``'s task; an error naming the fix if the task has none."""
    task = get_task(env.name)
    if task.team is None:
        raise UnknownTaskError(f"task {env.name} has no scripted team to generate demonstrations: give your own "
                               "with --demos, --validation and --heldout (see `cogail import`)")
    return task.team


def replace(task: Task, **changes) -> Task:
    """A copy of ``task`` with some fields changed (``dataclasses.replace``)."""
    return dataclasses.replace(task, **changes)
