"""cogail_envs: the collaboration tasks (installed from the repository's ``envs/`` folder)."""
from __future__ import annotations

import importlib

from .base import CollabEnv

TASKS = {
    "fetchq": ("fetchq", "FetchQuest"),
    "handover": ("handover", "Handover"),
    "seqmanip": ("seqmanip", "SeqManip"),
}


class UnknownTaskError(ValueError):
    pass


def make_env(task: str, **kwargs) -> CollabEnv:
    """Build a task environment by name (``fetchq``, ``handover``, ``seqmanip``)."""
    if task not in TASKS:
        raise UnknownTaskError(f"unknown task {task!r}: choose one of {', '.join(TASKS)}")
    module, cls = TASKS[task]
    mod = importlib.import_module(f"{__name__}.{module}")
    return getattr(mod, cls)(**kwargs)


__all__ = ["CollabEnv", "TASKS", "make_env", "UnknownTaskError"]
