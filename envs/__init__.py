"""cogail_envs: the task API (:mod:`.registry`) and the built-in collaboration tasks, one package each.

``get_task(name_or_reference)`` returns a :class:`Task`; ``make_env`` builds its environment. A task from
your own package is ``my_pkg.my_module:TASK`` (``docs/tasks.md``).
"""
from __future__ import annotations

from .base import CollabEnv, jitted
from .registry import (Task, Team, UnknownTaskError, builtin_task_names, get_task, make_env, register_task,
                       task_names, team_of)

__all__ = ["CollabEnv", "Task", "Team", "UnknownTaskError", "builtin_task_names", "get_task", "jitted", "make_env",
           "register_task", "task_names", "team_of"]
