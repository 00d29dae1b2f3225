"""Where a run's wall-clock time goes: RUN/speed.json, written by ``cogail train`` and ``cogail eval``.

Phases, in seconds (``PHASES``):

* ``start``: from the command's start to the training demonstrations: imports, the accelerator's start-up and the
  run folder (from ``train_run``'s call when it is not run by the ``cogail`` command);
* ``demos``: loading (or generating and caching) the training demonstrations and building the programs;
* ``bc``: the initial state and behaviour-cloning pre-training, their compilation included (0 on resume); on one
  device the training program is compiled while BC runs, and what of its compilation outlasts BC counts here;
* ``compile``: the first training call minus a steady-state call (the median of the later calls; the whole first
  call when there is only one);
* ``train``: the rest of the training loop (rollouts, updates, logs, checkpoints); ``train_parts``
  (``TRAIN_PARTS``) splits the ``bc`` and ``train`` phases further;
* ``eval``: evaluating the checkpoints (the test and validation splits loaded, the varied humans made); its parts
  are in ``eval_parts`` (``EVAL_PARTS``);
* ``write``: writing results.json / results.md and the figures.

``compiles`` (``CompileLog``): every XLA compilation of the command (JAX's monitoring events), by program: how
many, and their seconds (a persistent-cache hit counts its load); ``trace`` the seconds spent tracing and lowering
them. ``cogail bench --phases RUN`` tabulates them with the phases.

``total`` is the wall-clock of the commands (set-up included, so a little more than the phases' sum). A resumed
training adds its seconds to the earlier ones; an evaluation replaces the earlier evaluation's. The record also
holds the training's env steps/s after compilation, the device and whether deterministic GPU execution was on.
"""
from __future__ import annotations

import json
import statistics
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

PHASES = ("start", "demos", "bc", "compile", "train", "eval", "write")
TRAIN_PHASES = ("start", "demos", "bc", "compile", "train")
EVAL_PHASES = ("eval", "write")
# The evaluation's parts: the set-up (splits, varied humans); every checkpoint's program (interpolation, test,
# validation; tracing and compilation included); the extra sets' replays; and, not in the eval phase, the seconds
# its set-up and compilation took in the background while training ran (``cogail train --eval``).
EVAL_PARTS = ("setup", "checkpoints", "extra_sets", "prepared")
# The bc and train phases' parts: ``bc_run``, the initial state and BC until they are ready (main thread);
# ``chunk_compile``, the training program's compilation in the background meanwhile (one device, fresh run);
# ``compile_wait``, how long the bc phase waited for it after BC; ``calls``, the training calls after the first;
# ``median_call``, their median seconds; ``checkpoint_excess`` / ``other_excess``: the seconds over the median of
# the calls that copied or queued a checkpoint, and of the others (an upper bound on what checkpoints cost: where
# the pipelined calls alternate in length, as on a 2-core CPU, the excess mostly measures that; a run with fewer
# checkpoints measures their cost).
TRAIN_PARTS = ("bc_run", "chunk_compile", "compile_wait", "calls", "median_call", "checkpoint_excess",
               "other_excess")
FILE = "speed.json"


class CompileLog:
    """Every compilation of this process from the moment it is made, by program name, from JAX's monitoring events:
    ``backend`` (XLA's compilation, or the persistent cache's load) and ``trace`` (tracing and lowering to MLIR).
    ``table()``: {name: {"count", "backend", "trace"}} (seconds), largest first. One listener serves every log (a
    log only reads the events recorded since it was made). ``this_thread``: only the compilations of the thread that
    made the log (not those of threads working beside it, e.g. ``cogail data``'s training programs compiled ahead),
    so that the log's seconds are part of that thread's wall time."""

    _events: list = []
    _registered = False
    _lock = threading.Lock()
    BACKEND = "/jax/core/compile/backend_compile_duration"
    TRACE = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration")

    def __init__(self, this_thread: bool = False) -> None:
        self._thread = threading.get_ident() if this_thread else None
        cls = type(self)
        with cls._lock:
            if not cls._registered:
                import jax

                jax.monitoring.register_event_duration_secs_listener(cls._listen)
                cls._registered = True
            self._start = len(cls._events)

    @classmethod
    def _listen(cls, event: str, seconds: float, **kw) -> None:
        if event == cls.BACKEND or event in cls.TRACE:
            name = str(kw.get("fun_name", "?"))
            if name.startswith("jit(") and name.endswith(")"):  # one row per program: its trace and compilation
                name = name[4:-1]
            cls._events.append((event, name, float(seconds), threading.get_ident()))

    def table(self) -> dict:
        out: dict = {}
        for event, name, secs, thread in type(self)._events[self._start:]:
            if self._thread is not None and thread != self._thread:
                continue
            row = out.setdefault(name, {"count": 0, "backend": 0.0, "trace": 0.0})
            if event == self.BACKEND:
                row["count"] += 1
                row["backend"] += secs
            else:
                row["trace"] += secs
        return dict(sorted(out.items(), key=lambda kv: -(kv[1]["backend"] + kv[1]["trace"])))


class Phases:
    """Wall seconds per named phase: ``with clock("bc"): ...`` (a phase timed twice adds up); ``elapsed()`` is
    the time since the clock was made."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._t0 = time.perf_counter()

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + max(0.0, float(seconds))

    def elapsed(self) -> float:
        return time.perf_counter() - self._t0

    def take_process_start(self) -> None:
        """Move this clock's origin back to the command's start (``mark_process_start``), counting the seconds in
        between as ``start``; a no-op when no command marked one (or it was taken already)."""
        global _process_t0
        if _process_t0 is not None and _process_t0 < self._t0:
            self.add("start", self._t0 - _process_t0)
            self._t0 = _process_t0
        _process_t0 = None


_process_t0: float | None = None


def mark_process_start(on: bool = True) -> None:
    """Note the command's start (the ``cogail`` command calls it first, and with ``on=False`` when it ends), for
    the ``start`` phase of a run it trains."""
    global _process_t0
    _process_t0 = time.perf_counter() if on else None


def compile_estimate(call_seconds: list[float]) -> float:
    """Compilation in the first of several timed calls: its excess over the median later call."""
    if not call_seconds:
        return 0.0
    if len(call_seconds) == 1:
        return call_seconds[0]
    return max(0.0, call_seconds[0] - statistics.median(call_seconds[1:]))


def call_parts(call_seconds: list[float], checkpoint_calls: set[int]) -> dict[str, float]:
    """``TRAIN_PARTS``' share of the training loop: the calls after the first (which compiles), their median, and
    the seconds over it of the calls in ``checkpoint_calls`` (indices into ``call_seconds``) and of the others."""
    later = call_seconds[1:]
    if not later:
        return {"calls": 0, "median_call": 0.0, "checkpoint_excess": 0.0, "other_excess": 0.0}
    med = statistics.median(later)
    over = [(i, max(0.0, t - med)) for i, t in enumerate(call_seconds) if i > 0]
    return {"calls": len(later), "median_call": med,
            "checkpoint_excess": sum(x for i, x in over if i in checkpoint_calls),
            "other_excess": sum(x for i, x in over if i not in checkpoint_calls)}


def read(run_dir: str | Path) -> dict:
    """RUN/speed.json, or {} when it is missing or unreadable."""
    try:
        rec = json.loads((Path(run_dir) / FILE).read_text())
    except (OSError, ValueError):
        return {}
    return rec if isinstance(rec, dict) else {}


def write(run_dir: str | Path, record: dict) -> Path:
    path = Path(run_dir) / FILE
    path.write_text(json.dumps(record, indent=2))
    return path


def _finish(rec: dict) -> dict:
    rec["phases"] = {p: float(rec.get("phases", {}).get(p, 0.0)) for p in PHASES}
    rec["total"] = float(sum(rec.get("wall", {}).values()))
    return rec


def _merge_compiles(old: dict | None, new: dict | None) -> dict:
    out = {k: dict(v) for k, v in (old or {}).items()}
    for name, row in (new or {}).items():
        o = out.setdefault(name, {"count": 0, "backend": 0.0, "trace": 0.0})
        for k in ("count", "backend", "trace"):
            o[k] = o.get(k, 0) + row.get(k, 0)
    return dict(sorted(out.items(), key=lambda kv: -(kv[1]["backend"] + kv[1]["trace"])))


def merge_train(old: dict, clock: Phases, steady_steps: int, steady_seconds: float, resumed: bool,
                parts: dict | None = None, compiles: dict | None = None, **info) -> dict:
    """The record after a training call: ``clock``'s training phases (added to ``old``'s when ``resumed``, else
    replacing ``old``), the env steps and seconds after compilation, ``parts`` (``TRAIN_PARTS``, this call's:
    they replace ``old``'s) and ``info`` (task, device, ...)."""
    rec = dict(old) if resumed else {}
    phases = dict(rec.get("phases", {}))
    wall = dict(rec.get("wall", {}))
    for p in TRAIN_PHASES:
        phases[p] = phases.get(p, 0.0) + clock.seconds.get(p, 0.0)
    wall["train"] = wall.get("train", 0.0) + clock.elapsed()
    steps = int(rec.get("train_env_steps", 0)) + int(steady_steps)
    secs = float(rec.get("seconds_after_compile", 0.0)) + float(steady_seconds)
    rec.update(info, phases=phases, wall=wall, train_env_steps=steps, seconds_after_compile=secs,
               env_steps_per_s=steps / secs if steps and secs > 0 else None,
               train_parts={p: float((parts or {}).get(p, 0.0)) for p in TRAIN_PARTS},
               compiles=_merge_compiles(rec.get("compiles"), compiles))
    return _finish(rec)


def merge_eval(old: dict, clock: Phases, parts: Phases | None = None, compiles: dict | None = None,
               **info) -> dict:
    """The record after an evaluation: ``clock``'s eval and write phases (and ``parts``' ``EVAL_PARTS`` of the eval
    phase) replace ``old``'s; ``compiles`` (the evaluation's) are added to the training's."""
    rec = dict(old)
    rec["compiles"] = _merge_compiles(rec.get("compiles"), compiles)
    phases = dict(rec.get("phases", {}))
    phases.update({p: clock.seconds.get(p, 0.0) for p in EVAL_PHASES})
    rec.update(info, phases=phases, wall={**rec.get("wall", {}), "eval": clock.elapsed()},
               eval_parts={p: (parts.seconds.get(p, 0.0) if parts else 0.0) for p in EVAL_PARTS})
    return _finish(rec)


def device_info() -> dict:
    """The device a record was measured on and whether deterministic GPU execution was on."""
    import jax

    from .xla import deterministic_ops

    devs = jax.devices()
    return {"device": devs[0].device_kind, "device_count": len(devs), "platform": devs[0].platform,
            "deterministic_ops": deterministic_ops()}


def _cell(x) -> str:
    return "-" if not isinstance(x, (int, float)) or isinstance(x, bool) else f"{x:.1f}"


def phases_table(records: list[tuple[str, dict]]) -> str:
    """A markdown table, one row per (run name, speed.json record): seconds per phase, total, env steps/s."""
    head = ["run", "task", *PHASES, "total", "env steps/s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, rec in records:
        ph = rec.get("phases") or {}
        sps = rec.get("env_steps_per_s")
        row = [name, str(rec.get("task", "-")), *(_cell(ph.get(p)) for p in PHASES), _cell(rec.get("total")),
               f"{sps:.3g}" if isinstance(sps, (int, float)) else "-"]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def parts_table(records: list[tuple[str, dict]]) -> str:
    """A markdown table, one row per (run name, speed.json record): ``TRAIN_PARTS`` and ``EVAL_PARTS`` (seconds;
    ``calls`` a count); "-" where a record has none."""
    head = ["run", *TRAIN_PARTS, *(f"eval {p}" for p in EVAL_PARTS)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, rec in records:
        tp, ep = rec.get("train_parts") or {}, rec.get("eval_parts") or {}
        cells = [str(int(tp["calls"])) if p == "calls" and isinstance(tp.get(p), (int, float)) else
                 f"{tp[p]:.3f}" if p == "median_call" and isinstance(tp.get(p), (int, float)) else _cell(tp.get(p))
                 for p in TRAIN_PARTS]
        lines.append("| " + " | ".join([name, *cells, *(_cell(ep.get(p)) for p in EVAL_PARTS)]) + " |")
    return "\n".join(lines)


def compiles_table(records: list[tuple[str, dict]], top: int = 12) -> str:
    """A markdown table, one row per program compiled in any of the runs (``compiles`` of their speed.json): its
    compilations and seconds (XLA, tracing) per run; the ``top`` costliest programs of the first run lead."""
    names: list[str] = []
    for _, rec in records:
        for n in rec.get("compiles") or {}:
            if n not in names:
                names.append(n)
    cost = {n: max(sum((rec.get("compiles") or {}).get(n, {}).get(k, 0.0) for k in ("backend", "trace"))
                   for _, rec in records) for n in names}
    names = sorted(names, key=lambda n: -cost[n])
    head = ["program", *(f"{name}: n / XLA s / trace s" for name, _ in records)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    rest = names[top:]
    for n in names[:top]:
        cells = []
        for _, rec in records:
            r = (rec.get("compiles") or {}).get(n)
            cells.append("-" if not r else f"{r['count']} / {r['backend']:.1f} / {r['trace']:.1f}")
        lines.append("| " + " | ".join([f"`{n}`", *cells]) + " |")
    if rest or names:
        cells = []
        for _, rec in records:
            c = rec.get("compiles") or {}
            tot = [sum(c.get(n, {}).get(k, 0) for n in names) for k in ("count", "backend", "trace")]
            cells.append(f"{tot[0]} / {tot[1]:.1f} / {tot[2]:.1f}")
        lines.append("| " + " | ".join([f"all {len(names)} programs", *cells]) + " |")
    return "\n".join(lines)


__all__ = ["PHASES", "Phases", "CompileLog", "compiles_table", "mark_process_start", "compile_estimate", "call_parts", "read", "write", "merge_train",
           "merge_eval", "device_info", "EVAL_PARTS", "TRAIN_PARTS", "phases_table", "parts_table"]
