"""What `cogail train` says about the machine: the devices it runs on, a warning when a slow task at a
paper-sized budget is about to run on the CPU (with a time estimate and how to get the GPU build), and one
sentence for a device that runs out of memory."""
from __future__ import annotations

import os
from collections import Counter

import jax

PAPER_BUDGET = 1_000_000  # env steps per seed from which a run counts as paper-sized


def describe_devices() -> str:
    """One line: the backend and the devices, e.g. ``device: gpu, 2 x NVIDIA H200``."""
    devs = jax.devices()
    backend = jax.default_backend()
    if backend == "cpu":
        return f"device: cpu ({os.cpu_count() or 1} cores; install the GPU build with `make install` on a GPU machine)"
    kinds = Counter(d.device_kind for d in devs)
    return f"device: {backend}, " + ", ".join(f"{n} x {k}" for k, n in kinds.items())


def cpu_warning(cfg) -> list[str]:
    """Two lines (estimate; how to get the GPU build) for a task that says its CPU speed (``Task.cpu_steps_per_s``:
    Co-GAIL's update on an unloaded CPU, env steps/s per core summed over seeds; BC pre-training and evaluation
    come on top) at a paper-sized budget on the CPU, else []."""
    from cogail_envs import get_task

    per_core = get_task(cfg.task).cpu_steps_per_s
    if jax.default_backend() != "cpu" or not per_core or cfg.total_steps < PAPER_BUDGET:
        return []
    rate = per_core * (os.cpu_count() or 1)
    seconds = cfg.total_steps * len(cfg.seeds) / rate
    took = f"{seconds / 3600:.0f} h" if seconds >= 3600 * 1.5 else f"{seconds / 60:.0f} min"
    return [f"warning: {cfg.task} at {len(cfg.seeds)} seeds x {cfg.total_steps / 1e6:.1f}M env steps on this CPU "
            f"({os.cpu_count() or 1} cores): about {took} of training, plus BC and evaluation (one GPU: minutes)",
            "warning: on an NVIDIA GPU machine, `make install` installs the CUDA build of JAX "
            "(`nvidia-smi` must work); check with `python -c 'import jax; print(jax.devices())'`"]


# What XLA's errors say when a device's memory runs out: this run is too large, or another process holds the GPU's
# memory (JAX takes 75 % of it when a process starts, so a second process on the same GPU fails to create its
# cuBLAS handles while compiling).
MEMORY_SIGNS = ("resource_exhausted", "out of memory", "failed to create cublas handle", "blaslt is unavailable")


def memory_error(e: BaseException) -> str | None:
    """One sentence for a device error caused by memory, else None."""
    if not isinstance(e, jax.errors.JaxRuntimeError) or not any(m in str(e).lower() for m in MEMORY_SIGNS):
        return None
    return ("the device ran out of memory: if another process uses the same GPU, give each one a share "
            "(e.g. XLA_PYTHON_CLIENT_MEM_FRACTION=0.4 for two), else run fewer envs or seeds; "
            "an interrupted training run continues with --resume")
