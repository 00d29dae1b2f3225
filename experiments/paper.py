"""Rebuild the paper's tables: Table 1 (replay), Table 2 (interpolation), Fig. 3 (strategy proportions on
fetchq for the D1 / D2 mixtures), for every task x method (3 seeds each, one vmapped program per run).

    python experiments/paper.py --tasks fetchq --methods cogail,ma_gail --out results/paper [--mixes uniform,D1,D2]
    python experiments/paper.py --out docs/results/paper --tables-only --readme README.md

Each (task, method, mixture) makes its datasets (``cogail data``) and trains with the task's settings
(``cogail_envs.<task>.config``, plus ``--set``) into
``<out>/runs/<task>-<method>-<mix>-<hash>``, where ``<hash>`` is a short hash of the fully resolved training
config: a run is reused (resumed if interrupted) only if its config is the same, and any change (a ``--set``, a
new default) trains a new run. Every checkpoint is evaluated (``cogail eval``'s protocol); ``<out>/paper.json``
holds each run's results (keyed task/method/mixture, with the config hash). Every cell of the tables gives the
checkpoint selected on the validation split reported on the test split, the paper's protocol (max over
checkpoints of the mean over seeds, on test) and the paper's number: ``<out>/table1_replay.md``,
``<out>/table2_interpolation.md``, ``<out>/fig3_strategies.{md,png}``. Varied humans of the test split (``robust-*``) go
to ``<out>/robustness.md``; those drawn from the validation split (``val-robust-*``; with a patient human too on the
MJX tasks, ``patient-val-robust-*`` beside ``patient-validation``), for every run and ``--label`` variant, to
``<out>/robustness_validation.md``: choose variants there. ``--readme FILE`` rewrites the block
between ``<!-- results:begin -->`` and ``<!-- results:end -->`` in FILE with the same tables; ``--tables-only``
trains nothing and only rewrites the tables (and the README block) from ``<out>/paper.json``.

Jobs (one per task x method x mixture) run one per GPU: with several GPUs visible (``--gpus all``, the
default, or ``--gpus N``) each job is a process of its own on one GPU (``CUDA_VISIBLE_DEVICES``), at most one per
GPU at a time (``--jobs-per-gpu K``: K; the jobs share the GPU's memory, and their figures are those of one job at a
time; ``--task-jobs-per-gpu TASK=K``: at most K of TASK's at once on one GPU) and the rest queued, its results in
``<out>/jobs/<task>-<method>-<mix>/`` and merged into ``<out>/paper.json`` as it ends. Each task's datasets are made first, by one process per task
(``--data-only``; log ``<out>/jobs/<task>-data.log``), so that jobs side by side never write the same file; a task's
jobs start when its datasets are ready. On a task learned from people, the field's cross-play of its robots is a job of
its own too (``--crossplay`` on the task's rows, log ``<out>/jobs/<task>-cross-play.log``), started once the task's last
job has ended, beside the other tasks' jobs. ``--shard i/n`` runs only every n-th job from the i-th (0-based), so that
n hosts share the grid; ``--merge`` then joins their ``paper.json``.

Each run's entry records the commit it was trained at (and whether the code had uncommitted changes) and the
``--set`` overrides it was resolved with. A row is *stale* when it was not trained from this checkout's code (another
commit whose ``src/``, ``envs/`` or ``pyproject.toml`` differ from this one's, other built-in tasks' packages
``envs/<task>/`` aside, or whose own task's folder does, for a task of your own in this repository, or uncommitted
changes) or when its config is not what the current settings resolve to; ``--check`` lists the stale rows (exit
status 1 if any), and a grid run trains stale rows again instead of reusing them.

GPU execution is deterministic (XLA_FLAGS ``--xla_gpu_deterministic_ops=true``) unless ``--nondeterministic``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"

def paper_figures(column: str) -> dict:
    """The paper's figures (Table 1 ``replay``, Table 2 ``interpolation``) as {method: {task: (mean, std)}}, from
    the built-in tasks' settings (``Task.paper``)."""
    from cogail_envs import builtin_task_names, get_task

    out: dict = {}
    for t in builtin_task_names():
        for m, fig in get_task(t).paper.get(column, {}).items():
            out.setdefault(m, {})[t] = fig
    return out


MIX_SHARES = {"D1": (17, 17, 33, 33), "D2": (33, 33, 17, 17)}  # the demonstrations' strategy shares (%), Fig. 3
KEEP = ("task", "method", "seeds", "checkpoints", "paper_protocol", "selected", "last", "per_seed_best",
        "breakdowns_at", "strategy_distribution", "strategy_distribution_per_seed", "replay_by_strategy",
        "interpolation_events", "curves", "splits", "extra_sets",
        "validation_strategy_distribution", "coplay", "field")  # what paper.json keeps of results.json


def resolve_config(task, method, mix, seeds, extra: dict, budget: str = "paper"):
    """The run's config as `cogail train --task T --budget B --set ...` resolves it."""
    from cogail_jax.algo.config import resolve

    return resolve(task, budget, {**extra, "method": method, "mix": mix, "seeds": tuple(seeds)})


def config_hash(cfg) -> str:
    """A short hash of the fully resolved training config (every field, defaults included)."""
    return hashlib.sha256(json.dumps(json.loads(cfg.to_json()), sort_keys=True).encode()).hexdigest()[:10]


def run_dir(out: Path, cfg) -> Path:
    return out / "runs" / f"{cfg.task}-{cfg.method}-{cfg.mix}-{config_hash(cfg)}"


def validation_robustness_sets(task, mix) -> dict:
    """The varied humans drawn from the validation split (``val-robust-<variation>``), replayed at every checkpoint
    beside the test ones, so that robustness-oriented choices (a variant, its settings) are made on validation."""
    import cogail_envs
    from cogail_jax.data import varied as robustness

    from cogail_jax.data.io import ensure_default_demos
    from cogail_jax.apps.eval_runner import PATIENT

    env = cogail_envs.make_env(task)  # made here, explicitly: the evaluation itself only reads data
    team = cogail_envs.get_task(task).team
    if team is None or not team.variations:  # no scripted human to vary (a task learned from people)
        return {}
    sets = {"val-" + name: str(path)
            for name, path in robustness.ensure_robustness_sets(env, mix=mix, split="validation").items()}
    if env.has_patient_replay:  # and with a patient human, as the test's (choices on the patient protocol)
        sets.update({PATIENT + name: path for name, path in sets.items()})
        sets[PATIENT + "validation"] = str(ensure_default_demos(env, "validation", mix))
    return sets


# ----------------------------------------------------------------------------------------------- staleness
# what a run's figures depend on (git pathspecs from the top): not the apps that serve people or draw episodes (the
# play and collect pages, their controls, videos), which training and evaluation never import
CODE = (":/src", ":/envs", ":/pyproject.toml", *(f":(top,exclude)src/cogail_jax/apps/{f}" for f in
                                               ("play.py", "play.html", "collect.py", "collect.html", "controls.py",
                                                "video.py")))


def task_code(task: str | None = None) -> tuple[str, ...]:
    """What the figures of ``task``'s rows depend on: ``CODE`` without the other built-in tasks' packages
    (``envs/<name>/``; nothing outside a task's package names a task, so editing one task, or adding your own,
    leaves the other tasks' rows fresh), and a task of your own's folder where it lies in this repository
    (``own_task_folder``). ``None``: all of ``CODE``."""
    if task is None:
        return CODE
    import cogail_envs

    own = own_task_folder(task)
    return CODE + ((f":(top){own}",) if own else ()) + tuple(
        f":(top,exclude)envs/{name}" for name in cogail_envs.builtin_task_names()
        if name != task and (ROOT.parent / "envs" / name).is_dir())


def own_task_folder(task: str) -> str | None:
    """The folder, relative to this repository's top, of a task of your own given as ``module:TASK`` or
    ``folder:TASK`` (its package's folder, or the folder of its module file); None for a task named otherwise or
    one outside the repository."""
    if ":" not in task:
        return None
    from cogail_envs import get_task

    ref = task.rpartition(":")[0]
    path = Path(ref)
    if not path.exists():
        get_task(task)  # imports its module the way every command does
        file = getattr(sys.modules.get(ref), "__file__", None)
        if not file:
            return None
        path = Path(file)
    folder = (path if path.is_dir() else path.parent).resolve()
    try:
        return folder.relative_to(ROOT.parent.resolve()).as_posix()
    except ValueError:
        return None


def _git(*args) -> subprocess.CompletedProcess | None:
    try:
        return subprocess.run(["git", *args], capture_output=True, text=True, timeout=30, cwd=ROOT)
    except (OSError, subprocess.SubprocessError):
        return None


def head_commit() -> str | None:
    """This checkout's commit (None outside a git repository)."""
    r = _git("rev-parse", "HEAD")
    return r.stdout.strip() if r is not None and r.returncode == 0 else None


def code_changed(commit: str, head: str, task: str | None = None) -> bool | None:
    """Whether the code ``task``'s figures depend on (``task_code``) differs between ``commit`` and ``head`` (None:
    git cannot tell, e.g. an unknown commit)."""
    if commit == head:
        return False
    r = _git("diff", "--quiet", commit, head, "--", *task_code(task))
    return None if r is None or r.returncode not in (0, 1) else r.returncode == 1


def stale(results: dict, head: str | None = None) -> dict[str, str]:
    """The rows of ``results`` (paper.json) not trained from ``head``'s code (default: this checkout's) with the
    config the current settings resolve to: ``{key: why}``."""
    head = head or head_commit()
    why = {}
    for key, res in sorted(results.items()):
        task, method, mix = key.split("/")[:3]
        commit = res.get("commit")
        if not commit:
            why[key] = "no commit recorded (trained before runs recorded theirs)"
        elif res.get("dirty"):
            why[key] = f"trained from uncommitted changes to {commit[:10]}"
        elif "sets" not in res or "seeds" not in res:
            why[key] = "its --set overrides or seeds were not recorded"
        elif res.get("config_hash") != (now := config_hash(resolve_config(task, method, mix, res["seeds"],
                                                                          res["sets"]))):
            why[key] = f"config {res.get('config_hash')} is not what the settings resolve to now ({now})"
        elif head is None:
            why[key] = "this checkout is not a git repository: its code cannot be compared"
        else:
            changed = code_changed(commit, head, task)
            if changed is None:
                why[key] = f"commit {commit[:10]} is not in this repository"
            elif changed:
                why[key] = f"trained at {commit[:10]}: the code has changed since"
    return why


def run_one(task, method, mix, seeds, out: Path, extra: dict, every: int = 1,
            ckpt_batch: int | None = None) -> dict:
    from cogail_jax.algo.config import TrainConfig
    from cogail_jax.apps import eval_runner, train_loop
    from cogail_jax.data.sets import make_datasets

    cfg = resolve_config(task, method, mix, seeds, extra)
    make_datasets(cfg)  # `cogail data`
    run = run_dir(out, cfg)
    saved = run / "config.json"
    resume = saved.exists() and TrainConfig.load(saved) == cfg  # the same resolved config: resume / reuse
    if saved.exists() and not resume:
        raise SystemExit(f"{run} holds a run of another config: remove it")
    kept, sets = {}, validation_robustness_sets(task, mix)
    # as `cogail train --eval`: the evaluation, co-play included, is made ready while training runs (for the
    # default evaluation of every checkpoint in the default batches; any other is prepared by eval_run itself)
    prep = (eval_runner.EvalPrep(run, robustness=True, extra_sets=sets, coplay=True)
            if every == 1 and ckpt_batch is None else None)
    train_loop.train_run(cfg, run, resume=resume, progress=False, keep=kept,
                         on_compiled=prep.start if prep else None)
    res = eval_runner.eval_run(run, progress=False, every=every, robustness=True, ckpt_batch=ckpt_batch, memory=kept,
                               extra_sets=sets, prepared=prep, coplay=True)
    info = json.loads((run / "run_info.json").read_text()) if (run / "run_info.json").is_file() else {}
    return {**{k: res[k] for k in KEEP if k in res}, "config_hash": config_hash(cfg), "run": str(run),
            "eval_every": every, "commit": info.get("git_commit"), "dirty": info.get("git_dirty"), "sets": extra}


def row_digits(res: dict) -> dict[str, str]:
    """What the tables show of one row, as printed: the selected checkpoint, replay and interpolation (selected and
    paper protocol, mean +- std over seeds) and co-play with each partner (selected checkpoint)."""
    sel, pp = res.get("selected") or {}, res.get("paper_protocol") or {}
    out = {"selected checkpoint": str(sel.get("checkpoint", "-"))}
    for col in ("replay", "interpolation"):
        out[f"{col}: selected"], out[f"{col}: paper protocol"] = fmt(sel.get(col)), fmt(pp.get(col))
    got = (((res.get("coplay") or {}).get("learned") or {}).get("selected") or {}).get("success") or {}
    out.update({f"co-play with {p}": fmt(v) for p, v in sorted(got.items())})
    return out


def compare(results: dict, ref: dict) -> tuple[list[str], list[str]]:
    """The rows of ``results`` also in ``ref`` (e.g. docs/results/paper/paper.json): (keys whose printed figures are
    the same to the last digit, one line per figure that differs, 'key: what: here vs ref'). Co-play measured in one
    grid only (rows evaluated without it) is not compared."""
    same, diffs = [], []
    for key in sorted(set(results) & set(ref)):
        a, b = row_digits(results[key]), row_digits(ref[key])
        keys = sorted((set(a) | set(b)) - ({k for k in set(a) ^ set(b) if k.startswith("co-play")}))
        bad = [f"{key}: {k}: {a.get(k, '-')} vs {b.get(k, '-')}" for k in keys if a.get(k, "-") != b.get(k, "-")]
        (diffs.extend(bad) if bad else same.append(key))
    return same, diffs


# ----------------------------------------------------------------------------------------------- sweeps
def gpu_count(env=None) -> int:
    """The NVIDIA GPUs this process may use: CUDA_VISIBLE_DEVICES's entries where it is set, else ``nvidia-smi
    -L``'s; 0 without any."""
    env = os.environ if env is None else env
    if "CUDA_VISIBLE_DEVICES" in env:
        return len([d for d in env["CUDA_VISIBLE_DEVICES"].split(",") if d.strip() and d.strip() != "-1"])
    if not shutil.which("nvidia-smi"):
        return 0
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return 0
    return sum(line.startswith("GPU ") for line in out.splitlines())


def gpu_slots(gpus: str, env=None) -> list[str]:
    """The GPU ids jobs run on: ``all`` (every visible GPU; one slot, in this process, without any) or a number."""
    env = os.environ if env is None else env
    visible = [d.strip() for d in env.get("CUDA_VISIBLE_DEVICES", "").split(",") if d.strip()]
    n = gpu_count(env)
    ids = visible if visible else [str(i) for i in range(n)]
    if gpus == "all":
        return ids or ["-"]
    if not gpus.isdigit() or int(gpus) < 1:
        raise SystemExit(f"--gpus {gpus}: give a number of GPUs (1 or more) or all")
    k = int(gpus)
    if ids and k > len(ids):
        raise SystemExit(f"--gpus {k}: only {len(ids)} GPU(s) are visible; give at most {len(ids)} or all")
    return ids[:k] if ids else [str(i) for i in range(k)]


def shard_jobs(jobs: list, shard: str | None) -> list:
    """Every n-th job from the i-th (``shard`` "i/n", 0 <= i < n), in order; all of them for None."""
    if not shard:
        return list(jobs)
    try:
        i, n = (int(x) for x in shard.split("/"))
        if not 0 <= i < n:
            raise ValueError
    except ValueError:
        raise SystemExit(f"--shard {shard}: give i/n with 0 <= i < n, e.g. 0/2 on the first of two hosts")
    return list(jobs)[i::n]


def job_slots(gpus: list[str], per_gpu: int = 1) -> list[str]:
    """The slots of ``per_gpu`` jobs on each of ``gpus`` (``gpu_slots``'s ids), one GPU after another at each depth
    so that jobs spread over the GPUs first: the id itself for one job per GPU, else ``<id>:<k>``."""
    if per_gpu < 1:
        raise SystemExit(f"--jobs-per-gpu {per_gpu}: give 1 or more")
    return list(gpus) if per_gpu == 1 else [f"{g}:{k}" for k in range(per_gpu) for g in gpus]


def task_caps(items: list[str]) -> dict[str, tuple[str, int]]:
    """``--task-jobs-per-gpu TASK=K`` items as {task: (TASK, K)} for :func:`run_jobs`'s ``limit``: a task with
    variants stands for all of them, which share its K."""
    from cogail_envs import task_names

    caps = {}
    for item in items:
        name, _, k = item.partition("=")
        if not k.isdigit() or int(k) < 1:
            raise SystemExit(f"--task-jobs-per-gpu {item}: give TASK=K with K 1 or more, e.g. handover=3")
        if name not in task_names():
            raise SystemExit(f"--task-jobs-per-gpu {item}: no task {name!r}; give one of {', '.join(task_names())}")
        caps.update({t: (name, int(k)) for t in expand_tasks([name])})
    return caps


def check_tasks(tasks: list[str]) -> None:
    """``SystemExit`` with one sentence naming the fix if a task of ``--tasks`` does not exist."""
    from cogail_envs import UnknownTaskError, get_task

    for t in tasks:
        try:
            get_task(t)
        except UnknownTaskError as e:
            raise SystemExit(f"--tasks: {e}")


def check_grid(tasks: list[str], methods: list[str], seeds: str, mixes: str) -> list[int]:
    """The grid's methods, seeds and fetchq mixtures checked before anything runs: the seeds as integers, or
    ``SystemExit`` with one sentence naming the option and the fix."""
    from cogail_envs import get_task
    from cogail_jax.algo.config import METHODS

    if bad := [m for m in methods if m not in METHODS]:
        raise SystemExit(f"--methods: no method {bad[0]!r}; give comma-separated names of {', '.join(METHODS)}")
    try:
        seeds_ = [int(x) for x in seeds.split(",")]
    except ValueError:
        raise SystemExit(f"--seeds {seeds}: give comma-separated integers, e.g. 300,400,500")
    if "fetchq" in tasks:
        named = ("uniform", *get_task("fetchq").mixtures)
        if bad := [m for m in mixes.split(",") if m not in named]:
            raise SystemExit(f"--mixes: no fetchq mixture {bad[0]!r}; give comma-separated names of {', '.join(named)}")
    return seeds_


def slot_device(slot: str) -> str:
    """The GPU id (``CUDA_VISIBLE_DEVICES``) of a slot of :func:`job_slots`."""
    return slot.split(":")[0]


def run_jobs(jobs: list, slots: list[str], launch, poll: float = 0.5, ready=None, limit=None):
    """Run ``jobs`` at most one per slot at a time, in order, each as ``launch(job, slot)`` (a process: ``poll()``
    None while it runs, else its exit code); yields ``(job, exit code)`` as each ends. ``ready(job)``: True when a
    queued job may start, False while it must wait (the first ready one starts first), None when it never can (it is
    yielded with exit code None, not launched); without it every job is ready. ``limit(job)``: ``(group, k)``, at
    most k jobs of that group side by side on one GPU (:func:`slot_device`), or None for no limit."""
    queue, free, running = list(jobs), list(slots), {}
    ready = ready or (lambda job: True)
    limit = limit or (lambda job: None)

    def fits(job, slot):
        lim = limit(job)
        return lim is None or sum(slot_device(s) == slot_device(slot) and limit(j) is not None and limit(j)[0] == lim[0]
                                  for s, (j, _) in running.items()) < lim[1]

    while queue or running:
        for job in [j for j in queue if ready(j) is None]:
            queue.remove(job)
            yield job, None
        while free:
            pick = next(((j, s) for j in queue if ready(j) for s in free if fits(j, s)), None)
            if pick is None:
                break
            job, slot = pick
            queue.remove(job)
            free.remove(slot)
            running[slot] = (job, launch(job, slot))
        if queue and not running and not any(ready(j) for j in queue):
            raise RuntimeError(f"jobs wait on nothing that runs: {queue}")
        ended = [(slot, job, proc.poll()) for slot, (job, proc) in running.items() if proc.poll() is not None]
        for slot, job, code in ended:
            del running[slot]
            free.append(slot)
            yield job, code
        if not ended:
            time.sleep(poll)


DATA = "data"  # a data job: (task, DATA, "mix,mix", "method,method")


def job_name(job) -> str:
    return "-".join(job[:2]) if job[1] == DATA else "-".join(job)


def data_jobs(todo: list) -> list[tuple]:
    """One job per task of ``todo`` that makes every dataset its jobs need (their mixtures and methods)."""
    out = {}
    for t, m, mix in todo:
        mixes, methods = out.setdefault(t, ({}, {}))
        mixes[mix], methods[m] = None, None
    return [(t, DATA, ",".join(mixes), ",".join(methods)) for t, (mixes, methods) in out.items()]


def data_argv(a, job) -> list[str]:
    """The command of a data job: this script with ``--data-only`` on its task, mixtures and methods."""
    t, _, mixes, methods = job
    argv = [sys.executable, str(Path(__file__).resolve()), "--data-only", "--tasks", t, "--no-variants", "--methods",
            methods, "--mixes", mixes, "--seeds", a.seeds]
    for item in a.set:
        argv += ["--set", item]
    for flag, on in (("--nondeterministic", a.nondeterministic), ("--no-compile-cache", a.no_compile_cache)):
        argv += [flag] if on else []
    return argv


def make_data(tasks, methods, mixes_of, seeds, extra) -> None:
    """Every dataset of the grid's jobs (``make_datasets`` of each job's config) and the validation split's varied
    humans of each task and mixture (``validation_robustness_sets``), as the jobs themselves would make them; on a
    task learned from people, the field's BC models too (``field.prepare``), once instead of once per job."""
    from cogail_jax.data.sets import make_datasets
    from cogail_jax.eval import field

    for t in tasks:
        for mix in mixes_of(t):
            for m in methods:
                make_datasets(resolve_config(t, m, mix, seeds, extra))
            validation_robustness_sets(t, mix)
            field.prepare(resolve_config(t, methods[0], mix, seeds, extra))  # before the jobs, which then read them


CROSS = "cross-play"  # a cross-play job: (task, CROSS), ready once every job of its task has ended


def crossplay_argv(a, job, out: Path) -> list[str]:
    """The command of a cross-play job: this script with ``--crossplay`` on ``out`` (a folder holding the task's rows
    as its paper.json), which writes the task's matrix into ``out``'s crossplay.json."""
    return [sys.executable, str(Path(__file__).resolve()), "--crossplay", "--out", str(out)]


def job_argv(a, job, out: Path) -> list[str]:
    """The command of one job of this sweep (its own process, one GPU): this script on that one task x method x
    mixture, with the sweep's other options, into ``out``."""
    t, m, mix = job
    argv = [sys.executable, str(Path(__file__).resolve()), "--tasks", t, "--no-variants", "--methods", m, "--mixes",
            mix, "--out", str(out), "--gpus", "1", "--seeds", a.seeds, "--eval-every", str(a.eval_every)]
    for item in a.set:
        argv += ["--set", item]
    for flag, on in (("--force", a.force), ("--nondeterministic", a.nondeterministic),
                     ("--no-compile-cache", a.no_compile_cache)):
        argv += [flag] if on else []
    argv += ["--label", a.label] if a.label else []
    argv += ["--ckpt-batch", str(a.ckpt_batch)] if a.ckpt_batch else []
    return argv


# ----------------------------------------------------------------------------------------------- tables
def fmt(d) -> str:
    return f"{100 * d['mean']:.1f} +- {100 * d['std']:.1f}" if d else "-"


def figures(res: dict | None, column: str) -> tuple[str, str]:
    """(selected on validation, paper protocol) of one run for ``column`` replay / interpolation, formatted;
    results made before the protocol (no paper_protocol key) give "-"; BC-single has no co-policy human to
    interpolate with ("n/a")."""
    if column == "interpolation" and (res or {}).get("method") == "bc_single":
        return "n/a", "n/a"
    if not res or "paper_protocol" not in res:
        return "-", "-"
    sel = (res.get("selected") or {}).get(column)
    return fmt(sel), fmt(res["paper_protocol"][column])


def _paper(p) -> str:
    return f"{p[0]} +- {p[1]}" if p else "not reported"


def table(results: dict, tasks, methods, column: str, paper: dict) -> list[str]:
    head = "| method | " + " | ".join(f"{t}: selected | {t}: paper protocol | {t}: paper" for t in tasks) + " |"
    rows = [head, "| --- |" + " --- | --- | --- |" * len(tasks)]
    for m in methods:
        cells = [m]
        for t in tasks:
            cells += [*figures(results.get(f"{t}/{m}/uniform"), column), _paper(paper.get(m, {}).get(t))]
        rows.append("| " + " | ".join(cells) + " |")
    return rows


PROTOCOL_NOTE = ("Success rates in %, mean +- std over seeds, on the test split. *selected*: the checkpoint with "
                 "the best mean validation replay success, reported on test (nothing chosen on test). *paper "
                 "protocol*: as the paper reports, the checkpoint with the best mean over seeds on test, per column. "
                 "*paper*: the paper's figure (*not reported*: the paper gives none). -: not measured.")


def fig3_rows(results: dict, methods) -> list[str]:
    keys = [k for k in results if k.startswith("fetchq/") and k.count("/") == 2 and not k.endswith("/uniform")]
    mixes = sorted({k.split("/")[2] for k in keys})
    lines = ["| method | mixture | strategy shares at the selected checkpoint (s1 / s2 / s3 / s4) | at the "
             "paper-protocol interpolation checkpoint | demonstrations |", "| --- | --- | --- | --- | --- |"]
    for mix in mixes:
        for m in methods:
            res = results.get(f"fetchq/{m}/{mix}")
            if not res:
                continue
            sel = " / ".join(f"{100 * v:.0f}" for v in res["strategy_distribution"].values())
            pp = (res.get("paper_protocol") or {}).get("interpolation", {}).get("strategy_distribution")
            pp = " / ".join(f"{100 * v:.0f}" for v in pp.values()) if pp else "-"
            demo = " / ".join(map(str, MIX_SHARES.get(mix, ()))) or "-"
            lines.append(f"| {m} | {mix} | {sel} | {pp} | {demo} |")
    return lines if len(lines) > 2 else []


def fig3_png(results: dict, methods, path: Path) -> bool:
    keys = [k for k in results if k.startswith("fetchq/") and k.count("/") == 2 and not k.endswith("/uniform")]
    if not keys:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mixes = sorted({k.split("/")[2] for k in keys})
    fig, axes = plt.subplots(1, len(mixes), figsize=(5 * len(mixes), 3.5), squeeze=False)
    for ax, mix in zip(axes[0], mixes):
        ms = [m for m in methods if f"fetchq/{m}/{mix}" in results]
        for j, m in enumerate(ms):
            dist = list(results[f"fetchq/{m}/{mix}"]["strategy_distribution"].values())
            ax.bar([i + j * 0.8 / len(ms) for i in range(len(dist))], [100 * v for v in dist], width=0.8 / len(ms),
                   label=m)
        if mix in MIX_SHARES:
            ax.plot(range(4), MIX_SHARES[mix], "k_", ms=20, mew=2, label="demonstrations")
        ax.set_xticks(range(4), ["s1", "s2", "s3", "s4"])
        ax.set_title(f"fetchq {mix} (selected checkpoint)")
        ax.set_ylabel("% of successful rollouts")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


SHIPPED = {"fetchq": "train-varied-20", "handover": "480-demos-train-varied-10-policy-ema",
           "seqmanip": "1000-demos-train-varied-60-policy-ema-0.995-init-std-0.1-bc-std"}
"""The variant label whose run has the settings ``make train TASK=...`` uses (experiments/<task>_paper.json), where
they differ from the main table's (which trains every method on the team demonstrations alone)."""
BUDGETS = {"handover": {"2x": "2x-480-demos-train-varied-10-policy-ema"},
           "seqmanip": {"2x": "2x-1000-demos-train-varied-100-policy-ema-init-std-0.1-bc-std"}}
"""The variant labels of the larger budgets ``make train TASK=... BUDGET=b`` trains (experiments/<task>_<b>.json)."""


def shipped_runs():
    """(task, budget, label) of every configuration ``make train`` ships, the paper budget's first."""
    runs = [(t, "paper", label) for t, label in SHIPPED.items()]
    return runs + [(t, b, label) for t, labels in BUDGETS.items() for b, label in labels.items()]


def curves_png(results: dict, path: Path, method: str = "cogail") -> bool:
    """Learning curves of ``method`` per task, the main table's run and the shipped settings' run (``SHIPPED``):
    replay and interpolation success on test against updates, mean +- std over seeds, the checkpoint selected on
    validation dotted."""
    names = {f"{t}/{method}/uniform/{label}": "make train" + ("" if b == "paper" else f" BUDGET={b}")
             for t, b, label in shipped_runs()}

    def shown(k):
        parts = k.split("/")
        return (parts[1:] == [method, "uniform"] or k in names) and bool((results[k].get("curves") or {}).get("replay_success"))

    keys = sorted((k for k in results if shown(k)), key=lambda k: (k in names, names.get(k, "")))
    tasks = [t for t in ("fetchq", "handover", "seqmanip") if any(k.startswith(t + "/") for k in keys)]
    if not tasks:
        return False
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(tasks), figsize=(4.2 * len(tasks), 5.5), squeeze=False)
    for j, t in enumerate(tasks):
        for k in (k for k in keys if k.startswith(t + "/")):
            r, label = results[k], names.get(k, "main table")
            x = np.asarray(r["checkpoints"])
            for i, col in enumerate(("replay_success", "interpolation_success")):
                y = 100 * np.asarray(r["curves"][col], float)  # (seeds, checkpoints)
                line, = axes[i, j].plot(x, y.mean(0), label=label)
                axes[i, j].fill_between(x, y.mean(0) - y.std(0), y.mean(0) + y.std(0), alpha=0.2,
                                        color=line.get_color())
                sel = (r.get("selected") or {}).get("checkpoint")
                if sel is not None:
                    axes[i, j].axvline(sel, ls=":", color=line.get_color())
        axes[0, j].set_title(f"{t}: {method}")
        for i, name in enumerate(("replay success (%)", "interpolation success (%)")):
            axes[i, j].set_ylabel(name)
            axes[i, j].set_ylim(0, 100)
        axes[1, j].set_xlabel("update")
        axes[1, j].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def _pct(d) -> str:
    return f"{100 * d['mean']:.1f}" if d else "-"


def _in_distribution(r: dict, base: str | None):
    """The in-distribution replay at the selected checkpoint: the test split's (``base`` None), the validation
    split's (``"validation"``) or an extra set's."""
    if base is None:
        return r["selected"]["replay"]
    if base == "validation":
        return r["selected"].get("validation_replay")
    return ((r.get("extra_sets") or {}).get(base) or {}).get("selected")


def robustness_rows(results: dict, tasks, methods, prefix: str = "robust-", base: str | None = None,
                    keys=None) -> list[str]:
    """Replay success against varied humans at the selected checkpoint, next to in-distribution replay there.
    ``prefix``: the varied-human sets (``patient-robust-``: replayed with a patient human; ``val-robust-``: drawn
    from the validation split); ``base``: the in-distribution figure (``_in_distribution``). ``keys``: the results
    to tabulate, one row each named by its key (default: every method of ``tasks`` and the shipped settings). The
    held-out pose slices (``pose_heldout_<axis>``, one column each, after the varied humans) get a column of their own
    beside the worst set's: the worst slice's success over in-distribution replay, which the slices are judged by."""
    from cogail_envs.variations import is_held_out_set

    var = []
    for r in results.values():
        var += [k for k in (r.get("extra_sets") or {}) if k.startswith(prefix) and k not in var]
    if not var:
        return []
    var = [v for v in var if not is_held_out_set(v[len(prefix):])] + [v for v in var if is_held_out_set(v[len(prefix):])]
    held = [i for i, v in enumerate(var) if is_held_out_set(v[len(prefix):])]
    tail = " | worst / in-distribution |" + (" worst slice / in-distribution |" if held else "")
    lines = ["| task | method | in-distribution | " + " | ".join(v[len(prefix):] for v in var) + tail,
             "| --- | --- | --- |" + " --- |" * (len(var) + 1 + bool(held))]
    if keys is None:
        rows = [(t, m, f"{t}/{m}/uniform") for t in tasks for m in methods]
        rows += [(t, f"cogail ({label})", f"{t}/cogail/uniform/{label}") for t, _, label in shipped_runs() if t in tasks]
        rows.sort(key=lambda x: tasks.index(x[0]))
    else:
        rows = [(k.split("/")[0], "/".join(k.split("/")[1:]), k) for k in keys]
    for t, m, key in rows:
        r = results.get(key)
        if not r or not r.get("selected") or m == "bc_single":
            continue
        ind = _in_distribution(r, base)
        if not ind:
            continue
        vs = [((r.get("extra_sets") or {}).get(v) or {}).get("selected") for v in var]
        ratio = lambda xs: (f"{min(xs) / ind['mean']:.2f}" if xs and ind["mean"] > 0 else "-")  # noqa: E731
        cells = [ratio([x["mean"] for x in vs if x])]
        if held:
            cells.append(ratio([vs[i]["mean"] for i in held if vs[i]]))
        lines.append(f"| {t} | {m} | {_pct(ind)} | " + " | ".join(_pct(x) for x in vs) + " | " + " | ".join(cells)
                     + " |")
    return lines


def coplay_rows(results: dict, tasks, methods) -> list[str]:
    """Closed-loop co-play success (%, selected checkpoint, test episodes) of every method's robot with a reacting
    human: the task's scripted human, the worst of its variations of timing and path, the scripted human presenting
    the object in the held-out pose slices (``pose_heldout_<axis>``, or the older single ``pose_heldout``: the worst
    slice and its axis, a column where some row has one; -: that row's task has none, or the row predates them) and
    the BC proxy of the test humans; the scripted robot with the same partners as the reference, and each robot's
    proxy success over the scripted robot's."""
    from cogail_envs.variations import HELD_OUT, is_held_out_set

    timing = lambda p: p not in ("scripted", "proxy") and not is_held_out_set(p)  # noqa: E731  (timing and path)

    def worst_slice(got: dict, mean=lambda v: v["mean"]) -> str:
        held = [(mean(v), p) for p, v in got.items() if is_held_out_set(p)]
        if not held:
            return "-"
        x, p = min(held)
        return f"{100 * x:.1f}" + ("" if p == HELD_OUT else f" ({p[len(HELD_OUT) + 1:]})")
    rows = []  # (task, robot, scripted, worst, held-out, proxy, ratio)
    for t in tasks:
        ref = None
        for m in methods:
            cp = (results.get(f"{t}/{m}/uniform") or {}).get("coplay")
            if not cp:
                continue
            ref = ref or cp.get("scripted_robot")
            got = ((cp.get("learned") or {}).get("selected") or {}).get("success") or {}
            var = [got[p]["mean"] for p in cp.get("partners", []) if timing(p) and p in got]
            sr = (cp.get("scripted_robot") or {}).get("proxy")
            ratio = f"{got['proxy']['mean'] / sr:.2f}" if "proxy" in got and sr else "-"
            worst = f"{100 * min(var):.1f}" if var else "-"
            held = (_pct(got.get(HELD_OUT)) if HELD_OUT in got
                    else worst_slice({p: v for p, v in got.items() if p in cp.get("partners", [])}))
            rows.append((t, m, _pct(got.get("scripted")), worst, held, _pct(got.get("proxy")), ratio))
        if ref:
            var = [v for p, v in ref.items() if timing(p)]
            worst = f"{100 * min(var):.1f}" if var else "-"
            held = worst_slice(ref, mean=lambda v: v)
            proxy = f"{100 * ref['proxy']:.1f}" if "proxy" in ref else "-"
            rows.append((t, "scripted robot (reference)", f"{100 * ref.get('scripted', 0):.1f}", worst, held, proxy,
                         "1.00"))
    if not rows:
        return []
    cols = ["task", "robot", "scripted human", "its variations, worst", "held-out poses, worst slice", "BC proxy",
            "proxy / scripted robot's"]
    keep = [i for i in range(len(cols)) if i != 4 or any(r[4] != "-" for r in rows)]
    return (["| " + " | ".join(cols[i] for i in keep) + " |", "|" + " --- |" * len(keep)]
            + ["| " + " | ".join(r[i] for i in keep) + " |" for r in rows])


def coplay_table(results: dict, tasks, methods) -> list[str]:
    """The README's co-play table, beside Tables 1 and 2: a row per method (and the scripted robot as the reference),
    per task the selected checkpoint's co-play success (%, mean +- std over seeds) with the task's scripted human and
    with the BC proxy of the test humans; -: not measured."""
    def cp(t, m):
        return (results.get(f"{t}/{m}/uniform") or {}).get("coplay") or {}

    tasks = [t for t in tasks if any(cp(t, m) for m in methods)]
    if not tasks:
        return []
    lines = ["| robot | " + " | ".join(f"{t}: scripted human | {t}: BC proxy" for t in tasks) + " |",
             "| --- | " + " | ".join("---: | ---:" for _ in tasks) + " |"]
    for m in methods:
        if not any(cp(t, m) for t in tasks):
            continue
        cells = []
        for t in tasks:
            got = ((cp(t, m).get("learned") or {}).get("selected") or {}).get("success") or {}
            cells += [fmt(got.get("scripted")), fmt(got.get("proxy"))]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    refs = [next((cp(t, m)["scripted_robot"] for m in methods if cp(t, m).get("scripted_robot")), {}) for t in tasks]
    lines.append("| scripted robot (reference) | " + " | ".join(
        f"{100 * r['scripted']:.1f} | " + (f"{100 * r['proxy']:.1f}" if "proxy" in r else "-") if "scripted" in r
        else "- | -" for r in refs) + " |")
    return lines


def _best(results: dict, task: str, methods, column: str):
    """(Co-GAIL's selected mean, the best other method and its mean) of ``column`` on ``task``, or None."""
    def mean(m):
        r = results.get(f"{task}/{m}/uniform") or {}
        if column == "interpolation" and m == "bc_single":
            return None
        return ((r.get("selected") or {}).get(column) or {}).get("mean")

    mine, others = mean("cogail"), [(mean(m), m) for m in methods if m != "cogail" and mean(m) is not None]
    if mine is None or not others:
        return None
    best, who = max(others)
    return mine, who, best


def claims_rows(results: dict, tasks, methods) -> list[str]:
    """Where the grid stands on the paper's claims, claim by claim, each beside the paper's own figures."""
    lines = []
    for column, claim, table in (("replay", "Co-GAIL replays best", "Table 1"),
                                 ("interpolation", "Co-GAIL interpolates at least as well as the baselines", "Table 2")):
        paper = paper_figures(column)
        parts = []
        for t in tasks:
            got = _best(results, t, methods, column)
            if got is None:
                continue
            mine, who, best = got
            ours = "yes" if (mine >= best if column == "interpolation" else mine > best) else "no"
            pb = [(v[t][0], m) for m, v in paper.items() if m != "cogail" and t in v]
            pc = (paper.get("cogail") or {}).get(t)
            theirs = f"; paper: {pc[0]:.1f} vs {max(pb)[1]} {max(pb)[0]:.1f}" if pc and pb else ""
            parts.append(f"{t} {ours} ({100 * mine:.1f} vs {who} {100 * best:.1f}{theirs})")
        if parts:
            lines.append(f"- *{claim}* ({table}, selected checkpoint): " + "; ".join(parts) + ".")
    mixes = [mx for mx in ("D1", "D2") if any(f"fetchq/{m}/{mx}" in results for m in methods)]
    if mixes:
        parts = []
        for mx in mixes:
            rare = {m: min(results[f"fetchq/{m}/{mx}"]["strategy_distribution"].values())
                    for m in methods if (results.get(f"fetchq/{m}/{mx}") or {}).get("strategy_distribution")}
            if "cogail" in rare:
                low = min(((v, m) for m, v in rare.items() if m != "cogail"), default=None)
                parts.append(f"{mx}: Co-GAIL's rarest strategy {100 * rare['cogail']:.0f} %"
                             + (f", the lowest other {low[1]} {100 * low[0]:.0f} %" if low else ""))
        if parts:
            lines.append("- *Co-GAIL keeps every strategy under unbalanced mixtures* (Fig. 3, fetchq): "
                         + "; ".join(parts) + ".")
    parts = []
    for t in tasks:
        cp = (results.get(f"{t}/cogail/uniform") or {}).get("coplay") or {}
        got = (((cp.get("learned") or {}).get("selected") or {}).get("success") or {}).get("proxy")
        ref = (cp.get("scripted_robot") or {}).get("proxy")
        if got and ref:
            parts.append(f"{t} {got['mean'] / ref:.2f}")
    if parts:
        lines.append("- *Beyond the paper: co-play with a BC proxy of the test humans*, Co-GAIL's success over the "
                     "scripted robot's: " + "; ".join(parts) + ".")
    return lines


def stability_rows(results: dict) -> list[str]:
    """Selected vs last checkpoint (replay and interpolation, test) for every run, variants included."""
    lines = ["| run | replay: selected | replay: last | interpolation: selected | interpolation: last |",
             "| --- | --- | --- | --- | --- |"]
    for k in sorted(results):
        r = results[k]
        if not r.get("selected") or not r.get("last"):
            continue
        interp = ("n/a", "n/a") if r.get("method") == "bc_single" else \
            (fmt(r["selected"]["interpolation"]), fmt(r["last"]["interpolation"]))
        replay = (fmt(r["selected"]["replay"]), fmt(r["last"]["replay"]))
        lines.append(f"| {k} | {replay[0]} | {replay[1]} | {interp[0]} | {interp[1]} |")
    return lines if len(lines) > 2 else []


def variant_rows(results: dict) -> list[str]:
    keys = sorted(k for k in results if k.count("/") >= 3)
    if not keys:
        return []
    lines = ["| variant (task/method/mix/label) | replay: selected | replay: paper protocol | interpolation: selected "
             "| interpolation: paper protocol |", "| --- | --- | --- | --- | --- |"]
    for k in keys:
        (rs, rp), (is_, ip) = figures(results[k], "replay"), figures(results[k], "interpolation")
        lines.append(f"| {k} | {rs} | {rp} | {is_} | {ip} |")
    return lines


def shipped_rows(results: dict) -> list[str]:
    """What ``make train TASK=...`` gives (the ``SHIPPED`` variant of each task, else its main Co-GAIL row): replay and
    interpolation on test at the checkpoint selected on validation, by the paper's protocol and at the last one."""
    lines = ["| task (run) | replay: selected | replay: paper protocol | replay: last | interpolation: selected "
             "| interpolation: paper protocol | interpolation: last |", "| --- | --- | --- | --- | --- | --- | --- |"]
    runs = [(t, "paper", SHIPPED.get(t)) for t in ("fetchq", "handover", "seqmanip")]
    runs += sorted((t, b, label) for t, b, label in shipped_runs() if b != "paper")
    for t, budget, label in runs:
        keys = (f"{t}/cogail/uniform/{label}",) + ((f"{t}/cogail/uniform",) if budget == "paper" else ())
        key = next((k for k in keys if k in results), None)
        r = results.get(key) or {}
        if not r.get("paper_protocol") or not r.get("last"):
            continue
        cells = [c for col in ("replay", "interpolation")
                 for c in (fmt(r["selected"][col]), fmt(r["paper_protocol"][col]), fmt(r["last"][col]))]
        name = f"{t}, BUDGET={budget}" if budget != "paper" else t
        lines.append(f"| {name} ({'/'.join(key.split('/')[3:]) or 'main table'}) | " + " | ".join(cells) + " |")
    return lines if len(lines) > 2 else []


def validation_rows(results: dict) -> list[str]:
    """Every run's validation figures, on which checkpoints and variants are chosen: replay at the selected and the
    last checkpoint, interpolation from the validation initial states there, and its strategy shares (-: not
    measured; runs evaluated before the validation interpolation), and the number of validation episodes each
    checkpoint was replayed on (a task's runs are compared on one split: seqmanip's grew from 100 to 300)."""
    lines = ["| run | episodes | replay: selected | replay: last | interpolation: selected | interpolation: last "
             "| strategies (selected) |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for k in sorted(results):
        r = results[k]
        sel, last = r.get("selected") or {}, r.get("last") or {}
        if not sel.get("validation_replay"):
            continue
        episodes = (r.get("splits") or {}).get("validation", {}).get("episodes")
        cells = [str(episodes) if episodes else "-"]
        cells += [_pct(d.get(f)) for f in ("validation_replay", "validation_interpolation") for d in (sel, last)]
        shares = r.get("validation_strategy_distribution")
        cells.append(", ".join(f"{n} {100 * v:.0f} %" for n, v in shares.items()) if shares else "-")
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    return lines if len(lines) > 2 else []


def tables(results: dict, tasks, methods, out: Path, readme: Path | None = None) -> None:
    t1 = table(results, tasks, methods, "replay", paper_figures("replay"))
    t2 = table(results, tasks, methods, "interpolation", paper_figures("interpolation"))
    f3 = fig3_rows(results, methods)
    rob, stab, var = robustness_rows(results, tasks, methods), stability_rows(results), variant_rows(results)
    coplay, claims = coplay_rows(results, tasks, methods), claims_rows(results, tasks, methods)
    for name, title, rows in (("robustness.md", "Replay against varied humans (%, selected checkpoint, test)", rob),
                              ("coplay.md", "Closed-loop co-play with reacting humans (%, selected checkpoint)", coplay),
                              ("claims.md", "Where the grid stands on the paper's claims", claims),
                              ("stability.md", "Selected vs last checkpoint (%, test)", stab),
                              ("variants.md", "Variants of the shipped settings (%, test)", var),
                              ("validation.md", "Validation figures of every run (%, validation): choices are made "
                               "on these", validation_rows(results))):
        if rows:
            (out / name).write_text(f"# {title}\n\n" + "\n".join(rows) + "\n")
    patient = robustness_rows(results, tasks, methods, "patient-robust-", "patient-test")
    if rob and patient:
        with open(out / "robustness.md", "a") as f:
            f.write("\n## With a patient human\n\nThe same recordings, the human waiting for the robot to take what it "
                    "hands over instead of letting go on its recorded time (handover, seqmanip; in-distribution: the test "
                    "split replayed so):\n\n" + "\n".join(patient) + "\n")
    val_rows = [robustness_rows(results, [], [], pre, b, keys=sorted(results))
                for pre, b in (("val-robust-", "validation"), ("patient-val-robust-", "patient-validation"))]
    if any(val_rows):  # every run, the variants' too: their choices are made on these
        text = ["# Replay against varied validation humans (%, selected checkpoint, validation)", "",
                "Every run and variant (task/method/mix[/label]); variants are chosen on these, not on test.", ""]
        for title, rows in zip(("Plain replay", "With a patient human (in-distribution: the validation split so)"),
                               val_rows):
            text += [f"## {title}", "", *rows, ""] if rows else []
        (out / "robustness_validation.md").write_text("\n".join(text))
    (out / "table1_replay.md").write_text("# Table 1: replay success (%)\n\n" + PROTOCOL_NOTE + "\n\n"
                                          + "\n".join(t1) + "\n")
    (out / "table2_interpolation.md").write_text("# Table 2: interpolation success (%)\n\n" + PROTOCOL_NOTE
                                                 + "\n\n" + "\n".join(t2) + "\n")
    has_png = fig3_png(results, methods, out / "fig3_strategies.png")
    has_curves = curves_png(results, out / "curves.png")
    if f3:
        (out / "fig3_strategies.md").write_text(
            "# Fig. 3: strategies among successful fetchq interpolation rollouts (%)\n\n" + "\n".join(f3) + "\n")
    field, field_long = field_rows(results), field_seat_rows(results)
    if field:
        (out / "field.md").write_text("# The field's protocol on people's data (Overcooked)\n\n" + FIELD_NOTE + "\n\n"
                                      + "\n".join(field) + "\n\nPer seat, partner and H_proxy's quality (soups in "
                                      "brackets):\n\n" + "\n".join(field_long) + "\n")
    (out / "paper.json").write_text(json.dumps(results, indent=2))
    if readme is not None:
        block = ["Table 1, replay success (%):", "", *t1, "", "Table 2, interpolation success (%):", "", *t2, "",
                 PROTOCOL_NOTE]
        if f3:
            rel3 = Path(os.path.relpath(out / "fig3_strategies.md", readme.resolve().parent)).as_posix()
            block += ["", "Fig. 3, strategies among successful fetchq interpolation rollouts on the unbalanced "
                      f"mixtures D1 and D2 (the paper gives a plot, no numbers; the shares: [{rel3}]({rel3})):"]
            if has_png:
                rel = os.path.relpath(out / "fig3_strategies.png", readme.resolve().parent)
                block += ["", f"![Fig. 3: strategy shares on D1 and D2]({Path(rel).as_posix()})"]
        ship = shipped_rows(results)
        if ship:
            rel = Path(os.path.relpath(out / "variants.md", readme.resolve().parent)).as_posix()
            more = f"; every variant measured: [{rel}]({rel})" if var else ""
            block += ["", f"Co-GAIL with the settings `make train` uses (test, %{more}):", "", *ship]
        if has_curves:
            rel = Path(os.path.relpath(out / "curves.png", readme.resolve().parent)).as_posix()
            block += ["", "Learning curves (test, mean +- std over seeds; dotted: the checkpoint selected on "
                      "validation):", "", f"![Co-GAIL learning curves]({rel})"]
        if rob:
            rel = Path(os.path.relpath(out / "robustness.md", readme.resolve().parent)).as_posix()
            mine = rob[:2] + [r for r in rob[2:] if r.split("|")[2].strip().startswith("cogail")]
            last = ("the last two columns: the worst set's and the worst held-out pose slice's success over "
                    "in-distribution replay" if "worst slice" in rob[0] else
                    "the last column: the worst variation's success over in-distribution replay")
            block += ["", f"Co-GAIL's replay against varied humans (selected checkpoint, test, %; {last}; every method: "
                      f"[{rel}]({rel})):", "", *mine]
        if coplay:
            rel = Path(os.path.relpath(out / "coplay.md", readme.resolve().parent)).as_posix()
            held = " and presenting the object in the held-out pose slices" if "held-out poses" in coplay[0] else ""
            block += ["", "Closed-loop co-play: each method's robot with a reacting human, the task's scripted human and a "
                      "BC proxy of the test humans, beside the scripted robot (selected checkpoint, %; with each "
                      f"variation of the scripted human{held}: [{rel}]({rel})):", "",
                      *coplay_table(results, tasks, methods)]
        if claims:
            block += ["", "Where the grid stands on the paper's claims:", "", *claims]
        if stab:
            rel = os.path.relpath(out / "stability.md", readme.resolve().parent)
            block += ["", f"Selected vs last checkpoint, every run: [{Path(rel).as_posix()}]({Path(rel).as_posix()})."]
        if field:
            rel = Path(os.path.relpath(out / "field.md", readme.resolve().parent)).as_posix()
            block += ["", f"The field's protocol on people's data (Overcooked; per seat and partner: [{rel}]({rel})):",
                      "", *field, "", FIELD_NOTE]
        write_readme_block(readme, "\n".join(block))


def write_readme_block(readme: Path, text: str) -> None:
    """Replace what lies between the results markers of ``readme`` with ``text`` (the markers stay)."""
    doc = readme.read_text()
    if doc.count(BEGIN) != 1 or doc.count(END) != 1 or doc.index(BEGIN) > doc.index(END):
        raise SystemExit(f"{readme} needs one {BEGIN} ... {END} block")
    head, rest = doc.split(BEGIN)
    _, tail = rest.split(END)
    readme.write_text(f"{head}{BEGIN}\n<!-- generated by experiments/paper.py --tables-only; do not edit -->\n"
                      f"{text}\n{END}{tail}")


ORDER = ("bc_single", "bc_gail", "ma_gail", "ma_infogail", "diayn", "cogail")


def expand_tasks(tasks) -> list[str]:
    """Each task name, a task with ``VARIANTS`` in its package followed by them (``overcooked``: its five kitchens)."""
    import importlib

    from cogail_envs import get_task, registry

    out = []
    for t in tasks:
        out.append(t)
        module = registry._builtin_modules().get(t)
        if module and registry._module_task(module) is get_task(t):
            out += [v.name for v in getattr(importlib.import_module(module), "VARIANTS", ())]
    return list(dict.fromkeys(out))


def default_methods(tasks) -> list[str]:
    """The paper's six presets; with a task learned from people's recordings, the field's two baselines too."""
    from cogail_envs import get_task
    from cogail_jax.algo.config import FIELD_METHODS, PAPER_METHODS

    people = any(get_task(t).recorded is not None for t in tasks)
    return list(PAPER_METHODS) + (list(FIELD_METHODS) if people else [])


FIELD_ORDER = ("bc_single", "bc_gail", "ma_gail", "ma_infogail", "diayn", "ppo_sp", "ppo_bc", "cogail")
FIELD_PUBLISHED = {"bc_single": "bc", "ppo_bc": "ppo_bc", "ppo_sp": "ppo_sp"}  # our preset -> Carroll et al.'s agent


def field_rows(results: dict) -> list[str]:
    """The field's protocol table: each preset's robot with H_proxy (reward over 400 steps, mean +- s.e. over
    episodes, both seats pooled; per seat in field.md), each kitchen a column, Carroll et al.'s figure beside ours
    where they report the same kind of agent."""
    from cogail_envs import get_task

    keys = [k for k, r in results.items() if r.get("field") and len(k.split("/")) == 3]
    tasks = list(dict.fromkeys(k.split("/")[0] for k in keys))
    if not tasks:
        return []
    kitchens = [getattr(get_task(t).make_env(), "kitchen", t) for t in tasks]
    head = ["method", *[k.replace("_", " ") for k in kitchens]]
    rows = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    methods = [m for m in FIELD_ORDER if any(k.split("/")[1] == m for k in keys)]
    for m in methods:
        cells = [f"`{m}`"]
        for t in tasks:
            fd = (results.get(f"{t}/{m}/uniform") or {}).get("field")
            cell = "-" if not fd else (f"{fd['h_proxy']['both']['reward']['mean']:.1f} +- "
                                      f"{fd['h_proxy']['both']['reward']['se']:.1f}")
            pub = (get_task(t).paper.get("h_proxy") or {}).get(FIELD_PUBLISHED.get(m, ""))
            if pub:
                cell += f" (Carroll: {(pub[0][0] + pub[1][0]) / 2:.1f})"
            cells.append(cell)
        rows.append("| " + " | ".join(cells) + " |")
    return rows


def field_seat_rows(results: dict) -> list[str]:
    """field.md's long table: every row's figures per seat and partner, and H_proxy's quality."""
    from cogail_envs import get_task

    rows = ["| task | method | checkpoint | H_proxy, robot P0 | H_proxy, robot P1 | Carroll P0 / P1 | BC train (both) | "
            "self-play | H_proxy accuracy | H_proxy with itself |", "|" + " --- |" * 10]
    for key in sorted(k for k, r in results.items() if r.get("field") and len(k.split("/")) == 3):
        t, m = key.split("/")[:2]
        fd = results[key]["field"]
        f = lambda d: f"{d['reward']['mean']:.1f} +- {d['reward']['se']:.1f} ({d['score']['mean']:.2f})"  # noqa: E731
        pub = (get_task(t).paper.get("h_proxy") or {}).get(FIELD_PUBLISHED.get(m, ""))
        pubs = f"{pub[0][0]:.1f} / {pub[1][0]:.1f}" if pub else "-"
        q = fd["proxy_quality"]
        rows.append(f"| {t} | {m} | {fd['selected']['checkpoint']} | {f(fd['h_proxy']['seat0'])} | "
                    f"{f(fd['h_proxy']['seat1'])} | {pubs} | {f(fd['bc_train']['both'])} | {f(fd['self_play'])} | "
                    f"{100 * q['accuracy_heldout']:.1f} % | {f(q['with_itself'])} |")
    return rows


def write_crossplay(out: Path, matrices: dict) -> None:
    """Merge ``matrices`` (task -> cross-play matrix) into ``<out>/crossplay.json`` and rewrite ``crossplay.md``."""
    path = out / "crossplay.json"
    done = {**(json.loads(path.read_text()) if path.is_file() else {}), **matrices}
    path.write_text(json.dumps(done, indent=2))
    from cogail_jax.eval import field

    text = ["# Cross-play of the field's robots (reward over 400 steps, mean +- s.e., both seats pooled)", "",
            "Row: the robot in the human agent's slot; column: the robot in the robot's slot; the diagonal is "
            "self-play. Each at the checkpoint the field's protocol selected.", ""]
    for task, matrix in done.items():
        text += [f"## {task}", "", *field.crossplay_markdown(matrix), ""]
    (out / "crossplay.md").write_text("\n".join(text))


def crossplay(results: dict, out: Path, tasks=None) -> dict:
    """Each field task's cross-play matrix (``field.crossplay``): every row's robot with every other's, at the
    checkpoint the field's protocol selected, from the runs on disk; merged into ``<out>/crossplay.json`` and
    written as ``<out>/crossplay.md``. ``tasks``: only these (default: every field task). Returns the matrices it
    made, by task."""
    from cogail_jax.algo.config import TrainConfig
    from cogail_jax.apps.runs import Policies, build
    from cogail_jax.eval import field

    by_task: dict = {}
    made: dict = {}
    for key, r in results.items():
        parts = key.split("/")
        if (r.get("field") and len(parts) == 3 and (tasks is None or parts[0] in tasks)
                and (Path(r.get("run", "")) / "config.json").is_file()):
            by_task.setdefault(parts[0], {})[parts[1]] = r
    for task, rows in by_task.items():
        if len(rows) < 2:
            continue
        robots, env = {}, None
        for m in (m for m in FIELD_ORDER if m in rows):
            run = Path(rows[m]["run"])
            s = build(TrainConfig.load(run / "config.json"), need_heldout=False, need_validation=False, run_dir=run,
                      need_demos=False)
            robots[m] = (s.cfg, s.nets, Policies(run, s).load(int(rows[m]["field"]["selected"]["checkpoint"])))
            env = s.env
        made[task] = field.crossplay(env, robots, field.sizes()["episodes"])
        print(f"{task}: cross-play of {len(robots)} robots", flush=True)
    if made:
        write_crossplay(out, made)
    return made


FIELD_NOTE = ("Reward over 400 steps (20 per soup served), mean +- s.e. over every episode (3 seeds x 100 episodes x "
              "2 seats), each robot at the checkpoint selected with a BC model of the validation pairs, paired with "
              "H_proxy, a BC model of the test pairs that neither training nor selection reads. In brackets: "
              "Carroll et al. 2019's figure for the same kind of agent (mean of its two seats; `bc_single` beside "
              "their BC): their 'Performance with human proxy model' figure, values from "
              "HumanCompatibleAI/human_aware_rl@2507b93 (human_aware_rl/data/*_runs/*_performance.pickle); their "
              "game's old dynamics, PPO from scratch for millions of steps with shaped rewards, 5 seeds. Ours: "
              "JaxMARL's game (the same transitions on every recorded step), every preset from BC of the training "
              "pairs, 2M env steps per seed, no reward shaping.")


def table_axes(results: dict, tasks, methods):
    """Tasks and methods to tabulate: those asked for plus those already in paper.json (earlier calls)."""
    keys = [k.split("/") for k in results]
    ts = [t for t in ("fetchq", "handover", "seqmanip") if t in tasks or any(k[0] == t for k in keys)]
    keys = [k for k in keys if len(k) == 3]  # variants (a 4th part, the label) are tabulated apart
    ms = [m for m in ORDER if m in methods or any(k[1] == m for k in keys)]
    return ts, ms


def parse_sets(items) -> dict:
    from cogail_jax.apps.cli import parse_field

    extra = {}
    for item in items:
        if "=" not in item:
            raise SystemExit(f"--set needs FIELD=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        extra[k.strip()] = parse_field(k.strip(), v)
    return extra


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="the README block: --readme FILE rewrites the lines between "
                                       f"{BEGIN} and {END}")
    p.add_argument("--tasks", default="fetchq",
                   help="comma-separated; a task with variants (overcooked) stands for all of them (its five kitchens)")
    p.add_argument("--no-variants", action="store_true",
                   help="each task in --tasks alone, without its variants (`--tasks overcooked`: the Cramped Room "
                        "only); a grid's job processes run with it")
    p.add_argument("--methods", default="",
                   help="comma-separated (default: the paper's six; on a task learned from people, also the field's "
                        "ppo_bc and ppo_sp)")
    p.add_argument("--mixes", default="uniform", help="fetchq mixtures (D1, D2 give Fig. 3)")
    p.add_argument("--seeds", default="300,400,500")
    p.add_argument("--out", default="results/paper")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override config fields (parsed as `cogail train --set`; part of the config hash)")
    p.add_argument("--eval-every", type=int, default=1, help="evaluate every k-th checkpoint (default: all)")
    p.add_argument("--ckpt-batch", type=int, default=None, metavar="N",
                   help="evaluate N checkpoints in one device program (same results; default 8 on a GPU, 1 on the CPU)")
    p.add_argument("--label", default=None,
                   help="a variant of the shipped settings (with --set): its results are keyed task/method/mix/LABEL "
                        "and tabulated under 'Variants', not in Tables 1 and 2")
    p.add_argument("--force", action="store_true", help="evaluate again runs already in <out>/paper.json")
    p.add_argument("--merge", nargs="+", default=[], metavar="DIR",
                   help="train nothing: add the paper.json (and cross-play matrices) of each DIR (runs made side by "
                        "side) to --out's and rewrite the tables")
    p.add_argument("--tables-only", action="store_true",
                   help="train nothing: rewrite the tables (and --readme's block) from <out>/paper.json")
    p.add_argument("--check", action="store_true",
                   help="train nothing: list the rows of <out>/paper.json that were not trained from this checkout's "
                        "code with the current settings (exit status 1 if any)")
    p.add_argument("--compare", default=None, metavar="DIR",
                   help="train nothing: compare the rows of <out>/paper.json with DIR/paper.json's (e.g. the shipped "
                        "docs/results/paper after `make paper TASKS=... METHODS=...`), figure by figure as the tables "
                        "print them (exit status 1 if any differs)")
    p.add_argument("--readme", default=None, metavar="FILE",
                   help=f"also write the tables into FILE between {BEGIN} and {END}")
    p.add_argument("--gpus", default="all", metavar="N|all",
                   help="run the jobs one per GPU over this many GPUs (default: every visible one), each a process "
                        "of its own, the rest queued; with one GPU (or none) they run one after another here")
    p.add_argument("--jobs-per-gpu", type=int, default=1, metavar="K",
                   help="run K jobs side by side on each GPU (default 1); they share its memory and give the figures "
                        "of one job at a time, in less time where one job leaves the GPU idle")
    p.add_argument("--task-jobs-per-gpu", action="append", default=[], metavar="TASK=K",
                   help="at most K of TASK's jobs (a task with variants: of all its variants') side by side on one "
                        "GPU, below --jobs-per-gpu, e.g. handover=3 where its evaluations would not fit in memory "
                        "more times over; repeat for several tasks")
    p.add_argument("--data-only", action="store_true",
                   help="train nothing: make every dataset the grid's jobs need, as each job would (the runs' sets "
                        "and the validation split's varied humans)")
    p.add_argument("--shard", default=None, metavar="i/n",
                   help="run only every n-th job from the i-th (0-based), e.g. 0/2 and 1/2 on two hosts; join "
                        "their results with --merge")
    p.add_argument("--crossplay", action="store_true",
                   help="train nothing: the cross-play matrix of every field task's robots in <out>/paper.json (their "
                        "runs on disk), into <out>/crossplay.{json,md} (a grid side by side makes each task's as a job of its "
                        "own once the task's jobs have ended)")
    p.add_argument("--nondeterministic", action="store_true", help="allow nondeterministic GPU kernels")
    p.add_argument("--no-compile-cache", action="store_true",
                   help="do not keep compiled programs between runs (as `cogail train --no-compile-cache`)")
    a = p.parse_args(argv)
    sys.path.insert(0, str(ROOT.parent / "src"))
    from cogail_jax.apps.cli import enable_compile_cache, set_deterministic

    set_deterministic(not a.nondeterministic)  # before JAX starts
    enable_compile_cache(not a.no_compile_cache)
    extra = parse_sets(a.set)
    out = Path(a.out)
    readme = Path(a.readme) if a.readme else None
    tasks = a.tasks.split(",") if a.no_variants else expand_tasks(a.tasks.split(","))
    if a.jobs_per_gpu < 1:
        raise SystemExit(f"--jobs-per-gpu {a.jobs_per_gpu}: give 1 or more")
    check_tasks(tasks)
    methods = a.methods.split(",") if a.methods else default_methods(tasks)
    seeds = check_grid(tasks, methods, a.seeds, a.mixes)
    out.mkdir(parents=True, exist_ok=True)
    mixes_of = lambda t: a.mixes.split(",") if t == "fetchq" else ["uniform"]  # noqa: E731
    if a.data_only:
        make_data(tasks, methods, mixes_of, seeds, extra)
        return 0
    results = json.loads((out / "paper.json").read_text()) if (out / "paper.json").exists() else {}
    if a.compare:
        ref_file = Path(a.compare) / "paper.json"
        for f in (out / "paper.json", ref_file):
            if not f.is_file():
                raise SystemExit(f"{f} does not exist: give the --out folder of a grid and, to --compare, another's")
        same, diffs = compare(results, json.loads(ref_file.read_text()))
        for key in same:
            print(f"same to the last digit: {key}")
        for line in diffs:
            print(f"differs: {line}")
        if not same and not diffs:
            print(f"no row of {out / 'paper.json'} is in {ref_file}")
        return 1 if diffs or not same else 0
    if a.check:
        if not (out / "paper.json").is_file():
            raise SystemExit(f"{out / 'paper.json'} does not exist: give the --out folder of a grid (`make paper`'s "
                             f"results/paper, or docs/results/paper)")
        why = stale(results)
        for key, reason in why.items():
            print(f"stale: {key}: {reason}")
        print(f"{len(why)} of {len(results)} rows of {out / 'paper.json'} are stale" if why else
              f"all {len(results)} rows of {out / 'paper.json'} come from this checkout's code "
              f"({(head_commit() or '?')[:10]}) and the current settings")
        return 1 if why else 0
    if a.crossplay:
        crossplay(results, out)
        return 0
    if a.merge or a.tables_only:
        for d in a.merge:
            if (Path(d) / "paper.json").is_file():
                results.update(json.loads((Path(d) / "paper.json").read_text()))
            if (Path(d) / "crossplay.json").is_file():  # its tasks' cross-play matrices, where no smaller than ours
                ours = json.loads((out / "crossplay.json").read_text()) if (out / "crossplay.json").is_file() else {}
                theirs = json.loads((Path(d) / "crossplay.json").read_text())  # (a shard's has only its own robots)
                write_crossplay(out, {t: m for t, m in theirs.items() if len(m) >= len(ours.get(t, {}))})
        tables(results, *table_axes(results, [], []), out, readme)
        tasks = []
    todo, old_rows = [], stale(results) if tasks else {}
    for t in tasks:
        for m in methods:
            if not a.methods and m not in default_methods([t]):  # the field's baselines: on people's tasks only
                continue
            for mix in mixes_of(t):
                key = f"{t}/{m}/{mix}" + (f"/{a.label}" if a.label else "")
                h = config_hash(resolve_config(t, m, mix, seeds, extra))
                old = results.get(key) or {}
                if (old.get("config_hash") == h and old.get("eval_every") == a.eval_every and not a.force
                        and key not in old_rows):
                    print(f"{t:9} {m:12} {mix:8} already in {out / 'paper.json'} (same config {h}; --force to "
                          f"evaluate again)", flush=True)
                    continue
                todo.append((t, m, mix))
    todo = shard_jobs(todo, a.shard)
    caps = task_caps(a.task_jobs_per_gpu)
    gpus = gpu_slots(a.gpus)
    slots = job_slots(gpus, a.jobs_per_gpu) if gpus != ["-"] else gpus
    failed = []
    if len(slots) > 1 and len(todo) > 1:  # one process per job, K jobs per GPU at a time, each task's data first
        data = {job[0]: job for job in data_jobs(todo)}
        made: dict[str, int | None] = {}  # task -> its data job's exit code
        left = {t: sum(job[0] == t for job in todo) for t in data}  # each task's jobs not yet ended
        # each field task's cross-play is a job of its own, queued after the task's last job: it starts once they have
        # all ended and a slot is free, while the other tasks' jobs keep the remaining slots busy
        queue = list(data.values())
        for i, job in enumerate(todo):
            queue.append(job)
            if not any(j[0] == job[0] for j in todo[i + 1:]):
                queue.append((job[0], CROSS))

        def field_rows(task):  # the task's rows scored by the field's protocol (tasks learned from people)
            return [r for k, r in results.items() if k.split("/")[0] == task and r.get("field")]
        t0 = time.perf_counter()
        stamp = lambda: f"[{time.perf_counter() - t0:6.0f} s]"  # noqa: E731  (from the grid's start)

        def where(job):  # the job's folder and log
            name = job_name(job) + (f"-{a.label}" if a.label and job[1] != DATA else "")
            return out / "jobs" / name, out / "jobs" / f"{name}.log"

        def ready(job):
            if job[1] == DATA:
                return True
            if job[0] not in made:
                return False
            if job[1] == CROSS:  # never where the task's data failed or none of its rows is a field row
                return None if made[job[0]] != 0 or (not left[job[0]] and len(field_rows(job[0])) < 2) else (
                    not left[job[0]])
            return True if made[job[0]] == 0 else None

        def launch(job, slot):
            folder, log = where(job)
            log.parent.mkdir(parents=True, exist_ok=True)
            print(f"{stamp()} {' '.join(job[:3]):30} started on GPU {slot_device(slot)} (log: {log})", flush=True)
            if job[1] == CROSS:  # the task's rows as the job folder's paper.json: the cross-play reads them
                folder.mkdir(parents=True, exist_ok=True)
                rows = {k: r for k, r in results.items() if k.split("/")[0] == job[0]}
                (folder / "paper.json").write_text(json.dumps(rows, indent=1))
                (folder / "crossplay.json").unlink(missing_ok=True)
            argv = (data_argv(a, job) if job[1] == DATA else crossplay_argv(a, job, folder) if job[1] == CROSS
                    else job_argv(a, job, folder))
            return subprocess.Popen(argv, stdout=log.open("w"), stderr=subprocess.STDOUT,
                                    env={**os.environ, "CUDA_VISIBLE_DEVICES": slot_device(slot)})

        for job, code in run_jobs(queue, slots, launch, ready=ready, limit=lambda job: caps.get(job[0])):
            folder, log = where(job)
            if job[1] == CROSS:
                got = folder / "crossplay.json"
                if code == 0 and got.is_file():
                    write_crossplay(out, json.loads(got.read_text()))
                    print(f"{stamp()} {job[0]} cross-play done", flush=True)
                elif code is not None:
                    print(f"{stamp()} {job[0]} cross-play FAILED (exit {code}): see {log}", flush=True)
                continue
            if job[1] == DATA:
                made[job[0]] = code
                print(f"{stamp()} {job[0]} datasets " + ("ready" if code == 0 else f"FAILED (exit {code}): see {log}"),
                      flush=True)
                continue
            left[job[0]] -= 1
            if code is None:
                failed.append(job)
                print(f"{stamp()} {' '.join(job):30} not run: its task's datasets failed", flush=True)
                continue
            got = folder / "paper.json"
            if code or not got.is_file():
                failed.append(job)
                print(f"{stamp()} {' '.join(job):30} FAILED (exit {code}): see {log}", flush=True)
                continue
            results.update(json.loads(got.read_text()))
            print(f"{stamp()} {' '.join(job):30} done", flush=True)
            tables(results, *table_axes(results, tasks, methods), out, readme)
        print(f"{stamp()} every job ended", flush=True)
    else:
        for t, m, mix in todo:
            key = f"{t}/{m}/{mix}" + (f"/{a.label}" if a.label else "")
            res = run_one(t, m, mix, seeds, out, extra, a.eval_every, a.ckpt_batch)
            results[key] = res
            sel, pp = figures(res, "replay"), figures(res, "interpolation")
            print(f"{t:9} {m:12} {mix:8} replay {sel[0]} (paper protocol {sel[1]})  interp {pp[0]} "
                  f"(paper protocol {pp[1]})", flush=True)
            tables(results, *table_axes(results, tasks, methods), out, readme)
    if todo and (len(slots) <= 1 or len(todo) <= 1) and any(r.get("field") for r in results.values()):
        crossplay(results, out)  # one job at a time: the field's robots with one another, here (side by side: jobs)
    if (out / "table1_replay.md").exists():
        print((out / "table1_replay.md").read_text())
        print((out / "table2_interpolation.md").read_text())
    if failed:
        print(f"{len(failed)} job(s) failed: {', '.join(' '.join(j) for j in failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
