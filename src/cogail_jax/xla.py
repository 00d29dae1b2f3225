"""XLA flags the `cogail` commands set before JAX starts its backend: deterministic GPU execution."""
from __future__ import annotations

import os

DETERMINISTIC_FLAG = "--xla_gpu_deterministic_ops"


def set_deterministic(on: bool = True) -> bool:
    """Deterministic GPU execution (XLA's ``--xla_gpu_deterministic_ops=true``, appended to any XLA_FLAGS), the
    default of every ``cogail`` command; ``on=False`` (``--nondeterministic``) removes it. An explicit
    ``--xla_gpu_deterministic_ops=...`` already in XLA_FLAGS is kept when ``on``. Takes effect only if called
    before JAX starts its backend (the CLI calls it first thing). Returns ``deterministic_ops()``."""
    flags = os.environ.get("XLA_FLAGS", "").split()
    if not on:
        flags = [f for f in flags if not f.startswith(DETERMINISTIC_FLAG)]
    elif not any(f.startswith(DETERMINISTIC_FLAG) for f in flags):
        flags.append(f"{DETERMINISTIC_FLAG}=true")
    if flags:
        os.environ["XLA_FLAGS"] = " ".join(flags)
    else:
        os.environ.pop("XLA_FLAGS", None)
    return deterministic_ops()


def deterministic_ops() -> bool:
    """Whether XLA_FLAGS asks for deterministic GPU execution (the last ``--xla_gpu_deterministic_ops`` wins)."""
    vals = [f.split("=", 1)[1] if "=" in f else "true" for f in os.environ.get("XLA_FLAGS", "").split()
            if f.split("=", 1)[0] == DETERMINISTIC_FLAG]
    return bool(vals) and vals[-1].lower() in ("true", "1")
