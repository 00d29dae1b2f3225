"""Overcooked's settings: ``default_config()`` (a starting point: 400-step episodes, discrete actions), the
budgets, and the sizes of the people's splits (:mod:`.trials`; shown only, the files decide)."""
from __future__ import annotations


def default_config() -> dict:
    """TrainConfig fields of an overcooked run (80 updates x 25,600 env steps per seed, LSGAN discriminator; the GAIL
    presets add the task's reward to the discriminator's, task_reward 1, and the observation's std is floored at 1,
    each chosen on validation: docs/settings.md)."""
    return dict(
        total_steps=2_048_000, num_envs=64, unroll_length=400, updates_per_call=5, checkpoint_every=10,
        bc_steps=3000, disc_loss="lsgan", entropy_coef=0.01, history=4, task_reward=1.0,
        # the grid's 0/1 planes are centred, not scaled up: with a 0.01 floor a plane the people never lit (a start
        # cell and facing, an item on an unused counter) read 100 when it lit, in a quarter of the task's starts
        obs_std_floor=1.0,
    )


# named overrides of default_config() (`cogail train --budget NAME`, `make train BUDGET=NAME`)
BUDGETS = {"quick": {"total_steps": 256_000}}
# 400-step episodes per split of each kitchen's trials, each window in both seats (docs/overcooked.md, "Datasets";
# the files decide)
SPLITS = {
    "cramped_room": {"train": 36, "validation": 12, "test": 48},
    "asymmetric_advantages": {"train": 42, "validation": 12, "test": 48},
    "coordination_ring": {"train": 36, "validation": 12, "test": 48},
    "forced_coordination": {"train": 24, "validation": 12, "test": 36},
    "counter_circuit": {"train": 36, "validation": 12, "test": 42},
}


# Carroll et al. (NeurIPS 2019), "Performance with human proxy model" (the H_proxy bar chart): reward over 400 steps
# (20 per soup), mean +- s.e. over 5 seeds of 100 games, per seat of the AI (0: player 0, 1: player 1), under the
# game's old dynamics. The plotted values, from the authors' repository HumanCompatibleAI/human_aware_rl (branch
# neurips2019 @ 2507b93), human_aware_rl/data/{ppo_runs/ppo_bc_models_performance, ppo_runs/ppo_sp_models_performance,
# bc_runs/best_bc_models_performance}.pickle (BC: BC_train with BC_test, one model: s.e. over its 100 games).
PUBLISHED_SOURCE = ("Carroll et al. 2019, 'Performance with human proxy model' figure; values from "
                    "HumanCompatibleAI/human_aware_rl@2507b93, human_aware_rl/data/{ppo_runs,bc_runs}/*_performance.pickle")
PUBLISHED = {  # kitchen -> method -> (seat 0 (mean, se), seat 1 (mean, se))
    "cramped_room": {"ppo_sp": ((96.8, 5.3), (111.2, 3.0)), "ppo_bc": ((156.4, 1.5), (163.9, 1.6)),
                     "bc": ((103.5, 3.4), (110.0, 3.4))},
    "asymmetric_advantages": {"ppo_sp": ((37.5, 4.6), (103.2, 3.0)), "ppo_bc": ((72.6, 19.4), (178.8, 2.7)),
                              "bc": ((136.5, 7.0), (137.5, 8.4))},
    "coordination_ring": {"ppo_sp": ((66.9, 11.1), (72.8, 10.3)), "ppo_bc": ((126.4, 3.2), (129.8, 3.6)),
                          "bc": ((59.0, 5.4), (70.0, 4.0))},
    "forced_coordination": {"ppo_sp": ((23.2, 2.7), (37.9, 7.4)), "ppo_bc": ((58.9, 3.0), (76.9, 2.3)),
                            "bc": ((20.5, 4.3), (31.0, 5.0))},
    "counter_circuit": {"ppo_sp": ((31.0, 1.6), (32.0, 3.3)), "ppo_bc": ((69.5, 2.2), (57.6, 2.5)),
                        "bc": ((38.0, 4.0), (44.0, 3.0))},
}
