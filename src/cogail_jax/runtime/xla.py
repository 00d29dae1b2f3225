"""What the `cogail` commands set up before JAX compiles anything: deterministic GPU execution (XLA flags) and
the persistent compilation cache."""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Mapping

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


NO_CACHE_ENV = "COGAIL_NO_COMPILE_CACHE"
MIN_COMPILE_SECONDS = 1.0  # programs that compile faster are not worth a file


def compile_cache_dir(env: Mapping[str, str] | None = None, jax_dir: str | None = None) -> Path | None:
    """Where compiled programs are kept between runs: $COGAIL_CACHE, else a JAX_COMPILATION_CACHE_DIR already
    configured (``jax_dir``), else $XDG_CACHE_HOME/cogail/xla, else ~/.cache/cogail/xla; None when
    $COGAIL_NO_COMPILE_CACHE is 1 (or true, yes, on)."""
    env = os.environ if env is None else env
    if env.get(NO_CACHE_ENV, "").strip().lower() in ("1", "true", "yes", "on"):
        return None
    if env.get("COGAIL_CACHE"):
        return Path(env["COGAIL_CACHE"]).expanduser()
    if jax_dir:
        return Path(jax_dir).expanduser()
    base = Path(env["XDG_CACHE_HOME"]).expanduser() if env.get("XDG_CACHE_HOME") else Path.home() / ".cache"
    return base / "cogail" / "xla"


def enable_compile_cache(on: bool = True) -> Path | None:
    """Point JAX's persistent compilation cache at ``compile_cache_dir()`` (programs that take at least
    ``MIN_COMPILE_SECONDS`` to compile are stored, and a later run loads them instead of compiling), the default
    of every ``cogail`` command; ``on=False`` (``--no-compile-cache``) leaves JAX's settings as they are. Call it
    before the first compilation. Returns the folder, or None when off or when the folder cannot be made."""
    import jax

    path = compile_cache_dir(jax_dir=jax.config.jax_compilation_cache_dir) if on else None
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(f"warning: no compilation cache ({path}: {e.strerror}); set COGAIL_CACHE to a writable folder",
              file=sys.stderr)
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
