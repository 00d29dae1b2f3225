"""Shared fixtures, built once per test process and reused everywhere (CPU, tiny sizes). `make test` runs the
suite in two pytest-xdist worker processes; each builds the fixtures it needs, and both share one XLA
compilation cache (below)."""
from __future__ import annotations

import atexit
import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# The suite checks behaviour, not speed, at tiny sizes, where XLA's CPU compile time dominates: compile with less
# backend optimisation (tests/test_handover.py: 88 s of CPU time -> 51 s, and 41 s without LLVM's expensive passes).
# Inherited by the workers and subprocesses: the same flags everywhere, so the compilation cache keys and the
# bitwise-resume checks are unaffected.
# The flags also hold the one every `cogail` command adds (cogail_jax.runtime.xla.set_deterministic; a GPU flag, no
# change on the CPU): JAX's compilation cache keys read XLA_FLAGS when a program is compiled, so a worker whose
# first in-process `cli.main` appended it, or a `cogail` subprocess, would otherwise look for every program under
# keys of its own and compile again what the other worker and the other subprocesses compiled.
_FAST_COMPILE = ("--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false "
                 "--xla_llvm_disable_expensive_passes=true --xla_gpu_deterministic_ops=true")
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_FAST_COMPILE}".strip()
# One XLA compilation cache for the whole test run, in a fresh directory (CI starts empty, nothing is kept):
# a program that several tests compile under separate jit objects (every trainer.build / make_train_fns /
# train_run makes new ones), in the other xdist worker, or in the subprocesses the tests start (the kill /
# resume test's `cogail train` runs, the 2-device runs) is compiled once and loaded from it afterwards.
# pytest's main process imports this file before it starts the xdist workers, so it makes the directory and
# the workers and their subprocesses inherit it through the environment (it is set before jax is imported);
# the main process removes it at exit. The tests that check for recompilation count jit's own cache entries
# or its "Compiling" log, which a hit here does not hide. JAX writes an entry once and reads it whole; an
# entry read while the other worker is still writing it fails to load and is compiled again (a warning).
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _CACHE = tempfile.mkdtemp(prefix="cogail-test-xla-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _CACHE
    atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)
# The `cogail` commands the tests run (in this process and in subprocesses) keep their compiled programs there
# too, never in the user's cache folder (cogail_jax.runtime.xla.enable_compile_cache).
os.environ.setdefault("COGAIL_CACHE", os.environ["JAX_COMPILATION_CACHE_DIR"])

import pytest

from cogail_jax.algo.config import TrainConfig

TINY = dict(task="fetchq", num_envs=4, unroll_length=16, updates_per_call=2, checkpoint_every=2,
            total_steps=4 * 16 * 6, ppo_epochs=2, num_minibatches=2, inner_updates=2, inner_batch=32,
            bc_steps=0, eval_codes=4)


@pytest.fixture(scope="session")
def fetchq():
    import cogail_envs

    return cogail_envs.make_env("fetchq")


@pytest.fixture(scope="session")
def demo_files(tmp_path_factory, fetchq):
    """A small training file, a held-out (test) file and a validation file (scripted fetchq demonstrations): the
    runs of the tests are given their data, as `cogail data` gives a user's (nothing makes data on the side)."""
    from cogail_jax.data import io as data
    from cogail_jax.data import generate as demos

    d = tmp_path_factory.mktemp("demos")
    train = data.save_demos(d / "train.hdf5", fetchq, demos.generate(fetchq, 12, seed=0), seed=0)
    held = data.save_demos(d / "heldout.hdf5", fetchq, demos.generate(fetchq, 4, seed=1), seed=1)
    val = data.save_demos(d / "validation.hdf5", fetchq, demos.generate(fetchq, 4, seed=2), seed=2)
    return train, held, val


@pytest.fixture(scope="session")
def tiny_cfg(demo_files):
    train, held, val = demo_files
    return TrainConfig(**TINY, seeds=(3, 5), demos=str(train), heldout=str(held), validation=str(val))


# Scheduling for `make test` (pytest -n 2 --dist loadfile --no-loadscope-reorder): each test file runs on one
# worker, so its module-scoped fixtures (a compiled rollout, a trained run) are built once, and the files start
# heaviest first (longest-processing-time order) so that the two workers finish together. The weights are the
# seconds each file took under `make test` on the 2-core CPU; a file not listed counts 1 s per test.
# (xdist's loadgroup cannot split files more finely here: pytest 9 ignores the group suffix xdist 3.8 appends to
# the test ids, so every test became a unit of its own and the MJX env modules built their fixtures again.)
FILE_WEIGHTS = {
    "test_coplay.py": 310, "test_robustness.py": 170, "test_train.py": 170, "test_cli.py": 157,
    "test_sharding.py": 150, "test_collect.py": 144,
    "test_multiprocess.py": 136,  # (two processes at a time: more than its share of the CPU)
    "test_presets.py": 121, "test_overcooked_play.py": 89, "test_field.py": 86, "test_reliability.py": 80,
    "test_seqmanip.py": 74, "test_handover.py": 71, "test_discrete.py": 64, "test_protocol.py": 58,
    "test_data_step.py": 57, "test_example_task.py": 57, "test_tasks.py": 55, "test_portable.py": 47,
    "test_env_shards.py": 38, "test_data.py": 32, "test_play.py": 31, "test_segment_sums.py": 30,
    "test_programs.py": 24, "test_fetchq.py": 23, "test_pose_slice.py": 19, "test_overcooked.py": 17,
    "test_paper.py": 15, "test_generator.py": 7,
}


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    if not hasattr(config, "workerinput"):  # only in xdist's workers, whose collection the scheduler uses
        return
    first, count = {}, {}
    for i, it in enumerate(items):
        first.setdefault(it.path.name, i)
        count[it.path.name] = count.get(it.path.name, 0) + 1
    items.sort(key=lambda it: (-FILE_WEIGHTS.get(it.path.name, count[it.path.name]), first[it.path.name]))
