from pathlib import Path

import h5py
import numpy as np
import pytest
from cogail_envs import get_task

from cogail_jax.data import io as data


def test_round_trip(demo_files, fetchq):
    d = data.load_demos(demo_files[0], fetchq, require_init=True)
    assert d.num == 12 and d.obs.shape[2] == fetchq.observation_size
    assert d.actions_human.shape[2] == 2 and d.actions_robot.shape[2] == 2
    assert d.init.shape == (12, fetchq.init_size)
    with h5py.File(demo_files[0]) as f:
        assert f.attrs["task"] == "fetchq" and f.attrs["schema_version"] == data.SCHEMA_VERSION
        g = f["data/demo_3"]
        assert g.attrs["num_samples"] == len(g["obs"]) == d.length[3]
        assert g.attrs["strategy"] in (1, 2, 3, 4)
        np.testing.assert_array_equal(g["obs"][()], d.obs[3, : d.length[3]])


def _copy(src, dst, edit):
    with h5py.File(src) as f, h5py.File(dst, "w") as g:
        for k, v in f.attrs.items():
            g.attrs[k] = v
        f.copy("data", g)
        edit(g)
    return dst


CASES = {
    "missing key": (lambda g: g["data/demo_1"].__delitem__("actions_robot"), "no 'actions_robot'"),
    "wrong dims": (lambda g: (g["data/demo_2"].__delitem__("obs"),
                              g["data/demo_2"].create_dataset("obs", data=np.zeros((5, 7))))[1], "shape (5, 7)"),
    "nan": (lambda g: g["data/demo_0/actions_human"].__setitem__((0, 0), np.nan), "NaN"),
    "task mismatch": (lambda g: g.attrs.__setitem__("task", "handover"), "task 'handover'"),
    "empty": (lambda g: g.__delitem__("data") or g.create_group("data"), "empty"),
    "no data group": (lambda g: g.__delitem__("data"), "no 'data' group"),
    "strategy out of range": (lambda g: g["data/demo_1"].attrs.__setitem__("strategy", 9), "strategy 9 is not one"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_loader_errors_name_file_demo_problem(case, demo_files, fetchq, tmp_path):
    edit, needle = CASES[case]
    bad = _copy(demo_files[0], tmp_path / "bad.hdf5", edit)
    with pytest.raises(data.DatasetError) as e:
        data.load_demos(bad, fetchq)
    msg = str(e.value)
    assert str(bad) in msg and needle in msg and "\n" not in msg
    if case in ("missing key", "wrong dims", "nan", "strategy out of range"):
        assert "demo_" in msg


def test_a_file_in_another_layout_says_what_it_holds_and_how_to_convert_it(fetchq):
    """A robomimic-like file whose demos are not named demo_<i> (examples/: traj_<i>) is not "empty": the sentence
    names what its data group holds and the command that converts it."""
    src = Path(__file__).parents[1] / "examples" / "fetchq_robomimic_style.hdf5"
    with pytest.raises(data.DatasetError) as e:
        data.load_demos(src, fetchq)
    msg = str(e.value)
    assert "holds 4 groups named traj_0, traj_1, traj_2, ..., not demo_<i>" in msg and "empty" not in msg, msg
    assert f"`cogail import --task fetchq --in {src} --out FILE.hdf5`" in msg and "\n" not in msg, msg


def test_loader_not_hdf5_and_missing(fetchq, tmp_path):
    junk = tmp_path / "junk.hdf5"
    junk.write_bytes(b"this is not hdf5")
    with pytest.raises(data.DatasetError, match="could not be read as an HDF5 file .*signature"):
        data.load_demos(junk, fetchq)
    with pytest.raises(data.DatasetError, match="does not exist"):
        data.load_demos(tmp_path / "nope.hdf5", fetchq)


def test_default_demos_are_cached(fetchq, tmp_path, monkeypatch):
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path))
    monkeypatch.setitem(get_task("fetchq").splits, "train", 5)
    p = data.ensure_default_demos(fetchq, "train", verbose=False)
    assert p.exists() and data.load_demos(p, fetchq).num == 5
    mtime = p.stat().st_mtime
    assert data.ensure_default_demos(fetchq, "train", verbose=False) == p and p.stat().st_mtime == mtime
    # a cached file made under other physics (another env fingerprint) is regenerated
    import h5py

    with h5py.File(p, "a") as f:
        f.attrs["env_version"] = "other-physics"
    data.ensure_default_demos(fetchq, "train", verbose=False)
    with h5py.File(p, "r") as f:
        assert f.attrs["env_version"] == fetchq.version
    # so is one made when the split's default size was another (e.g. a validation split that grew)
    monkeypatch.setitem(get_task("fetchq").splits, "train", 7)
    data.ensure_default_demos(fetchq, "train", verbose=False)
    assert data.load_demos(p, fetchq).num == 7


def test_default_demos_of_another_size_get_their_own_file(fetchq, tmp_path, monkeypatch):
    """num_demos / ensure_default_demos(num=N): N scripted demos in a file of their own, beside the default."""
    from cogail_jax.algo.config import ConfigError, TrainConfig

    monkeypatch.setenv("COGAIL_DATA", str(tmp_path))
    monkeypatch.setitem(get_task("fetchq").splits, "train", 5)
    p5 = data.ensure_default_demos(fetchq, "train", verbose=False)
    p7 = data.ensure_default_demos(fetchq, "train", verbose=False, num=7)
    assert p7 != p5 and p7.name == "fetchq_uniform_train_7.hdf5" and p5.name == "fetchq_uniform_train.hdf5"
    assert data.load_demos(p5, fetchq).num == 5 and data.load_demos(p7, fetchq).num == 7
    assert data.ensure_default_demos(fetchq, "train", verbose=False, num=5) == p5  # the default count: same file
    from cogail_jax.apps import runs

    s = runs.build(TrainConfig(task="fetchq", num_demos=7), need_heldout=False)  # the trainer asks for them
    assert int(s.expert["demo"].max()) + 1 == 7
    with pytest.raises(ConfigError, match="num_demos"):
        TrainConfig(task="fetchq", num_demos=-1).validate()


def test_ten_thousand_demos_one_call(fetchq):
    from cogail_jax.data import generate as demos

    eps = demos.generate(fetchq, 10000, seed=2, batch=10000)  # the generator at a width of 10000 episodes
    assert eps.obs.shape[0] == 10000 and eps.success.mean() > 0.99



def test_a_file_locked_by_another_descriptor_is_still_read_and_appended(demo_files, fetchq, tmp_path):
    # a process forked while the file was open (XLA's GPU compilers) holds its lock until it exits
    import fcntl
    import os
    import shutil

    path = shutil.copyfile(demo_files[0], tmp_path / "held.hdf5")
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert data.load_demos(path, fetchq).num == 12
        d = data.load_demos(demo_files[0], fetchq)
        n = int(d.length[0])
        i = data.append_demo(path, fetchq, d.obs[0, :n], d.actions_human[0, :n], d.actions_robot[0, :n], d.init[0])
        assert i == 12 and data.load_demos(path, fetchq).num == 13
    finally:
        os.close(fd)
