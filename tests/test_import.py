"""`cogail import`: the example files round-trip; bad inputs end in one clear line (exit 2)."""
import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from cogail_jax.apps import cli
from cogail_jax.data import io as data

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NPZ = EXAMPLES / "fetchq_demos.npz"
ROBO = EXAMPLES / "fetchq_robomimic_style.hdf5"
MAP = EXAMPLES / "fetchq_robomimic_map.json"


def test_examples_are_small():
    for p in (NPZ, ROBO, MAP):
        assert p.exists() and p.stat().st_size < 200 * 1024


def _cli(capsys, *args):
    rc = cli.main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_import_example_npz_round_trips(tmp_path, capsys, fetchq):
    out = tmp_path / "mine.hdf5"
    rc, stdout, err = _cli(capsys, "import", "--task", "fetchq", "--in", NPZ, "--out", out)
    assert rc == 0, err
    assert "imported 6 fetchq demonstrations" in stdout
    z = np.load(NPZ)
    d = data.load_demos(out, fetchq, require_init=True)
    assert d.num == 6
    np.testing.assert_array_equal(d.length, z["length"])
    np.testing.assert_array_equal(d.strategy, z["strategy"])
    np.testing.assert_array_equal(d.init, z["init"])
    for i, n in enumerate(z["length"]):
        np.testing.assert_array_equal(d.obs[i, :n], z["obs"][i, :n])
        np.testing.assert_array_equal(d.actions_human[i, :n], z["actions"][i, :n, :2])
        np.testing.assert_array_equal(d.actions_robot[i, :n], z["actions"][i, :n, 2:])


def _robo_arrays():
    with h5py.File(ROBO, "r") as f:
        g = f["data"]
        names = sorted(g, key=lambda n: int(n.split("_")[1]))
        return [dict(obs=np.concatenate([g[n]["obs/agent_pos"][()], g[n]["obs/treasure_pos"][()],
                                         g[n]["obs/status"][()]], -1),
                     actions=g[n]["actions"][()], init=g[n]["reset_params"][()],
                     strategy=int(g[n].attrs["strategy_id"])) for n in names]


def _check_robo(path, env):
    ref = _robo_arrays()
    d = data.load_demos(path, env, require_init=True)
    assert d.num == len(ref)
    for i, r in enumerate(ref):
        n = len(r["obs"])
        assert d.length[i] == n and d.strategy[i] == r["strategy"]
        np.testing.assert_array_equal(d.obs[i, :n], r["obs"])
        np.testing.assert_array_equal(d.actions_human[i, :n], r["actions"][:, :2])
        np.testing.assert_array_equal(d.actions_robot[i, :n], r["actions"][:, 2:])
        np.testing.assert_array_equal(d.init[i], r["init"])


def test_import_robomimic_style_with_map_file(tmp_path, capsys, fetchq):
    out = tmp_path / "robo.hdf5"
    rc, stdout, err = _cli(capsys, "import", "--task", "fetchq", "--in", ROBO, "--out", out, "--map", MAP)
    assert rc == 0, err
    assert "imported 4 fetchq demonstrations" in stdout
    _check_robo(out, fetchq)


def test_import_robomimic_style_with_keys_on_the_command_line(tmp_path, capsys, fetchq):
    m = json.loads(MAP.read_text())
    keys = [f"--key={k}={v}" for k, v in m.items() if not k.startswith("_")]
    out = tmp_path / "robo2.hdf5"
    rc, _, err = _cli(capsys, "import", "--task", "fetchq", "--in", ROBO, "--out", out, *keys)
    assert rc == 0, err
    _check_robo(out, fetchq)


def test_import_npz_object_arrays_and_pairs(tmp_path, fetchq):
    """Per-demo object arrays with separate human / robot actions; obs with the final state included."""
    from cogail_jax.data.importer import import_demos

    z = np.load(NPZ)
    lens = z["length"]
    obs = np.empty(len(lens), object)
    ah, ar = np.empty(len(lens), object), np.empty(len(lens), object)
    for i, n in enumerate(lens):
        obs[i] = z["obs"][i, :n + 1] if n < z["obs"].shape[1] else z["obs"][i, :n]
        ah[i], ar[i] = z["actions"][i, :n, :2], z["actions"][i, :n, 2:]
    src = tmp_path / "objects.npz"
    np.savez(src, observations=obs, actions_human=ah, actions_robot=ar, label=z["strategy"], task="fetchq")
    s = import_demos(src, tmp_path / "o.hdf5", "fetchq", {"obs": "observations", "strategy": "label"})
    assert s.num == len(lens) and s.with_init == 0
    assert s.trimmed_obs == int((lens < z["obs"].shape[1]).sum())
    d = data.load_demos(tmp_path / "o.hdf5", fetchq)
    np.testing.assert_array_equal(d.length, lens)
    np.testing.assert_array_equal(d.strategy, z["strategy"])
    np.testing.assert_array_equal(d.actions_robot[0, : lens[0]], z["actions"][0, : lens[0], 2:])


def test_import_project_file_is_a_validated_copy(tmp_path, fetchq):
    from cogail_jax.data.importer import import_demos

    train = tmp_path / "train.hdf5"
    import_demos(NPZ, train, "fetchq")
    import_demos(train, tmp_path / "copy.hdf5", "fetchq")
    a, b = data.load_demos(train, fetchq), data.load_demos(tmp_path / "copy.hdf5", fetchq)
    np.testing.assert_array_equal(a.obs, b.obs)
    np.testing.assert_array_equal(a.strategy, b.strategy)
    import shutil

    import h5py

    shutil.copy(train, tmp_path / "bad.hdf5")  # a damaged project file is refused, and nothing is written
    with h5py.File(tmp_path / "bad.hdf5", "r+") as f:
        f["data/demo_1/obs"][2, 0] = np.nan
    with pytest.raises(data.DatasetError, match="demo_1.*NaN"):
        import_demos(tmp_path / "bad.hdf5", tmp_path / "out.hdf5", "fetchq")
    assert not (tmp_path / "out.hdf5").exists()


# ----------------------------------------------------------------------------------------------- errors
def _bad_npz(tmp_path, **changes):
    z = dict(np.load(NPZ))
    for k, v in changes.items():
        if v is None:
            z.pop(k)
        else:
            z[k] = v
    p = tmp_path / "bad.npz"
    np.savez(p, **z)
    return p


def _wrong_task_h5(tmp_path):
    p = tmp_path / "handover.hdf5"
    with h5py.File(ROBO, "r") as f, h5py.File(p, "w") as g:
        f.copy("data", g)
        g.attrs["task"] = "handover"
    return p


def _text_file(tmp_path):
    p = tmp_path / "notes.hdf5"
    p.write_text("these are not demonstrations\n")
    return p


CASES = {
    # name: (make input, extra args, words the one-line message must hold)
    "missing key": (lambda t: _bad_npz(t, actions=None), [], ["has no actions", "bad.npz", "--key actions="]),
    "misnamed key": (lambda t: ROBO, ["--map", MAP, "--key", "obs=observations"],
                     ["demo traj_0", "no dataset 'observations'", "obs/agent_pos"]),
    "obs is a group": (lambda t: ROBO, ["--key", "demo_prefix=traj_"], ["is a group", "--key obs=obs/"]),
    "wrong dims": (lambda t: _bad_npz(t, obs=np.load(NPZ)["obs"][..., :11]), [],
                   ["demo 0", "shape (141, 11)", "(T, 12)"]),
    "wrong action dims": (lambda t: _bad_npz(t, actions=np.load(NPZ)["actions"][..., :3]), [],
                          ["demo 0", "(T, 4)", "2 human then 2 robot"]),
    "wrong task (file)": (_wrong_task_h5, ["--map", MAP], ["task 'handover', not 'fetchq'", "--task handover"]),
    "wrong task (dims)": (lambda t: NPZ, ["--task", "handover"], ["task handover needs (T, 14)", "--task"]),
    "bad strategy": (lambda t: _bad_npz(t, strategy=np.full(6, 9)), [], ["strategy", "is 9", "1..4"]),
    "nan": (lambda t: _bad_npz(t, obs=np.where(np.arange(12) == 3, np.nan, np.load(NPZ)["obs"])), [],
            ["NaN", "demo 0"]),
    "no demo group": (lambda t: ROBO, ["--key", "group=episodes"], ["no group 'episodes'", "data, mask"]),
    "not a data file": (_text_file, [], ["neither HDF5 nor a NumPy .npz", "notes.hdf5"]),
    "missing file": (lambda t: t / "nope.npz", [], ["does not exist"]),
    "unknown field": (lambda t: NPZ, ["--key", "observations=obs"], ["unknown field 'observations'"]),
    "malformed key": (lambda t: NPZ, ["--key", "obs"], ["FIELD=SOURCE"]),
    "bad map file": (lambda t: (t / "m.json").write_text("{obs: x") and NPZ, ["--map", "MAPJSON"], ["not valid JSON"]),
    "zero demos": (lambda t: _bad_npz(t, obs=np.zeros((0, 5, 12)), actions=np.zeros((0, 5, 4)),
                                      strategy=np.zeros(0, int), length=np.zeros(0, int), init=np.zeros((0, 4))), [],
                   ["bad.npz holds no demonstrations"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_import_errors_are_one_clear_line(case, tmp_path, capsys):
    make, extra, needles = CASES[case]
    src = make(tmp_path)
    extra = [str(tmp_path / "m.json") if a == "MAPJSON" else a for a in extra]
    out = tmp_path / "out.hdf5"
    rc, _, err = _cli(capsys, "import", "--task", "fetchq", "--in", src, "--out", out, *extra)
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("cogail import: error: ")
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert not out.exists() and not list(tmp_path.glob("out.hdf5*"))  # no temporary file left either
