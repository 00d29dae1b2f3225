import h5py
import numpy as np
import pytest

from cogail_jax import data


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
}


@pytest.mark.parametrize("case", list(CASES))
def test_loader_errors_name_file_demo_problem(case, demo_files, fetchq, tmp_path):
    edit, needle = CASES[case]
    bad = _copy(demo_files[0], tmp_path / "bad.hdf5", edit)
    with pytest.raises(data.DatasetError) as e:
        data.load_demos(bad, fetchq)
    msg = str(e.value)
    assert str(bad) in msg and needle in msg and "\n" not in msg
    if case in ("missing key", "wrong dims", "nan"):
        assert "demo_" in msg


def test_loader_not_hdf5_and_missing(fetchq, tmp_path):
    junk = tmp_path / "junk.hdf5"
    junk.write_bytes(b"this is not hdf5")
    with pytest.raises(data.DatasetError, match="not an HDF5 file"):
        data.load_demos(junk, fetchq)
    with pytest.raises(data.DatasetError, match="does not exist"):
        data.load_demos(tmp_path / "nope.hdf5", fetchq)


def test_default_demos_are_cached(fetchq, tmp_path, monkeypatch):
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path))
    monkeypatch.setitem(data.DEFAULT_NUM, "fetchq", 5)
    monkeypatch.setitem(data.DEFAULT_VARIED, "fetchq", 0)
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


def test_default_demos_of_another_size_get_their_own_file(fetchq, tmp_path, monkeypatch):
    """num_demos / ensure_default_demos(num=N): N scripted demos in a file of their own, beside the default."""
    from cogail_jax.config import ConfigError, TrainConfig

    monkeypatch.setenv("COGAIL_DATA", str(tmp_path))
    monkeypatch.setitem(data.DEFAULT_NUM, "fetchq", 5)
    monkeypatch.setitem(data.DEFAULT_VARIED, "fetchq", 0)
    p5 = data.ensure_default_demos(fetchq, "train", verbose=False)
    p7 = data.ensure_default_demos(fetchq, "train", verbose=False, num=7)
    assert p7 != p5 and p7.name == "fetchq_uniform_train_7.hdf5" and p5.name == "fetchq_uniform_train.hdf5"
    assert data.load_demos(p5, fetchq).num == 5 and data.load_demos(p7, fetchq).num == 7
    assert data.ensure_default_demos(fetchq, "train", verbose=False, num=5) == p5  # the default count: same file
    from cogail_jax import trainer

    s = trainer.build(TrainConfig(task="fetchq", num_demos=7), need_heldout=False)  # the trainer asks for them
    assert int(s.expert["demo"].max()) + 1 == 7
    with pytest.raises(ConfigError, match="num_demos"):
        TrainConfig(num_demos=-1).validate()


def _small_defaults(monkeypatch, tmp_path, varied=1):
    """Default splits of 3 fetchq team demonstrations and ``varied`` varied humans per variation, under tmp_path."""
    monkeypatch.setenv("COGAIL_DATA", str(tmp_path))
    for table in (data.DEFAULT_NUM, data.DEFAULT_VALIDATION, data.DEFAULT_TEST):
        monkeypatch.setitem(table, "fetchq", 3)
    monkeypatch.setitem(data.DEFAULT_VARIED, "fetchq", varied)


def _variations(path) -> list[str]:
    with h5py.File(path) as f:
        return [f["data"][f"demo_{i}"].attrs["variation"] for i in range(len(f["data"]))]


def test_default_train_demos_add_varied_humans(fetchq, tmp_path, monkeypatch):
    """The default training set: the team's demonstrations, then DEFAULT_VARIED varied humans per variation (each
    successful with its strategy when re-simulated, tagged with its variation); validation and test get none."""
    from cogail_envs.teams import VARIATIONS

    from cogail_jax import robustness

    _small_defaults(monkeypatch, tmp_path)
    p = data.ensure_default_demos(fetchq, "train", verbose=False)
    assert p.name == "fetchq_uniform_train.hdf5" and _variations(p) == [""] * 3 + list(VARIATIONS)
    with h5py.File(p) as f:
        assert f.attrs["varied_per_variation"] == 1
    d = data.load_demos(p, fetchq, require_init=True)
    assert np.isin(d.strategy, [1, 2, 3, 4]).all() and (d.metrics["success"] > 0).all()
    assert (d.length > 10).all() and (d.length <= fetchq.max_episode_steps).all()
    rep = robustness.validate_episodes(fetchq, d.init[3:], d.actions_human[3:], d.actions_robot[3:], batch=4)
    assert (rep["success"] > 0).all() and (rep["executed"] == d.strategy[3:]).all()
    np.testing.assert_array_equal(rep["length"], d.length[3:])
    for split in ("validation", "test"):
        q = data.ensure_default_demos(fetchq, split, verbose=False)
        assert _variations(q) == [""] * 3
        with h5py.File(q) as f:
            assert f.attrs["varied_per_variation"] == 0


def test_default_train_demos_of_another_varied_count(fetchq, tmp_path, monkeypatch, capsys):
    """varied=0 gets a file of its own with the same team demonstrations; a cached file made with another count
    (or before varied humans, no attribute) is regenerated."""
    _small_defaults(monkeypatch, tmp_path)
    p0 = data.ensure_default_demos(fetchq, "train", verbose=False, varied=0)
    p1 = data.ensure_default_demos(fetchq, "train", verbose=False)
    assert p0.name == "fetchq_uniform_train_v0.hdf5" and p1.name == "fetchq_uniform_train.hdf5"
    assert _variations(p0) == [""] * 3 and len(_variations(p1)) == 9
    d0, d1 = data.load_demos(p0, fetchq), data.load_demos(p1, fetchq)
    np.testing.assert_array_equal(d0.obs, d1.obs[:3, : d0.obs.shape[1]])
    assert data.ensure_default_demos(fetchq, "train", verbose=False, varied=1) == p1  # the default count
    with h5py.File(p1, "a") as f:
        del f.attrs["varied_per_variation"]  # missing: 0
    assert data.ensure_default_demos(fetchq, "train") == p1 and len(_variations(p1)) == 9
    monkeypatch.setitem(data.DEFAULT_VARIED, "fetchq", 0)
    assert data.ensure_default_demos(fetchq, "train") == p1 and _variations(p1) == [""] * 3
    out = capsys.readouterr().out
    assert "holds 0 varied-human episodes per variation, not 1: regenerating" in out
    assert "holds 1 varied-human episodes per variation, not 0: regenerating" in out


def test_varied_humans_only_in_the_train_split(fetchq, tmp_path):
    import json

    from cogail_envs.teams import VARIATIONS

    from cogail_jax import robustness
    from cogail_jax.config import ConfigError, TrainConfig

    with pytest.raises(ValueError, match="train split only"):
        data.ensure_default_demos(fetchq, "test", verbose=False, varied=1)
    assert data.default_demo_path("fetchq", "validation", varied=0) == data.default_demo_path("fetchq", "validation")
    seeds = {sp: {robustness.variation_seed(v, sp) for v in VARIATIONS} for sp in ("train", "validation", "test")}
    assert not (seeds["train"] & seeds["validation"]) and not (seeds["train"] & seeds["test"])
    with pytest.raises(ConfigError, match="varied_demos"):
        TrainConfig(varied_demos=-2).validate()
    saved = json.loads(TrainConfig().to_json())
    del saved["varied_demos"]  # a run saved before the field: trained without varied humans
    (tmp_path / "config.json").write_text(json.dumps(saved))
    assert TrainConfig.load(tmp_path / "config.json").varied_demos == 0


def test_ten_thousand_demos_one_call(fetchq):
    from cogail_jax import demos

    eps = demos.generate(fetchq, 10000, seed=2)
    assert eps.obs.shape[0] == 10000 and eps.success.mean() > 0.99

