"""Orbax checkpoints of a run, portable across device layouts: RUN/checkpoints/ holds whole (seed-stacked)
TrainStates, for exact resume (the newest, plus as many as the user keeps: ``manager(run, keep=...)``);
RUN/policies/ holds, at every checkpoint, the delivered policy only (what evaluation, play and video read:
``save_policy``, restored like any checkpoint).

A checkpoint is restored onto the devices of the process that loads it, whatever device kind or count saved it
(a run trained on GPUs is evaluated, played and resumed on a CPU, on fewer devices or on more). A checkpoint that
cannot be read on any layout (damaged or missing files) is reported as corrupt; one that holds another model
(a different configuration) is reported as a mismatch, a user error, never as corruption."""
from __future__ import annotations

import json
import logging
import re
import shutil
import sys
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

logging.getLogger("absl").setLevel(logging.ERROR)


class CheckpointError(RuntimeError):
    """A checkpoint cannot be restored."""


class CheckpointCorrupt(CheckpointError):
    """Its files are damaged or missing: unreadable on any device layout."""


class CheckpointMismatch(CheckpointError):
    """Readable, but it holds another model (tree structure, shapes or dtypes) than this configuration builds."""


class Manager(ocp.CheckpointManager):
    """Orbax's manager, remembering why checkpoints failed to restore (for one clear message when none did)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.failures: dict[int, CheckpointError] = {}


FULL, POLICIES = "checkpoints", "policies"


def manager(run_dir: str | Path, keep: int | None = None, folder: str = FULL) -> Manager:
    """The run's checkpoints (``folder``: ``FULL`` training states, or ``POLICIES``); ``keep``: how many of the
    newest a save leaves (None: all)."""
    path = Path(run_dir).absolute() / folder
    if jax.process_count() == 1:
        return Manager(path, item_handlers=ocp.StandardCheckpointHandler(), options=ocp.CheckpointManagerOptions(
            max_to_keep=keep, create=True, enable_async_checkpointing=False))
    # Several processes (runtime.distributed): each process's manager works alone (process 0 writes, every process
    # reads), so Orbax must not wait for the others at its barriers.
    pid = jax.process_index()
    path.mkdir(parents=True, exist_ok=True)
    return Manager(path, item_handlers=ocp.StandardCheckpointHandler(), options=ocp.CheckpointManagerOptions(
        max_to_keep=keep, create=False, enable_async_checkpointing=False,
        multiprocessing_options=ocp.options.MultiprocessingOptions(
            primary_host=pid, active_processes={pid}, barrier_sync_key_prefix=f"cogail-{folder}-{pid}")))


def policy_manager(run_dir: str | Path) -> Manager | None:
    """RUN/policies' manager, or None where the run has none (trained before policies were kept apart)."""
    return manager(run_dir, folder=POLICIES) if (Path(run_dir) / POLICIES).is_dir() else None


def _empty(x) -> bool:
    return int(np.prod(x.shape)) == 0


def _fill_empty(tree):
    """Orbax cannot store zero-size arrays (MJX's ``mjx.Data`` has some): store a 1-element stand-in."""
    return jax.tree.map(lambda x: np.zeros((1,), x.dtype) if _empty(x) else x, tree)


def _abstract_for_disk(abstract):
    return jax.tree.map(lambda a: jax.ShapeDtypeStruct((1,), a.dtype) if _empty(a) else a, abstract)


# ------------------------------------------------------------------------------------------------ layouts
def layout(tree=None) -> dict:
    """The devices a state lives on (its arrays' devices; else this process's default device)."""
    devs = set()
    for x in jax.tree.leaves(tree) if tree is not None else ():
        if isinstance(x, jax.Array) and not _empty(x):
            devs |= set(x.sharding.device_set)
    devs = sorted(devs, key=lambda d: d.id) or jax.local_devices()[:1]
    return {"platform": devs[0].platform, "device_kind": devs[0].device_kind, "device_count": len(devs)}


def describe(lay: dict | None) -> str:
    """'2 devices (cpu)', '1 device (NVIDIA H100 80GB HBM3)'."""
    if not lay:
        return "an unrecorded layout"
    n = int(lay.get("device_count", 1))
    kind = lay.get("device_kind") or lay.get("platform") or "?"
    return f"{n} device{'s' if n != 1 else ''} ({kind})"


def saved_layout(mgr: ocp.CheckpointManager, step: int) -> dict | None:
    """The layout checkpoint ``step`` was saved on (None for checkpoints that did not record it)."""
    try:
        return (mgr.metadata(int(step)).custom_metadata or {}).get("layout")
    except Exception:  # noqa: BLE001 - metadata of an old or damaged checkpoint
        return None


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def run_layout(run_dir: str | Path) -> dict | None:
    """The layout a run trains on now (run_info.json's ``layout``), None if not recorded."""
    return _read_json(Path(run_dir) / "run_info.json").get("layout")


def record_layout(run_dir: str | Path, lay: dict, update: int) -> None:
    """run_info.json: ``layout`` is the device layout the run trains on now; ``layouts`` lists each layout it
    was trained on with the update it started from (each checkpoint's own is in its Orbax metadata)."""
    path = Path(run_dir) / "run_info.json"
    info = _read_json(path)
    hist = info.get("layouts") or []
    if not hist or {k: v for k, v in hist[-1].items() if k != "from_update"} != lay:
        hist.append({"from_update": int(update), **lay})
    info["layout"], info["layouts"] = lay, hist
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(info, indent=2))
    tmp.replace(path)


# ------------------------------------------------------------------------------------------- save/restore
def save(mgr: ocp.CheckpointManager, step: int, state, **metadata) -> None:
    """Write atomically (Orbax writes to a temporary folder and renames it when complete); the checkpoint's
    metadata records the device layout it was saved on (and ``metadata``)."""
    if step in mgr.all_steps():
        return
    if jax.process_count() > 1:  # Orbax writes no process-local device arrays in a multi-process run: host copies
        state = jax.device_get(state)
    mgr.save(int(step), args=ocp.args.StandardSave(_fill_empty(state)),
             custom_metadata={"layout": layout(state), **metadata})
    mgr.wait_until_finished()


def save_policy(mgr: ocp.CheckpointManager, step: int, policy: dict, config: dict) -> None:
    """The delivered policy of checkpoint ``step`` (``apps.runs._eval_tree``: the co-policy's and psi's parameters
    and the observation normaliser, seed axis first), with the run's config in its metadata."""
    save(mgr, step, policy, config=config)


class BackgroundSaver:
    """Checkpoints written while training goes on, in a worker thread, one at a time in submission order.

    ``copy(state)`` copies the state on its devices (asynchronously: the training call that follows donates its
    input, so the copy is what gets written); ``submit(step, copy)`` queues it for ``save`` (returning at once unless ``MAX_PENDING`` are queued);
    ``wait()`` returns once every submitted checkpoint is on disk and re-raises the first error; ``close()`` waits,
    then stops the thread. Each checkpoint is still atomic (``save``): a run killed mid-write resumes from the
    previous one."""

    def __init__(self, mgr: ocp.CheckpointManager, policies: ocp.CheckpointManager | None = None,
                 config: dict | None = None):
        from concurrent.futures import ThreadPoolExecutor

        self.mgr, self.policies, self.config = mgr, policies, config or {}
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="checkpoint")
        self._pending = []

    @staticmethod
    def copy(state):
        return jax.tree.map(jnp.copy, state)

    MAX_PENDING = 2  # copies queued at most (a slower disk makes training wait rather than fill device memory)

    def _save(self, step: int, copy, policy) -> None:
        if policy is not None and self.policies is not None:
            save_policy(self.policies, step, policy, self.config)
        save(self.mgr, step, copy)

    def submit(self, step: int, copy, policy=None) -> None:
        """Queue checkpoint ``step``: the training state ``copy`` and, with a policy manager, its delivered
        ``policy`` (written first: a run killed between the two resumes from the previous state and writes the
        same policy again)."""
        while len(self._pending) >= self.MAX_PENDING:
            self._pending.pop(0).result()
        done = [f for f in self._pending if f.done()]
        self._pending = [f for f in self._pending if not f.done()]
        for f in done:  # an earlier save's error surfaces at the next checkpoint
            f.result()
        self._pending.append(self._pool.submit(self._save, step, copy, policy))

    def wait(self) -> None:
        pending, self._pending = self._pending, []
        for f in pending:
            f.result()

    def close(self) -> None:
        try:
            self.wait()
        finally:
            self._pool.shutdown()


def steps(mgr: ocp.CheckpointManager) -> list[int]:
    return sorted(mgr.all_steps())


def prune(mgr: ocp.CheckpointManager, keep) -> list[int]:
    """Delete every checkpoint of ``mgr`` but the steps in ``keep``; returns the steps deleted."""
    gone = [st for st in steps(mgr) if st not in set(map(int, keep))]
    for st in gone:
        mgr.delete(st)
    return gone


def _key(k) -> str:
    for attr in ("name", "key", "idx"):
        if hasattr(k, attr):
            return str(getattr(k, attr))
    return str(k)


def _flat(tree, is_leaf=None) -> dict[str, object]:
    leaves = jax.tree_util.tree_flatten_with_path(tree, is_leaf=is_leaf)[0]
    return {"/".join(_key(k) for k in path): x for path, x in leaves}


def _check_fits(mgr, step: int, disk_abstract) -> None:
    """Compare the checkpoint's own metadata (tree, shapes, dtypes) with what this configuration builds.
    Unreadable metadata: CheckpointCorrupt; another tree: CheckpointMismatch."""
    where = f"checkpoint {step} in {mgr.directory}"
    try:
        meta = mgr.item_metadata(int(step))
        meta = getattr(meta, "tree", meta)
        saved = _flat(meta, is_leaf=lambda x: hasattr(x, "shape") and hasattr(x, "dtype"))
        if not saved:
            raise ValueError("no arrays listed")
    except Exception as e:  # noqa: BLE001 - missing / damaged metadata files
        _quiet_failed_reads()
        raise CheckpointCorrupt(f"{where} is unreadable: its files are damaged or missing ({_short(e)})") from e
    want = _flat(disk_abstract)
    if set(saved) != set(want):
        extra, missing = sorted(set(saved) - set(want)), sorted(set(want) - set(saved))
        raise CheckpointMismatch(
            f"{where} holds another model than this run's configuration builds "
            f"({len(saved)} arrays saved, {len(want)} expected; e.g. "
            f"{'saved only: ' + extra[0] if extra else 'missing: ' + missing[0]}): it was written by another "
            f"configuration or version; use the config.json it was trained with or another --run")
    for k, a in want.items():
        m = saved[k]
        if tuple(m.shape) != tuple(a.shape) or np.dtype(m.dtype) != np.dtype(a.dtype):
            raise CheckpointMismatch(
                f"{where} holds another model than this run's configuration builds ({k}: saved "
                f"{tuple(m.shape)} {np.dtype(m.dtype)}, expected {tuple(a.shape)} {np.dtype(a.dtype)}): it was "
                f"written by another configuration or version; use the config.json it was trained with or "
                f"another --run")


def _closed_loop_noise(unraisable) -> bool:
    e = unraisable.exc_value
    return isinstance(e, RuntimeError) and str(e) == "Event loop is closed"


def _quiet_failed_reads() -> None:
    """A failed Orbax restore leaves TensorStore reads pending; each reports, when it ends, a "RuntimeError:
    Event loop is closed" traceback through ``sys.unraisablehook`` or straight to ``sys.stderr``. Drop exactly
    those (the failure itself is reported once, as a CheckpointError); anything else goes where it went."""
    prev = sys.unraisablehook
    if getattr(prev, "_cogail_quiet", False):
        return

    def hook(unraisable):
        if not _closed_loop_noise(unraisable):
            prev(unraisable)

    hook._cogail_quiet = True
    sys.unraisablehook = hook
    if not isinstance(sys.stderr, _QuietStderr):
        sys.stderr = _QuietStderr(sys.stderr)


# A failed Orbax restore leaves TensorStore reads pending; when each ends, its thread prints straight to sys.stderr
# (not through a hook) a traceback of "RuntimeError: Event loop is closed", in pieces that interleave between threads.
_NOISE_LINE = re.compile(r"\s*(?:Traceback \(most recent call last\):|File \"[^\"]*asyncio[/\\]base_events\.py\", "
                         r"line \d+, in (?:call_soon_threadsafe|_check_closed)|self\._check_closed\(\)|"
                         r"raise RuntimeError\('Event loop is closed'\)|RuntimeError: Event loop is closed)\s*")


class _QuietStderr:
    """``sys.stderr`` from the first restore on: what threads other than the main one write is put together line
    by line (per thread; a thread's ``flush`` passes on its unfinished line) and passed on without the lines of
    those tracebacks; the main thread's goes straight through (progress bars, warnings)."""

    def __init__(self, real):
        self.real, self.parts, self.lock = real, {}, threading.Lock()

    def write(self, text: str) -> int:
        if threading.current_thread() is threading.main_thread():
            return self.real.write(text)
        with self.lock:
            *lines, self.parts[threading.get_ident()] = (self.parts.get(threading.get_ident(), "") + text).split("\n")
            kept = [line for line in lines if not _NOISE_LINE.fullmatch(line)]
            if kept:
                self.real.write("\n".join(kept) + "\n")
        return len(text)

    def flush(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            with self.lock:
                part = self.parts.pop(threading.get_ident(), "")
            if part and not _NOISE_LINE.fullmatch(part):
                self.real.write(part)
        self.real.flush()

    def __getattr__(self, name):
        return getattr(self.real, name)


def _short(e: BaseException) -> str:
    msg = " ".join(str(e).split())
    return f"{type(e).__name__}: {msg[:160]}{'...' if len(msg) > 160 else ''}" if msg else type(e).__name__


def _restore(mgr, step: int, abstract_state):
    _quiet_failed_reads()  # before the reads: a failed one's pending reads may end before its error is caught
    disk_abstract = _abstract_for_disk(abstract_state)
    _check_fits(mgr, step, disk_abstract)
    dev = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    # Target shardings on this process's first device: Orbax then never uses the shardings stored at save time.
    target = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=dev), disk_abstract)
    try:
        disk = mgr.restore(int(step), args=ocp.args.StandardRestore(target))
    except Exception:  # noqa: BLE001 - retry without any device layout before calling the files damaged
        _quiet_failed_reads()
        try:
            host = jax.tree.map(lambda a: np.zeros(a.shape, a.dtype), disk_abstract)
            disk = jax.device_put(mgr.restore(int(step), args=ocp.args.StandardRestore(host)), dev)
        except Exception as e:  # noqa: BLE001
            raise CheckpointCorrupt(f"checkpoint {step} in {mgr.directory} is unreadable: its files are damaged "
                                    f"or missing ({_short(e)})") from e
    return jax.tree.map(lambda d, a: jnp.zeros(a.shape, a.dtype, device=dev) if _empty(a) else d,
                        disk, abstract_state)


def restore(mgr: ocp.CheckpointManager, step: int, abstract_state):
    """Restore checkpoint ``step`` onto this process's first device, whatever layout saved it (values bitwise
    as saved; ``trainer.place_on_devices`` spreads them over several). Raises CheckpointCorrupt (damaged or
    missing files) or CheckpointMismatch (another model)."""
    try:
        return _restore(mgr, step, abstract_state)
    except CheckpointError as e:
        if hasattr(mgr, "failures"):
            mgr.failures[int(step)] = e
        raise


def nothing_restored(mgr: ocp.CheckpointManager, run_dir: str | Path) -> CheckpointError:
    """The error for a run none of whose checkpoints restored: one sentence naming the run and the reasons."""
    failures = getattr(mgr, "failures", {})
    bad = sorted(s for s, e in failures.items() if isinstance(e, CheckpointCorrupt))
    other = sorted(s for s, e in failures.items() if isinstance(e, CheckpointMismatch))
    why = []
    if bad:
        why.append(f"checkpoint{'s' if len(bad) > 1 else ''} {', '.join(map(str, bad))} "
                   f"{'are' if len(bad) > 1 else 'is'} damaged (files missing or unreadable)")
    if other:
        why.append(f"checkpoint{'s' if len(other) > 1 else ''} {', '.join(map(str, other))} "
                   f"hold{'' if len(other) > 1 else 's'} another model than its config.json builds")
    reason = " and ".join(why) or "it has no checkpoints"
    return CheckpointError(f"no checkpoint of {Path(run_dir)} can be restored: {reason}; retrain the run "
                           f"(or pass another --run)")


def quarantine(mgr: ocp.CheckpointManager, step: int) -> Path:
    """Move an unreadable checkpoint aside (never delete what a user made) so it can be rewritten."""
    src = Path(mgr.directory) / str(step)
    dst_dir = Path(mgr.directory).parent / "corrupt_checkpoints"
    dst_dir.mkdir(exist_ok=True)
    dst = dst_dir / f"{step}.{int(time.time())}"
    shutil.move(str(src), str(dst))
    mgr.reload()
    return dst


def restore_latest_valid(mgr: ocp.CheckpointManager, abstract_state, log=print):
    """Restore the newest readable checkpoint onto this process's first device. Damaged ones (unreadable on
    any layout) are reported and moved to ``corrupt_checkpoints/``; one that holds another model raises
    CheckpointMismatch (a user error: nothing is moved). Returns (step, state) or (None, None)."""
    for step in reversed(steps(mgr)):
        try:
            return step, restore(mgr, step, abstract_state)
        except CheckpointCorrupt as e:
            if jax.process_index() != 0:  # process 0 moves it aside (runtime.distributed); the others go on
                log(f"warning: {e}; trying the previous one")
                continue
            dst = quarantine(mgr, step)
            log(f"warning: {e}; moved it to {dst} and trying the previous one")
    return None, None
