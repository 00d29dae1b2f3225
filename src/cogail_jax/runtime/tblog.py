"""The training scalars a run logged to TensorBoard, read back (tensorboardX writes them; no TensorFlow needed):
the co-policy's success in its own training episodes between checkpoints, for ``results.json``."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np


def _records(path: Path):
    """The payloads of a TFRecord file (length, its CRC, payload, its CRC); a record cut off at the end (an
    interrupted run) is skipped."""
    data = path.read_bytes()
    i = 0
    while i + 12 <= len(data):
        (n,) = struct.unpack_from("<Q", data, i)
        start = i + 12
        if start + n + 4 > len(data):
            return
        yield data[start:start + n]
        i = start + n + 4


def _event_files(log_dir: Path) -> list[Path]:
    """A writer's event files in the order they were begun (their names hold the start time in seconds)."""
    def begun(p):
        parts = p.name.split(".")
        return (int(parts[3]) if len(parts) > 3 and parts[3].isdigit() else 0, p.name)

    return sorted(Path(log_dir).glob("events.out.tfevents.*"), key=begun)


def read_scalars(log_dir: str | Path, tags) -> dict[str, dict[int, float]]:
    """{tag: {step: value}} of ``tags`` in every event file of ``log_dir``; a step written again (a resumed run
    redoing the updates after its last checkpoint) keeps its later value."""
    from tensorboardX.proto.event_pb2 import Event

    out = {t: {} for t in tags}
    for f in _event_files(Path(log_dir)):
        for rec in _records(f):
            ev = Event.FromString(rec)
            for v in ev.summary.value:
                if v.tag in out:
                    out[v.tag][int(ev.step)] = float(v.simple_value)
    return out


def episode_windows(checkpoints, min_updates: int) -> list[int]:
    """The checkpoints that end windows of at least ``min_updates`` updates each; the last checkpoint ends the last
    window, which takes in a shorter remainder (a run shorter than ``min_updates``: one window). A failed training
    episode ends only at the time limit, a successful one sooner, so a window shorter than the limit counts the
    successes of episodes whose failures it does not see."""
    ends, start = [], 0
    for c in checkpoints:
        if c - start >= min_updates:
            ends.append(int(c))
            start = c
    if checkpoints and (not ends or ends[-1] != checkpoints[-1]):
        ends[-1:] = [int(checkpoints[-1])]
    return ends


def training_success(run_dir: str | Path, seeds, steps_per_update: int, checkpoints) -> dict | None:
    """The co-policy's success rate in its own training episodes over each interval between checkpoints (the
    updates after the previous checkpoint up to this one): episodes that succeeded over episodes that ended, per
    seed and as their mean. None where the run logged no training episodes (BC-single)."""
    per_seed = {}
    for sd in seeds:
        logs = read_scalars(Path(run_dir) / "tb" / f"seed_{sd}", ("train/episode_success", "train/episodes"))
        rate, ends = logs["train/episode_success"], logs["train/episodes"]
        if not ends:
            return None
        updates = np.array(sorted(ends)) // steps_per_update
        n = np.array([ends[s] for s in sorted(ends)])
        won = n * np.array([rate.get(s, 0.0) for s in sorted(ends)])
        rows, prev = [], 0
        for c in checkpoints:
            m = (updates > prev) & (updates <= c)
            rows.append(float(won[m].sum() / n[m].sum()) if n[m].sum() > 0 else None)
            prev = c
        per_seed[str(sd)] = rows
    mean = [None if any(per_seed[s][i] is None for s in per_seed) else float(np.mean([per_seed[s][i] for s in per_seed]))
            for i in range(len(checkpoints))]
    return {"checkpoints": list(map(int, checkpoints)), "mean": mean, "per_seed": per_seed}
