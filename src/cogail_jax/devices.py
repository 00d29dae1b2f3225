"""What `cogail train` says about the machine at start: the devices it runs on, and a warning when an MJX
task at a paper-sized budget is about to run on the CPU (with a time estimate and how to get the GPU build)."""
from __future__ import annotations

import os
from collections import Counter

import jax

MJX_TASKS = ("handover", "seqmanip")
PAPER_BUDGET = 1_000_000  # env steps per seed from which a run counts as paper-sized
# Co-GAIL training on the CPU, env steps/s per core summed over seeds, at the paper's layouts (handover 64 envs
# x 94 steps, seqmanip 1000 x 10), measured with `cogail bench TASK --sizes N --unroll U --no-peer` on a 2-core
# machine; BC pre-training and evaluation come on top.
CPU_STEPS_PER_S_PER_CORE = {"handover": 400.0, "seqmanip": 300.0}


def describe_devices() -> str:
    """One line: the backend and the devices, e.g. ``device: gpu, 2 x NVIDIA H200``."""
    devs = jax.devices()
    backend = jax.default_backend()
    if backend == "cpu":
        return f"device: cpu ({os.cpu_count() or 1} cores; install the GPU build with `make install` on a GPU machine)"
    kinds = Counter(d.device_kind for d in devs)
    return f"device: {backend}, " + ", ".join(f"{n} x {k}" for k, n in kinds.items())


def cpu_warning(cfg) -> list[str]:
    """Two lines (estimate; how to get the GPU build) for an MJX task at a paper budget on the CPU, else []."""
    if jax.default_backend() != "cpu" or cfg.task not in MJX_TASKS or cfg.total_steps < PAPER_BUDGET:
        return []
    rate = CPU_STEPS_PER_S_PER_CORE[cfg.task] * (os.cpu_count() or 1)
    seconds = cfg.total_steps * len(cfg.seeds) / rate
    took = f"{seconds / 3600:.0f} h" if seconds >= 3600 * 1.5 else f"{seconds / 60:.0f} min"
    return [f"warning: {cfg.task} ({len(cfg.seeds)} seeds x {cfg.total_steps:.3g} env steps) on this CPU: about {took} "
            f"of training (about {os.cpu_count() or 1} cores; on one GPU: minutes)",
            "warning: on an NVIDIA GPU machine, `make install` installs the CUDA build of JAX "
            "(`nvidia-smi` must work); check with `python -c 'import jax; print(jax.devices())'`"]
