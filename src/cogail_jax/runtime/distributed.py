"""Several processes, one run: joining JAX's distributed runtime, which process writes, barriers, and arrays brought
back to the host from devices of every process.

A run of N processes (one per host, or one per GPU) sees every process's devices as one mesh
(``train_loop.seed_mesh``); each process computes the same initial state, places its share
(``train_loop.global_put``) and runs the same program. Process 0 alone writes the run folder (config, logs,
checkpoints, results); every process reads it (a resumed run restores on each)."""
from __future__ import annotations

import jax
import numpy as np

# how long a process waits for the others to join (a peer that never starts ends the run with an error then)
JOIN_TIMEOUT_S = 300
# how long a process waits at a barrier for the others (process 0 evaluates while the others wait)
BARRIER_TIMEOUT_S = 24 * 3600


def join(coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None,
         cluster: bool = False) -> None:
    """Join the distributed runtime before anything starts JAX's backend: with ``coordinator`` ("HOST:PORT" of
    process 0), ``num_processes`` and ``process_id``, or (``cluster``) from what a scheduler sets (SLURM, Open MPI,
    Kubernetes: ``jax.distributed.initialize()`` reads it itself). Nothing to join: nothing happens."""
    from ..algo.config import ConfigError

    given = [coordinator is not None, num_processes is not None, process_id is not None]
    if any(given) and not all(given):
        raise ConfigError("a multi-process run needs --coordinator HOST:PORT, --num-processes N and --process-id I "
                          "together (or --cluster under a scheduler that sets them)")
    if all(given):
        if not 0 <= process_id < num_processes:
            raise ConfigError(f"--process-id {process_id} must be in 0..{num_processes - 1} (--num-processes)")
        jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                                   process_id=process_id, initialization_timeout=JOIN_TIMEOUT_S)
    elif cluster:
        jax.distributed.initialize(initialization_timeout=JOIN_TIMEOUT_S)


def processes() -> int:
    return jax.process_count()


def primary() -> bool:
    """Whether this process writes the run folder (process 0)."""
    return jax.process_index() == 0


_barriers = {"n": 0}


def barrier(name: str) -> None:
    """Every process waits here until all have come (no-op with one process). Uses the runtime's coordination
    service, not a device collective, so process 0 may take long (evaluation) before it comes."""
    if processes() == 1:
        return
    from jax._src import distributed as _d

    _barriers["n"] += 1
    _d.global_state.client.wait_at_barrier(f"cogail-{name}-{_barriers['n']}", BARRIER_TIMEOUT_S * 1000)


def to_host(tree):
    """``tree``'s arrays as numpy, whole, in every process (arrays spread over several processes are gathered:
    a collective, so every process must call this at the same point)."""
    if processes() == 1:
        return jax.device_get(tree)
    from jax.experimental import multihost_utils

    def one(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable and not x.is_fully_replicated:
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return np.asarray(x.addressable_data(0))
        return np.asarray(jax.device_get(x))

    return jax.tree.map(one, tree)
