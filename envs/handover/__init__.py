"""HR-Handover (MuJoCo MJX): the env (:mod:`.env`), its scripted team (:mod:`.team`) and settings (:mod:`.config`)."""
from ..registry import Task
from . import config
from .env import Handover
from .team import TEAM

TASK = Task(
    name="handover", env=Handover, team=TEAM, default_config=config.default_config, budgets=config.BUDGETS,
    splits=config.SPLITS, paper=config.PAPER, cameras=("front", "top"),
    spots=("handover_x", "handover_y", "handover_z"),
    legend=(("#2f6fd6", "you (human, near camera)"), ("#d64040", "robot")),
    # Co-GAIL's update on an unloaded CPU, env steps/s per core (`cogail bench handover --sizes 64 --unroll 94`)
    cpu_steps_per_s=1500.0,
    train_env=config.TRAIN_ENV,
    description="HR-Handover: a human gripper fetches a bar and hands it to the robot (left / middle / right)",
)

__all__ = ["TASK", "Handover"]
