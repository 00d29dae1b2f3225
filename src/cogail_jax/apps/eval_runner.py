"""The evaluation host loop: evaluate every checkpoint of a run (:mod:`cogail_jax.eval.rollouts`' programs),
report with :mod:`cogail_jax.eval.protocol`, replay extra sets; ``EvalPrep`` makes it ready during training."""
from __future__ import annotations

import json
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np
from cogail_envs import get_task

from ..runtime import checkpoint as ckpt
from ..data import io as data
from ..data import manifest
from ..data import sets as data_sets
from ..eval import field as field_eval
from ..eval import rollouts
from ..eval import protocol
from ..eval import coplay as coplay_eval
from ..runtime import tblog, timing
from ..algo.config import ConfigError, TrainConfig
from .runs import Policies, RunError, Setup, _eval_tree, build, total_updates


def replay_results_dir(run_dir: str | Path, replay_file: str | Path) -> Path:
    """Where an extra test set's own results go (``eval --replay-file FILE``): RUN/replay-<file stem>/."""
    return Path(run_dir) / f"replay-{Path(replay_file).stem}"


def _checkpoints_to_evaluate(store: Policies, every: int) -> list[int]:
    steps = [st for st in store.steps() if st > 0] or store.steps()
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


def _checkpoint_params(store: Policies, memory: dict | None, step: int) -> dict:
    """``eval_params`` of checkpoint ``step``: from ``memory`` (kept by the training loop) or read from the run's
    policies (``runs.Policies``)."""
    if memory and step in memory:
        return memory[step]
    return store.load(step)


def _lengths(sets, key: str = "length") -> np.ndarray:
    """One array of ``key`` (the recordings' lengths) over episode sets (``heldout_arrays``)."""
    return np.concatenate([np.asarray(e[key]) for e in sets] or [np.zeros(0, int)])


def _extra_batch(s: Setup, eps: dict) -> tuple[dict, dict]:
    """The extra sets' episodes stacked into one replay batch (``rollouts.make_replay_fn``'s ``episodes``) and each
    set's slice of it."""
    batch, part = rollouts.stack_sets(eps, steps=rollouts.replay_steps(s.env, _lengths(eps.values()),
                                                                       _lengths(eps.values(), "margin")))
    return {k: batch[k] for k in ("init", "ah", "length", "patient", "margin")}, part


def _replay_extra_sets(s: Setup, store: Policies, res: dict, extra_sets: dict, memory: dict | None = None,
                       eps: dict | None = None, replay=None) -> dict:
    """Replay each extra set at the selected and the paper-protocol replay checkpoints: all sets stacked into one
    batch (one compiled replay program, one call per checkpoint); returns {name: protocol.summarize_extra_set(...)}.
    ``memory``: checkpoints kept by the training loop (``eval_run``); ``eps``: the sets' episodes, if read already;
    ``replay``: ``rollouts.make_replay_fn``'s program, if made already."""
    replay = replay or rollouts.make_replay_fn(s.cfg, s.env, s.nets)
    cks = _extra_set_checkpoints(res)
    states = {st: _checkpoint_params(store, memory, st) for st in sorted(set(cks.values()))}
    eps = _extra_episodes(s, extra_sets) if eps is None else eps
    if not eps:
        return {}
    arrays, part = _extra_batch(s, eps)
    at = {st: np.asarray(jax.device_get(replay(states[st]["params"], states[st]["norm"], arrays))["success"])
          for st in states}  # once per checkpoint: the selected one is often the paper protocol's too
    succ = {key: at[st] for key, st in cks.items()}
    return {name: protocol.summarize_extra_set({key: x[:, part[name]] for key, x in succ.items()},
                                               eps[name]["strategy"], s.cfg.seeds, s.env.strategy_names, cks,
                                               file=path)
            for name, path in extra_sets.items()}


def _extra_sets_results(s: Setup, per_ckpt: dict, res: dict, eps: dict, files: dict) -> dict:
    """{name: protocol.summarize_extra_set(...)} of the extra sets replayed (with every checkpoint) in the
    evaluation batch, at the selected and the paper-protocol replay checkpoints, plus ``curve``: the replay
    success of every seed at every checkpoint."""
    cks, steps = _extra_set_checkpoints(res), sorted(per_ckpt)
    out = {}
    for name in files:
        out[name] = protocol.summarize_extra_set({key: per_ckpt[st]["extra"][name] for key, st in cks.items()},
                                                 eps[name]["strategy"], s.cfg.seeds, s.env.strategy_names, cks,
                                                 file=files[name])
        # (seeds, checkpoints), like results.json's curves: the set's replay success at every checkpoint
        out[name]["curve"] = np.stack([per_ckpt[st]["extra"][name].mean(1) for st in steps], 1).tolist()
    return out


def _save_extra_sets(run_dir: Path, res: dict, names) -> None:
    for name in names:
        d = replay_results_dir(run_dir, name)
        d.mkdir(parents=True, exist_ok=True)
        r = protocol.extra_set_results(res, name)
        (d / "results.json").write_text(json.dumps(r, indent=2))
        (d / "results.md").write_text(protocol.extra_set_results_markdown(r))


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
    steps = _checkpoints_to_evaluate(Policies(run_dir), every)
    if res.get("policies_kept") is not None:  # evaluated, then its policies pruned: current until it trains on
        return every == 1 and "paper_protocol" in res and steps == res["policies_kept"]
    return "paper_protocol" in res and res.get("selected") is not None and res.get("checkpoints") == steps


def prune_policies(run_dir: str | Path) -> list[int]:
    """After an evaluation: delete the delivered policies of RUN/policies/ that RUN/results.json reports no figure
    of (``protocol.reported_checkpoints``; the newest is kept too). results.json keeps every checkpoint's evaluation
    and records the steps kept (``policies_kept``); extra sets, co-play, play and video read those. Returns the
    steps deleted (none for a run without RUN/policies/: its full training states are never pruned here)."""
    run_dir = Path(run_dir)
    res = json.loads((run_dir / "results.json").read_text())
    store = Policies(run_dir)
    if store.full or not store.steps():
        return []
    keep = set(protocol.reported_checkpoints(res)) | {store.steps()[-1]}
    if set(store.steps()) <= keep:
        return []
    # results.json first: a run stopped in between still has every policy it names, and its next prune ends the job
    res["policies_kept"] = [st for st in store.steps() if st in keep]
    (run_dir / "results.json").write_text(json.dumps(res, indent=2))
    return ckpt.prune(store.mgr, keep)


def was_pruned(run_dir: str | Path) -> bool:
    """Whether RUN was evaluated and its policies then pruned (``prune_policies``): its results.json stands."""
    try:
        return json.loads((Path(run_dir) / "results.json").read_text()).get("policies_kept") is not None
    except (OSError, ValueError):
        return False


def _refuse_pruned(run_dir: Path, store: Policies) -> None:
    """A run whose evaluated policies were pruned cannot be evaluated at every checkpoint again."""
    try:
        res = json.loads((run_dir / "results.json").read_text())
    except (OSError, ValueError):
        return
    if res.get("policies_kept") is not None and set(res.get("checkpoints") or ()) - set(store.steps()):
        raise RunError(f"{run_dir} keeps the policies of the checkpoints its evaluation reports only "
                       f"({res['policies_kept']}), and its results.json holds every checkpoint's evaluation: add "
                       "test sets with --replay-file, redo co-play with --coplay-only, or train it again with "
                       "--keep-policies all to evaluate every checkpoint anew")


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
    s = build(TrainConfig.load(run_dir / "config.json"), need_heldout=False, run_dir=run_dir)
    res["extra_sets"] = {**(res.get("extra_sets") or {}), **_replay_extra_sets(s, Policies(run_dir, s), res, sets)}
    protocol.save_results(run_dir, res)
    _save_extra_sets(run_dir, res, sets)
    return res


def eval_run(run_dir: str | Path, progress: bool = True, every: int = 1, replay_file: str | Path | None = None,
             extra_sets: dict[str, str | Path] | None = None, ckpt_batch: int | None = None,
             robustness: bool = False, memory: dict | None = None, extra_curves: bool = False,
             prepared: EvalInputs | None = None, coplay: bool = False, coplay_episodes: int | None = None) -> dict:
    """Evaluate every checkpoint of a run; write results.json / results.md and figures into the run dir.

    Every checkpoint and seed is evaluated on the test split (replay, interpolation, latent codes) and on the
    validation split (replay); ``protocol.summarize`` turns that into the reported figures (paper protocol,
    selected on validation, last).

    ``extra_sets``: {name: demonstration file}: further test sets (recorded trials, imported files, varied human
    trajectories, one file per variation), replayed and reported at the selected checkpoint and at the
    paper-protocol replay checkpoint (one compiled replay program, ``_replay_extra_sets``); results in
    results.json's ``extra_sets[name]`` and in RUN/replay-<name>/results.{json,md}. ``extra_curves``: replay them
    at every checkpoint instead, in the batch of the test and validation splits, and add each set's ``curve``
    (and RUN/robustness_curves.png), for several times the evaluation's work; the figures are the same on the CPU
    and move at the rounding level on a GPU (where a batch's kernels depend on its size).

    The interpolation rollouts and the replays of the test and validation splits run as one batch of one
    compiled program (``rollouts.make_eval_fn``), at every checkpoint.
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

    ``coplay``: also closed-loop co-play (:mod:`cogail_jax.eval.coplay`): the learned robot at the selected and the
    paper-protocol replay checkpoints, and the task's scripted robot as reference, each with every partner (the
    scripted human, each of its variations, a human proxy behaviour-cloned on the test split), ``coplay_episodes``
    episodes per partner (default ``coplay.default_episodes()``); results.json's ``coplay``, RUN/coplay.png. On a
    task learned from people (``field.supported``: people's data, both seats) it is the field's protocol instead
    (:mod:`cogail_jax.eval.field`: the robot with H_proxy, a behaviour clone of the test pairs, in both seats, at
    the checkpoint selected with the validation pairs' clone): results.json's ``field``.

    ``prepared``: the run's ``EvalInputs`` made already, or the ``EvalPrep`` making them while training runs (waited
    for in the eval phase's set-up); its extra sets and ``extra_curves`` then stand for the arguments'.

    The seconds spent evaluating and writing replace the ``eval`` and ``write`` phases of RUN/speed.json."""
    clock, part_clock, compiles = timing.Phases(), timing.Phases(), timing.CompileLog()
    run_dir = Path(run_dir)
    TrainConfig.load(run_dir / "config.json")  # no run, or a damaged config: one sentence before anything is read
    with clock("eval"):
        with part_clock("setup"):
            store = Policies(run_dir)
            _refuse_pruned(run_dir, store)
            steps = _checkpoints_to_evaluate(store, every)
            if not steps:
                raise RunError(f"{run_dir} has no checkpoints yet: train it first")
            if hasattr(prepared, "result"):  # an EvalPrep still at work: the eval phase pays for the wait
                prepared = prepared.result()
            inp = prepared or _eval_inputs(run_dir, _extra_sets(extra_sets, replay_file), robustness, extra_curves)
            s, sets, eps, part = inp.s, inp.sets, inp.eps, inp.part
            store.s = s
        with part_clock("checkpoints"):
            per_ckpt, codes = _evaluate_checkpoints(s, store, steps, inp.held, part, ckpt_batch, progress,
                                                    memory, inp.evaluate_fn)
            if not per_ckpt:
                raise ckpt.nothing_restored(store.mgr, run_dir)
            res, at, lat = _summarize(s, per_ckpt, codes, part)
            windows = tblog.episode_windows(res["checkpoints"], -(-s.env.max_episode_steps // s.cfg.unroll_length))
            train_succ = tblog.training_success(run_dir, s.cfg.seeds, s.cfg.steps_per_update, windows)
            if train_succ is not None:  # the co-policy's own training episodes, from the run's TensorBoard logs
                res["training_success"] = train_succ
            if sets and inp.extra_curves:
                res["extra_sets"] = _extra_sets_results(s, per_ckpt, res, eps, sets)
        with part_clock("extra_sets"):
            if sets and not inp.extra_curves:
                res["extra_sets"] = _replay_extra_sets(s, store, res, sets, memory, eps, inp.replay_fn)
        if coplay and not field_eval.supported(s.env):
            with part_clock("coplay"):
                res["coplay"] = _coplay(s, store, res, memory, coplay_episodes, inp.coplay)
        elif coplay:  # a task learned from people: the field's protocol
            with part_clock("field"):
                res["field"] = field_eval.evaluate(s, lambda st: _checkpoint_params(store, memory, st), steps)
    with clock("write"):
        _write_eval_outputs(run_dir, s, res, at, lat, sets, robustness)
    if prepared is not None:
        part_clock.add("prepared", prepared.seconds)
    timing.write(run_dir, timing.merge_eval(timing.read(run_dir), clock, part_clock, compiles.table(),
                                            **timing.device_info()))
    return res


def _coplay(s: Setup, store: Policies, res: dict, memory: dict | None, episodes: int | None,
            prepared: coplay_eval.Prepared | None = None) -> dict:
    """results.json's ``coplay``: co-play at the selected and the paper-protocol replay checkpoints
    (``coplay.evaluate``; ``prepared``: its set-up made already, used where made for these ``episodes``)."""
    cks = _extra_set_checkpoints(res)
    states = {st: _checkpoint_params(store, memory, st) for st in sorted(set(cks.values()))}
    if prepared is not None and prepared.episodes != int(episodes or coplay_eval.default_episodes()):
        prepared = None
    return coplay_eval.evaluate(s, {key: (st, states[st]) for key, st in cks.items()}, episodes, prepared=prepared)


def eval_coplay(run_dir, episodes: int | None = None) -> dict:
    """Co-play alone, for an evaluated run: at the checkpoints its results.json reports (selected, paper protocol),
    written into results.json's ``coplay``, results.md and RUN/coplay.png; nothing else is evaluated again."""
    run_dir = Path(run_dir)
    try:
        res = json.loads((run_dir / "results.json").read_text())
    except (OSError, ValueError):
        raise RunError(f"{run_dir} has no results.json to add co-play to: evaluate it first (cogail eval --run "
                       f"{run_dir})") from None
    s = build(TrainConfig.load(run_dir / "config.json"), run_dir=run_dir)
    store = Policies(run_dir)
    store.s = s
    res["coplay"] = _coplay(s, store, res, None, episodes)
    protocol.save_results(run_dir, res)
    coplay_eval.figure(res["coplay"], run_dir / "coplay.png",
                       title=f"{s.cfg.method} on {s.cfg.task}: closed-loop co-play")
    return res


@dataclass
class EvalInputs:
    """What evaluating a run needs before it reads a checkpoint: the set-up, the extra sets (name -> file) and
    their episodes, the batch of every checkpoint's program (test, validation; the extra sets too with
    ``extra_curves``) and each set's slice of it, the two programs (``rollouts.make_eval_fn``,
    ``rollouts.make_replay_fn``) and, where prepared, co-play's. ``seconds``: how long making them took
    (``EvalPrep``)."""
    s: Setup
    sets: dict
    eps: dict
    held: dict
    part: dict
    extra_curves: bool
    evaluate_fn: object
    replay_fn: object
    seconds: float = 0.0
    coplay: coplay_eval.Prepared | None = None  # co-play's proxy and compiled program (``coplay_eval.prepare``)


def _eval_inputs(run_dir: Path, sets: dict[str, str], robustness: bool, extra_curves: bool) -> EvalInputs:
    s, sets = _eval_setup(run_dir, sets, robustness)
    eps = _extra_episodes(s, sets)
    split_sets = {"test": s.heldout, "validation": s.validation,
                  **{EXTRA + n: e for n, e in eps.items() if extra_curves}}
    held, part = rollouts.stack_sets(split_sets, steps=rollouts.replay_steps(
        s.env, _lengths(split_sets.values()), _lengths(split_sets.values(), "margin")))
    return EvalInputs(s, sets, eps, held, part, extra_curves, rollouts.make_eval_fn(s.cfg, s.env, s.nets),
                      rollouts.make_replay_fn(s.cfg, s.env, s.nets))


def _eval_struct(state) -> dict:
    """The shapes of ``eval_params(state)`` (on this process's first device, as it puts them)."""
    dev = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=dev), _eval_tree(state))


def _compile_eval(inp: EvalInputs, struct: dict, checkpoints: int, coplay: tuple | None = None) -> None:
    """Compile ``inp``'s programs for a run of ``checkpoints`` checkpoints (``struct``: ``_eval_struct``) as
    ``eval_run`` will call them: the checkpoints' program for ``default_ckpt_batch`` of them, the replay of the
    extra sets for one checkpoint, and with ``coplay`` (its episodes per partner, or None for the default) co-play's
    proxy and program (``inp.coplay``), or on a task learned from people the field's plays (into the compilation
    cache, where its evaluation finds them). They are traced one after another in this thread and each compiles in a
    thread of its own as soon as it is traced (XLA's compilations run side by side; tracing holds Python's lock, and
    three programs tracing at once took three times as long each, slowing the training loop beside them)."""
    c = default_ckpt_batch(checkpoints)
    stacked = jax.tree.map(lambda x: jax.ShapeDtypeStruct((c,) + x.shape, x.dtype, sharding=x.sharding), struct)
    with ThreadPoolExecutor(3, thread_name_prefix="eval-compile") as pool:
        compiling = [pool.submit(inp.evaluate_fn.lower(stacked["params"], stacked["norm"], inp.held).compile)]
        if inp.eps and not inp.extra_curves:
            compiling.append(pool.submit(inp.replay_fn.lower(struct["params"], struct["norm"],
                                                             _extra_batch(inp.s, inp.eps)[0]).compile))
        if coplay is not None and not field_eval.supported(inp.s.env):
            p = coplay_eval.prepare(inp.s, coplay[0])
            compiling.append(pool.submit(p.run.lower(struct["params"], struct["norm"], p.proxy, p.batch).compile))
            inp.coplay = p
        elif coplay is not None:  # on a task learned from people, the field's plays (its BC models kept or fitted)
            compiling += [pool.submit(lowered.compile)
                          for lowered in field_eval.Field(inp.s).lower_plays(struct, checkpoints)]
        for f in compiling:
            f.result()


SWITCH_INTERVAL = 2e-4  # seconds: how soon a thread waiting for Python's lock gets it while EvalPrep traces


class EvalPrep:
    """``cogail train --eval``'s evaluation made ready while training runs, when the host is idle and the device
    busy: in a background thread, the test, validation and varied-human sets are loaded and the evaluation
    programs traced and compiled (``EvalInputs``; with ``coplay``, co-play's proxy trained and its program compiled
    too, for ``coplay_episodes``). ``start`` starts it once the training program has compiled
    (``train_run``'s ``on_compiled``: while BC runs on a fresh one-device run, else after the first training call;
    started beside the training program's compilation instead, it slowed that compilation, on the critical path,
    by more than it saved: docs/notes.md); ``result()`` waits for it. A preparation that fails prints a warning, and ``eval_run`` then
    prepares again itself (raising the error, if it is one, where it belongs)."""

    def __init__(self, run_dir: str | Path, robustness: bool = True, extra_curves: bool = False,
                 extra_sets: dict[str, str | Path] | None = None, coplay: bool = False,
                 coplay_episodes: int | None = None):
        self.run_dir, self.robustness, self.extra_curves = Path(run_dir), robustness, extra_curves
        self.coplay = (coplay_episodes,) if coplay else None
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
            _compile_eval(inp, struct, checkpoints, self.coplay)
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


PATIENT = "patient-"  # an extra set replayed with a patient human (rollouts._episodes_fn, the task's replay_hold)


def _extra_episodes(s: Setup, sets: dict[str, str]) -> dict[str, dict]:
    """The extra sets' replay episodes (humans from outside the splits: with the replay margin); a set named
    ``patient-...`` is replayed with a patient human."""
    return {name: rollouts.heldout_arrays(data.load_demos(path, s.env, require_init=True),
                                          patient=name.startswith(PATIENT), margin=True)
            for name, path in sets.items()}


def check_inputs(s: Setup, robustness: bool = True) -> None:
    """The evaluation's own files of ``s``'s run (``s``: its set-up without them, ``build(..., need_heldout=False)``),
    checked before ``cogail train --eval`` trains: the test and validation splits (there, and holding what replay
    reads, ``init`` included) and with ``robustness`` the varied humans (there, and so too). A missing or malformed
    one raises the error the evaluation would raise after training. Cheap: the files' layouts, not their arrays
    (``io.check_demos``)."""
    env = s.task_env or s.env  # where the generated sets are found; their episodes are read in ``s.env``
    for split in (data_sets.TEST, data_sets.VALIDATION):
        data.check_demos(data_sets.split_path(s.cfg, split, env=env, verbose=False), s.env, require_init=True)
    if robustness:
        for path in data_sets.robustness_paths(s.cfg, env=env, verbose=False).values():
            data.check_demos(path, s.env, require_init=True)


def _eval_setup(run_dir: Path, sets: dict[str, str], robustness: bool) -> tuple[Setup, dict[str, str]]:
    """The run's set-up with the test and validation splits, and the extra sets to replay: ``sets``, those of an
    earlier evaluation whose files still exist, and with ``robustness`` the varied humans (``cogail data`` makes
    them; checked against the run's data manifest)."""
    try:  # the extra sets of an earlier evaluation are evaluated again at the new checkpoints
        prev = json.loads((run_dir / "results.json").read_text()).get("extra_sets") or {}
    except (OSError, ValueError, AttributeError):
        prev = {}
    for name, e in prev.items():
        if name not in sets and isinstance(e, dict) and e.get("file") and Path(e["file"]).exists():
            sets[name] = e["file"]
    s = build(TrainConfig.load(run_dir / "config.json"), run_dir=run_dir)
    if robustness:
        varied = {k: str(v) for k, v in data_sets.robustness_paths(s.cfg).items()}
        sets.update(varied)
        if s.env.has_patient_replay:  # the same humans, waiting for the robot where the task says
            sets.update({PATIENT + name: path for name, path in {"test": s.files["test"], **varied}.items()})
        manifest.check(run_dir, varied, s.env.version)  # the run's own sets (a user's extra sets may grow)
    return s, sets


MAX_CKPT_BATCH = 64  # checkpoints per evaluation program on an accelerator, at most


def default_ckpt_batch(checkpoints: int) -> int:
    """Checkpoints per evaluation program when none is given: on an accelerator all of them (up to
    ``MAX_CKPT_BATCH``), so one device program evaluates the run; 1 on the CPU (where a wider batch only costs
    memory and compilation)."""
    return 1 if jax.default_backend() == "cpu" else max(1, min(int(checkpoints), MAX_CKPT_BATCH))


def _out_of_memory(e: Exception) -> bool:
    return "RESOURCE_EXHAUSTED" in str(e) or "out of memory" in str(e).lower()


def _evaluate_checkpoints(s: Setup, store: Policies, steps: list[int], held: dict, part: dict, ckpt_batch: int,
                          progress: bool, memory: dict | None = None, evaluate_fn=None) -> tuple[dict, object]:
    """{step: _split_sets(...)} for every checkpoint that restores (``ckpt_batch`` of them per device call), and
    the interpolation codes. A device call that runs out of memory is tried again with half as many checkpoints
    per call (a warning names the ``--ckpt-batch`` to give next time)."""
    from tqdm import tqdm

    evaluate_fn = evaluate_fn or rollouts.make_eval_fn(s.cfg, s.env, s.nets)
    per_ckpt = {}
    ckpt_batch = max(1, min(int(ckpt_batch or default_ckpt_batch(len(steps))), len(steps)))
    bar = tqdm(total=len(steps), desc="eval", disable=not progress, file=sys.stdout)
    stack = lambda *x: jax.numpy.stack(x)  # noqa: E731
    i = 0
    while i < len(steps):
        group = []
        for step in steps[i:i + ckpt_batch]:
            try:
                group.append((step, _checkpoint_params(store, memory, step)))
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
                      f"{ckpt_batch} (give --ckpt-batch {ckpt_batch} next time; on a GPU another batch can move "
                      f"figures at the rounding level, so compare runs evaluated with the same batch)", flush=True)
                continue
            for j, (step, _) in enumerate(group):
                per_ckpt[step] = _split_sets(jax.tree.map(lambda x: x[j], out), part)
        bar.update(len(steps[i:i + ckpt_batch]))
        i += ckpt_batch
    bar.close()
    return per_ckpt, rollouts.interpolation_codes(s.cfg.eval_codes)


def _summarize(s: Setup, per_ckpt: dict, codes, part: dict):
    """The reported figures (``protocol.summarize``) with the splits and the latent map; returns (results, the
    selected checkpoint's evaluation, its latent codes or None)."""
    cfg = s.cfg
    res = protocol.summarize(cfg.task, cfg.method, cfg.seeds, per_ckpt, s.env.strategy_names, codes,
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
    protocol.save_results(out_dir, res)
    _save_extra_sets(out_dir, res, sets)
    protocol.write_figures(out_dir, res, lat, np.asarray(s.heldout["strategy"]), s.env.strategy_names)
    from ..data.varied import PREFIX as ROBUST

    if robustness and any(name.startswith(ROBUST) for name in res.get("extra_sets") or {}):  # the task has them
        from ..eval import robustness as rfig

        rfig.robustness_figure(res, out_dir / "robustness.png", title=f"{cfg.method} on {cfg.task}: varied humans")
        curves = out_dir / "robustness_curves.png"
        if rfig.robustness_curve_figure(res, curves, title=f"{cfg.method} on {cfg.task}: varied humans per "
                                      "checkpoint") is None:
            curves.unlink(missing_ok=True)  # an earlier evaluation's (with extra_curves): not these results
    if res.get("coplay"):
        coplay_eval.figure(res["coplay"], out_dir / "coplay.png",
                           title=f"{cfg.method} on {cfg.task}: closed-loop co-play")
    task = get_task(cfg.task)
    if task.spots and all(k in at["interp_metrics"] for k in task.spots):  # where the strategy happened (Fig. 4a)
        protocol.write_spots(out_dir / f"{task.name}_spots.png", res, task.spots, at["interp_metrics"],
                             at["interp_success"], s.train_metrics, what=task.name)


__all__ = ["eval_run", "eval_coplay", "eval_extra_sets", "EvalPrep", "results_current", "replay_results_dir",
           "default_ckpt_batch", "prune_policies", "was_pruned"]
