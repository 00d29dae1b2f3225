"""Install the JAX build that fits this machine, at the version pyproject.toml pins (`make install` runs it).

An NVIDIA GPU (``nvidia-smi`` on PATH and answering) gets the CUDA build that matches the CUDA version its
driver reports: ``jax[cuda13]`` for CUDA 13 or newer, ``jax[cuda12]`` for CUDA 12 (each brings its own
CUDA libraries as pip packages). Anything else, or ``CPU=1``, gets the CPU build. An installed build that
already fits is left alone, so re-running costs a fraction of a second.

    python tools/install_jax.py            # detect and install
    python tools/install_jax.py --dry-run  # print the pip command instead of running it (or DRY_RUN=1)
    CPU=1 python tools/install_jax.py      # the CPU build even on a GPU machine
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CUDA_PLUGINS = ("jax-cuda12-plugin", "jax-cuda12-pjrt", "jax-cuda13-plugin", "jax-cuda13-pjrt")


def _truthy(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() not in ("", "0", "false", "no")


def pinned_jax_version(pyproject: Path = ROOT / "pyproject.toml") -> str:
    """The version in pyproject.toml's ``jax==X`` requirement."""
    m = re.search(r'"jax==([^"\s;]+)"', pyproject.read_text())
    if not m:
        raise SystemExit(f"install_jax: no \"jax==VERSION\" requirement in {pyproject}")
    return m.group(1)


def driver_cuda_version() -> tuple[int, int] | None:
    """(major, minor) of the CUDA version in ``nvidia-smi``'s header, or None without a working NVIDIA driver."""
    exe = shutil.which("nvidia-smi")
    if exe is None:
        return None
    try:
        out = subprocess.run([exe], capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(r"CUDA Version:\s*(\d+)\.(\d+)", out)
    return (int(m.group(1)), int(m.group(2))) if m else None


def choose(version: str, cuda: tuple[int, int] | None, force_cpu: bool) -> tuple[str, str]:
    """(build, reason): build is "cpu", "cuda12" or "cuda13"."""
    if force_cpu:
        return "cpu", "CPU=1"
    if cuda is None:
        return "cpu", "no NVIDIA GPU found (nvidia-smi missing or not answering)"
    if cuda[0] >= 13:
        return "cuda13", f"NVIDIA driver for CUDA {cuda[0]}.{cuda[1]}"
    if cuda[0] == 12:
        return "cuda12", f"NVIDIA driver for CUDA {cuda[0]}.{cuda[1]}"
    return "cpu", (f"the NVIDIA driver supports only CUDA {cuda[0]}.{cuda[1]}; jax {version}'s GPU builds need "
                   f"CUDA 12 or newer: update the driver and run `make install` again")


def _installed(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def install_command(build: str, version: str, python: str = sys.executable) -> list[str]:
    pip = [python, "-m", "pip", "install"]
    return pip + ([f"jax=={version}", f"jaxlib=={version}"] if build == "cpu" else [f"jax[{build}]=={version}"])


def commands(build: str, version: str, always: bool = False, python: str = sys.executable) -> list[list[str]]:
    """The pip commands that install ``build`` (uninstalling another build's CUDA plugin first); the install
    command is left out when that build is already installed, unless ``always``."""
    stale = [d for d in CUDA_PLUGINS if _installed(d) and (build == "cpu" or build not in d)]
    cmds = [[python, "-m", "pip", "uninstall", "-y", *stale]] if stale else []
    done = _installed("jax") == version and _installed("jaxlib") == version
    if build != "cpu":
        done = done and _installed(f"jax-{build}-plugin") == version
    if always or not done:
        cmds.append(install_command(build, version, python))
    return cmds


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dry-run", action="store_true", help="print the pip command instead of running it (or DRY_RUN=1)")
    p.add_argument("--python", default=sys.executable,
                   help="the interpreter whose environment gets JAX (default: this one)")
    a = p.parse_args(argv)
    dry = a.dry_run or _truthy("DRY_RUN")
    version = pinned_jax_version()
    build, reason = choose(version, driver_cuda_version(), _truthy("CPU"))
    name = f"jax[{build}]=={version}" if build != "cpu" else f"jax=={version} (CPU)"
    print(f"install_jax: {reason} -> {name}", flush=True)
    cmds = commands(build, version, always=dry, python=a.python)
    if dry:
        for c in cmds:
            print(shlex.join(c))
        return 0
    if not cmds:
        print("install_jax: already installed", flush=True)
    for c in cmds:
        print("+ " + shlex.join(c), flush=True)
        subprocess.run(c, check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
