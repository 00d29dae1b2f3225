"""experiments/paper.py assembles the paper's tables from run results (no training here)."""
import importlib.util
from pathlib import Path

import pytest

spec = importlib.util.spec_from_file_location("paper", Path(__file__).parents[1] / "experiments" / "paper.py")
paper = importlib.util.module_from_spec(spec)
spec.loader.exec_module(paper)


def _res(r, i, dist=(0.25, 0.25, 0.25, 0.25)):
    return {"replay_success": {"mean": r, "std": 0.01, "per_seed": {}},
            "interpolation_success": {"mean": i, "std": 0.02, "per_seed": {}},
            "strategy_distribution": dict(zip("abcd", dist)), "best_checkpoint": {}}


def test_tables(tmp_path):
    results = {"fetchq/cogail/uniform": _res(0.55, 0.1), "fetchq/ma_gail/uniform": _res(0.3, 0.2),
               "fetchq/cogail/D1": _res(0.5, 0.1, (0.1, 0.1, 0.4, 0.4)), "fetchq/cogail/D2": _res(0.5, 0.1)}
    paper.tables(results, ["fetchq"], ["cogail", "ma_gail", "diayn"], tmp_path)
    t1 = (tmp_path / "table1_replay.md").read_text()
    assert "| cogail | 55.0 +- 1.0 | 53.3 +- 4.4 |" in t1
    assert "| diayn | - | 44.4 +- 8.4 |" in t1
    t2 = (tmp_path / "table2_interpolation.md").read_text()
    assert "| ma_gail | 20.0 +- 2.0 | 78.5 +- 7.2 |" in t2
    assert "| cogail | D1 | 10 | 10 | 40 | 40 |" in (tmp_path / "fig3_strategies.md").read_text()
    assert (tmp_path / "fig3_strategies.png").exists() and (tmp_path / "paper.json").exists()


def test_paper_help():
    with pytest.raises(SystemExit) as e:
        paper.main(["--help"])
    assert e.value.code == 0


def test_merge_adds_side_by_side_runs_to_the_tables(tmp_path):
    """`paper.py --merge DIR...` (runs made side by side by experiments/gpu_grid.sh) adds each DIR's paper.json
    to --out's, keeps what --out had, trains nothing, and skips entries that are not result folders."""
    import json

    out, a, b = tmp_path / "out", tmp_path / "a", tmp_path / "b"
    for d, res in ((out, {"fetchq/cogail/uniform": _res(0.55, 0.1)}), (a, {"handover/cogail/uniform": _res(0.4, 0.2)}),
                   (b, {"handover/diayn/uniform": _res(0.46, 0.3)})):
        d.mkdir()
        (d / "paper.json").write_text(json.dumps(res))
    (tmp_path / "a.log").write_text("not a folder")
    assert paper.main(["--out", str(out), "--merge", str(a), str(b), str(tmp_path / "a.log")]) == 0
    merged = json.loads((out / "paper.json").read_text())
    assert set(merged) == {"fetchq/cogail/uniform", "handover/cogail/uniform", "handover/diayn/uniform"}
    t1 = (out / "table1_replay.md").read_text()
    assert "| cogail | 55.0 +- 1.0 | 53.3 +- 4.4 | 40.0 +- 1.0 | 43.9 +- 6.3 |" in t1
    assert "| diayn | - | 44.4 +- 8.4 | 46.0 +- 1.0 | 22.7 +- 1.5 |" in t1


def test_runs_already_in_paper_json_are_skipped(tmp_path, monkeypatch, capsys):
    """A resumed grid call (experiments/gpu_grid.sh) only finishes what was cut: an entry already in
    <out>/paper.json is not trained or evaluated again unless --force is given."""
    import json

    (tmp_path / "paper.json").write_text(json.dumps({"fetchq/cogail/uniform": _res(0.6, 0.5)}))
    calls = []

    def fake_run_one(task, method, mix, *a, **k):
        calls.append((task, method, mix))
        return {**_res(0.1, 0.1), "strategy_distribution": {}, "best_checkpoint": {}}

    monkeypatch.setattr(paper, "run_one", fake_run_one)
    argv = ["--tasks", "fetchq", "--methods", "cogail,ma_gail", "--out", str(tmp_path)]
    paper.main(argv)
    assert calls == [("fetchq", "ma_gail", "uniform")]
    assert "already in" in capsys.readouterr().out
    saved = json.loads((tmp_path / "paper.json").read_text())
    assert saved["fetchq/cogail/uniform"]["replay_success"]["mean"] == 0.6
    paper.main(argv + ["--force"])
    assert calls[1:] == [("fetchq", "cogail", "uniform"), ("fetchq", "ma_gail", "uniform")]
