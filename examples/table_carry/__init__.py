"""Table-Carry (pure JAX): two agents carry a long table through a door. A worked example of a task defined
outside ``cogail_envs``: the env (:mod:`.env`), its scripted team (:mod:`.team`) and settings (:mod:`.config`).

Use it as ``--task examples.table_carry:TASK`` from the repository's root (``docs/tasks.md``); two people record
demonstrations of it with ``cogail collect --task examples.table_carry:TASK`` (``docs/collect.md``).
"""
from cogail_envs.registry import Task

from . import config
from .env import TableCarry
from .team import TEAM

TASK = Task(
    name="table_carry", env=TableCarry, team=TEAM, default_config=config.default_config, budgets=config.BUDGETS,
    splits=config.SPLITS, legend=(("#f07828", "you (human end)"), ("#28a0e6", "robot end")),
    description="Table-Carry: two agents carry a long table through a door; whose end goes first (2 strategies)",
)

__all__ = ["TASK", "TableCarry"]
