"""Typed configuration: one dataclass, one source of truth for defaults, method presets as flag sets.

A run's config is resolved in layers (:func:`resolve`): these field defaults, then the task's own settings
(its ``default_config()``, under a named budget), then a JSON file of fields, then the command line."""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

METHODS = ("cogail", "ma_infogail", "ma_gail", "bc_gail", "bc_single", "diayn", "ppo_bc", "ppo_sp")
# the paper's six; the field's two baselines on people's data (Carroll et al. 2019) train on the task's own reward
PAPER_METHODS = METHODS[:6]
FIELD_METHODS = ("ppo_bc", "ppo_sp")
OBS_FRAMES = ("world", "both", "object")


class ConfigError(ValueError):
    """A configuration a user gave that cannot run; the message says what to change."""


@dataclass(frozen=True)
class TrainConfig:
    # what
    task: str = ""  # a task name (cogail_envs.task_names()) or your own, "my_pkg.my_module:TASK"
    method: str = "cogail"
    seeds: tuple[int, ...] = (300, 400, 500)
    demos: str | None = None  # training demonstrations (HDF5); default: generated and cached
    heldout: str | None = None  # test demonstrations for replay evaluation (default: the task's test split)
    validation: str | None = None  # validation demonstrations, for checkpoint selection (default: the task's own)
    num_demos: int = 0  # size of the generated default training set (0: the task's default split size)
    # our addition (0 = the paper): that many varied-human episodes of each of the robustness protocol's six
    # variations added to the default training set (robustness.ensure_varied_training_set; README, "Robustness")
    train_varied: int = 0
    mix: str = "uniform"  # strategy mixture of the default datasets (uniform, D1, D2)
    # the task's time limit in env steps, for training and evaluation (0: the task's own). Generated demonstrations
    # are made under the task's own limit either way.
    max_episode_steps: int = 0
    # budget
    total_steps: int = 6_000_000  # env steps per seed
    num_envs: int = 64
    unroll_length: int = 94  # num_envs * unroll_length env steps per update (~6000, the paper's buffer)
    # the rollout's, GAE's and the return normaliser's scans over the unroll, unrolled by this factor: fewer loop
    # iterations, each doing more (2 made fetchq's update 13 % faster on an H100; BENCHMARKS.md)
    scan_unroll: int = 1
    updates_per_call: int = 10  # updates fused into one jitted call (lax.scan)
    # the env batch as data parallelism (our addition, 1 = off): each seed's num_envs split into this many shards,
    # each rolling out its share and drawing its share of every minibatch, with the updates' gradients averaged
    # over the shards (algo/shards.py). A run on several devices (--devices) puts one shard per device; on one
    # device the shards run side by side with the same arithmetic
    env_shards: int = 1
    # how the seed axis runs on several devices (--devices): "shard_map" (one SPMD program), "per_device" (the
    # one-device program on each device, from threads) or "auto" (the task's default_config(), else per_device: an
    # MJX task's 2-device shard_map program crashes XLA's GPU compiler)
    multi_device: str = "auto"
    checkpoint_every: int = 30  # updates
    # PPO (co-policy)
    lr: float = 3e-4  # linear decay to 0 over the run
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ppo_epochs: int = 4
    num_minibatches: int = 4
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    max_grad_norm: float = 0.5
    init_log_std: float = -1.6  # std 0.2: the demonstrations are smooth; a noisier start is told apart at once
    # our addition (off = the paper's state-independent std from init_log_std): after BC pre-training, each action
    # dimension's std is the RMS of the cloned mean's residual on the demonstrations (the maximum-likelihood std of
    # the cloned Gaussian), clipped to [0.01, exp(init_log_std)]: the co-policy explores as much as the
    # demonstrators varied on each dimension (README, "HR-SeqManip")
    bc_std: bool = False
    reward_norm: bool = True
    policy_cooldown: int = 0  # the run's last N updates: PPO trains the critic only, the co-policy moves by the
    #   L_a / L_r steps alone (our addition, 0 = off; README, "HR-SeqManip")
    # PPO+BC (our addition, 0 = off): every PPO minibatch adds bc_coef x the squared error of the co-policy's
    # mean on an expert minibatch, both agents acting on psi's code of the expert history (without L_a: on the
    # demonstration's code, losses.expert_code). Unlike lambda_a /
    # lambda_r, whose separate Adam step is scale-free per tower, this weight sets the balance against the
    # discriminator's policy gradient inside one optimizer step (README, "HR-SeqManip")
    bc_coef: float = 0.0
    # the delivered policy (our addition, 0 = off): an exponential moving average of the co-policy's and psi's
    # parameters, updated after every update with this decay; checkpoints keep it beside the trained parameters,
    # and evaluation, play and video act with it (the average of a GAN's generator over its last iterates)
    policy_ema: float = 0.0
    obs_std_floor: float = 1e-2  # floor of the observation normaliser's std (0.1 for the MJX tasks' configs)
    # which observation features the networks read (our addition; the others normalise to 0): "world" the task's
    # own observation without the object-centric features (the env's ``object_frame_dims``: the object's pose in
    # each agent's frame and the reverse), "both" all of them, "object" the object-centric features instead of the
    # absolute orientations (the env's ``orientation_dims``: nothing that tells how the scene is turned)
    obs_frame: str = "both"
    # the observation's change since the previous step beside it (our addition): the actor, the critic and the
    # discriminator also read s_t - s_{t-1} of what they read, in units of the demonstrations' per-step change (0 at
    # an episode's first step), so a partner who holds still reads the same wherever and however they hold the object
    motion: bool = False
    # the co-policy's actor as two towers, one per agent, instead of one network with both agents' actions (our
    # addition; BC-GAIL and PPO_BC always have two, their human tower frozen): what the robot learns is not shaped by
    # fitting the human's actions, which depend on how the human holds the object
    separate_towers: bool = False
    # discriminator
    disc_loss: str = "auto"  # "bce" | "lsgan" | "auto" (the task's default_config(), else lsgan)
    disc_lr: float = 3e-4
    gp_coef: float = 10.0
    # instance noise (our addition, off = the paper): the expert actions the discriminator sees get the policy's
    # current Gaussian action noise and the same clip to [-1, 1] as the policy's executed actions, so that the
    # discriminator cannot tell the two apart by the noise alone (scripted demos are near noise-free on some
    # dims, e.g. the gripper's exactly +-1) and its reward has to be about what the agents do (README)
    disc_instance_noise: bool = False
    # the task's own reward (e.g. 20 per soup served) added with this weight to the discriminator's (our addition, 0 =
    # the paper: a GAIL preset imitates the people alone); the PPO presets (ppo_bc, ppo_sp) train on the task's reward
    # alone and ignore it
    task_reward: float = 0.0
    # strategy code, psi, aux losses
    code_dim: int = 2
    code_grid: int = 5
    code_noise: float = 0.2
    history: int = 4  # K: psi reads s_{t-K..t} and a^H_{t-1}
    lambda_z: float = 0.05  # the paper gives no value; 1.0 erodes interpolation (README)
    lambda_a: float = 1.0
    diversity_coef: float = 0.1  # DIAYN: weight of the diversity reward
    lambda_r: float = 1.0  # our addition: robot-action reconstruction on expert data with psi's code (0 = paper;
    #   without L_a, where psi never learns the demonstrations' codes, with each demonstration's code from BC
    #   pre-training, held fixed: losses.expert_code)
    aux_lr: float = 3e-4
    # the aux (psi, L_z / L_a / L_r) and discriminator learning rates decay linearly to 0 over the run, as PPO's
    # does (off = constant, the paper's code)
    aux_lr_decay: bool = False
    inner_updates: int = 4  # discriminator / psi updates per train step (Algorithm 1's "update step = 1..n")
    inner_batch: int = 256
    # behaviour-cloning pre-training of the co-policy (and of psi, in presets with L_a) on the demonstrations
    bc_steps: int = 0
    bc_lr: float = 1e-3
    # evaluation
    eval_codes: int = 100

    # --- derived ---------------------------------------------------------------------------------
    @property
    def steps_per_update(self) -> int:
        return self.num_envs * self.unroll_length

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.steps_per_update)

    # --- method presets: which terms are on (losses.objective_terms assembles them) ------------
    @property
    def multi_device_mode(self) -> str:
        if self.multi_device != "auto":
            return self.multi_device
        return task_default(self.task, "multi_device", "per_device")

    @property
    def use_code(self) -> bool:  # strategy code z and psi
        return self.method in ("cogail", "ma_infogail", "diayn")

    @property
    def use_lz(self) -> bool:  # L_z through the human action mean
        return self.method in ("cogail", "ma_infogail")

    @property
    def use_la(self) -> bool:  # L_a on expert data
        return self.method == "cogail"

    @property
    def task_rl(self) -> bool:  # PPO on the task's own reward, no discriminator (the field's baselines)
        return self.method in FIELD_METHODS

    @property
    def use_diversity(self) -> bool:  # DIAYN reward log q(z|h) - log p(z) for the co-policy
        return self.method == "diayn"

    @property
    def bc_only(self) -> bool:  # no environment interaction, no discriminator
        return self.method == "bc_single"

    @property
    def two_towers(self) -> bool:  # the actor's human and robot towers are separate networks
        return self.separate_towers or self.freeze_human

    @property
    def freeze_human(self) -> bool:  # BC-GAIL, PPO_BC: the human tower is trained by BC only, then frozen
        return self.method in ("bc_gail", "ppo_bc")

    def validate(self) -> "TrainConfig":
        if not self.task:
            from cogail_envs import task_names

            raise ConfigError(f"no task given: pass --task, one of {', '.join(task_names())} or my_pkg.my_module:TASK")
        from cogail_envs import UnknownTaskError, get_task

        try:
            mixtures = get_task(self.task).mixtures
        except UnknownTaskError as e:
            raise ConfigError(str(e))
        if self.mix != "uniform" and self.mix not in mixtures:
            raise ConfigError(f"unknown mixture {self.mix!r} for {self.task}: choose one of "
                              f"{', '.join(['uniform', *mixtures])}")
        if self.method not in METHODS:
            raise ConfigError(f"unknown method {self.method!r}: choose one of {', '.join(METHODS)}")
        if not self.seeds:
            raise ConfigError("no seeds given: pass --seeds, e.g. --seeds 300,400,500")
        if any(not 0 <= s < 2 ** 32 for s in self.seeds):
            raise ConfigError(f"seeds {list(self.seeds)}: a seed is an integer from 0 to {2 ** 32 - 1}")
        for name in ("total_steps", "num_envs", "unroll_length", "scan_unroll", "updates_per_call", "checkpoint_every",
                     "ppo_epochs", "num_minibatches", "inner_updates", "inner_batch", "eval_codes"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"{name.replace('_', '-')} must be positive, got {getattr(self, name)}")
        if self.env_shards <= 0 or self.num_envs % self.env_shards or self.inner_batch % self.env_shards:
            raise ConfigError(f"env-shards ({self.env_shards}) must be positive and divide num-envs ({self.num_envs}) "
                              f"and inner-batch ({self.inner_batch}): pick a divisor of both")
        if self.env_shards > 1 and (self.steps_per_update // self.env_shards) % self.num_minibatches:
            raise ConfigError(
                f"each of the {self.env_shards} env-shards' steps per update ({self.steps_per_update // self.env_shards}) "
                f"must be divisible by num-minibatches ({self.num_minibatches})")
        if self.obs_frame not in OBS_FRAMES:
            raise ConfigError(f"obs_frame must be one of {', '.join(OBS_FRAMES)}, got {self.obs_frame!r}")
        if self.motion and self.history < 2:
            raise ConfigError(f"motion reads the change since the previous step from psi's history, which needs "
                              f"history >= 2, got {self.history}: set history=2 or more, or motion=false")
        if not self.obs_std_floor > 0:
            raise ConfigError(f"obs_std_floor must be positive, got {self.obs_std_floor}")
        if self.multi_device not in ("auto", "shard_map", "per_device"):
            raise ConfigError(f"multi_device must be auto, shard_map or per_device, got {self.multi_device!r}")
        if self.max_episode_steps < 0:
            raise ConfigError(f"max_episode_steps must be >= 0 (0: the task's own time limit), got {self.max_episode_steps}")
        if self.num_demos < 0:
            raise ConfigError(f"num_demos must be >= 0 (0: the task's default), got {self.num_demos}")
        if self.train_varied < 0:
            raise ConfigError(f"train_varied must be >= 0 (varied-human episodes per variation), got {self.train_varied}")
        if self.train_varied and self.demos:
            raise ConfigError(f"train_varied={self.train_varied} (e.g. from the task's settings) adds varied humans "
                              "to the task's default training set, not to --demos: add --set train_varied=0 to train "
                              "on your file alone")
        if self.policy_cooldown < 0:
            raise ConfigError(f"policy_cooldown must be >= 0, got {self.policy_cooldown}")
        if not 0 <= self.policy_ema < 1:
            raise ConfigError(f"policy_ema must be in [0, 1) (a decay per update; 0 = off), got {self.policy_ema}")
        if self.bc_coef < 0:
            raise ConfigError(f"bc_coef must be >= 0, got {self.bc_coef}")
        if self.bc_std and not self.bc_steps:
            raise ConfigError("bc_std sets the action std from BC pre-training: give bc_steps > 0 too")
        if self.history < 0 or self.bc_steps < 0:
            raise ConfigError("history and bc-steps must be >= 0")
        if self.steps_per_update % self.num_minibatches:
            raise ConfigError(
                f"num-envs x unroll-length ({self.steps_per_update}) must be divisible by num-minibatches "
                f"({self.num_minibatches})")
        if self.disc_loss not in ("auto", "bce", "lsgan"):
            raise ConfigError(f"disc-loss must be auto, bce or lsgan, got {self.disc_loss!r}")
        return self

    def replace(self, **kw) -> "TrainConfig":
        return dataclasses.replace(self, **kw)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        d = dict(d)
        for key, value in REMOVED.items():  # a run's config.json from before a field was removed
            if key in d and (got := d.pop(key)) != value:
                raise ConfigError(f"config field {key} was removed (it measured no gain; docs/notes.md), and this "
                                  f"config sets it to {got!r}: drop it, or use a checkout from before its removal "
                                  f"for a run trained with it")
        unknown = set(d) - names
        if unknown:
            raise unknown_fields(sorted(unknown))
        for key, value in d.items():
            check_value(key, value, "")
        if "seeds" in d:
            d["seeds"] = tuple(int(s) for s in d["seeds"])
        return cls(**d)

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        """The config a run wrote (``RUN/config.json``); ``ConfigError`` saying what is wrong with the file and
        what to do if it is missing, not JSON, not an object or holds a field that is not a field or not of its
        type."""
        path = Path(path)
        fix = "pass the --run of a training run, or put back the config.json it was trained with"
        if not path.is_file():
            raise ConfigError(f"{path.parent} is not a run directory (no config.json): {fix}")
        try:
            d = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise ConfigError(f"{path} cannot be read as JSON ({e}): {fix}") from None
        if not isinstance(d, dict):
            raise ConfigError(f"{path} holds a JSON {type(d).__name__}, not a config's object of fields: {fix}")
        try:
            return cls.from_dict(d)
        except ConfigError as e:
            raise ConfigError(f"{path}: {e}") from None


# Fields removed after they measured no gain (docs/notes.md), with the value every run had unless asked otherwise: a
# run's config.json holding that value still loads; another value stops with what to do.
def unknown_fields(names, where: str = "") -> ConfigError:
    """The error for config fields that do not exist, with the nearest field names."""
    import difflib

    known = [f.name for f in dataclasses.fields(TrainConfig)]
    near = [m for n in names for m in difflib.get_close_matches(n, known, n=1)]
    hint = f"did you mean {', '.join(map(repr, near))}? " if near else ""
    what = "field" if len(names) == 1 else "fields"
    return ConfigError(f"{where}unknown config {what} {', '.join(map(repr, names))}: {hint}the fields are "
                       f"TrainConfig's, in src/cogail_jax/algo/config.py")


def check_value(name: str, value, where: str):
    """``value`` (from a JSON config) if it has the type of field ``name``'s default; ``ConfigError`` naming the
    field and the type it wants otherwise. Fields whose default is None take any value."""
    default = {f.name: f.default for f in dataclasses.fields(TrainConfig)}[name]
    kind = type(default)
    ok = {bool: lambda v: isinstance(v, bool),
          int: lambda v: isinstance(v, int) and not isinstance(v, bool),
          float: lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
          str: lambda v: isinstance(v, str),
          tuple: lambda v: (isinstance(v, (list, tuple))
                            and all(isinstance(x, int) and not isinstance(x, bool) for x in v)),
          }.get(kind, lambda v: True)
    if default is not None and not ok(value):
        want = {bool: "true or false", int: "an integer", float: "a number", str: "a string",
                tuple: "a list of integers"}[kind]
        raise ConfigError(f"{where}{name} is {json.dumps(value)}, expected {want}")
    return value


REMOVED = {"la_codes": "demo", "bc_codes": "demo", "encoder": "mlp", "action_frame": "base"}


# The fields that only the training update reads (its losses, optimiser steps and schedule): the programs that do not
# train (the initial state, BC, the evaluation's programs) are kept between runs (``programs.stored``) under
# ``program_key(cfg)``, the config with these at their defaults, so that a run that changes only these (a sweep of
# bc_coef, say) loads those programs instead of tracing them again. tests/test_programs.py checks that changing
# each of them leaves every such program unchanged.
UPDATE_ONLY = ("total_steps", "updates_per_call", "checkpoint_every", "lr", "gamma", "gae_lambda", "clip_eps",
               "ppo_epochs", "num_minibatches", "value_coef", "entropy_coef", "max_grad_norm", "reward_norm",
               "policy_cooldown", "bc_coef", "gp_coef", "disc_lr", "disc_instance_noise", "lambda_z",
               "diversity_coef", "aux_lr", "inner_updates", "task_reward")


# Of those, the real numbers: the training program takes them as arguments (``hyper_values``), not as constants, so
# that a run that changes only their values (not which of them are 0, which switches terms off) runs the kept
# training program of another (``chunk_key``).
HYPER = ("lr", "gamma", "gae_lambda", "clip_eps", "value_coef", "entropy_coef", "max_grad_norm", "bc_coef", "gp_coef",
         "disc_lr", "lambda_z", "diversity_coef", "aux_lr", "task_reward")


def hyper_values(cfg: TrainConfig) -> dict[str, float]:
    """The ``HYPER`` fields of ``cfg``, by name."""
    return {name: float(getattr(cfg, name)) for name in HYPER}


def chunk_key(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with each ``HYPER`` field reduced to whether it is 0: the key under which the training program is
    kept."""
    return cfg.replace(**{name: float(getattr(cfg, name) != 0) for name in HYPER})


def program_key(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with the ``UPDATE_ONLY`` fields at their defaults: the key under which a program that does not train
    is kept."""
    defaults = TrainConfig()
    return cfg.replace(**{name: getattr(defaults, name) for name in UPDATE_ONLY})


def field_help() -> dict[str, object]:
    return {f.name: f.default for f in dataclasses.fields(TrainConfig)}


def task_default(task: str, name: str, default):
    """The task's own value of a config field (its ``default_config()``), else ``default``; an "auto" field reads it."""
    from cogail_envs import get_task

    return get_task(task).default_config().get(name, default)


def resolve(task: str, budget: str = "paper", fields: dict | None = None) -> TrainConfig:
    """A run's config: the field defaults, updated with ``task``'s settings under ``budget`` (its
    ``default_config()`` and ``budgets[budget]``), then with ``fields`` (a JSON file's, the command line's). With
    your own training file (``demos``) the task's ``train_varied`` does not apply unless ``fields`` sets it."""
    from cogail_envs import UnknownTaskError, get_task

    fields = dict(fields or {})
    task = fields.pop("task", None) or task
    if not task:
        return TrainConfig.from_dict(fields).validate()  # raises: no task given
    try:
        own = get_task(task).config(budget)
    except UnknownTaskError as e:
        raise ConfigError(str(e))
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    for key, value in own.items():  # your own task's settings: named as such
        if key in names:
            check_value(key, value, f"task {task}'s settings ({budget}): ")
    if fields.get("demos") and "train_varied" not in fields:  # your training file: the task's varied humans are
        own.pop("train_varied", None)                         # added to its own training set, not to yours
    return TrainConfig.from_dict({**own, **fields, "task": task}).validate()


__all__ = ["TrainConfig", "ConfigError", "check_value", "unknown_fields", "METHODS", "PAPER_METHODS", "FIELD_METHODS", "HYPER", "UPDATE_ONLY", "chunk_key", "field", "field_help",
           "hyper_values", "program_key", "resolve", "task_default"]
