"""Orbax checkpoints of the whole (seed-stacked) TrainState; corrupt ones are detected and skipped."""
from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

logging.getLogger("absl").setLevel(logging.ERROR)


class CheckpointError(RuntimeError):
    pass


def manager(run_dir: str | Path) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(
        Path(run_dir).absolute() / "checkpoints",
        options=ocp.CheckpointManagerOptions(max_to_keep=None, create=True, enable_async_checkpointing=False),
    )


def _empty(x) -> bool:
    return int(np.prod(x.shape)) == 0


def _fill_empty(tree):
    """Orbax cannot store zero-size arrays (MJX's ``mjx.Data`` has some): store a 1-element stand-in."""
    return jax.tree.map(lambda x: np.zeros((1,), x.dtype) if _empty(x) else x, tree)


def _abstract_for_disk(abstract):
    return jax.tree.map(lambda a: jax.ShapeDtypeStruct((1,), a.dtype) if _empty(a) else a, abstract)


def save(mgr: ocp.CheckpointManager, step: int, state) -> None:
    """Write atomically (Orbax writes to a temporary folder and renames it when complete)."""
    if step in mgr.all_steps():
        return
    mgr.save(int(step), args=ocp.args.StandardSave(_fill_empty(state)))
    mgr.wait_until_finished()


def steps(mgr: ocp.CheckpointManager) -> list[int]:
    return sorted(mgr.all_steps())


def restore(mgr: ocp.CheckpointManager, step: int, abstract_state):
    try:
        disk = mgr.restore(int(step), args=ocp.args.StandardRestore(_abstract_for_disk(abstract_state)))
        return jax.tree.map(lambda d, a: jnp.zeros(a.shape, a.dtype) if _empty(a) else d, disk, abstract_state)
    except Exception as e:  # noqa: BLE001 - any failure means this checkpoint is unusable
        raise CheckpointError(f"checkpoint {step} in {mgr.directory} is unreadable ({type(e).__name__})") from e


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
    """Restore the newest readable checkpoint. Unreadable ones are reported and moved to
    ``corrupt_checkpoints/``. Returns (step, state) or (None, None)."""
    for step in reversed(steps(mgr)):
        try:
            return step, restore(mgr, step, abstract_state)
        except CheckpointError as e:
            dst = quarantine(mgr, step)
            log(f"warning: {e}; moved it to {dst} and trying the previous one")
    return None, None
