"""The training host loop: start or resume a run, call the jitted chunk with progress and TensorBoard logs,
checkpoint in the background. Everything on the device is :mod:`cogail_jax.algo.train`."""
from __future__ import annotations

import json
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax
import numpy as np

from ..runtime import checkpoint as ckpt
from ..runtime import distributed
from ..data import manifest
from ..runtime import timing
from ..algo.config import TrainConfig
from .runs import RunError, Setup, _eval_tree, build, eval_params, run_config, total_updates, write_run_dir


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


def seed_mesh(devices: str | int | None, num_seeds: int, env_shards: int = 1):
    """The mesh a run's state is placed on (``devices``: a number or "all", of every process's devices), None for
    one device: with ``env_shards`` > 1 and at least that many devices, an ``("seeds", "envs")`` mesh with one env
    shard per device along "envs" (fewer devices: the shards run side by side on each), else a 1-D ``("seeds",)``
    mesh; the seed axis takes as many of the remaining devices as split the seeds evenly."""
    from jax.sharding import Mesh

    avail = jax.devices()
    if devices is None and distributed.processes() > 1:
        devices = "all"  # several processes: one mesh over every process's devices
    n = len(avail) if devices in ("all", None) else int(devices)
    if devices is None or n <= 1:
        return None
    if n > len(avail):
        raise RunError(f"--devices {n} asked for more devices than the {len(avail)} visible ones")
    e = env_shards if 1 < env_shards <= n else 1
    s = n // e
    while num_seeds % s:  # the seed axis must split evenly
        s -= 1
    if e == 1:
        return None if s <= 1 else Mesh(np.asarray(avail[:s]), ("seeds",))
    return Mesh(np.asarray(avail[:s * e]).reshape(s, e), ("seeds", "envs"))


def place_on_devices(state, expert, devices, num_seeds, env_shards: int = 1):
    """Shard the leading seed axis of the state over the mesh, and the env axis of its env leaves
    (``train.env_leaves``) over the mesh's "envs" axis; replicate the demonstrations. One program: jit follows the
    input shardings, so every device runs its seeds' (and env shard's) rollouts and updates."""
    mesh = seed_mesh(devices, num_seeds, env_shards)
    if mesh is None:
        if distributed.processes() > 1:
            raise RunError(f"a run of {distributed.processes()} processes has nothing to spread over their "
                           f"{jax.device_count()} devices ({num_seeds} seed(s), env_shards={env_shards}): "
                           f"pass --env-shards {jax.device_count()} (or a multiple of the seeds' count of devices)")
        return state, expert
    from jax.sharding import NamedSharding, PartitionSpec as P

    from ..algo.train import env_leaves

    envs = "envs" in mesh.axis_names
    seeds = "seeds" if mesh.shape["seeds"] > 1 else None  # as jit writes its outputs' specs: no axis of size 1
    # Empty leaves (MJX's unused act / mocap / userdata fields, shape (seeds, envs, 0)) leave the sharded program
    # replicated: placing them so from the start keeps every call's input shardings equal to the previous call's
    # outputs (placed P("seeds") they made the second call compile the whole chunk again).
    specs = jax.tree.map(lambda f, x: P() if x.size == 0 else P(seeds, "envs") if f and envs else P(seeds) if seeds
                         else P(), env_leaves(state), state)
    state = jax.tree.map(lambda sp, x: global_put(x, NamedSharding(mesh, sp)), specs, state)
    expert = jax.tree.map(lambda x: global_put(x, NamedSharding(mesh, P())), expert)
    return state, expert


def global_put(x, sharding):
    """``x`` (the same value in every process) placed with ``sharding``, whose devices may span processes."""
    if jax.process_count() == 1:
        return jax.device_put(x, sharding)
    host = np.asarray(jax.device_get(x))
    return jax.make_array_from_callback(host.shape, sharding, lambda idx: host[idx])


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
    """A background thread, started: the training chunk compiled for ``state``'s shapes (arrays or
    ``jax.ShapeDtypeStruct``), then ``on_compiled(s, state)`` (``EvalPrep.start``). The main thread meanwhile
    compiles the initial state's program and runs BC (XLA's compilation and the device loop hold no Python lock).
    A failure only costs the time: the first training call compiles the chunk (and raises the error) itself.
    ``seconds["chunk_compile"]``: how long the compilation took."""
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


def _for_checkpoint(s: Setup, state):
    """The training state as a checkpoint stores it: the env's states as ``env.checkpoint_state`` leaves them (MJX
    tasks zero what their next step recomputes; resume stays bit-exact)."""
    return state.replace(env_state=s.env.checkpoint_state(state.env_state))


def _start_state(s: Setup, mgr, run_dir: Path, resume: bool, devices, clock: timing.Phases, on_compiled=None,
                 parts: dict | None = None):
    """The state training starts from (restored on resume, else fresh with BC pre-training, timed as ``bc``),
    placed on the devices; returns (state, first update, whether ``on_compiled`` was called or is pending).
    On one device a fresh run compiles the training chunk while the initial state compiles and BC runs
    (``_compile_during_bc``, for the shapes ``init.abstract`` gives), its compilation in the ``bc`` phase where it
    outlasts them. ``parts`` receives the bc phase's ``timing.TRAIN_PARTS``."""
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
            t0 = time.perf_counter()
            if seed_mesh(devices, len(cfg.seeds), cfg.env_shards) is None:  # one device: the chunk compiles meanwhile
                here = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])  # where init puts its state
                abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=here),
                                        s.init.abstract(cfg.seeds, s.expert))
                compiling.append(_compile_during_bc(s, abstract, on_compiled, parts))
            state = jax.block_until_ready(s.init(cfg.seeds, s.expert))
            t1 = time.perf_counter()
            for t in compiling:
                t.join()
            parts.update(bc_run=t1 - t0, compile_wait=time.perf_counter() - t1)
    state, s.expert = place_on_devices(state, s.expert, devices, len(cfg.seeds), cfg.env_shards)
    here = ckpt.layout(state)
    if fresh:  # (no policy: evaluation starts at the first checkpoint)
        first = _for_checkpoint(s, state)
        first = distributed.to_host(first) if distributed.processes() > 1 else first
        if distributed.primary():
            ckpt.save(mgr, 0, first)
        del first
    else:
        saved = ckpt.saved_layout(mgr, start) or ckpt.run_layout(run_dir)
        if saved and (saved.get("device_count"), saved.get("device_kind")) != (here["device_count"],
                                                                              here["device_kind"]):
            print(f"restored {len(cfg.seeds)} seeds saved on {ckpt.describe(saved)} onto {ckpt.describe(here)}",
                  flush=True)
    if distributed.primary():
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


def _check_and_log(writers, metrics, update0: int, cfg: TrainConfig, saver) -> dict:
    """One call's metrics to the host: stop on non-finite parameters, else log them to TensorBoard."""
    metrics = distributed.to_host(metrics)
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
    writes = distributed.primary()  # of several processes, process 0 alone writes (runtime.distributed)
    writers = [FileWriter(str(run_dir / "tb" / f"seed_{sd}")) for sd in cfg.seeds] if writes else []
    bar = tqdm(total=total, initial=start, unit="upd", disable=not (progress and writes), dynamic_ncols=True,
               file=sys.stdout)
    saver = ckpt.BackgroundSaver(mgr, ckpt.manager(run_dir, folder=ckpt.POLICIES), json.loads(cfg.to_json()))
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
            if to_save is not None and writes:
                saver.submit(*to_save, policy=_eval_tree(to_save[1]))
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
            copy = None
            if at_ckpt:  # several processes: every one takes part in gathering the state to the host
                copy = (stats.update, saver.copy(_for_checkpoint(s, state)) if distributed.processes() == 1
                        else distributed.to_host(_for_checkpoint(s, state)))
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


KEEP_FULL = 1  # full training states a run keeps by default: the newest, which resume needs


def train_run(cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True,
              stop_after: int | None = None, devices: str | int | None = None, keep: dict | None = None,
              on_compiled=None, keep_full: int | None = KEEP_FULL, given=None, check=None) -> Path:
    """Train (or resume) a run; returns the run directory. Every checkpoint writes the delivered policy to
    RUN/policies/ (what evaluation, play and video read) and the whole training state to RUN/checkpoints/, of
    which the ``keep_full`` newest are kept (resume starts from the newest; None keeps every one). ``stop_after``
    stops early after that many updates (tests use it to simulate an interrupted run). Records the time of each phase in RUN/speed.json
    (``timing``; a resumed run adds to it). ``keep``: a dict that receives each checkpoint's ``eval_params``
    as it is written, for ``eval_run(..., memory=keep)``. ``on_compiled``: see ``_train_loop``. ``given``: the
    fields the user gave, compared on ``resume`` with the run's own (``runs.run_config``). ``check``: called with
    the run's ``Setup`` once its training data are read, before the run folder is written (e.g. the evaluation's
    inputs: ``eval_runner.check_inputs``); the data are read, and ``check`` runs, before anything is written, so that
    a run whose inputs are wrong leaves no folder behind."""
    if keep_full is not None and keep_full < 1:  # before anything is read or written
        raise RunError(f"--keep-full {keep_full}: a run keeps at least its newest training state (resume needs it); "
                       "pass 1 or more, or all")
    clock, compiles = timing.Phases(), timing.CompileLog()
    clock.take_process_start()  # the command's imports before this call count as "start"
    run_dir = Path(run_dir)
    writes = distributed.primary()  # of several processes, process 0 alone writes the run folder
    if distributed.processes() > 1 and devices is None:
        devices = "all"  # every process's devices: one mesh
    s = None
    if writes:
        with clock("start"):
            cfg, starts = run_config(cfg, run_dir, resume, given)
            resume = resume and not starts  # a folder that never trained starts afresh
            from ..runtime.devices import cpu_warning, describe_devices  # a CPU warning for paper-sized MJX runs
            print("\n".join([describe_devices(), *cpu_warning(cfg)]), flush=True)
        with clock("demos"):  # found, not made (`cogail data` makes them): read before the run folder is written
            s = build(cfg, need_heldout=False)
            if check is not None:
                check(s)
        with clock("start"):
            if starts:
                write_run_dir(cfg, run_dir)
    with clock("start"):
        distributed.barrier("prepared")
        if not writes:  # the config process 0 wrote (the resumed run's own on --resume)
            cfg = TrainConfig.load(run_dir / "config.json")
    with clock("demos"):
        if writes:  # recorded in RUN/data.json (and checked against it on resume)
            manifest.check(run_dir, s.files, s.env.version)
            manifest.record_expert(run_dir, s.expert)
        else:
            s = build(cfg, need_heldout=False)
    mgr = ckpt.manager(run_dir, keep=keep_full)
    parts: dict = {}
    state, start, called = _start_state(s, mgr, run_dir, resume, devices, clock, on_compiled, parts)
    stats = _train_loop(s, state, mgr, run_dir, start, progress, stop_after, keep, None if called else on_compiled)
    compile_s = timing.compile_estimate(stats.call_seconds)
    clock.add("compile", compile_s)
    clock.add("train", stats.loop_seconds - compile_s)
    parts.update(timing.call_parts(stats.call_seconds, stats.checkpoint_calls))
    if not writes:
        return run_dir
    timing.write(run_dir, timing.merge_train(
        timing.read(run_dir) if resume else {}, clock, stats.steady_steps, stats.steady_seconds, resume, parts,
        compiles.table(), task=s.cfg.task, method=s.cfg.method, updates=stats.update, seeds=len(s.cfg.seeds),
        steps_per_update=s.cfg.steps_per_update, **timing.device_info()))
    return run_dir


