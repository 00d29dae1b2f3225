"""Reading a run's TensorBoard scalars back: resumed runs, cut-off files, the training success between checkpoints."""
import numpy as np
import pytest

from cogail_jax.runtime import tblog


def _write(log_dir, suffix, rows):
    """One event file of ``rows`` [(step, {tag: value})], as the trainer writes them (one event per step)."""
    from tensorboardX import FileWriter
    from tensorboardX.proto.summary_pb2 import Summary

    w = FileWriter(str(log_dir), filename_suffix=suffix)
    for step, vals in rows:
        w.add_summary(Summary(value=[Summary.Value(tag=k, simple_value=v) for k, v in vals.items()]), step)
    w.close()


def test_a_resumed_run_keeps_the_later_values_and_a_cut_off_record_is_skipped(tmp_path):
    _write(tmp_path, ".a", [(s, {"train/x": 0.0}) for s in (10, 20, 30, 40)])
    _write(tmp_path, ".b", [(s, {"train/x": 1.0, "train/y": 2.0}) for s in (30, 40, 50)])  # resumed after step 20
    (f,) = [p for p in tmp_path.iterdir() if p.name.endswith(".b")]
    f.write_bytes(f.read_bytes() + b"\x20\x00\x00\x00\x00\x00\x00\x00abc")  # an interrupted write
    got = tblog.read_scalars(tmp_path, ("train/x", "train/y", "train/z"))
    assert got["train/x"] == {10: 0.0, 20: 0.0, 30: 1.0, 40: 1.0, 50: 1.0}
    assert got["train/y"] == {30: 2.0, 40: 2.0, 50: 2.0} and got["train/z"] == {}


def test_training_success_weighs_updates_by_their_episodes(tmp_path):
    """Per interval between checkpoints: successful episodes over ended ones, per seed and their mean."""
    spu = 100  # env steps per update: the logs' steps
    runs = {7: [(0.5, 2), (0.0, 0), (1.0, 2), (0.25, 4)], 8: [(0.0, 1), (0.0, 1), (0.5, 2), (0.5, 2)]}
    for seed, ups in runs.items():
        _write(tmp_path / "tb" / f"seed_{seed}", "", [((u + 1) * spu, {"train/episode_success": r, "train/episodes": n})
                                                     for u, (r, n) in enumerate(ups)])
    ts = tblog.training_success(tmp_path, (7, 8), spu, [2, 4])
    assert ts["checkpoints"] == [2, 4]
    np.testing.assert_allclose(ts["per_seed"]["7"], [1 / 2, 3 / 6])  # updates 1-2: 1 of 2; 3-4: 2 + 1 of 6
    np.testing.assert_allclose(ts["per_seed"]["8"], [0.0, 2 / 4])
    np.testing.assert_allclose(ts["mean"], [0.25, 0.5])
    assert tblog.training_success(tmp_path, (9,), spu, [2]) is None  # no training episodes logged


@pytest.mark.parametrize("ckpts", [[0, 4], [1, 2, 3, 4]])
def test_intervals_without_episodes_are_none(tmp_path, ckpts):
    _write(tmp_path / "tb" / "seed_1", "", [((u + 1) * 10, {"train/episode_success": 1.0, "train/episodes": 0.0 if u < 2
                                                            else 1.0}) for u in range(4)])
    ts = tblog.training_success(tmp_path, (1,), 10, ckpts)
    assert ts["mean"][0] is None and ts["mean"][-1] == 1.0


def test_episode_windows_span_at_least_one_time_limit():
    """Windows end at checkpoints, each at least the time limit's updates long (a shorter one would count the early
    successes without the failures that end at the limit); the last checkpoint ends the last window, which takes in a
    shorter remainder."""
    assert tblog.episode_windows([30, 60, 90, 120, 150, 180], 60) == [60, 120, 180]
    assert tblog.episode_windows([30, 60, 90, 120, 150], 60) == [60, 150]
    assert tblog.episode_windows([30, 60, 90], 4) == [30, 60, 90]
    assert tblog.episode_windows([30, 60, 90, 100], 45) == [100]
    assert tblog.episode_windows([10], 60) == [10]
    assert tblog.episode_windows([], 60) == []


def test_results_md_gives_the_first_and_last_interval():
    from cogail_jax.eval import rollouts
    from cogail_jax.eval import protocol

    (line,) = [x for x in protocol._training_success_line({"checkpoints": [2, 4, 6], "mean": [None, 0.125, 0.5]}) if x]
    assert "12.5 % over updates 3-4" in line and "50.0 % over updates 5-6" in line
    assert protocol._training_success_line({"checkpoints": [2], "mean": [None]}) == []
    assert protocol._training_success_line(None) == []
