"""Datasets of people: a task whose demonstrations are recordings (``Task.recorded``), written as the project's files.

``cogail data`` asks the task for each split's episodes (``recorded(env, split)``) and writes them in the project's
schema (:mod:`.io`), with where they came from (``source_*`` file attrs: the source file and its sha256, e.g. the
trials of Carroll et al. 2019 as the ``overcooked-ai`` distribution ships them). A file is made again when the task's
version or the source's hash changes; the run's data manifest (:mod:`.manifest`) records those attrs beside the
file's content hash.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import io
from .generate import Episodes

MIXTURE = "recorded"


def path(task: str, split: str) -> Path:
    return io.default_demo_path(task, split, MIXTURE)


def source_attrs(p: Path) -> dict[str, str]:
    """The ``source_*`` attrs of a recorded file (empty for other files or a missing one)."""
    import h5py

    try:
        with h5py.File(p, "r") as f:
            return {k: str(v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()
                    if k.startswith("source_")}
    except OSError:
        return {}


def episodes(rec: dict) -> Episodes:
    n = len(rec["length"])
    return Episodes(obs=np.asarray(rec["obs"], np.float32), actions_human=np.asarray(rec["actions_human"], np.float32),
                    actions_robot=np.asarray(rec["actions_robot"], np.float32),
                    length=np.asarray(rec["length"], np.int64), strategy=np.asarray(rec["strategy"], np.int64),
                    executed=np.asarray(rec.get("executed", rec["strategy"]), np.int64),
                    success=np.asarray(rec.get("success", np.ones(n)), np.float32),
                    init=np.asarray(rec["init"], np.float32), final_metrics=dict(rec.get("final_metrics") or {}))


def ensure(env, task, split: str, make: bool = True, verbose: bool = True) -> Path:
    """The file of a recorded task's split, made from ``task.recorded(env, split)`` when missing or stale (another
    version of the task, or another source file); with ``make=False`` a missing or stale file raises
    ``io.MissingDataError``."""
    import h5py

    split = io.split_name(split)
    p = path(env.name, split)
    if p.exists():
        if io._stored_version(p) == env.version and source_attrs(p):
            return p
        if not make:
            raise io.missing(p, f"the {split} split", "was made by another version of the task")
    if not make:
        raise io.missing(p, f"the {split} split")
    if verbose:
        print(f"making the {split} split of {env.name} from its recordings -> {p}", flush=True)
    rec = task.recorded(env, split)
    eps = episodes(rec)
    io.save_demos(p, env, eps, mixture=MIXTURE, seed=0)
    tmp = p.with_suffix(f"{p.suffix}.attrs.tmp")
    p.replace(tmp)
    with h5py.File(tmp, "a") as f:  # where the episodes came from, and each episode's pair of people
        for k, v in dict(rec.get("source") or {}).items():
            f.attrs[f"source_{k}"] = str(v)
        if "pair" in rec:
            for i, pair in enumerate(np.asarray(rec["pair"])):
                f["data"][f"demo_{i}"].attrs["pair"] = int(pair)
    tmp.replace(p)
    if verbose:
        print(f"  {eps.length.shape[0]} episodes, {int(eps.length.sum())} steps", flush=True)
    return p


__all__ = ["ensure", "path", "source_attrs", "episodes", "MIXTURE"]
