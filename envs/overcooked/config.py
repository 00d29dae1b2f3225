"""Overcooked's settings: ``default_config()`` (a starting point: 400-step episodes, discrete actions), the
budgets, and the sizes of the people's splits (:mod:`.trials`; shown only, the files decide)."""
from __future__ import annotations


def default_config() -> dict:
    """TrainConfig fields of an overcooked run (320 updates x 25,600 env steps per seed, LSGAN discriminator)."""
    return dict(
        total_steps=2_048_000, num_envs=64, unroll_length=400, updates_per_call=5, checkpoint_every=10,
        bc_steps=3000, disc_loss="lsgan", entropy_coef=0.01, history=4,
    )


# named overrides of default_config() (`cogail train --budget NAME`, `make train BUDGET=NAME`)
BUDGETS = {"quick": {"total_steps": 256_000}}
# 400-step episodes per split of each kitchen's trials (docs/overcooked.md, "Datasets"; the files decide)
SPLITS = {
    "cramped_room": {"train": 18, "validation": 6, "test": 24},
    "asymmetric_advantages": {"train": 21, "validation": 6, "test": 24},
    "coordination_ring": {"train": 18, "validation": 6, "test": 24},
    "forced_coordination": {"train": 12, "validation": 6, "test": 18},
    "counter_circuit": {"train": 18, "validation": 6, "test": 21},
}
