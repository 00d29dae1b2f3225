"""Table-Carry's settings: ``default_config()`` (``TrainConfig`` fields for a small CPU-friendly run) and the
sizes of the default dataset splits."""
from __future__ import annotations


def default_config() -> dict:
    """TrainConfig fields of a table_carry run: 40 updates x 512 env steps per seed, BCE discriminator."""
    return dict(
        total_steps=20_480, num_envs=16, unroll_length=32, updates_per_call=2, checkpoint_every=4, bc_steps=500,
        disc_loss="bce", obs_std_floor=0.01,
    )


# named overrides of default_config() (`cogail train --budget NAME`)
BUDGETS = {"longer": {"total_steps": 204_800, "checkpoint_every": 20}}
SPLITS = {"train": 40, "validation": 20, "test": 20}
