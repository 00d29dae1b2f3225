"""What a user's first `make train` costs: per task, the same two commands as `make train TASK=T` (`cogail data`, then
`cogail train ... --eval`), timed from the shell,

* ``cold``: a fresh compilation cache and a fresh data folder (nothing made, nothing compiled);
* ``warm``: the same commands again, into a new run folder;
* ``new-config``: a config not trained before (``--set bc_coef=5``), with the datasets on disk,

then the run folders' sizes (without tb/), whether the cold and warm results.json are the same file, the phases
and compilations of each run (``cogail bench --phases``), and the training command's seconds outside its phases
(interpreter and imports before its clock starts, pruning and exit after; of it, the seconds after its last line of
output). Each log line carries its seconds since its command started.

    python experiments/first_run.py --tasks fetchq,handover,seqmanip --out runs/first-run

Everything goes under ``--out``: ``cache/`` and ``data/`` (set as $COGAIL_CACHE and $COGAIL_DATA for the commands),
one run folder per task and case, and ``first_run.md`` / ``first_run.json`` with the table.
"""
from __future__ import annotations

import argparse
import filecmp
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

CASES = (("cold", ()), ("warm", ()), ("new-config", ("--set", "bc_coef=5")))


def folder_mb(path: Path, skip: str = "tb") -> float:
    """Megabytes of the files under ``path``, leaving out its ``skip`` folder."""
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and skip not in p.relative_to(path).parts[:1]
               ) / 1e6


def timed(args: list[str], env: dict, log: Path) -> tuple[float, float]:
    """Run ``args``, its output into ``log`` with each line's seconds since the start; returns (seconds, seconds
    after its last line of output: the command's exit)."""
    t0 = time.perf_counter()
    last = 0.0
    with log.open("a") as f:
        f.write(f"$ {' '.join(args)}\n")
        f.flush()
        with subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as proc:
            for line in proc.stdout:
                last = time.perf_counter() - t0
                f.write(f"{last:8.1f} | {line}")
        code = proc.wait()
    if code:
        sys.exit(f"{' '.join(args)} failed (exit {code}): see {log}")
    total = time.perf_counter() - t0
    return total, total - last


def data_account(log: Path) -> dict:
    """The data command's own account in ``log``: seconds until its datasets were ready and the compilation seconds
    among them (its own thread's, not the training programs compiled beside them)."""
    found = re.findall(r"datasets ready in ([\d.]+) s \(([\d.]+) s of it compiling\)", log.read_text(errors="replace"))
    return {"data_ready_s": float(found[-1][0]), "data_compile_s": float(found[-1][1])} if found else {}


def run_task(task: str, out: Path, seeds: str, budget: str, cases=tuple(c for c, _ in CASES)) -> list[dict]:
    env = {**os.environ, "COGAIL_CACHE": str(out / "cache"), "COGAIL_DATA": str(out / "data"),
           "PYTHONUNBUFFERED": "1"}  # each line logged as it is printed
    cogail = [sys.executable, "-m", "cogail_jax.apps.cli"]
    common = ["--task", task, "--budget", budget, "--seeds", seeds]
    rows = []
    for case, extra in CASES:
        if case not in cases:
            continue
        run = out / f"{task}-{case}"
        shutil.rmtree(run, ignore_errors=True)
        log = out / f"{task}-{case}.log"
        log.unlink(missing_ok=True)
        t_data, _ = timed([*cogail, "data", *common, *extra], env, log)
        account = data_account(log)
        t_train, exit_s = timed([*cogail, "train", *common, *extra, "--run", str(run), "--eval", "--no-progress"], env,
                                log)
        phases = json.loads((run / "speed.json").read_text()).get("phases") or {}
        rows.append({"task": task, "case": case, "data_s": t_data, "train_s": t_train, "total_s": t_data + t_train,
                     "run_mb": folder_mb(run), "phases": phases, "run": str(run),
                     "outside_phases_s": t_train - sum(phases.values()), "train_exit_s": exit_s, **account})
        print(f"{task} {case}: data {t_data:.1f} s + train {t_train:.1f} s = {t_data + t_train:.1f} s, "
              f"run folder {rows[-1]['run_mb']:.1f} MB", flush=True)
        (out / f"{task}-{case}.json").write_text(json.dumps(rows[-1], indent=1))
    cold, warm = (out / f"{task}-{c}" / "results.json" for c in ("cold", "warm"))  # (warm may follow with --keep)
    same = cold.exists() and warm.exists() and filecmp.cmp(cold, warm, shallow=False)
    for r in rows:
        r["cold_warm_results_identical"] = same
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| task | case | `cogail data` s (compiling) | `cogail train --eval` s | whole s | run folder MB (no tb/) | "
             "phases: start / demos / bc / compile / train / eval / write | outside the phases (of it after the last output) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ph = r["phases"] or {}
        split = " / ".join(f"{ph.get(p, 0):.1f}" for p in ("start", "demos", "bc", "compile", "train", "eval", "write"))
        comp = f" ({r['data_compile_s']:.1f})" if "data_compile_s" in r else ""
        lines.append(f"| {r['task']} | {r['case']} | {r['data_s']:.1f}{comp} | {r['train_s']:.1f} | **{r['total_s']:.1f}** | "
                     f"{r['run_mb']:.1f} | {split} | {r['outside_phases_s']:.1f} ({r['train_exit_s']:.1f}) |")
    same = {r["task"]: r["cold_warm_results_identical"] for r in rows}
    lines += ["", "cold and warm results.json identical (byte for byte): "
              + ", ".join(f"{t} {'yes' if v else 'NO'}" for t, v in same.items())]
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", default="fetchq", help="comma-separated task names")
    p.add_argument("--out", default="runs/first-run", help="folder for the caches, data, runs and the table")
    p.add_argument("--seeds", default="300,400,500")
    p.add_argument("--budget", default="paper")
    p.add_argument("--cases", default="cold,warm,new-config", help="which of cold, warm, new-config to run, in order")
    p.add_argument("--keep", action="store_true",
                   help="keep --out's cache and data of an earlier invocation (to run the later cases on their own)")
    a = p.parse_args(argv)
    out = Path(a.out).absolute()
    tasks = [t for t in a.tasks.split(",") if t]
    cases = tuple(a.cases.split(","))
    if not tasks:
        raise SystemExit("--tasks is empty: give comma-separated task names, e.g. fetchq,handover")
    from cogail_envs import UnknownTaskError, get_task

    for t in tasks:
        try:
            get_task(t)
        except UnknownTaskError as e:
            raise SystemExit(f"--tasks: {e}")
    if bad := [c for c in cases if c not in ("cold", "warm", "new-config")]:
        raise SystemExit(f"--cases: no case {bad[0]!r}; give comma-separated cold, warm, new-config")
    if out.exists() and not out.is_dir():
        raise SystemExit(f"--out {out} is a file: give a folder")
    mine = out / ".first_run"  # what this script made; it never deletes a folder it did not make
    if not a.keep and not mine.exists() and any((out / d).exists() for d in ("cache", "data")):
        raise SystemExit(f"--out {out} holds a cache/ or data/ that this script did not make: give a new folder "
                         "(nothing there is deleted)")
    for d in ("cache", "data") if not a.keep else ():  # cold means cold: nothing compiled or made before
        shutil.rmtree(out / d, ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)
    mine.touch()
    rows = []
    for task in tasks:
        rows += run_task(task, out, a.seeds, a.budget, cases)
        (out / "first_run.json").write_text(json.dumps(rows, indent=1))
    from cogail_jax.apps.bench import phases_report

    report = table(rows) + "\n\n" + phases_report([r["run"] for r in rows])
    (out / "first_run.md").write_text(report + "\n")
    print(report)


if __name__ == "__main__":
    main()
