"""The host loop: set up a run directory, train with progress and TensorBoard logs, checkpoint, evaluate."""
from __future__ import annotations

import functools
import json
import math
import os
import platform
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax
import numpy as np

from . import checkpoint as ckpt
from . import data, evaluate, tblog, timing, train
from .config import ConfigError, TrainConfig


class RunError(RuntimeError):
    """A problem with a run (directory, checkpoints, numerics) that the user must act on."""


@dataclass
class Setup:
    cfg: TrainConfig
    env: object
    expert: dict
    heldout: dict | None
    init: object
    chunk: object
    nets: dict
    train_metrics: dict | None = None
    validation: dict | None = None  # validation episodes (evaluate.heldout_arrays), for checkpoint selection
    files: dict | None = None  # split name (test, validation) -> the demonstration file it was read from


def effective_updates_per_call(cfg: TrainConfig) -> int:
    return math.gcd(cfg.updates_per_call, cfg.checkpoint_every)


def total_updates(cfg: TrainConfig) -> int:
    upc = effective_updates_per_call(cfg)
    return int(math.ceil(cfg.num_updates / upc) * upc)


def build(cfg: TrainConfig, need_heldout: bool = True, need_validation: bool | None = None) -> Setup:
    """Environment, demonstrations and jitted programs of a config. ``need_heldout``: load the test split
    (``cfg.heldout`` or the task's default test file); ``need_validation`` (default: as ``need_heldout``): load
    the validation split (``cfg.validation`` or the default validation file)."""
    import cogail_envs

    cfg = cfg.validate()
    cfg = cfg.replace(updates_per_call=effective_updates_per_call(cfg))
    env = task_env = cogail_envs.make_env(cfg.task)  # task_env: the task's own limit (the cached demos')
    if cfg.max_episode_steps and cfg.max_episode_steps != env.max_episode_steps:
        env = cogail_envs.make_env(cfg.task, max_episode_steps=cfg.max_episode_steps)
    if cfg.train_varied:
        from .robustness import ensure_varied_training_set

        train_path = ensure_varied_training_set(task_env, cfg.mix, cfg.num_demos, cfg.train_varied)
    else:
        train_path = cfg.demos or data.ensure_default_demos(task_env, "train", cfg.mix, num=cfg.num_demos)
    demos = data.load_demos(train_path, env)
    expert = train.expert_arrays(demos, cfg.history)
    heldout, validation, files = None, None, {}
    if need_heldout:
        files["test"] = cfg.heldout or data.ensure_default_demos(task_env, "test", cfg.mix)
        heldout = evaluate.heldout_arrays(data.load_demos(files["test"], env, require_init=True))
    if need_heldout if need_validation is None else need_validation:
        files["validation"] = cfg.validation or data.ensure_default_demos(task_env, "validation", cfg.mix)
        validation = evaluate.heldout_arrays(data.load_demos(files["validation"], env, require_init=True))
    init, chunk, nets = train.make_train_fns(cfg, env, train.fit_normalizer(expert, cfg.obs_std_floor))
    return Setup(cfg, env, expert, heldout, init, chunk, nets, demos.metrics, validation,
                 {k: str(v) for k, v in files.items()})


def run_metadata() -> dict:
    import importlib.metadata as md

    versions = {}
    for p in ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "brax", "mujoco", "mujoco-mjx", "numpy", "h5py"):
        try:
            versions[p] = md.version(p)
        except md.PackageNotFoundError:
            versions[p] = None
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                                cwd=Path(__file__).parent).stdout.strip() or None
    except Exception:  # noqa: BLE001
        commit = None
    from .xla import deterministic_ops

    return {"versions": versions, "git_commit": commit, "python": sys.version.split()[0],
            "platform": platform.platform(), "devices": [str(d) for d in jax.devices()],
            "time": time.strftime("%Y-%m-%d %H:%M:%S"),
            # deterministic GPU kernels (on by default in the `cogail` CLI; off with --nondeterministic)
            "xla_gpu_deterministic_ops": deterministic_ops(), "xla_flags": os.environ.get("XLA_FLAGS", "")}


def prepare_run_dir(cfg: TrainConfig, run_dir: Path, resume: bool) -> TrainConfig:
    cfg_path = run_dir / "config.json"
    if resume:
        if not cfg_path.exists():
            raise RunError(f"cannot resume: {run_dir} has no config.json; start a new run without --resume")
        saved = TrainConfig.load(cfg_path)
        if saved.task != cfg.task or saved.method != cfg.method:
            raise RunError(f"cannot resume: {run_dir} is a {saved.method} run on {saved.task}, "
                           f"not {cfg.method} on {cfg.task}; pass the same --task/--method or another --run")
        return saved
    if cfg_path.exists() and ckpt.steps(ckpt.manager(run_dir)):
        raise RunError(f"{run_dir} already holds a run: pass --resume to continue it or choose another --run")
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg_path.write_text(cfg.to_json())
    (run_dir / "run_info.json").write_text(json.dumps(run_metadata(), indent=2))
    return cfg


def _log_scalars(writers, metrics, update0, steps_per_update):
    """TensorBoard scalars ``train/<metric>`` of each update and seed (``metrics``: name -> (updates, seeds)):
    one event per update and seed holding every metric (an event per value cost more host time than the
    update itself on fetchq)."""
    from tensorboardX.proto.summary_pb2 import Summary

    tags = {k: f"train/{k}" for k in metrics}
    for u in range(next(iter(metrics.values())).shape[0]):
        step = (update0 + u + 1) * steps_per_update
        for i, w in enumerate(writers):
            w.add_summary(Summary(value=[Summary.Value(tag=tags[k], simple_value=float(v[u, i]))
                                         for k, v in metrics.items()]), step)


def seed_mesh(devices: str | int | None, num_seeds: int):
    """A 1-D mesh over the devices that share the seed axis (``devices``: a number or "all"); None for one."""
    from jax.sharding import Mesh

    avail = jax.devices()
    n = len(avail) if devices in ("all", None) else int(devices)
    if devices is None or n <= 1:
        return None
    if n > len(avail):
        raise RunError(f"--devices {n} asked for more devices than the {len(avail)} visible ones")
    while num_seeds % n:  # the seed axis must split evenly
        n -= 1
    if n <= 1:
        return None
    return Mesh(np.asarray(avail[:n]), ("seeds",))


def place_on_devices(state, expert, devices, num_seeds):
    """Shard the leading seed axis of the state over the mesh; replicate the demonstrations. One program:
    jit follows the input shardings, so every device runs its seeds' rollouts and updates."""
    mesh = seed_mesh(devices, num_seeds)
    if mesh is None:
        return state, expert
    from jax.sharding import NamedSharding, PartitionSpec as P

    # Empty leaves (MJX's unused act / mocap / userdata fields, shape (seeds, envs, 0)) leave the sharded program
    # replicated: placing them so from the start keeps every call's input shardings equal to the previous call's
    # outputs (placed P("seeds") they made the second call compile the whole chunk again).
    state = jax.tree.map(lambda x: jax.device_put(x, NamedSharding(mesh, P() if x.size == 0 else P("seeds"))), state)
    expert = jax.device_put(expert, NamedSharding(mesh, P()))
    return state, expert


@dataclass
class LoopStats:
    """What the training loop did: the update reached, each call's seconds (the first compiles), and the env
    steps and seconds after the first call (the steady state)."""
    update: int
    call_seconds: list[float]
    loop_seconds: float = 0.0
    steady_steps: int = 0
    steady_seconds: float = 0.0
    checkpoint_calls: set = field(default_factory=set)  # calls that copied or queued a checkpoint


def _abstract(tree):
    """Shapes, dtypes and (where committed to devices) shardings of a tree of arrays, as jit sees them when they
    are passed to it (reading none of them: they may still be computed)."""
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding if getattr(
        x, "committed", True) else None), tree)


def _compile_during_bc(s: Setup, state, on_compiled, seconds: dict) -> threading.Thread:
    """A background thread, started: the training chunk compiled for ``state``'s shapes, then ``on_compiled(s,
    state)`` (``EvalPrep.start``). The main thread meanwhile runs BC: a long device loop that the GPU runtime
    drives from the calling thread, which holds no Python lock then. A failure only costs the time: the first
    training call compiles the chunk (and raises the error) itself. ``seconds["chunk_compile"]``: how long the
    compilation took."""
    abstract = _abstract(state)

    def work():
        t0 = time.perf_counter()
        try:
            s.chunk.lower(abstract, s.expert).compile()
        except Exception:  # noqa: BLE001
            return
        finally:
            seconds["chunk_compile"] = time.perf_counter() - t0
        if on_compiled is not None:
            on_compiled(s, abstract)

    t = threading.Thread(target=work, name="compile-during-bc", daemon=True)
    t.start()
    return t


def _start_state(s: Setup, mgr, run_dir: Path, resume: bool, devices, clock: timing.Phases, on_compiled=None,
                 parts: dict | None = None):
    """The state training starts from (restored on resume, else fresh with BC pre-training, timed as ``bc``),
    placed on the devices; returns (state, first update, whether ``on_compiled`` was called or is pending).
    On one device a fresh run compiles the training chunk while BC runs (``_compile_during_bc``), its compilation
    in the ``bc`` phase where it outlasts BC. ``parts`` receives the bc phase's ``timing.TRAIN_PARTS``."""
    parts = {} if parts is None else parts
    cfg = s.cfg
    state, start = None, 0
    if resume:  # restored onto this process's first device, whatever layout saved it; placed below
        abstract = s.init.abstract(cfg.seeds, s.expert)
        step, state = ckpt.restore_latest_valid(mgr, abstract)
        if step is not None:
            start = step
            print(f"resuming {run_dir} from update {step}", flush=True)
    fresh = state is None
    compiling = []
    if fresh:
        with clock("bc"):
            before_bc = None
            if seed_mesh(devices, len(cfg.seeds)) is None:  # one device: the chunk compiles while BC runs
                def before_bc(st):
                    compiling.append(_compile_during_bc(s, st, on_compiled, parts))
            t0 = time.perf_counter()
            state = jax.block_until_ready(s.init(cfg.seeds, s.expert, before_bc))
            t1 = time.perf_counter()
            for t in compiling:
                t.join()
            parts.update(bc_run=t1 - t0, compile_wait=time.perf_counter() - t1)
    state, s.expert = place_on_devices(state, s.expert, devices, len(cfg.seeds))
    here = ckpt.layout(state)
    if fresh:
        ckpt.save(mgr, 0, state)
    else:
        saved = ckpt.saved_layout(mgr, start) or ckpt.run_layout(run_dir)
        if saved and (saved.get("device_count"), saved.get("device_kind")) != (here["device_count"],
                                                                              here["device_kind"]):
            print(f"restored {len(cfg.seeds)} seeds saved on {ckpt.describe(saved)} onto {ckpt.describe(here)}",
                  flush=True)
    ckpt.record_layout(run_dir, here, start)
    return state, start, bool(compiling)


def _postfix(metrics: dict, stats: LoopStats) -> dict:
    el = stats.steady_seconds
    post = {"env_steps/s": f"{stats.steady_steps / el:.3g}" if el > 0 and stats.steady_steps else "-"}
    for key, short in (("episode_success", "succ"), ("disc_loss", "d_loss"), ("loss_z", "L_z"),
                       ("loss_a", "L_a"), ("bc_loss", "bc")):
        if key in metrics:
            post[short] = f"{metrics[key][-1].mean():.3f}"
    return post


EVAL_PARAMS = ("actor", "psi")  # what evaluating a checkpoint reads of its parameters


def _eval_tree(state) -> dict:
    """The delivered policy's actor and psi (``train.policy_params``) and the observation normaliser of ``state``."""
    policy = train.policy_params(state.params)
    return {"params": {k: policy[k] for k in EVAL_PARAMS}, "norm": state.norm}


def eval_params(state) -> dict:
    """What evaluating a checkpoint reads of its state: the actor's and psi's parameters and the observation
    normaliser (seed axis first), on this process's first device, as ``checkpoint.restore`` puts them."""
    return jax.device_put(_eval_tree(state), jax.devices()[0])


def _check_and_log(writers, metrics, update0: int, cfg: TrainConfig, saver) -> dict:
    """One call's metrics to the host: stop on non-finite parameters, else log them to TensorBoard."""
    metrics = jax.device_get(metrics)
    if np.any(metrics["nonfinite"] > 0):
        saver.wait()
        u = update0 + int(np.argmax(np.any(metrics["nonfinite"] > 0, axis=1))) + 1
        raise RunError(f"training diverged at update {u} (non-finite parameters); the last good "
                       f"checkpoint (update {max(ckpt.steps(saver.mgr))}) is kept: lower --lr or change the seed")
    _log_scalars(writers, metrics, update0, cfg.steps_per_update)
    return metrics


def _train_loop(s: Setup, state, mgr, run_dir: Path, start: int, progress: bool, stop_after: int | None,
                keep: dict | None = None, on_compiled=None):
    """Call the jitted chunk until the budget (or ``stop_after``), logging and checkpointing; returns LoopStats.

    The host never holds the device up: each call is dispatched before the previous call's metrics are logged; a
    checkpoint's state is copied on the device right after its call and written by a background thread
    (``checkpoint.BackgroundSaver``) once that call's metrics show finite parameters, while the next call runs.
    ``keep``: filled with {update: eval_params(...)} of every checkpoint written, so that ``eval_run`` need not
    read them back from disk. ``on_compiled(s, state)`` is called once the first call has run (``EvalPrep.start``)."""
    from tensorboardX import FileWriter
    from tqdm import tqdm

    cfg, upc, total = s.cfg, s.cfg.updates_per_call, total_updates(s.cfg)
    writers = [FileWriter(str(run_dir / "tb" / f"seed_{sd}")) for sd in cfg.seeds]
    bar = tqdm(total=total, initial=start, unit="upd", disable=not progress, dynamic_ncols=True, file=sys.stdout)
    saver = ckpt.BackgroundSaver(mgr)
    stats, t_loop = LoopStats(start, []), time.perf_counter()
    pending = None  # (first update, device metrics, (update, state copy) or None) of the call not logged yet

    def drain():
        nonlocal pending
        if pending is not None:
            (u0, m, to_save), pending = pending, None
            if u0 != start and stats.call_seconds:  # a finished call after the first (compiling) one
                stats.steady_steps += upc * cfg.steps_per_update * len(cfg.seeds)
                stats.steady_seconds = time.perf_counter() - t_loop - stats.call_seconds[0]
            bar.set_postfix(_postfix(_check_and_log(writers, m, u0, cfg, saver), stats))
            if to_save is not None:
                saver.submit(*to_save)
                if keep is not None:
                    keep[to_save[0]] = eval_params(to_save[1])

    try:
        t_last = time.perf_counter()
        while stats.update < total and (stop_after is None or stats.update < stop_after):
            state, metrics = s.chunk(state, s.expert)
            if not stats.call_seconds:  # the first call compiles: timed on its own
                jax.block_until_ready(metrics)
                if on_compiled is not None:
                    on_compiled(s, state)
            u0, stats.update = stats.update, stats.update + upc
            at_ckpt = stats.update % cfg.checkpoint_every == 0 or stats.update >= total
            copy = (stats.update, saver.copy(state)) if at_ckpt else None
            if at_ckpt or (pending is not None and pending[2] is not None):  # copies one, or queues the last
                stats.checkpoint_calls.add(len(stats.call_seconds))
            drain()
            pending = (u0, metrics, copy)
            now = time.perf_counter()
            stats.call_seconds.append(now - t_last)
            t_last = now
            stats.loop_seconds = now - t_loop
            stats.steady_seconds = stats.loop_seconds - stats.call_seconds[0]
            bar.update(upc)
        drain()
        saver.wait()
        stats.loop_seconds = time.perf_counter() - t_loop
        stats.steady_seconds = stats.loop_seconds - stats.call_seconds[0] if stats.call_seconds else 0.0
    finally:
        saver.close()
        bar.close()
        for w in writers:
            w.close()
    return stats


def train_run(cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True,
              stop_after: int | None = None, devices: str | int | None = None, keep: dict | None = None,
              on_compiled=None) -> Path:
    """Train (or resume) a run; returns the run directory. ``stop_after`` stops early after that many updates
    (tests use it to simulate an interrupted run). Records the time of each phase in RUN/speed.json
    (``timing``; a resumed run adds to it). ``keep``: a dict that receives each checkpoint's ``eval_params``
    as it is written, for ``eval_run(..., memory=keep)``. ``on_compiled``: see ``_train_loop``."""
    clock = timing.Phases()
    clock.take_process_start()  # the command's imports before this call count as "start"
    run_dir = Path(run_dir)
    with clock("start"):
        cfg = prepare_run_dir(cfg, run_dir, resume)
        from .devices import cpu_warning, describe_devices  # where it runs; a CPU warning for paper-sized MJX runs
        print("\n".join([describe_devices(), *cpu_warning(cfg)]), flush=True)
    with clock("demos"):
        s = build(cfg, need_heldout=False)
    mgr = ckpt.manager(run_dir)
    parts: dict = {}
    state, start, called = _start_state(s, mgr, run_dir, resume, devices, clock, on_compiled, parts)
    stats = _train_loop(s, state, mgr, run_dir, start, progress, stop_after, keep, None if called else on_compiled)
    compile_s = timing.compile_estimate(stats.call_seconds)
    clock.add("compile", compile_s)
    clock.add("train", stats.loop_seconds - compile_s)
    parts.update(timing.call_parts(stats.call_seconds, stats.checkpoint_calls))
    timing.write(run_dir, timing.merge_train(
        timing.read(run_dir) if resume else {}, clock, stats.steady_steps, stats.steady_seconds, resume, parts,
        task=s.cfg.task, method=s.cfg.method, updates=stats.update, seeds=len(s.cfg.seeds),
        steps_per_update=s.cfg.steps_per_update, **timing.device_info()))
    return run_dir


def replay_results_dir(run_dir: str | Path, replay_file: str | Path) -> Path:
    """Where an extra test set's own results go (``eval --replay-file FILE``): RUN/replay-<file stem>/."""
    return Path(run_dir) / f"replay-{Path(replay_file).stem}"


def _checkpoints_to_evaluate(mgr, every: int) -> list[int]:
    steps = [st for st in ckpt.steps(mgr) if st > 0] or ckpt.steps(mgr)
    if every > 1 and steps:  # evaluate every k-th checkpoint (and always the last)
        steps = sorted(set(steps[every - 1::every]) | {steps[-1]})
    return steps


EXTRA = "extra:"  # the slices of the extra test sets in the evaluation batch (``stack_sets``' parts)


def _split_sets(out: dict, part: dict) -> dict:
    """One checkpoint's evaluation of the stacked batch (test, validation and the extra sets), split into its
    sets: ``extra`` holds each extra set's replay success."""
    t, v = part["test"], part["validation"]
    interp = ("interp_success", "interp_strategy", "interp_metrics", "val_interp_success", "val_interp_strategy")
    r = {k: ({m: np.asarray(x) for m, x in out[k].items()} if isinstance(out[k], dict) else np.asarray(out[k]))
         for k in interp}
    r["replay_success"] = np.asarray(out["replay_success"])[:, t]
    r["val_replay_success"] = np.asarray(out["replay_success"])[:, v]
    r["replay_metrics"] = {m: np.asarray(x)[:, t] for m, x in out["replay_metrics"].items()}
    r["latent"] = np.asarray(out["latent"])[:, t]
    r["extra"] = {k[len(EXTRA):]: np.asarray(out["replay_success"])[:, sl] for k, sl in part.items()
                  if k.startswith(EXTRA)}
    return r


def _extra_set_checkpoints(res: dict) -> dict[str, int]:
    cks = {"paper_protocol": int(res["paper_protocol"]["replay"]["checkpoint"])}
    if res.get("selected"):
        cks = {"selected": int(res["selected"]["checkpoint"]), **cks}
    return cks


def _abstract_state(s: Setup):
    """A zero-argument function giving the shapes of ``s``'s training state (``init.abstract``: from the kept
    initial-state and BC programs, traced where none is kept; only when a checkpoint is read from disk), computed
    once."""
    return functools.cache(lambda: s.init.abstract(s.cfg.seeds, s.expert))


def _checkpoint_params(mgr, abstract, memory: dict | None, step: int) -> dict:
    """``eval_params`` of checkpoint ``step``: from ``memory`` (kept by the training loop) or read from disk
    (``abstract()``: the state's shapes, ``_abstract_state``)."""
    if memory and step in memory:
        return memory[step]
    return eval_params(ckpt.restore(mgr, step, abstract()))


def _lengths(sets, key: str = "length") -> np.ndarray:
    """One array of ``key`` (the recordings' lengths) over episode sets (``heldout_arrays``)."""
    return np.concatenate([np.asarray(e[key]) for e in sets] or [np.zeros(0, int)])


def _extra_batch(s: Setup, eps: dict) -> tuple[dict, dict]:
    """The extra sets' episodes stacked into one replay batch (``evaluate.make_replay_fn``'s ``episodes``) and each
    set's slice of it."""
    batch, part = evaluate.stack_sets(eps, steps=evaluate.replay_steps(s.env, _lengths(eps.values()),
                                                                       _lengths(eps.values(), "margin")))
    return {k: batch[k] for k in ("init", "ah", "length", "patient", "margin")}, part


def _replay_extra_sets(s: Setup, mgr, abstract, res: dict, extra_sets: dict, memory: dict | None = None,
                       eps: dict | None = None, replay=None) -> dict:
    """Replay each extra set at the selected and the paper-protocol replay checkpoints: all sets stacked into one
    batch (one compiled replay program, one call per checkpoint); returns {name: evaluate.summarize_extra_set(...)}.
    ``memory``: checkpoints kept by the training loop (``eval_run``); ``eps``: the sets' episodes, if read already;
    ``replay``: ``evaluate.make_replay_fn``'s program, if made already."""
    replay = replay or evaluate.make_replay_fn(s.cfg, s.env, s.nets)
    cks = _extra_set_checkpoints(res)
    states = {st: _checkpoint_params(mgr, abstract, memory, st) for st in sorted(set(cks.values()))}
    eps = _extra_episodes(s, extra_sets) if eps is None else eps
    if not eps:
        return {}
    arrays, part = _extra_batch(s, eps)
    at = {st: np.asarray(jax.device_get(replay(states[st]["params"], states[st]["norm"], arrays))["success"])
          for st in states}  # once per checkpoint: the selected one is often the paper protocol's too
    succ = {key: at[st] for key, st in cks.items()}
    return {name: evaluate.summarize_extra_set({key: x[:, part[name]] for key, x in succ.items()},
                                               eps[name]["strategy"], s.cfg.seeds, s.env.strategy_names, cks,
                                               file=path)
            for name, path in extra_sets.items()}


def _extra_sets_results(s: Setup, per_ckpt: dict, res: dict, eps: dict, files: dict) -> dict:
    """{name: evaluate.summarize_extra_set(...)} of the extra sets replayed (with every checkpoint) in the
    evaluation batch, at the selected and the paper-protocol replay checkpoints, plus ``curve``: the replay
    success of every seed at every checkpoint."""
    cks, steps = _extra_set_checkpoints(res), sorted(per_ckpt)
    out = {}
    for name in files:
        out[name] = evaluate.summarize_extra_set({key: per_ckpt[st]["extra"][name] for key, st in cks.items()},
                                                 eps[name]["strategy"], s.cfg.seeds, s.env.strategy_names, cks,
                                                 file=files[name])
        # (seeds, checkpoints), like results.json's curves: the set's replay success at every checkpoint
        out[name]["curve"] = np.stack([per_ckpt[st]["extra"][name].mean(1) for st in steps], 1).tolist()
    return out


def _save_extra_sets(run_dir: Path, res: dict, names) -> None:
    for name in names:
        d = replay_results_dir(run_dir, name)
        d.mkdir(parents=True, exist_ok=True)
        r = evaluate.extra_set_results(res, name)
        (d / "results.json").write_text(json.dumps(r, indent=2))
        (d / "results.md").write_text(evaluate.extra_set_results_markdown(r))


def _extra_sets(extra_sets, replay_file) -> dict[str, str]:
    sets = {str(k): str(v) for k, v in (extra_sets or {}).items()}
    if replay_file is not None:
        sets[Path(replay_file).stem] = str(replay_file)
    for name in sets:
        if not name or "/" in name or name.startswith("."):
            raise RunError(f"extra set name {name!r} cannot name a directory: use letters, digits, - and _")
    return sets


def results_current(run_dir: str | Path, every: int = 1) -> bool:
    """Whether RUN/results.json follows the reporting protocol and covers exactly the checkpoints that
    ``eval_run(run_dir, every=every)`` would evaluate now (so extra sets can be added without re-evaluating)."""
    run_dir = Path(run_dir)
    try:
        res = json.loads((run_dir / "results.json").read_text())
    except (OSError, ValueError):
        return False
    return ("paper_protocol" in res and res.get("selected") is not None
            and res.get("checkpoints") == _checkpoints_to_evaluate(ckpt.manager(run_dir), every))


def eval_extra_sets(run_dir: str | Path, extra_sets: dict[str, str | Path]) -> dict:
    """Add extra test sets to an evaluated run without evaluating every checkpoint again: each set (name ->
    demonstration file with ``init``, e.g. recorded trials, an imported file, varied human trajectories) is
    replayed at the checkpoints RUN/results.json chose (selected on validation, paper-protocol replay); the
    results are merged into results.json's ``extra_sets`` (a set of the same name is replaced), results.md is
    rewritten, and each set also gets RUN/replay-<name>/results.{json,md}. Returns the updated results."""
    run_dir = Path(run_dir)
    sets = _extra_sets(extra_sets, None)
    try:
        res = json.loads((run_dir / "results.json").read_text())
    except (OSError, ValueError):
        raise RunError(f"{run_dir} has not been evaluated yet (no readable results.json): run `cogail eval --run "
                       f"{run_dir}` first")
    if "paper_protocol" not in res:
        raise RunError(f"{run_dir}/results.json predates the reporting protocol: evaluate the run again")
    s = build(TrainConfig.load(run_dir / "config.json"), need_heldout=False)
    mgr = ckpt.manager(run_dir)
    abstract = _abstract_state(s)
    res["extra_sets"] = {**(res.get("extra_sets") or {}), **_replay_extra_sets(s, mgr, abstract, res, sets)}
    evaluate.save_results(run_dir, res)
    _save_extra_sets(run_dir, res, sets)
    return res


def eval_run(run_dir: str | Path, progress: bool = True, every: int = 1, replay_file: str | Path | None = None,
             extra_sets: dict[str, str | Path] | None = None, ckpt_batch: int | None = None,
             robustness: bool = False, memory: dict | None = None, extra_curves: bool = False,
             prepared: EvalInputs | None = None) -> dict:
    """Evaluate every checkpoint of a run; write results.json / results.md and figures into the run dir.

    Every checkpoint and seed is evaluated on the test split (replay, interpolation, latent codes) and on the
    validation split (replay); ``evaluate.summarize`` turns that into the reported figures (paper protocol,
    selected on validation, last).

    ``extra_sets``: {name: demonstration file}: further test sets (recorded trials, imported files, varied human
    trajectories, one file per variation), replayed and reported at the selected checkpoint and at the
    paper-protocol replay checkpoint (one compiled replay program, ``_replay_extra_sets``); results in
    results.json's ``extra_sets[name]`` and in RUN/replay-<name>/results.{json,md}. ``extra_curves``: replay them
    at every checkpoint instead, in the batch of the test and validation splits, and add each set's ``curve``
    (and RUN/robustness_curves.png), for several times the evaluation's work; the figures are the same on the CPU
    and move at the rounding level on a GPU (where a batch's kernels depend on its size).

    The interpolation rollouts and the replays of the test and validation splits run as one batch of one
    compiled program (``evaluate.make_eval_fn``), at every checkpoint.
    ``replay_file``: one more extra set, named after the file's stem. To add sets to a run evaluated already,
    ``eval_extra_sets`` skips the evaluation of every checkpoint.

    ``robustness``: also replay against varied humans (``robustness.ensure_robustness_sets``: the test split's
    human varied in pace, pauses, path, noise and a change of mind, one extra set ``robust-<variation>`` each) and
    draw RUN/robustness.png.

    ``ckpt_batch`` > 1: that many checkpoints are evaluated in one device program (their parameters stacked on a
    new axis, vmapped; the last group padded), with the same results as one at a time; memory grows with it.
    None: ``default_ckpt_batch(...)`` (every checkpoint in one program on an accelerator, one at a time on the CPU).

    ``memory``: {update: ``eval_params``} kept by the training loop (``train_run(..., keep=...)``): those
    checkpoints are not read back from disk (the same values: the results are the same).

    ``prepared``: the run's ``EvalInputs`` made already, or the ``EvalPrep`` making them while training runs (waited
    for in the eval phase's set-up); its extra sets and ``extra_curves`` then stand for the arguments'.

    The seconds spent evaluating and writing replace the ``eval`` and ``write`` phases of RUN/speed.json."""
    clock, part_clock = timing.Phases(), timing.Phases()
    run_dir = Path(run_dir)
    if not (run_dir / "config.json").exists():
        raise RunError(f"{run_dir} is not a run directory (no config.json): pass the --run of a training run")
    with clock("eval"):
        with part_clock("setup"):
            mgr = ckpt.manager(run_dir)
            steps = _checkpoints_to_evaluate(mgr, every)
            if not steps:
                raise RunError(f"{run_dir} has no checkpoints yet: train it first")
            if hasattr(prepared, "result"):  # an EvalPrep still at work: the eval phase pays for the wait
                prepared = prepared.result()
            inp = prepared or _eval_inputs(run_dir, _extra_sets(extra_sets, replay_file), robustness, extra_curves)
            s, sets, eps, part = inp.s, inp.sets, inp.eps, inp.part
            abstract = _abstract_state(s)
        with part_clock("checkpoints"):
            per_ckpt, codes = _evaluate_checkpoints(s, mgr, abstract, steps, inp.held, part, ckpt_batch, progress,
                                                    memory, inp.evaluate_fn)
            if not per_ckpt:
                raise ckpt.nothing_restored(mgr, run_dir)
            res, at, lat = _summarize(s, per_ckpt, codes, part)
            windows = tblog.episode_windows(res["checkpoints"], -(-s.env.max_episode_steps // s.cfg.unroll_length))
            train_succ = tblog.training_success(run_dir, s.cfg.seeds, s.cfg.steps_per_update, windows)
            if train_succ is not None:  # the co-policy's own training episodes, from the run's TensorBoard logs
                res["training_success"] = train_succ
            if sets and inp.extra_curves:
                res["extra_sets"] = _extra_sets_results(s, per_ckpt, res, eps, sets)
        with part_clock("extra_sets"):
            if sets and not inp.extra_curves:
                res["extra_sets"] = _replay_extra_sets(s, mgr, abstract, res, sets, memory, eps, inp.replay_fn)
    with clock("write"):
        _write_eval_outputs(run_dir, s, res, at, lat, sets, robustness)
    if prepared is not None:
        part_clock.add("prepared", prepared.seconds)
    timing.write(run_dir, timing.merge_eval(timing.read(run_dir), clock, part_clock, **timing.device_info()))
    return res


@dataclass
class EvalInputs:
    """What evaluating a run needs before it reads a checkpoint: the set-up, the extra sets (name -> file) and
    their episodes, the batch of every checkpoint's program (test, validation; the extra sets too with
    ``extra_curves``) and each set's slice of it, and the two programs (``evaluate.make_eval_fn``,
    ``evaluate.make_replay_fn``). ``seconds``: how long making them took (``EvalPrep``)."""
    s: Setup
    sets: dict
    eps: dict
    held: dict
    part: dict
    extra_curves: bool
    evaluate_fn: object
    replay_fn: object
    seconds: float = 0.0


def _eval_inputs(run_dir: Path, sets: dict[str, str], robustness: bool, extra_curves: bool) -> EvalInputs:
    s, sets = _eval_setup(run_dir, sets, robustness)
    eps = _extra_episodes(s, sets)
    split_sets = {"test": s.heldout, "validation": s.validation,
                  **{EXTRA + n: e for n, e in eps.items() if extra_curves}}
    held, part = evaluate.stack_sets(split_sets, steps=evaluate.replay_steps(
        s.env, _lengths(split_sets.values()), _lengths(split_sets.values(), "margin")))
    return EvalInputs(s, sets, eps, held, part, extra_curves, evaluate.make_eval_fn(s.cfg, s.env, s.nets),
                      evaluate.make_replay_fn(s.cfg, s.env, s.nets))


def _eval_struct(state) -> dict:
    """The shapes of ``eval_params(state)`` (on this process's first device, as it puts them)."""
    dev = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=dev), _eval_tree(state))


def _compile_eval(inp: EvalInputs, struct: dict, checkpoints: int) -> None:
    """Compile ``inp``'s programs for a run of ``checkpoints`` checkpoints (``struct``: ``_eval_struct``) as
    ``eval_run`` will call them: the checkpoints' program for ``default_ckpt_batch`` of them, the replay of the
    extra sets for one checkpoint."""
    c = default_ckpt_batch(checkpoints)
    stacked = jax.tree.map(lambda x: jax.ShapeDtypeStruct((c,) + x.shape, x.dtype, sharding=x.sharding), struct)
    inp.evaluate_fn.lower(stacked["params"], stacked["norm"], inp.held).compile()
    if inp.eps and not inp.extra_curves:
        inp.replay_fn.lower(struct["params"], struct["norm"], _extra_batch(inp.s, inp.eps)[0]).compile()


SWITCH_INTERVAL = 2e-4  # seconds: how soon a thread waiting for Python's lock gets it while EvalPrep traces


class EvalPrep:
    """``cogail train --eval``'s evaluation made ready while training runs, when the host is idle and the device
    busy: in a background thread, the test, validation and varied-human sets are loaded (made if missing) and the
    evaluation programs traced and compiled (``EvalInputs``). ``start`` starts it once the training program has
    compiled (``train_run``'s ``on_compiled``: while BC runs on a fresh one-device run, else after the first
    training call); ``result()`` waits for it. A preparation that fails prints a warning, and ``eval_run`` then
    prepares again itself (raising the error, if it is one, where it belongs)."""

    def __init__(self, run_dir: str | Path, robustness: bool = True, extra_curves: bool = False,
                 extra_sets: dict[str, str | Path] | None = None):
        self.run_dir, self.robustness, self.extra_curves = Path(run_dir), robustness, extra_curves
        self.extra_sets = _extra_sets(extra_sets, None)
        self._thread: threading.Thread | None = None
        self._out: EvalInputs | None = None
        self._error: Exception | None = None

    def start(self, s: Setup, state) -> None:
        if self._thread is None:
            total, every = total_updates(s.cfg), s.cfg.checkpoint_every
            args = (_eval_struct(state), total // every + (1 if total % every else 0))
            self._thread = threading.Thread(target=self._prepare, args=args, name="eval-prep", daemon=True)
            self._thread.start()

    def _prepare(self, struct: dict, checkpoints: int) -> None:
        t0, interval = time.perf_counter(), sys.getswitchinterval()
        sys.setswitchinterval(min(interval, SWITCH_INTERVAL))  # the training loop waits less for Python's lock
        try:
            inp = _eval_inputs(self.run_dir, dict(self.extra_sets), self.robustness, self.extra_curves)
            _compile_eval(inp, struct, checkpoints)
            inp.seconds = time.perf_counter() - t0
            self._out = inp
        except Exception as e:  # noqa: BLE001  (eval_run prepares again and raises it there)
            self._error = e
        finally:
            sys.setswitchinterval(interval)

    def result(self) -> EvalInputs | None:
        if self._thread is None:
            return None
        self._thread.join()
        if self._error is not None and not isinstance(self._error, (ConfigError, data.DatasetError, RunError)):
            print(f"warning: preparing the evaluation during training failed ({self._error}); preparing it now",
                  flush=True)  # (a user's error is raised again by eval_run, in one sentence)
        return self._out


PATIENT = "patient-"  # an extra set replayed with a patient human (evaluate._episodes_fn, the task's replay_hold)


def _extra_episodes(s: Setup, sets: dict[str, str]) -> dict[str, dict]:
    """The extra sets' replay episodes (humans from outside the splits: with the replay margin); a set named
    ``patient-...`` is replayed with a patient human."""
    return {name: evaluate.heldout_arrays(data.load_demos(path, s.env, require_init=True),
                                          patient=name.startswith(PATIENT), margin=True)
            for name, path in sets.items()}


def _eval_setup(run_dir: Path, sets: dict[str, str], robustness: bool) -> tuple[Setup, dict[str, str]]:
    """The run's set-up with the test and validation splits, and the extra sets to replay: ``sets``, those of an
    earlier evaluation whose files still exist, and with ``robustness`` the varied humans (made if missing)."""
    try:  # the extra sets of an earlier evaluation are evaluated again at the new checkpoints
        prev = json.loads((run_dir / "results.json").read_text()).get("extra_sets") or {}
    except (OSError, ValueError, AttributeError):
        prev = {}
    for name, e in prev.items():
        if name not in sets and isinstance(e, dict) and e.get("file") and Path(e["file"]).exists():
            sets[name] = e["file"]
    s = build(TrainConfig.load(run_dir / "config.json"))
    if robustness:
        from . import robustness as rb

        varied = rb.ensure_robustness_sets(s.env, mix=s.cfg.mix)
        sets.update(varied)
        if s.env.has_patient_replay:  # the same humans, waiting for the robot where the task says
            sets.update({PATIENT + name: path for name, path in {"test": s.files["test"], **varied}.items()})
    return s, sets


MAX_CKPT_BATCH = 64  # checkpoints per evaluation program on an accelerator, at most


def default_ckpt_batch(checkpoints: int) -> int:
    """Checkpoints per evaluation program when none is given: on an accelerator all of them (up to
    ``MAX_CKPT_BATCH``), so one device program evaluates the run; 1 on the CPU (where a wider batch only costs
    memory and compilation)."""
    return 1 if jax.default_backend() == "cpu" else max(1, min(int(checkpoints), MAX_CKPT_BATCH))


def _out_of_memory(e: Exception) -> bool:
    return "RESOURCE_EXHAUSTED" in str(e) or "out of memory" in str(e).lower()


def _evaluate_checkpoints(s: Setup, mgr, abstract, steps: list[int], held: dict, part: dict, ckpt_batch: int,
                          progress: bool, memory: dict | None = None, evaluate_fn=None) -> tuple[dict, object]:
    """{step: _split_sets(...)} for every checkpoint that restores (``ckpt_batch`` of them per device call), and
    the interpolation codes. A device call that runs out of memory is tried again with half as many checkpoints
    per call (a warning names the ``--ckpt-batch`` to give next time)."""
    from tqdm import tqdm

    evaluate_fn = evaluate_fn or evaluate.make_eval_fn(s.cfg, s.env, s.nets)
    per_ckpt = {}
    ckpt_batch = max(1, min(int(ckpt_batch or default_ckpt_batch(len(steps))), len(steps)))
    bar = tqdm(total=len(steps), desc="eval", disable=not progress, file=sys.stdout)
    stack = lambda *x: jax.numpy.stack(x)  # noqa: E731
    i = 0
    while i < len(steps):
        group = []
        for step in steps[i:i + ckpt_batch]:
            try:
                group.append((step, _checkpoint_params(mgr, abstract, memory, step)))
            except ckpt.CheckpointError as e:
                print(f"warning: {e}; skipped", flush=True)
        if group:
            pad = [st for _, st in group] + [group[-1][1]] * (ckpt_batch - len(group))  # one compiled shape
            try:
                out = jax.device_get(evaluate_fn(jax.tree.map(stack, *[st["params"] for st in pad]),
                                                 jax.tree.map(stack, *[st["norm"] for st in pad]), held))
            except Exception as e:  # noqa: BLE001  (XLA's out-of-memory error has no public class)
                if ckpt_batch == 1 or not _out_of_memory(e):
                    raise
                ckpt_batch = max(1, ckpt_batch // 2)
                print(f"warning: the device ran out of memory evaluating {len(pad)} checkpoints at once; trying "
                      f"{ckpt_batch} (give --ckpt-batch {ckpt_batch} next time)", flush=True)
                continue
            for j, (step, _) in enumerate(group):
                per_ckpt[step] = _split_sets(jax.tree.map(lambda x: x[j], out), part)
        bar.update(len(steps[i:i + ckpt_batch]))
        i += ckpt_batch
    bar.close()
    return per_ckpt, evaluate.interpolation_codes(s.cfg.eval_codes)


def _summarize(s: Setup, per_ckpt: dict, codes, part: dict):
    """The reported figures (``evaluate.summarize``) with the splits and the latent map; returns (results, the
    selected checkpoint's evaluation, its latent codes or None)."""
    cfg = s.cfg
    res = evaluate.summarize(cfg.task, cfg.method, cfg.seeds, per_ckpt, s.env.strategy_names, codes,
                             heldout_strategy=s.heldout["strategy"])
    res["splits"] = {name: {"file": s.files[name], "episodes": int(part[name].stop - part[name].start)}
                     for name in ("test", "validation")}
    if cfg.train_varied:  # the varied-human sets then hold kinds of person the robot was trained on
        res["train_varied"] = int(cfg.train_varied)
    if cfg.policy_ema:  # what was evaluated: the moving average of the trained networks
        res["policy_ema"] = float(cfg.policy_ema)
    at = per_ckpt[res["breakdowns_at"]["checkpoint"]]  # the selected checkpoint
    i0 = int(np.argmax(at["val_replay_success"].mean(1)))  # latent map: the seed best on validation there
    lat = at["latent"][i0] if cfg.use_code else None
    res["latent_map"] = {"seed": int(cfg.seeds[i0]), "checkpoint": res["breakdowns_at"]["checkpoint"],
                         "codes": None if lat is None else lat.tolist(),
                         "strategy": np.asarray(s.heldout["strategy"]).tolist()}
    return res, at, lat


def _write_eval_outputs(out_dir: Path, s: Setup, res: dict, at: dict, lat, sets: dict, robustness: bool) -> None:
    """results.json / results.md, each extra set's results and the figures."""
    cfg = s.cfg
    out_dir.mkdir(parents=True, exist_ok=True)
    evaluate.save_results(out_dir, res)
    _save_extra_sets(out_dir, res, sets)
    evaluate.write_figures(out_dir, res, lat, np.asarray(s.heldout["strategy"]), s.env.strategy_names)
    if robustness:
        from . import robustness as rb

        rb.robustness_figure(res, out_dir / "robustness.png", title=f"{cfg.method} on {cfg.task}: varied humans")
        curves = out_dir / "robustness_curves.png"
        if rb.robustness_curve_figure(res, curves, title=f"{cfg.method} on {cfg.task}: varied humans per "
                                      "checkpoint") is None:
            curves.unlink(missing_ok=True)  # an earlier evaluation's (with extra_curves): not these results
    if "handover_x" in at["interp_metrics"]:  # HR-Handover: where the handovers happened (paper Fig. 4a)
        im = {k: at["interp_metrics"][k] for k in ("handover_x", "handover_y", "handover_z")}
        evaluate.write_handover_spots(out_dir, res, im, at["interp_success"], s.train_metrics)


__all__ = ["train_run", "eval_run", "eval_extra_sets", "EvalPrep", "RunError", "ConfigError", "build"]
