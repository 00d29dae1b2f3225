"""HR-SeqManip (MuJoCo MJX): the env (:mod:`.env`), its scripted team (:mod:`.team`) and settings (:mod:`.config`)."""
from ..registry import Task
from . import config
from .env import SeqManip
from .team import TEAM

TASK = Task(
    name="seqmanip", env=SeqManip, team=TEAM, default_config=config.default_config, budgets=config.BUDGETS,
    splits=config.SPLITS, paper=config.PAPER, cameras=("front", "drawer"),
    legend=(("#2f6fd6", "you (human, near camera)"), ("#d64040", "robot")),
    # Co-GAIL's update on an unloaded CPU, env steps/s per core (its env step costs 1.5x handover's)
    cpu_steps_per_s=1000.0,
    train_env=config.TRAIN_ENV,
    description="HR-SeqManip: put a bar into a drawer, handed over or placed by the human (2 strategies)",
)

__all__ = ["TASK", "SeqManip"]
