"""One run over several processes (JAX's distributed runtime, CPU collectives over gloo on localhost): two processes
of one CPU device each, the run's env batch in two shards (one per process), interrupted and resumed through
`cogail train --resume`, give the parameters of one uninterrupted process with two devices, bit for bit. (Every
average over the shards is gathered and summed in shard order, ``algo.shards``: the reduction order does not depend
on how the shards lie on devices and processes, so no tolerance is needed.)"""
import json
import os
import socket
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from test_sharding import FAST_COMPILE

CFG = dict(task="fetchq", num_envs=8, unroll_length=8, updates_per_call=1, checkpoint_every=2, total_steps=8 * 8 * 6,
           ppo_epochs=1, num_minibatches=2, inner_updates=1, inner_batch=16, bc_steps=0, eval_codes=4, seeds=[3],
           env_shards=2)

WORKER = textwrap.dedent("""
    import json, sys
    from cogail_jax.runtime import distributed
    pid, nproc, port, run, stop = sys.argv[1:6]
    if int(nproc) > 1:
        distributed.join(f"127.0.0.1:{port}", int(nproc), int(pid))
    if sys.argv[7:] == ["mjx"]:  # an MJX task's model and data lie on this process's device, not process 0's
        import jax, cogail_envs
        env = cogail_envs.make_env("handover")
        assert {d for x in jax.tree.leaves((env.mx, env._template)) if isinstance(x, jax.Array)
                for d in x.devices()} == {jax.local_devices()[0]}
    from cogail_jax.algo.config import TrainConfig
    from cogail_jax.apps.train_loop import train_run
    cfg = TrainConfig.from_dict(json.loads(sys.argv[6]))
    train_run(cfg, run, progress=False, stop_after=int(stop) or None, devices="all")
    print("DONE", pid, flush=True)
""")


def _port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _env(devices: int) -> dict:
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices} {FAST_COMPILE}")
    env.pop("JAX_PLATFORMS", None)
    return env


def _together(cmds, env, cwd):
    """Start every command at once; wait for all (a process whose peer failed may abort): [(rc, output)]."""
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=cwd)
             for c in cmds]
    out = []
    for p in procs:
        try:
            text, _ = p.communicate(timeout=600)
        except subprocess.TimeoutExpired:
            p.kill()
            text, _ = p.communicate()
        out.append((p.returncode, text))
    return out


def _policy(run, step):
    import orbax.checkpoint as ocp

    m = ocp.CheckpointManager(run / "policies", item_handlers=ocp.StandardCheckpointHandler())
    meta = m.item_metadata(step)
    meta = getattr(meta, "tree", meta)
    target = jax.tree.map(lambda a: np.zeros(a.shape, a.dtype), meta,
                          is_leaf=lambda x: hasattr(x, "shape") and hasattr(x, "dtype"))
    return jax.tree.leaves(m.restore(step, args=ocp.args.StandardRestore(target)))


@pytest.fixture(scope="module")
def runs(tmp_path_factory, demo_files):
    d = tmp_path_factory.mktemp("multiprocess")
    (d / "worker.py").write_text(WORKER)
    cfg = json.dumps({**CFG, "demos": str(demo_files[0])})
    py = sys.executable
    # two processes, one device each, stopped after 4 of the 6 updates ...
    port = _port()
    first = _together([[py, "worker.py", str(i), "2", str(port), "two", "4", cfg] for i in (0, 1)], _env(1), d)
    # ... and resumed by the command line, as a user resumes an interrupted multi-process run
    port = _port()
    cli = [py, "-m", "cogail_jax.apps.cli", "train", "--run", "two", "--resume", "--no-progress",
           "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2"]
    resumed = _together([cli + ["--process-id", str(i)] for i in (0, 1)], _env(1), d)
    # one process with two devices, uninterrupted
    one = _together([[py, "worker.py", "0", "1", "0", "one", "0", cfg]], _env(2), d)
    return d, first, resumed, one


def test_two_processes_resumed_equal_one_process(runs):
    d, first, resumed, one = runs
    for rc, text in first + resumed + one:
        assert rc == 0, text[-3000:]
    assert "process 1: trained; process 0 writes two" in resumed[1][1]
    assert "resuming two from update 4" in resumed[0][1]
    info = json.loads((d / "two" / "run_info.json").read_text())
    assert info["layout"]["device_count"] == 2
    for step in (2, 4, 6):  # every checkpoint's delivered policy, bit for bit
        a, b = _policy(d / "two", step), _policy(d / "one", step)
        assert len(a) == len(b) > 0 and all(np.array_equal(x, y) for x, y in zip(a, b)), step
    # process 0 alone wrote the run folder: one TensorBoard log, the newest full state only
    assert sorted(p.name for p in (d / "two" / "tb").iterdir()) == ["seed_3"]
    assert sorted(p.name for p in (d / "two" / "checkpoints").iterdir() if p.name.isdigit()) == ["6"]


def test_two_processes_per_device_seeds(tmp_path, demo_files):
    """The MJX tasks' multi-device mode (``multi_device=per_device``: each device runs the one-device program on its
    seeds, no collectives) over two processes: each process runs its own device's seed, and the run equals one
    process with two devices, bit for bit. Each process builds an MJX env on its own device first."""
    (tmp_path / "worker.py").write_text(WORKER)
    cfg = json.dumps({**CFG, "seeds": [3, 4], "env_shards": 1, "total_steps": 8 * 8 * 2, "multi_device": "per_device",
                      "demos": str(demo_files[0])})
    py, port = sys.executable, _port()
    two = _together([[py, "worker.py", str(i), "2", str(port), "two", "0", cfg, "mjx"] for i in (0, 1)], _env(1),
                    tmp_path)
    one = _together([[py, "worker.py", "0", "1", "0", "one", "0", cfg]], _env(2), tmp_path)
    for rc, text in two + one:
        assert rc == 0, text[-3000:]
    a, b = _policy(tmp_path / "two", 2), _policy(tmp_path / "one", 2)
    assert len(a) == len(b) > 0 and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert a[0].shape[0] == 2  # both seeds, gathered from the two processes


def test_join_needs_all_three_flags():
    from cogail_jax.algo.config import ConfigError
    from cogail_jax.runtime import distributed

    with pytest.raises(ConfigError, match="--coordinator HOST:PORT, --num-processes N and --process-id I"):
        distributed.join("127.0.0.1:1234", 2, None)
    with pytest.raises(ConfigError, match="--process-id 2 must be in 0..1"):
        distributed.join("127.0.0.1:1234", 2, 2)
