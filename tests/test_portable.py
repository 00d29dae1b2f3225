"""Checkpoints are portable across device layouts: saved on 2 (forced CPU) devices, evaluated and resumed on 1,
resumed on 2 again; only damaged files make a checkpoint corrupt."""
import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

from cogail_jax.runtime import checkpoint as ckpt
from cogail_jax.apps import cli
from cogail_jax.apps import eval_runner, runs, train_loop
from test_sharding import FAST_COMPILE

# as tests/test_sharding.py: the 2-device subprocesses check layouts, not speed (and share compiled programs with
# its 2-device run of the same config through the test run's compilation cache: the same flags give the same keys)
TWO = f"--xla_force_host_platform_device_count=2 {FAST_COMPILE}"


def _on_two_devices(body: str, cwd) -> str:
    script = "import os\nos.environ['XLA_FLAGS'] = " + repr(TWO) + "\nimport jax\nassert len(jax.devices()) == 2\n"
    r = subprocess.run([sys.executable, "-c", script + textwrap.dedent(body)], capture_output=True, text=True,
                       timeout=600, cwd=cwd)
    assert r.returncode == 0 and "OK" in r.stdout, r.stdout[-2000:] + r.stderr[-3000:]
    return r.stdout


def _leaves(run, step, cfg):
    s = runs.build(cfg, need_heldout=False)
    state = ckpt.restore(ckpt.manager(run), step, jax.eval_shape(lambda: s.init(cfg.seeds, s.expert)))
    assert {d.platform for x in jax.tree.leaves(state) for d in x.sharding.device_set} == {"cpu"}
    return [np.asarray(x) for x in jax.tree.leaves(jax.device_get(state))]


def _copy(run, dst):
    shutil.copytree(run, dst)
    return dst


@pytest.fixture(scope="module")
def cfg(tiny_cfg):
    return tiny_cfg  # 6 updates, a checkpoint every 2 (the programs other tests compile: one compilation cache)


@pytest.fixture(scope="module")
def two_dev_run(cfg, tmp_path_factory):
    """Trained to update 2 on 2 devices, every training state kept; ``truth``: checkpoint 2 as Orbax restores it onto the layout that saved
    it (its stored shardings)."""
    d = tmp_path_factory.mktemp("portable")
    run, truth = d / "run", d / "truth2.npz"
    _on_two_devices(f"""
        import json, numpy as np, orbax.checkpoint as ocp
        from cogail_jax.runtime import checkpoint as ckpt
        from cogail_jax.apps import eval_runner, runs, train_loop
        from cogail_jax.algo.config import TrainConfig
        cfg = TrainConfig.from_dict(json.loads({cfg.to_json()!r}))
        train_loop.train_run(cfg, {str(run)!r}, progress=False, devices=2, stop_after=2, keep_full=None)
        s = runs.build(cfg, need_heldout=False)
        ab = ckpt._abstract_for_disk(jax.eval_shape(lambda: s.init(cfg.seeds, s.expert)))
        raw = ckpt.manager({str(run)!r}).restore(2, args=ocp.args.StandardRestore(ab))
        assert len(jax.tree.leaves(raw)[0].sharding.device_set) == 2
        np.savez({str(truth)!r}, *[np.asarray(x) for x in jax.tree.leaves(jax.device_get(raw))])
        print("OK")
    """, d)
    return run, [v for _, v in sorted(np.load(truth).items(), key=lambda kv: int(kv[0].split("_")[1]))]


@pytest.fixture(scope="module")
def resumed_on_one(cfg, two_dev_run, tmp_path_factory):
    """The 2-device run resumed on this process's one device up to update 4."""
    run = _copy(two_dev_run[0], tmp_path_factory.mktemp("one") / "run")
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        train_loop.train_run(cfg, run, resume=True, progress=False, stop_after=4)
    return run, out.getvalue()


def test_two_devices_to_one_eval_and_resume(cfg, two_dev_run, resumed_on_one):
    run2, truth = two_dev_run
    assert ckpt.saved_layout(ckpt.manager(run2), 2)["device_count"] == 2
    got = _leaves(run2, 2, cfg)  # restored on 1 device: bitwise what 2 devices saved
    assert len(got) == len(truth)
    for a, b in zip(got, truth):  # (zero-size leaves are stored as 1-element stand-ins)
        assert a.dtype == b.dtype and (a.size == 0 and b.shape == (1,) or np.array_equal(a, b)), (a, b)
    run, out = resumed_on_one
    assert f"resuming {run} from update 2" in out
    assert "restored 2 seeds saved on 2 devices (cpu) onto 1 device (cpu)" in out
    assert not (run / "corrupt_checkpoints").exists()  # a layout mismatch is never corruption
    mgr = ckpt.manager(run)
    # the newest training state is kept (resume needs no other); the policies of every checkpoint, of both layouts
    assert ckpt.steps(mgr) == [4] and ckpt.saved_layout(mgr, 4)["device_count"] == 1
    assert ckpt.steps(ckpt.policy_manager(run)) == [2, 4]
    info = json.loads((run / "run_info.json").read_text())
    assert info["layout"]["device_count"] == 1
    assert [(x["from_update"], x["device_count"]) for x in info["layouts"]] == [(0, 2), (2, 1)]
    res = eval_runner.eval_run(run, progress=False)  # checkpoints of both layouts
    assert res["checkpoints"] == [2, 4]


def test_one_device_to_two(cfg, resumed_on_one, tmp_path):
    run = _copy(resumed_on_one[0], tmp_path / "run")
    truth = tmp_path / "truth4.npz"
    np.savez(truth, *_leaves(run, 4, cfg))
    out = _on_two_devices(f"""
        import numpy as np
        from cogail_jax.runtime import checkpoint as ckpt
        from cogail_jax.apps import cli
        from cogail_jax.apps import eval_runner, runs, train_loop
        from cogail_jax.algo.config import TrainConfig
        run = {str(run)!r}
        assert cli.main(["train", "--run", run, "--resume", "--devices", "2", "--no-progress", "--keep-full",
                         "all"]) == 0
        mgr = ckpt.manager(run)
        assert ckpt.steps(mgr) == [4, 6], ckpt.steps(mgr)
        assert ckpt.saved_layout(mgr, 6)["device_count"] == 2
        cfg = TrainConfig.load(run + "/config.json")
        s = runs.build(cfg, need_heldout=False)
        st = ckpt.restore(mgr, 4, jax.eval_shape(lambda: s.init(cfg.seeds, s.expert)))
        truth = np.load({str(truth)!r})
        for i, x in enumerate(jax.tree.leaves(jax.device_get(st))):
            np.testing.assert_array_equal(np.asarray(x), truth[f"arr_{{i}}"])
        print("OK")
    """, tmp_path)
    assert "resuming" in out and "from update 4" in out
    assert "restored 2 seeds saved on 1 device (cpu) onto 2 devices (cpu)" in out


def _damage(ckpt_dir: Path, how: str):
    data = max((p for p in (ckpt_dir / "default").rglob("*") if p.is_file() and p.parent.name == "d"),
               key=lambda p: p.stat().st_size)
    if how == "delete":
        data.unlink()
    else:
        data.write_bytes(data.read_bytes()[:100])


def test_damaged_checkpoint_is_set_aside(cfg, two_dev_run, tmp_path, capsys):
    run = _copy(two_dev_run[0], tmp_path / "run")
    _damage(run / "checkpoints" / "2", "delete")
    train_loop.train_run(cfg, run, resume=True, progress=False, stop_after=0)
    out = capsys.readouterr().out
    assert "checkpoint 2" in out and "damaged" in out and f"resuming {run} from update 0" in out
    assert [p.name.split(".")[0] for p in (run / "corrupt_checkpoints").iterdir()] == ["2"]
    assert ckpt.steps(ckpt.manager(run)) == [0]


def test_eval_without_restorable_checkpoint_says_why(cfg, two_dev_run, tmp_path, capsys):
    run = _copy(two_dev_run[0], tmp_path / "run")
    # another model (a changed config): a user error, reported as such; nothing is set aside
    c = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**c, "history": 2}))
    assert cli.main(["eval", "--run", str(run), "--no-progress", "--no-robustness"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("cogail eval: error: "), err
    assert f"no checkpoint of {run} can be restored" in err and "another model" in err
    with pytest.raises(ckpt.CheckpointMismatch):
        train_loop.train_run(cfg.replace(history=2), run, resume=True, progress=False, stop_after=0)
    assert not (run / "corrupt_checkpoints").exists()
    # damaged files (evaluation reads the policies)
    (run / "config.json").write_text(json.dumps(c))
    _damage(run / "policies" / "2", "truncate")
    assert cli.main(["eval", "--run", str(run), "--no-progress", "--no-robustness"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("cogail eval: error: "), err
    assert f"no checkpoint of {run} can be restored: checkpoint 2 is damaged" in err


def test_run_without_policies_is_evaluated_from_its_training_states(cfg, two_dev_run, tmp_path):
    """A run trained before policies were kept apart (no RUN/policies/): evaluation, play and video read its full
    training states instead, with the same figures."""
    run = _copy(two_dev_run[0], tmp_path / "run")
    res = eval_runner.eval_run(run, progress=False)
    shutil.rmtree(run / "policies")
    old = eval_runner.eval_run(run, progress=False)
    assert res["checkpoints"] == old["checkpoints"] == [2]
    for key in ("replay_success", "validation_replay_success", "interpolation_success"):
        assert old["curves"][key] == res["curves"][key], key
    # (an untrained run replays nothing: psi's codes of the demonstrations tell the parameters read apart)
    np.testing.assert_allclose(old["latent_map"]["codes"], res["latent_map"]["codes"], rtol=1e-5, atol=1e-6)
