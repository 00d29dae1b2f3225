"""``python -m cogail_envs.overcooked``: print the figures of ``docs/overcooked.md`` (:mod:`.report`)."""
from .report import main

main()
