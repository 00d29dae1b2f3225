"""Overcooked-AI on JaxMARL (pure JAX), learned from people: the env (:mod:`.env`), its kitchens (:mod:`.kitchen`),
the human-human trials of Carroll et al. 2019 as datasets (:mod:`.trials`) and settings (:mod:`.config`).

``overcooked`` is the cramped room; the other kitchens are the tasks ``overcooked_<kitchen>`` (``VARIANTS``).
No scripted team: the training, validation and test sets are people's trials (``Task.recorded``).
"""
import functools

from ..registry import Task
from . import config, trials
from .env import STAY, Overcooked
from .kitchen import KITCHENS

# cogail play: the keys of the 6 actions (up 0, down 1, right 2, left 3, stay 4, interact 5); no key: stay. The
# people of the trials played at about 6.7 steps per second (1200 steps in 180 s).
PLAY_KEYS = {"ArrowUp": 0, "KeyW": 0, "ArrowDown": 1, "KeyS": 1, "ArrowRight": 2, "KeyD": 2, "ArrowLeft": 3, "KeyA": 3,
             "Space": 5}
LEGEND = (("#f07828", "you (human, player 0)"), ("#28a0e6", "robot (player 1)"))


def _task(kitchen: str) -> Task:
    name = "overcooked" if kitchen == "cramped_room" else f"overcooked_{kitchen}"
    env = Overcooked if kitchen == "cramped_room" else functools.partial(Overcooked, kitchen=kitchen)
    return Task(
        name=name, env=env, team=None, recorded=trials.recorded, default_config=config.default_config,
        play_keys=PLAY_KEYS, play_idle=STAY, play_hz=7.0,
        play_help="move: arrow keys or WASD (gamepad: left stick)\nSpace: interact (pick up, put down, serve; "
                  "gamepad: A)",
        budgets=config.BUDGETS, splits=config.SPLITS[kitchen], legend=LEGEND,
        paper={"h_proxy": config.PUBLISHED[kitchen], "source": config.PUBLISHED_SOURCE},
        description=f"Overcooked-AI, {kitchen.replace('_', ' ')}: two cooks make and serve onion soups (JaxMARL), "
                    "learned from the human-human trials of Carroll et al. 2019",
    )


TASK = _task("cramped_room")
VARIANTS = tuple(_task(k) for k in KITCHENS if k != "cramped_room")

__all__ = ["KITCHENS", "TASK", "VARIANTS", "Overcooked"]
