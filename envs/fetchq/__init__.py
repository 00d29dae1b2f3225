"""2D-Fetch-Quest (pure JAX): the env (:mod:`.env`), its scripted team (:mod:`.team`) and settings (:mod:`.config`)."""
from ..registry import Task
from . import config
from .env import FetchQuest
from .team import TEAM

TASK = Task(
    name="fetchq", env=FetchQuest, team=TEAM, default_config=config.default_config, budgets=config.BUDGETS,
    splits=config.SPLITS, mixtures=config.MIXTURES, paper=config.PAPER,
    legend=(("#f07828", "you (human)"), ("#28a0e6", "robot")),
    description="2D-Fetch-Quest: two agents open each other's rooms to fetch two treasures (4 strategies)",
)

__all__ = ["TASK", "FetchQuest"]
