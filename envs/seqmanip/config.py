"""HR-SeqManip's settings: ``default_config()`` (the paper's budget, 1000 generated demonstrations where the paper
had 120, plus what validation chose; the reasons are in ``docs/settings.md``), the larger budget, the dataset split
sizes and the paper's figures."""
from __future__ import annotations


def default_config() -> dict:
    """TrainConfig fields of a seqmanip run (1000 updates x 10000 env steps per seed, laid out as 1000 envs x 10
    steps; LSGAN discriminator)."""
    return dict(
        total_steps=10_000_000, num_envs=1000, unroll_length=10, updates_per_call=10, checkpoint_every=30,
        bc_steps=40_000, obs_std_floor=0.1, num_demos=1000, disc_instance_noise=True, policy_cooldown=400,
        bc_coef=10.0, policy_ema=0.995, train_varied=60, init_log_std=-2.3, bc_std=True, disc_loss="lsgan",
        multi_device="per_device", obs_frame="object", separate_towers=True,
    )


# the training split's robot starts turned up to 1.0 rad and up to 8 cm above or below its home height (the env's
# options; validation, test and the training rollouts start it at home): chosen on validation (docs/settings.md)
TRAIN_ENV = {"robot_start_yaw": 1.0, "robot_start_z": 0.08}
BUDGETS = {"2x": {"total_steps": 20_000_000, "train_varied": 100, "policy_ema": 0.98}}
# the validation split is larger: replay success moves by about 5 points per seed between checkpoints on 100
# episodes, and the best of 34 such checkpoints was a high draw by about as much (docs/notes.md)
SPLITS = {"train": 120, "validation": 300, "test": 60}
PAPER = {
    "replay": {"bc_single": (15.0, 2.3), "bc_gail": (16.6, 7.1), "ma_gail": (21.0, 3.7), "ma_infogail": (26.6, 8.8),
               "diayn": (18.3, 7.1), "cogail": (40.0, 8.2)},
    "interpolation": {"ma_gail": (46.2, 10.3), "ma_infogail": (51.7, 7.5), "diayn": (45.4, 7.9),
                      "cogail": (31.6, 2.5)},
}
