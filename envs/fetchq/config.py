"""2D-Fetch-Quest's settings: ``default_config()`` (the paper's, plus what validation chose; the reasons are
in ``docs/settings.md``), the larger or smaller budgets, the dataset split sizes, the paper's strategy
mixtures and figures."""
from __future__ import annotations


def default_config() -> dict:
    """TrainConfig fields of a fetchq run (1000 updates x 6016 env steps per seed, BCE discriminator)."""
    return dict(
        total_steps=6_016_000, num_envs=64, unroll_length=94, scan_unroll=2, updates_per_call=10,
        checkpoint_every=30, bc_steps=3000, aux_lr_decay=True, train_varied=20, disc_loss="bce",
        multi_device="shard_map", obs_std_floor=1e-2,
    )


# named overrides of default_config() (`cogail train --budget NAME`, `make train BUDGET=NAME`)
BUDGETS = {"quick": {"total_steps": 902_400, "scan_unroll": 1}}
SPLITS = {"train": 60, "validation": 100, "test": 60}
# the paper's unbalanced strategy mixtures: D1 = {17, 17, 33, 33} %, D2 = {33, 33, 17, 17} %
MIXTURES = {"D1": (1 / 6, 1 / 6, 1 / 3, 1 / 3), "D2": (1 / 3, 1 / 3, 1 / 6, 1 / 6)}
# the paper's Table 1 (replay) and Table 2 (interpolation): (mean, std) in %
PAPER = {
    "replay": {"bc_single": (21.1, 1.9), "bc_gail": (27.2, 5.0), "ma_gail": (30.0, 3.4), "ma_infogail": (40.0, 1.7),
               "diayn": (44.4, 8.4), "cogail": (53.3, 4.4)},
    "interpolation": {"ma_gail": (78.5, 7.2), "ma_infogail": (80.2, 3.0), "diayn": (80.2, 3.6),
                      "cogail": (82.1, 3.1)},
}
