"""`cogail report`: one self-contained HTML page from a (fake) run directory."""
import base64
import json
from pathlib import Path

import numpy as np
import pytest

from cogail_jax.apps import cli
from cogail_jax.algo.config import TrainConfig

def _results(seeds) -> dict:
    """An evaluation of 3 checkpoints (made-up success rates) through the reporting protocol."""
    from cogail_jax.eval import rollouts
    from cogail_jax.eval import protocol

    rng = np.random.default_rng(0)
    per_ckpt = {}
    for c, step in enumerate((2, 4, 6)):
        per_ckpt[step] = {"replay_success": (rng.random((len(seeds), 20)) < 0.2 * c + 0.3).astype(float),
                          "val_replay_success": (rng.random((len(seeds), 30)) < 0.2 * c + 0.2).astype(float),
                          "interp_success": (rng.random((len(seeds), 16)) < 0.5).astype(float),
                          "interp_strategy": rng.integers(1, 5, (len(seeds), 16))}
    return protocol.summarize("fetchq", "cogail", seeds, per_ckpt, ("s1", "s2", "s3", "s4"), None)


def _png(path: Path, color) -> bytes:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(1, 1))
    fig.subplots().imshow(np.full((4, 4, 3), color, np.uint8))
    fig.savefig(path, format="png")
    return path.read_bytes()


def _fake_run(root: Path, evaluated: bool = True, seeds=(1, 2)) -> Path:
    from tensorboardX import SummaryWriter

    run = root / "run"
    run.mkdir()
    cfg = TrainConfig(seeds=seeds, num_envs=8, unroll_length=10, total_steps=400)
    (run / "config.json").write_text(cfg.to_json())
    (run / "run_info.json").write_text(json.dumps({"packages": {"jax": "0.0-test"}, "git_commit": "abc1234"}))
    for s in seeds:
        w = SummaryWriter(str(run / "tb" / f"seed_{s}"))
        for u in range(1, 6):
            step = u * cfg.steps_per_update
            w.add_scalar("train/disc_loss", 1.0 / u + s, step)
            w.add_scalar("train/disc_acc_expert", 0.5 + 0.05 * u, step)
            w.add_scalar("train/loss_a", 2.0 / u, step)
            w.add_scalar("train/episode_success", 0.1 * u, step)
            w.add_scalar("train/reward", -u, step)
        w.close()
    if evaluated:
        from cogail_jax.eval import rollouts
        from cogail_jax.eval import protocol

        protocol.save_results(run, _results(seeds))
        _png(run / "strategy_distribution.png", (200, 30, 30))
    return run


def test_read_scalars_matches_what_was_written(tmp_path):
    from cogail_jax.apps.report import read_scalars

    run = _fake_run(tmp_path)
    sc = read_scalars(run / "tb")
    assert list(sc) == ["1", "2"]
    steps, vals = sc["2"]["train/disc_loss"]
    np.testing.assert_array_equal(steps, 80 * np.arange(1, 6))
    np.testing.assert_allclose(vals, 1.0 / np.arange(1, 6) + 2, rtol=1e-6)


def test_report_of_an_evaluated_run(tmp_path, capsys):
    run = _fake_run(tmp_path)
    png = (run / "strategy_distribution.png").read_bytes()
    (run / "videos").mkdir()
    (run / "videos" / "rollouts.gif").write_bytes(b"GIF89a-fake")
    assert cli.main(["report", "--run", str(run)]) == 0
    page = (run / "report.html").read_text()
    assert "wrote" in capsys.readouterr().out
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert base64.b64encode(png).decode() in page  # the run's figure, embedded
    assert "data:image/gif;base64," + base64.b64encode(b"GIF89a-fake").decode() in page
    # the evaluation table from results.md, led by the checkpoint selected on validation
    res = json.loads((run / "results.json").read_text())
    sel = res["selected"]["replay"]
    assert "<th>checkpoint choice</th>" in page and "selected on validation" in page
    assert f"{100 * sel['mean']:.1f} +- {100 * sel['std']:.1f}" in page and "paper protocol" in page
    assert f"replay, selected on validation (ckpt {res['selected']['checkpoint']})" in page  # the summary card
    # learning curves (one per group) + the eval curve + the run's png: at least 5 embedded PNGs
    assert page.count("data:image/png;base64,") >= 5
    for title in ("Episode success", "Discriminator", "Losses", "Learning curves", "Configuration"):
        assert title in page
    assert "abc1234" in page and "not been evaluated" not in page
    assert "src=\"http" not in page and "<script" not in page  # self-contained


def test_report_of_a_run_not_evaluated_yet(tmp_path, capsys):
    run = _fake_run(tmp_path, evaluated=False)
    out = tmp_path / "elsewhere" / "r.html"
    assert cli.main(["report", "--run", str(run), "--out", str(out)]) == 0
    page = out.read_text()
    assert "has not been evaluated yet" in page and "cogail eval --run" in page
    assert page.count("data:image/png;base64,") >= 3


def test_report_of_a_run_that_logged_nothing(tmp_path):
    from cogail_jax.apps.report import build_report

    run = tmp_path / "empty"
    run.mkdir()
    (run / "config.json").write_text(TrainConfig().to_json())
    page = build_report(run).read_text()
    assert "No TensorBoard scalars" in page and "not been evaluated" in page


def test_report_of_a_directory_that_is_not_a_run(tmp_path, capsys):
    assert cli.main(["report", "--run", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a run directory" in err[0]


@pytest.mark.parametrize("cmd", ["import", "report"])
def test_help(cmd, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main([cmd, "--help"])
    assert e.value.code == 0 and "usage: cogail" in capsys.readouterr().out


def test_summary_breaks_replay_and_interpolation_down_by_events():
    """results.json: replay success per held-out strategy and how far rollouts got (each event's share), at
    the breakdown checkpoint; categorical events (1 human / 2 robot) are split by value, continuous ones left out."""
    from cogail_jax.eval import rollouts
    from cogail_jax.eval import protocol

    hs = np.array([1, 1, 2, 2])
    ck = {
        10: {"replay_success": np.array([[1, 0, 0, 0]], float), "interp_success": np.array([[0, 0, 0]], float),
             "interp_strategy": np.zeros((1, 3), int),
             "interp_metrics": {"opened_by": np.array([[0, 1, 2]], float), "spot": np.array([[0.3, 0.1, 0.2]])},
             "replay_metrics": {"success": np.array([[1, 0, 0, 0]], float), "opened_by": np.array([[1, 1, 0, 2]], float)}},
        20: {"replay_success": np.array([[1, 0, 1, 1]], float), "interp_success": np.array([[1, 0, 0]], float),
             "interp_strategy": np.array([[2, 0, 0]]),
             "interp_metrics": {"opened_by": np.array([[2, 2, 0]], float), "spot": np.array([[0.3, 0.1, 0.2]])},
             "replay_metrics": {"success": np.array([[1, 0, 1, 1]], float), "opened_by": np.array([[1, 0, 2, 2]], float)}},
    }
    res = protocol.summarize("t", "cogail", (7,), ck, ("a", "b"), None, heldout_strategy=hs)
    assert res["per_seed_best"]["replay"]["checkpoint"] == {"7": 20}
    assert res["breakdowns_at"]["checkpoint"] == 20  # no validation results here: at the last checkpoint
    assert res["replay_by_strategy"] == {"a": 0.5, "b": 1.0}
    assert res["replay_events_by_strategy"]["a"] == {"opened_by=1": 0.5, "opened_by=2": 0.0, "success": 0.5}
    assert res["replay_events_by_strategy"]["b"] == {"opened_by=1": 0.0, "opened_by=2": 1.0, "success": 1.0}
    assert res["interpolation_events"] == pytest.approx({"opened_by=1": 0.0, "opened_by=2": 2 / 3})
    md = protocol.results_markdown(res)
    assert "a 50.0 %" in md and "Events in replays of b demonstrations" in md
