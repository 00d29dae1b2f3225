"""tools/install_jax.py picks the JAX build from the NVIDIA driver's CUDA version (a fake nvidia-smi on PATH)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "install_jax.py"
VERSION = re.search(r'"jax==([^"]+)"', (ROOT / "pyproject.toml").read_text()).group(1)

HEADER = """Mon Nov 23 10:00:00 2026
+-----------------------------------------------------------------------------------------+
| NVIDIA-SMI {driver}             Driver Version: {driver}     CUDA Version: {cuda}     |
|-----------------------------------------+------------------------+----------------------+
| GPU  Name                 Persistence-M | Bus-Id          Disp.A | Volatile Uncorr. ECC |
|   0  NVIDIA H200                    On  |   00000000:18:00.0 Off |                    0 |
+-----------------------------------------------------------------------------------------+
"""


def _run(tmp_path, cuda=None, **env):
    """Runs the script's dry run with PATH holding only a fake nvidia-smi (or nothing); returns its lines."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    if cuda is not None:
        smi = bin_dir / "nvidia-smi"
        header = HEADER.format(driver="580.65.06", cuda=cuda)  # PATH has no cat: the fake is a Python script
        smi.write_text(f"#!{sys.executable}\nprint({header!r})\n")
        smi.chmod(0o755)
    full = {k: v for k, v in os.environ.items() if k not in ("CPU", "DRY_RUN")}
    full.update(PATH=str(bin_dir), **env)
    out = subprocess.run([sys.executable, str(SCRIPT), "--dry-run", "--python", "PY"], env=full, check=True,
                         capture_output=True, text=True).stdout
    return out.strip().splitlines()


@pytest.mark.parametrize("cuda,build", [("12.8", "cuda12"), ("12.2", "cuda12"), ("13.0", "cuda13"),
                                        ("13.1", "cuda13")])
def test_driver_cuda_version_picks_the_cuda_build(tmp_path, cuda, build):
    lines = _run(tmp_path, cuda)
    assert f"CUDA {cuda}" in lines[0]
    assert lines[-1] == f"PY -m pip install 'jax[{build}]=={VERSION}'"


def test_no_nvidia_smi_gives_the_cpu_build(tmp_path):
    lines = _run(tmp_path)
    assert "no NVIDIA GPU" in lines[0]
    assert lines[-1] == f"PY -m pip install jax=={VERSION} jaxlib=={VERSION}"


def test_cpu_1_forces_the_cpu_build_on_a_gpu_machine(tmp_path):
    lines = _run(tmp_path, "12.8", CPU="1")
    assert "CPU=1" in lines[0]
    assert lines[-1] == f"PY -m pip install jax=={VERSION} jaxlib=={VERSION}"


def test_a_driver_older_than_cuda_12_gets_the_cpu_build_and_says_why(tmp_path):
    lines = _run(tmp_path, "11.4")
    assert "update the driver" in lines[0]
    assert lines[-1] == f"PY -m pip install jax=={VERSION} jaxlib=={VERSION}"


def test_dry_run_from_the_environment_runs_nothing(tmp_path):
    """DRY_RUN=1 without --dry-run: the same printout, and pip is never started (the command is "PY")."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "CPU"}
    env.update(PATH=str(bin_dir), DRY_RUN="1")
    out = subprocess.run([sys.executable, str(SCRIPT), "--python", "PY"], env=env, check=True,
                         capture_output=True, text=True).stdout
    assert out.strip().splitlines()[-1] == f"PY -m pip install jax=={VERSION} jaxlib=={VERSION}"


def test_train_start_lines_name_the_device_and_warn_on_paper_sized_mjx_runs_on_a_cpu():
    from types import SimpleNamespace

    from cogail_jax.runtime.devices import cpu_warning, describe_devices

    assert describe_devices().startswith("device: cpu")
    paper = SimpleNamespace(task="handover", total_steps=1_804_800, seeds=(300, 400, 500))
    lines = cpu_warning(paper)
    assert len(lines) == 2 and "about" in lines[0] and "make install" in lines[1]
    assert cpu_warning(SimpleNamespace(task="fetchq", total_steps=6_016_000, seeds=(300,))) == []
    assert cpu_warning(SimpleNamespace(task="seqmanip", total_steps=20_000, seeds=(300,))) == []
