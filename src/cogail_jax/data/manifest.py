"""A run's data manifest, RUN/data.json: which files it was trained and evaluated on, and what was in them.

Each entry (by set name: ``train``, ``validation``, ``test``, ``robust-<variation>``, extra sets) records the
file's path, the task version (physics / observation / team fingerprint) it was made under and a content hash
of its episodes (every demo's arrays and strategy, in order). A set is recorded the first time a command uses
it; afterwards a file whose content no longer matches stops the command with one sentence, so an old run is
never evaluated on data regenerated under other physics without anyone noticing.

``expert`` records the shapes of the training arrays, so that ``cogail play`` and ``cogail video`` can restore
the run's checkpoints with no demonstration file on disk.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from .io import DatasetError

NAME = "data.json"


class DataMismatchError(DatasetError):
    """A dataset no longer matches the run's manifest."""


def content_hash(path: str | os.PathLike) -> str:
    """sha256 of a demonstration file's episodes: each demo's datasets (name, dtype, shape, bytes) and strategy, in
    demo order (independent of HDF5's layout, timestamps and unrelated attributes)."""
    import h5py

    h = hashlib.sha256()
    with h5py.File(path, "r") as f:
        data = f.get("data")
        names = sorted(data.keys(), key=lambda k: (len(k), k)) if data is not None else []
        for name in names:
            g = data[name]
            h.update(name.encode())
            h.update(str(int(g.attrs.get("strategy", 0))).encode())
            for key in sorted(g.keys()):
                a = np.ascontiguousarray(g[key][()])
                h.update(f"{key}|{a.dtype}|{a.shape}".encode())
                h.update(a.tobytes())
    return h.hexdigest()[:16]


def _stored_version(path) -> str | None:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            v = f.attrs.get("env_version")
    except OSError:
        return None
    return None if v is None else str(v.decode() if isinstance(v, bytes) else v)


def read(run_dir: str | os.PathLike) -> dict:
    p = Path(run_dir) / NAME
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return {}


def _write(run_dir, man: dict) -> None:
    p = Path(run_dir) / NAME
    tmp = p.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(man, indent=2))
    os.replace(tmp, p)


def entry(path: str | os.PathLike, env_version: str | None = None) -> dict:
    """A set's record: its path, task version and content hash, and for people's recordings where they came from
    (the file's ``source_*`` attrs: the source file and its sha256)."""
    from .recorded import source_attrs

    out = {"path": str(path), "env_version": _stored_version(path) or env_version, "content_hash": content_hash(path)}
    source = source_attrs(Path(path))
    return {**out, "source": {k[len("source_"):]: v for k, v in source.items()}} if source else out


def check(run_dir: str | os.PathLike, sets: dict[str, str | os.PathLike], env_version: str | None = None) -> None:
    """Check each set (name -> file) against the run's manifest and record those it does not hold yet. A set whose
    file changed raises ``DataMismatchError`` naming the file and the fix; nothing is regenerated."""
    man = read(run_dir)
    files = man.setdefault("sets", {})
    changed = False
    for name, path in sets.items():
        path = Path(path)
        if not path.exists():
            raise DataMismatchError(f"{path} ({name}) is missing: make it with `cogail data` and the run's options, "
                                    f"or restore the file {run_dir} was trained and evaluated with")
        new = entry(path, env_version)
        old = files.get(name)
        if old is None:
            files[name] = new
            changed = True
        elif old["content_hash"] != new["content_hash"]:
            why = (f"was made under another version of the task ({new['env_version']}, the run's: "
                   f"{old['env_version']})" if old.get("env_version") != new["env_version"] else "has changed")
            raise DataMismatchError(f"{path} ({name}) {why} since {run_dir} recorded it: restore that file, or "
                                    f"evaluate the run again from scratch by removing {Path(run_dir) / NAME}")
    if changed:
        _write(run_dir, man)


def record_expert(run_dir: str | os.PathLike, expert: dict) -> None:
    """Record the shapes and dtypes of the training arrays (``algo.train.expert_arrays``)."""
    man = read(run_dir)
    man["expert"] = {k: {"shape": list(np.shape(v)), "dtype": str(np.asarray(v).dtype)} for k, v in expert.items()}
    man["expert_demos"] = int(np.max(expert["demo"])) + 1
    _write(run_dir, man)


def expert_struct(run_dir: str | os.PathLike) -> dict | None:
    """Zero arrays of the recorded training arrays' shapes (``record_expert``), or None if not recorded."""
    man = read(run_dir)
    e = man.get("expert")
    if not e:
        return None
    out = {k: np.zeros(v["shape"], v["dtype"]) for k, v in e.items()}
    if "demo" in out:  # the demonstration index of each step: as many demonstrations as training had
        n = len(out["demo"])
        out["demo"] = (np.arange(n) * int(man.get("expert_demos", 1)) // max(n, 1)).astype(out["demo"].dtype)
    if "count" in out and "obs" in out:  # how many rows are steps: all of them (a zero count samples nothing)
        out["count"] = np.asarray(len(out["obs"]), out["count"].dtype)
    return out


__all__ = ["DataMismatchError", "content_hash", "check", "read", "record_expert", "expert_struct", "NAME"]
