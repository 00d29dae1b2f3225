"""The field's protocol (cogail_jax.eval.field): H_proxy is fitted on the test pairs alone, the robot plays both
seats, held-out accuracy holds out both copies of a window, and the episodes' figures are the game's."""
from __future__ import annotations

import types

import h5py
import jax
import numpy as np
import pytest

import cogail_envs
from cogail_jax.algo.config import TrainConfig
from cogail_jax.data import recorded
from cogail_jax.eval import coplay, field

pytest.importorskip("pandas")
from cogail_envs.overcooked.features import FEATURES  # noqa: E402


@pytest.fixture(scope="module")
def people(tmp_path_factory):
    """The cramped room's three splits of people, written as `cogail data` writes them."""
    d = tmp_path_factory.mktemp("people")
    env = cogail_envs.make_env("overcooked")
    task = cogail_envs.get_task("overcooked")
    files = {}
    for split in ("train", "validation", "test"):
        rec = task.recorded(env, split)
        files[split] = d / f"{split}.hdf5"
        from cogail_jax.data import io  # noqa: PLC0415

        io.save_demos(files[split], env, recorded.episodes(rec))
        with h5py.File(files[split], "a") as f:
            for i, pair in enumerate(rec["pair"]):
                f["data"][f"demo_{i}"].attrs["pair"] = int(pair)
    return env, files


@pytest.fixture(scope="module")
def few_people(people, tmp_path_factory):
    """The first episodes of each split (train 4, validation 4, test 12: six windows in both seats, of which the fifth is
    held out), as `cogail data` writes them: BC fits on them take a few seconds (full-batch Adam over every step)."""
    env, files = people
    d = tmp_path_factory.mktemp("few-people")
    out = {}
    for split, n in (("train", 4), ("validation", 4), ("test", 12)):
        out[split] = d / f"{split}.hdf5"
        with h5py.File(files[split], "r") as src, h5py.File(out[split], "w") as dst:
            dst.attrs.update(src.attrs)
            dst.attrs["num_demos"] = n
            data = dst.create_group("data")
            data.attrs.update(src["data"].attrs)
            for i in range(n):
                src.copy(src["data"][f"demo_{i}"], data, f"demo_{i}")
    held = field.held_out_episodes(field.split_arrays(out["test"], env)["obs"], env)
    assert held.any() and not held.all()
    return env, out


def _first(a: dict, n: int) -> dict:
    """A split's arrays (``field.split_arrays``) cut to its first ``n`` episodes."""
    return {k: v[:n] for k, v in a.items()}


def _pairs(path) -> set[int]:
    with h5py.File(path, "r") as f:
        return {int(g.attrs["pair"]) for g in f["data"].values()}


def test_h_proxy_sees_only_the_test_pairs(people, monkeypatch):
    env, files = people
    pairs = {k: _pairs(v) for k, v in files.items()}
    assert not pairs["test"] & (pairs["train"] | pairs["validation"])  # people the robot never met
    fitted = []
    monkeypatch.setattr(field, "fit_bc", lambda x, y, steps, seed: fitted.append((x, y, seed)) or len(fitted) - 1)
    monkeypatch.setattr(field, "accuracy", lambda *a: 0.0)
    monkeypatch.setattr(field, "models_path", lambda *a: None)  # fitted here, not read from an earlier test's
    s = types.SimpleNamespace(env=env, cfg=TrainConfig(task="overcooked"), files={k: str(v) for k, v in files.items()},
                              nets=None)
    f = field.Field(s, {"episodes": 1, "select_episodes": 1, "bc_steps": 1})
    samples = {k: field.seat_samples(env, **{n: field.split_arrays(v, env)[n] for n in ("obs", "ah", "ar", "length")})
               for k, v in files.items()}
    x, y = fitted[f.h_proxy][:2]
    np.testing.assert_array_equal(x, samples["test"][0])
    np.testing.assert_array_equal(y, samples["test"][1])
    np.testing.assert_array_equal(fitted[f.bc_train][0], samples["train"][0])
    np.testing.assert_array_equal(fitted[f.bc_validation][0], samples["validation"][0])


def test_held_out_windows_take_both_seats(people):
    env, files = people
    obs = field.split_arrays(files["test"], env)["obs"]
    held = field.held_out_episodes(obs, env)
    assert held.any() and not held.all()
    perm = np.asarray(env.seat_view)
    for i in range(0, len(obs), 2):  # each window's two copies: the human agent as player 0, then as player 1
        np.testing.assert_array_equal(obs[i + 1, 0], obs[i, 0][perm])
        assert held[i] == held[i + 1]
    # every trial starts from the same state: windows that share a first observation are still windows of their own,
    # so every fifth of the N / 2 windows is held out
    assert any(np.array_equal(obs[i, 0], obs[0, 0]) for i in range(2, len(obs), 2))
    assert held.sum() == 2 * (len(obs) // 2 // int(round(1 / field.HOLDOUT)))


def test_both_seats_are_played(monkeypatch):
    seats = []
    f = field.Field.__new__(field.Field)
    f.s = types.SimpleNamespace(cfg=TrainConfig(task="overcooked", seeds=(1,)))

    def play(self, a0, a1, kinds, episodes, salt, human_seat=0):
        seats.append((kinds, human_seat))
        return {"reward": np.full((1, episodes), 20.0 * (1 + human_seat)), "score": np.ones((1, episodes))}

    monkeypatch.setattr(field.Field, "play", play)
    r = f.with_partner("robot", "partner", 3, 0)
    assert sorted(seats) == [(("bc", "robot"), 0), (("bc", "robot"), 1)]  # the robot in its slot, either player
    assert r["seat0"]["reward"]["mean"] == 40.0 and r["seat1"]["reward"]["mean"] == 20.0  # seat: the robot's player
    assert r["both"]["episodes"] == 6 and r["both"]["reward"]["mean"] == 30.0


def test_two_bc_players_play_the_game(people):
    env, files = people
    a = _first(field.split_arrays(files["validation"], env), 2)  # one window in both seats: 1600 samples
    x, y, _ = field.seat_samples(env, a["obs"], a["ah"], a["ar"], a["length"])
    # the models read the task's hand-made features of each view (and their change over 1 and 3 steps), not its grid
    assert x.shape[1] == (1 + len(coplay.PROXY_LAGS)) * FEATURES
    bc = field.fit_bc(x, y, 200, 0)
    out = {}
    play = field.make_play(env, None, None, ("bc", "bc"))
    for seat in (0, 1):
        out[seat] = jax.tree.map(np.asarray, play(bc, bc, field.episode_keys(4, 0), np.int32(seat)))
        assert out[seat]["reward"].shape == (1, 4)
        np.testing.assert_array_equal(out[seat]["reward"], 20 * out[seat]["score"])  # 20 per soup served
    assert field.accuracy(bc, x, y) > 0.5
    st = field.stats(out[0], (0,))
    assert st["episodes"] == 4 and st["reward"]["se"] >= 0


def test_bc_models_are_fitted_once_per_splits(few_people, monkeypatch, tmp_path):
    """The first run on a task's splits fits the BC models and measures H_proxy's quality; a later run on the same
    splits reads both (nothing fitted, nothing played); other splits get their own."""
    env, files = few_people
    monkeypatch.setenv("COGAIL_CACHE", str(tmp_path))
    s = types.SimpleNamespace(env=env, cfg=TrainConfig(task="overcooked"), files={k: str(v) for k, v in files.items()},
                              nets=None)
    # 4 episodes, as test_two_bc_players_play_the_game plays: the two-BC-player program compiles to what that test
    # compiled (one compilation, from the shared cache)
    n = {"episodes": 4, "select_episodes": 1, "bc_steps": 20}
    first = field.Field(s, n)
    q = first.proxy_quality()
    assert first.path.is_file() and first.path.parent.parent == tmp_path
    monkeypatch.setattr(field, "fit_bc", lambda *a: pytest.fail("fitted again"))
    monkeypatch.setattr(field.Field, "play", lambda *a, **k: pytest.fail("played again"))
    again = field.Field(s, n)
    assert again.proxy_quality() == q
    for a, b in zip(jax.tree.leaves(first.h_proxy), jax.tree.leaves(again.h_proxy)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    swapped = {**s.files, "validation": s.files["train"], "train": s.files["validation"]}
    assert field.models_path(swapped, n, env) != first.path


def test_cogail_data_fits_the_models_a_run_then_reads(few_people, monkeypatch, tmp_path):
    """`cogail data` (``field.prepare``) fits the BC models and H_proxy's quality of a config's splits before any run:
    a run's evaluation on the same splits then fits and plays nothing for them. A task outside the field's protocol
    gets nothing."""
    env, files = few_people
    monkeypatch.setenv("COGAIL_CACHE", str(tmp_path))
    n = {"episodes": 4, "select_episodes": 1, "bc_steps": 20}  # as the test above: its programs, from the cache
    monkeypatch.setattr(field, "sizes", lambda: dict(n))
    cfg = TrainConfig(task="overcooked", demos=str(files["train"]), validation=str(files["validation"]),
                      heldout=str(files["test"]))
    kept = field.prepare(cfg)
    assert kept is not None and kept.is_file() and kept.parent.parent == tmp_path
    monkeypatch.setattr(field, "fit_bc", lambda *a: pytest.fail("fitted again"))
    monkeypatch.setattr(field.Field, "play", lambda *a, **k: pytest.fail("played again"))
    run = field.Field(types.SimpleNamespace(env=env, cfg=cfg, files={k: str(v) for k, v in files.items()}, nets=None))
    assert run.path == kept and run.proxy_quality()["with_itself"]["episodes"] == 4
    assert field.prepare(TrainConfig(task="fetchq")) is None


def test_selection_plays_checkpoints_side_by_side_as_one_at_a_time(people, monkeypatch):
    """Selection's checkpoints played together give each the figure it gets alone (same draws, no mixing of
    checkpoints or seeds), with the last batch padded."""
    env, files = people
    monkeypatch.setattr(field, "SELECT_BATCH", 2)
    a = _first(field.split_arrays(files["validation"], env), 2)
    x, y, _ = field.seat_samples(env, a["obs"], a["ah"], a["ar"], a["length"])
    partner = field.fit_bc(x, y, 50, 0)
    calls = []

    class Sim(field.Field):  # a robot that is a BC model at a temperature: distinct checkpoints, distinct play
        def __init__(self):
            self.s = types.SimpleNamespace(cfg=TrainConfig(task="overcooked", seeds=(1, 2)), env=env)
            self.n, self.bc_validation = {"select_episodes": 3}, partner

        def play(self, a0, a1, kinds, episodes, salt, human_seat=0):
            calls.append(a1["t"].shape[0])
            scale = np.asarray(a1["t"])[:, None]  # (robot x seed, 1)
            keys = np.asarray(field.episode_keys(episodes, salt + human_seat))[:, 0][None].astype(np.float64)
            return {"reward": scale * keys % 97.0}

    robots = [{"t": np.full((2,), float(t)), "code": np.ones(2)} for t in (1, 2, 3)]
    batched = Sim().select(robots)
    monkeypatch.setattr(field, "SELECT_BATCH", 1)
    calls_batched = list(calls)
    alone = Sim().select(robots)
    np.testing.assert_allclose(batched, alone)
    assert len(set(batched)) == 3 and calls_batched == [4, 4, 4, 4]  # 2 batches x 2 seats, the last padded
