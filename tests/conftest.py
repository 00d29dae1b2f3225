"""Shared, session-scoped fixtures: compile once, reuse everywhere (CPU, tiny sizes)."""
from __future__ import annotations

import atexit
import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# One XLA compilation cache for the whole session, in a fresh directory (CI starts empty, nothing is kept):
# a program that several tests compile under separate jit objects (every trainer.build / make_train_fns /
# train_run makes new ones) or in the subprocesses they start (the kill / resume test's four `cogail train`
# runs, the 2-device runs) is compiled once and loaded from it afterwards. Set before jax is imported, in the
# environment, so that subprocesses inherit it. The tests that check for recompilation count jit's own cache
# entries or its "Compiling" log, which a hit here does not hide.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _CACHE = tempfile.mkdtemp(prefix="cogail-test-xla-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _CACHE
    atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)

import pytest

from cogail_jax.config import TrainConfig

TINY = dict(task="fetchq", num_envs=4, unroll_length=16, updates_per_call=2, checkpoint_every=2,
            total_steps=4 * 16 * 6, ppo_epochs=2, num_minibatches=2, inner_updates=2, inner_batch=32,
            bc_steps=0, eval_codes=4)


@pytest.fixture(scope="session")
def fetchq():
    import cogail_envs

    return cogail_envs.make_env("fetchq")


@pytest.fixture(scope="session")
def demo_files(tmp_path_factory, fetchq):
    """A small training file and a held-out file (scripted fetchq demonstrations)."""
    from cogail_jax import data, demos

    d = tmp_path_factory.mktemp("demos")
    train = data.save_demos(d / "train.hdf5", fetchq, demos.generate(fetchq, 12, seed=0), seed=0)
    held = data.save_demos(d / "heldout.hdf5", fetchq, demos.generate(fetchq, 4, seed=1), seed=1)
    return train, held


@pytest.fixture(scope="session")
def tiny_cfg(demo_files):
    train, held = demo_files
    return TrainConfig(**TINY, seeds=(3, 5), demos=str(train), heldout=str(held))
