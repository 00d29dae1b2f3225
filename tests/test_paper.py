"""experiments/paper.py assembles the paper's tables from run results (no training here)."""
import importlib.util
import json
import shutil
from pathlib import Path

import pytest

_loader = importlib.util.spec_from_file_location("paper", Path(__file__).parents[1] / "experiments" / "paper.py")
paper = importlib.util.module_from_spec(_loader)
_loader.loader.exec_module(paper)


@pytest.fixture(autouse=True)
def _keep_xla_flags(monkeypatch):  # paper.main sets XLA_FLAGS (deterministic GPU execution)
    import os

    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))


def _s(mean, std=0.01, ckpt=None):
    return {"mean": mean, "std": std, "per_seed": {}, **({"checkpoint": ckpt} if ckpt is not None else {})}


def _res(sel_r, pp_r, sel_i=0.1, pp_i=0.2, dist=(0.25, 0.25, 0.25, 0.25), pp_dist=(0.4, 0.2, 0.2, 0.2)):
    return {"paper_protocol": {"replay": _s(pp_r, 0.02, 30),
                               "interpolation": {**_s(pp_i, 0.02, 20), "strategy_distribution": dict(zip("abcd", pp_dist))}},
            "selected": {"checkpoint": 40, "replay": _s(sel_r), "interpolation": _s(sel_i),
                         "validation_replay": _s(0.5)},
            "last": {"checkpoint": 40, "replay": _s(sel_r), "interpolation": _s(sel_i)},
            "strategy_distribution": dict(zip("abcd", dist))}


def test_tables_give_selected_paper_protocol_and_paper(tmp_path):
    results = {"fetchq/cogail/uniform": _res(0.55, 0.6), "fetchq/ma_gail/uniform": _res(0.3, 0.35, 0.2, 0.25),
               "fetchq/cogail/D1": _res(0.5, 0.5, dist=(0.1, 0.1, 0.4, 0.4)), "fetchq/cogail/D2": _res(0.5, 0.5),
               "fetchq/diayn/uniform": {"replay_success": _s(0.9)},  # made before the protocol: no figures
               "fetchq/bc_gail/uniform": _res(0.4, 0.45, 0.3, 0.35)}
    paper.tables(results, ["fetchq"], ["cogail", "ma_gail", "diayn", "bc_gail"], tmp_path)
    t1 = (tmp_path / "table1_replay.md").read_text()
    assert "| method | fetchq: selected | fetchq: paper protocol | fetchq: paper |" in t1
    assert "| cogail | 55.0 +- 1.0 | 60.0 +- 2.0 | 53.3 +- 4.4 |" in t1
    assert "| diayn | - | - | 44.4 +- 8.4 |" in t1
    t2 = (tmp_path / "table2_interpolation.md").read_text()
    assert "| ma_gail | 20.0 +- 1.0 | 25.0 +- 2.0 | 78.5 +- 7.2 |" in t2
    assert "| bc_gail | 30.0 +- 1.0 | 35.0 +- 2.0 | not reported |" in t2  # the paper gives no figure
    f3 = (tmp_path / "fig3_strategies.md").read_text()
    assert "| cogail | D1 | 10 / 10 / 40 / 40 | 40 / 20 / 20 / 20 | 17 / 17 / 33 / 33 |" in f3
    assert (tmp_path / "fig3_strategies.png").exists() and (tmp_path / "paper.json").exists()


def test_tables_only_rewrites_the_readme_block(tmp_path):
    out = tmp_path / "docs" / "results" / "paper"
    out.mkdir(parents=True)
    (out / "paper.json").write_text(json.dumps({"fetchq/cogail/uniform": _res(0.55, 0.6),
                                                "fetchq/cogail/D1": _res(0.5, 0.5)}))
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\nintro\n\n{paper.BEGIN}\nold table\n{paper.END}\n\nafter\n")
    assert paper.main(["--out", str(out), "--tables-only", "--readme", str(readme)]) == 0
    doc = readme.read_text()
    assert doc.startswith("# x\n\nintro\n\n" + paper.BEGIN) and doc.endswith(paper.END + "\n\nafter\n")
    assert "old table" not in doc and "| cogail | 55.0 +- 1.0 | 60.0 +- 2.0 | 53.3 +- 4.4 |" in doc
    assert "](docs/results/paper/fig3_strategies.png)" in doc
    assert paper.main(["--out", str(out), "--tables-only", "--readme", str(readme)]) == 0
    assert readme.read_text() == doc  # idempotent
    readme.write_text("no markers")
    with pytest.raises(SystemExit, match="results:begin"):
        paper.main(["--out", str(out), "--tables-only", "--readme", str(readme)])


def test_paper_help(capsys):
    with pytest.raises(SystemExit) as e:
        paper.main(["--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and "usage:" in out and "--tables-only" in out and "--merge" in out


def test_merge_adds_side_by_side_runs_to_the_tables(tmp_path):
    out, a, b = tmp_path / "out", tmp_path / "a", tmp_path / "b"
    for d, res in ((out, {"fetchq/cogail/uniform": _res(0.55, 0.6)}), (a, {"handover/cogail/uniform": _res(0.4, 0.45)}),
                   (b, {"handover/diayn/uniform": _res(0.46, 0.5)})):
        d.mkdir()
        (d / "paper.json").write_text(json.dumps(res))
    (tmp_path / "a.log").write_text("not a folder")
    assert paper.main(["--out", str(out), "--merge", str(a), str(b), str(tmp_path / "a.log")]) == 0
    merged = json.loads((out / "paper.json").read_text())
    assert set(merged) == {"fetchq/cogail/uniform", "handover/cogail/uniform", "handover/diayn/uniform"}
    t1 = (out / "table1_replay.md").read_text()
    assert "| cogail | 55.0 +- 1.0 | 60.0 +- 2.0 | 53.3 +- 4.4 | 40.0 +- 1.0 | 45.0 +- 2.0 | 43.9 +- 6.3 |" in t1
    assert "| diayn | - | - | 44.4 +- 8.4 | 46.0 +- 1.0 | 50.0 +- 2.0 | 22.7 +- 1.5 |" in t1


def test_merge_takes_the_cross_play_of_the_merged_grids(tmp_path):
    """A merged grid's cross-play matrices replace the same tasks' and keep the others', but never by a smaller one
    (a shard's, of only the robots it trained)."""
    cell = lambda m: {"reward": {"mean": m, "se": 0.0}}  # noqa: E731
    out, a = tmp_path / "out", tmp_path / "a"
    two = {"x": {"x": cell(4.0), "z": cell(4.0)}, "z": {"x": cell(4.0), "z": cell(4.0)}}
    for d, matrices in ((out, {"k1": {"x": {"x": cell(1.0)}}, "k2": {"x": {"x": cell(2.0)}}, "k3": two}),
                        (a, {"k2": {"y": {"y": cell(3.0)}}, "k3": {"y": {"y": cell(5.0)}}})):
        d.mkdir()
        (d / "paper.json").write_text(json.dumps({}))
        (d / "crossplay.json").write_text(json.dumps(matrices))
    assert paper.main(["--out", str(out), "--merge", str(a)]) == 0
    assert json.loads((out / "crossplay.json").read_text()) == {"k1": {"x": {"x": cell(1.0)}},
                                                                 "k2": {"y": {"y": cell(3.0)}}, "k3": two}
    assert "| y | 3.0 +- 0.0 |" in (out / "crossplay.md").read_text()


def test_runs_are_cached_by_their_full_resolved_config(tmp_path, monkeypatch, capsys):
    """An entry of paper.json is reused only if its run's resolved config (hash) is the same: any --set that
    changes the config trains again (in a run directory of its own); one that gives the default value does not;
    --set booleans parse (false is false)."""
    calls = []

    def fake_run_one(task, method, mix, seeds, out, extra, every=1, ckpt_batch=1):
        calls.append((task, method, mix, dict(extra)))
        cfg = paper.resolve_config(task, method, mix, seeds, extra)
        return {**_res(0.1, 0.1), "config_hash": paper.config_hash(cfg), "eval_every": every,
                "run": str(paper.run_dir(out, cfg)), "commit": paper.head_commit(), "dirty": False,
                "sets": dict(extra), "seeds": list(seeds)}

    monkeypatch.setattr(paper, "run_one", fake_run_one)
    argv = ["--tasks", "fetchq", "--methods", "cogail", "--out", str(tmp_path)]
    paper.main(argv)
    paper.main(argv)  # same config: skipped
    assert len(calls) == 1 and "already in" in capsys.readouterr().out
    paper.main(argv + ["--set", "disc_instance_noise=false"])  # the default value: the same config
    assert len(calls) == 1
    paper.main(argv + ["--set", "disc_instance_noise=true"])
    assert calls[-1][3] == {"disc_instance_noise": True} and len(calls) == 2
    paper.main(argv + ["--set", "lr=1e-4", "--set", "disc_instance_noise=true"])
    assert len(calls) == 3
    paper.main(argv + ["--set", "lr=1e-4", "--set", "disc_instance_noise=true", "--force"])
    assert len(calls) == 4
    paper.main(argv + ["--seeds", "1,2"])  # seeds are part of the config
    assert len(calls) == 5
    base = paper.resolve_config("fetchq", "cogail", "uniform", [300, 400, 500], {})
    other = paper.resolve_config("fetchq", "cogail", "uniform", [300, 400, 500], {"lr": 1e-4})
    assert paper.run_dir(tmp_path, base) != paper.run_dir(tmp_path, other)
    assert paper.run_dir(tmp_path, base).name.startswith("fetchq-cogail-uniform-")
    # a run's hash survives its config.json, and a default given explicitly is the same config
    assert paper.config_hash(base) == paper.config_hash(type(base).from_dict(json.loads(base.to_json())))
    assert paper.config_hash(base) == paper.config_hash(
        paper.resolve_config("fetchq", "cogail", "uniform", [300, 400, 500], {"lr": base.lr}))
    assert paper.parse_sets(["reward_norm=false"]) == {"reward_norm": False}


def test_stale_rows_are_reported_and_trained_again(tmp_path, monkeypatch, capsys):
    """A row is fresh only if it was trained from this checkout's code (its commit, or one whose src/, envs/ and
    pyproject.toml are the same, without uncommitted changes) with the config the current settings resolve to;
    ``--check`` lists every other row with why, and exits 1; a grid run trains a stale row again."""
    head = paper.head_commit()
    if head is None:
        pytest.skip("not a git checkout")
    seeds = [300, 400, 500]
    h = paper.config_hash(paper.resolve_config("fetchq", "cogail", "uniform", seeds, {}))
    h_lr = paper.config_hash(paper.resolve_config("fetchq", "cogail", "uniform", seeds, {"lr": 1e-4}))
    fresh = {**_res(0.5, 0.5), "commit": head, "dirty": False, "sets": {}, "seeds": seeds, "config_hash": h}
    rows = {"fetchq/cogail/uniform": fresh,
            "fetchq/cogail/uniform/lr": {**fresh, "sets": {"lr": 1e-4}, "config_hash": h_lr},  # a labelled variant
            "fetchq/ma_gail/uniform": {**fresh, "config_hash": h},  # ma_gail's settings do not give cogail's config
            "fetchq/cogail/uniform/old": {**_res(0.5, 0.5)},  # trained before runs recorded their commit
            "fetchq/cogail/uniform/dirty": {**fresh, "dirty": True},
            "fetchq/cogail/uniform/elsewhere": {**fresh, "commit": "f" * 40}}
    last_code = paper._git("log", "-1", "--format=%H", "--", *paper.CODE).stdout.strip()
    rows["fetchq/cogail/D1"] = {**fresh, "commit": last_code,  # the code is the same as HEAD's: fresh
                                "config_hash": paper.config_hash(paper.resolve_config("fetchq", "cogail", "D1", seeds,
                                                                                      {}))}
    root = paper._git("rev-list", "--max-parents=0", "HEAD").stdout.split()[0]
    old_code = paper.code_changed(root, head)  # the first commit's code: not this one's (unless a shallow clone)
    if old_code:
        rows["fetchq/cogail/uniform/root"] = {**fresh, "commit": root}
    why = paper.stale(rows)
    assert set(why) == {"fetchq/ma_gail/uniform", "fetchq/cogail/uniform/old", "fetchq/cogail/uniform/dirty",
                        "fetchq/cogail/uniform/elsewhere"} | ({"fetchq/cogail/uniform/root"} if old_code else set()), why
    assert "not what the settings resolve to" in why["fetchq/ma_gail/uniform"]
    assert "no commit" in why["fetchq/cogail/uniform/old"] and "uncommitted" in why["fetchq/cogail/uniform/dirty"]
    assert "not in this repository" in why["fetchq/cogail/uniform/elsewhere"]
    if old_code:
        assert "the code has changed" in why["fetchq/cogail/uniform/root"]
    # --check: every stale row and why, exit status 1; only fresh rows: 0
    (tmp_path / "paper.json").write_text(json.dumps(rows))
    assert paper.main(["--check", "--out", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert all(f"stale: {k}: {v}" in out for k, v in why.items()), out
    (tmp_path / "paper.json").write_text(json.dumps({k: rows[k] for k in ("fetchq/cogail/uniform",
                                                                          "fetchq/cogail/uniform/lr")}))
    assert paper.main(["--check", "--out", str(tmp_path)]) == 0
    with pytest.raises(SystemExit, match="does not exist"):
        paper.main(["--check", "--out", str(tmp_path / "nowhere")])
    # a grid run trains the stale row again, even with the same config hash; the fresh one is reused
    (tmp_path / "paper.json").write_text(json.dumps({"fetchq/cogail/uniform": {**fresh, "dirty": True,
                                                                                "eval_every": 1}}))
    calls = []
    monkeypatch.setattr(paper, "run_one", lambda t, m, mix, s, o, e, every=1, ckpt_batch=1: calls.append(m) or
                        {**fresh, "eval_every": every})
    paper.main(["--tasks", "fetchq", "--methods", "cogail", "--out", str(tmp_path)])
    paper.main(["--tasks", "fetchq", "--methods", "cogail", "--out", str(tmp_path)])
    assert calls == ["cogail"]


def test_a_task_s_rows_go_stale_with_its_own_code_only(tmp_path, monkeypatch):
    """A commit that changes only another built-in task's package (envs/<other>/) leaves a task's rows fresh; one
    that changes its own package, the shared envs/ modules or src/ makes them stale."""
    repo = tmp_path / "repo"
    for rel in ("src/cogail_jax/a.py", "envs/base.py", "envs/fetchq/config.py", "envs/handover/config.py",
                "envs/seqmanip/config.py", "experiments/paper.py", "pyproject.toml", "src/cogail_jax/apps/play.py",
                "src/cogail_jax/apps/collect.py"):
        (repo / rel).parent.mkdir(parents=True, exist_ok=True)
        (repo / rel).write_text("x = 1\n")
    monkeypatch.setattr(paper, "ROOT", repo / "experiments")
    git = lambda *a: paper._git(*a).stdout.strip()  # noqa: E731
    git("-C", str(repo), "init", "-q")  # (git runs in experiments/)

    def commit(rel=None):
        if rel:
            (repo / rel).write_text((repo / rel).read_text() + "y = 2\n")
        git("add", "-A")
        git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c", "--allow-empty")
        return git("rev-parse", "HEAD")

    first = commit()
    other = commit("envs/handover/config.py")
    assert paper.code_changed(first, other, "seqmanip") is False
    assert paper.code_changed(first, other, "handover") is True and paper.code_changed(first, other) is True
    for rel in ("envs/seqmanip/config.py", "envs/base.py", "src/cogail_jax/a.py", "pyproject.toml"):
        assert paper.code_changed(other, commit(rel), "seqmanip") is True, rel
    assert paper.code_changed(first, commit("experiments/paper.py"), "fetchq") is True  # (src/ changed since first)
    last = git("rev-parse", "HEAD")
    assert paper.code_changed(git("rev-parse", "HEAD~1"), last, "fetchq") is False  # experiments/ is not code
    for rel in ("src/cogail_jax/apps/play.py", "src/cogail_jax/apps/collect.py"):  # never run by training or eval
        before = git("rev-parse", "HEAD")
        assert paper.code_changed(before, commit(rel)) is False, rel
        assert paper.code_changed(before, git("rev-parse", "HEAD"), "fetchq") is False, rel
    # a task of your own in the repository: its folder counts for its rows, and for no other task's
    monkeypatch.setattr(paper, "own_task_folder", lambda t: "mine" if t == "mine:TASK" else None)
    (repo / "mine").mkdir()
    (repo / "mine" / "env.py").write_text("x = 1\n")
    before = commit()
    after = commit("mine/env.py")
    assert paper.code_changed(before, after, "mine:TASK") is True
    assert paper.code_changed(before, after, "seqmanip") is False


def test_a_task_of_your_own_is_found_in_the_repository(tmp_path):
    """``own_task_folder``: the folder of a task given as module:TASK or folder:TASK, relative to the repository's
    top; None for a built-in task's name and for a task outside the repository."""
    root = Path(paper.ROOT).parent
    if not (root / "examples" / "table_carry").is_dir():
        pytest.skip("no example task in this checkout")
    assert paper.own_task_folder("examples.table_carry:TASK") == "examples/table_carry"
    assert paper.own_task_folder(f"{root / 'examples' / 'table_carry'}:TASK") == "examples/table_carry"
    assert ":(top)examples/table_carry" in paper.task_code("examples.table_carry:TASK")
    assert paper.own_task_folder("seqmanip") is None
    assert paper.own_task_folder(f"{tmp_path}:TASK") is None


def _coplay(scripted, proxy, ref_proxy=0.8):
    parts = ["scripted", "slow", "pauses", "proxy"]
    got = {"scripted": _s(scripted), "slow": _s(scripted - 0.2), "pauses": _s(scripted - 0.1), "proxy": _s(proxy)}
    return {"partners": parts, "learned": {"selected": {"checkpoint": 40, "success": got}},
            "scripted_robot": {"scripted": 1.0, "slow": 0.9, "pauses": 0.7, "proxy": ref_proxy}}


def test_claims_and_coplay_are_generated_from_the_grid(tmp_path):
    """The co-play table (every method, and the scripted robot as the reference) and the claim-by-claim summary
    come from paper.json alone, each claim beside the paper's figures; the README block carries every method's co-play
    (scripted human, BC proxy) and the claims."""
    results = {"fetchq/cogail/uniform": {**_res(0.8, 0.8, 0.9, 0.9), "method": "cogail", "coplay": _coplay(0.9, 0.6)},
               "fetchq/ma_gail/uniform": {**_res(0.7, 0.7, 0.95, 0.95), "method": "ma_gail",
                                          "coplay": _coplay(0.8, 0.4)},
               "fetchq/bc_single/uniform": {**_res(0.85, 0.85), "method": "bc_single"},
               "fetchq/cogail/D1": _res(0.5, 0.5, dist=(0.1, 0.2, 0.3, 0.4)),
               "fetchq/ma_gail/D1": _res(0.5, 0.5, dist=(0.0, 0.2, 0.3, 0.5))}
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{paper.BEGIN}\nold\n{paper.END}\noutro\n")
    paper.tables(results, ["fetchq"], ["cogail", "ma_gail", "bc_single"], tmp_path, readme)
    cp = (tmp_path / "coplay.md").read_text()
    assert "| fetchq | cogail | 90.0 | 70.0 | 60.0 | 0.75 |" in cp, cp
    assert "| fetchq | ma_gail | 80.0 | 60.0 | 40.0 | 0.50 |" in cp
    assert "| fetchq | scripted robot (reference) | 100.0 | 70.0 | 80.0 | 1.00 |" in cp
    claims = (tmp_path / "claims.md").read_text()
    # replay: bc_single (85) beats Co-GAIL (80); interpolation: ma_gail (95) beats it, bc_single has none
    assert "*Co-GAIL replays best* (Table 1, selected checkpoint): fetchq no (80.0 vs bc_single 85.0; paper: 53.3 vs " \
           "diayn 44.4)." in claims, claims
    assert "fetchq no (90.0 vs ma_gail 95.0; paper: 82.1 vs ma_infogail 80.2)" in claims, claims
    assert "D1: Co-GAIL's rarest strategy 10 %, the lowest other ma_gail 0 %" in claims
    assert "fetchq 0.75" in claims
    text = readme.read_text()
    assert "| robot | fetchq: scripted human | fetchq: BC proxy |" in text  # every method beside Tables 1 and 2
    assert "| cogail | 90.0 +- 1.0 | 60.0 +- 1.0 |" in text and "| ma_gail | 80.0 +- 1.0 | 40.0 +- 1.0 |" in text
    assert "| bc_single |" not in text.split("Closed-loop co-play")[1].split("\n\n")[1]  # not measured: no row
    assert "| scripted robot (reference) | 100.0 | 80.0 |" in text
    assert "Where the grid stands on the paper's claims" in text and "*Co-GAIL replays best*" in text


def test_bc_single_has_no_interpolation_figure(tmp_path):
    results = {"fetchq/bc_single/uniform": {**_res(0.4, 0.45, 0.0, 0.0), "method": "bc_single"},
               "fetchq/cogail/uniform": {**_res(0.55, 0.6), "method": "cogail"}}
    paper.tables(results, ["fetchq"], ["bc_single", "cogail"], tmp_path)
    assert "| bc_single | 40.0 +- 1.0 | 45.0 +- 2.0 | 21.1 +- 1.9 |" in (tmp_path / "table1_replay.md").read_text()
    assert "| bc_single | n/a | n/a | not reported |" in (tmp_path / "table2_interpolation.md").read_text()
    assert "| fetchq/bc_single/uniform | 40.0 +- 1.0 | 40.0 +- 1.0 | n/a | n/a |" in \
        (tmp_path / "stability.md").read_text()


def test_learning_curves_figure(tmp_path):
    curves = {"replay_success": [[0.1, 0.5, 0.4], [0.2, 0.6, 0.5]],
              "interpolation_success": [[0.0, 0.3, 0.2], [0.1, 0.4, 0.3]]}
    with_curves = {**_res(0.55, 0.6), "checkpoints": [10, 20, 30], "curves": curves}
    assert not paper.curves_png({"fetchq/cogail/uniform": _res(0.55, 0.6)}, tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()
    results = {"fetchq/cogail/uniform": with_curves, "fetchq/cogail/uniform/variant": with_curves,
               "handover/ma_gail/uniform": with_curves}  # another method: not drawn
    assert paper.curves_png(results, tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 10_000
    import matplotlib.image

    h, w = matplotlib.image.imread(tmp_path / "curves.png").shape[:2]
    assert w < h  # one column (fetchq): handover's row is another method's
    assert paper.curves_png({**results, "handover/cogail/uniform": with_curves}, tmp_path / "two.png")
    h, w = matplotlib.image.imread(tmp_path / "two.png").shape[:2]
    assert w > h  # a column per task


def test_readme_shows_the_shipped_settings_with_their_last_checkpoint_and_robustness(tmp_path):
    """The README block has a row per task for the run with `make train`'s settings (its SHIPPED variant, else the
    main row), with the last checkpoint beside the selected one, and that run in the robustness table."""
    var = {"extra_sets": {"robust-slow": {"selected": _s(0.45)}, "robust-detour": {"selected": _s(0.3)}}}
    results = {"fetchq/cogail/uniform": {**_res(0.55, 0.6), **var},
               f"fetchq/cogail/uniform/{paper.SHIPPED['fetchq']}": {**_res(0.6, 0.7), **var,
                                                                     "last": {"replay": _s(0.5), "interpolation": _s(0.3)}},
               "handover/cogail/uniform": _res(0.4, 0.45),
               f"handover/cogail/uniform/{paper.BUDGETS['handover']['2x']}": {**_res(0.7, 0.8), **var}}
    out, readme = tmp_path / "out", tmp_path / "README.md"
    out.mkdir()
    (out / "paper.json").write_text(json.dumps(results))
    readme.write_text(f"{paper.BEGIN}\n{paper.END}\n")
    assert paper.main(["--out", str(out), "--tables-only", "--readme", str(readme)]) == 0
    doc = readme.read_text()
    assert (f"| fetchq ({paper.SHIPPED['fetchq']}) | 60.0 +- 1.0 | 70.0 +- 2.0 | 50.0 +- 1.0 | 10.0 +- 1.0 | "
            "20.0 +- 2.0 | 30.0 +- 1.0 |") in doc
    assert "| handover (main table) | 40.0 +- 1.0 | 45.0 +- 2.0 | 40.0 +- 1.0 |" in doc
    assert f"| handover, BUDGET=2x ({paper.BUDGETS['handover']['2x']}) | 70.0 +- 1.0 | 80.0 +- 2.0 |" in doc  # a larger budget
    assert f"| fetchq | cogail ({paper.SHIPPED['fetchq']}) | 60.0 | 45.0 | 30.0 | 0.50 |" in doc
    assert "| fetchq | cogail | 55.0 | 45.0 | 30.0 | 0.55 |" in doc
    assert "patient" not in (out / "robustness.md").read_text()


def test_robustness_with_a_patient_human_has_its_own_table(tmp_path):
    """A run replayed with a patient human too (handover's patient-* sets) gets a second robustness table, whose
    in-distribution figure is the patient replay of the test split."""
    sets = {"robust-slow": {"selected": _s(0.45)}, "patient-test": {"selected": _s(0.9)},
            "patient-robust-slow": {"selected": _s(0.81)}}
    results = {"handover/cogail/uniform": {**_res(0.6, 0.5), "extra_sets": sets}}
    out = tmp_path / "out"
    out.mkdir()
    (out / "paper.json").write_text(json.dumps(results))
    assert paper.main(["--out", str(out), "--tables-only"]) == 0
    plain, patient = (out / "robustness.md").read_text().split("## With a patient human")
    assert "| handover | cogail | 60.0 | 45.0 | 0.75 |" in plain and "patient" not in plain
    assert "| handover | cogail | 90.0 | 81.0 | 0.90 |" in patient


def test_each_held_out_slice_is_a_column_and_the_worst_slice_is_judged_alone():
    """One column per held-out pose slice, after the varied humans whatever order the results list them in, and the
    worst slice's success over in-distribution replay beside the worst set's."""
    sets = {"robust-pose_heldout_roll": {"selected": _s(0.54)}, "robust-slow": {"selected": _s(0.3)},
            "robust-pose_heldout_x": {"selected": _s(0.48)}}
    rows = paper.robustness_rows({"handover/cogail/uniform": {**_res(0.6, 0.5), "extra_sets": sets}},
                                 ["handover"], ["cogail"])
    assert rows[0] == ("| task | method | in-distribution | slow | pose_heldout_roll | pose_heldout_x | "
                       "worst / in-distribution | worst slice / in-distribution |")
    assert rows[2] == "| handover | cogail | 60.0 | 30.0 | 54.0 | 48.0 | 0.50 | 0.80 |"
    assert rows[1].count("---") == 8


def test_variants_are_compared_on_the_validation_humans(tmp_path):
    """Every run and variant gets a row of the validation varied humans (plain and with a patient human), whose
    in-distribution figure is the validation split's replay at the selected checkpoint: the basis of a choice."""
    def sets(slow, p_val, p_slow):
        return {"val-robust-slow": {"selected": _s(slow)}, "val-robust-fast": {"selected": _s(0.45)},
                "patient-validation": {"selected": _s(p_val)}, "patient-val-robust-slow": {"selected": _s(p_slow)},
                "patient-val-robust-fast": {"selected": _s(p_val)}, "robust-slow": {"selected": _s(0.1)}}
    results = {"handover/cogail/uniform": {**_res(0.6, 0.5), "extra_sets": sets(0.4, 0.9, 0.72)},
               "handover/cogail/uniform/more": {**_res(0.6, 0.5), "extra_sets": sets(0.3, 0.8, 0.76)}}
    out = tmp_path / "out"
    out.mkdir()
    (out / "paper.json").write_text(json.dumps(results))
    assert paper.main(["--out", str(out), "--tables-only"]) == 0
    plain, patient = (out / "robustness_validation.md").read_text().split("## With a patient human")
    assert "| handover | cogail/uniform | 50.0 | 40.0 | 45.0 | 0.80 |" in plain
    assert "| handover | cogail/uniform/more | 50.0 | 30.0 | 45.0 | 0.60 |" in plain
    assert "| handover | cogail/uniform | 90.0 | 72.0 | 90.0 | 0.80 |" in patient
    assert "| handover | cogail/uniform/more | 80.0 | 76.0 | 80.0 | 0.95 |" in patient
    assert "val-" not in (out / "robustness.md").read_text()


def test_every_run_has_a_row_of_its_validation_figures(tmp_path):
    """validation.md: replay and the validation interpolation at the selected and the last checkpoint, and the
    validation rollouts' strategy shares, for every run with a validation split; - where one was not measured."""
    new = _res(0.6, 0.5)
    new["selected"]["validation_interpolation"], new["last"]["validation_replay"] = _s(0.35), _s(0.45)
    new["last"]["validation_interpolation"] = _s(0.3)
    new["validation_strategy_distribution"] = {"hands-over": 0.25, "opens": 0.75}
    new["splits"] = {"validation": {"file": "v.hdf5", "episodes": 300}, "test": {"file": "t.hdf5", "episodes": 60}}
    results = {"seqmanip/cogail/uniform/new": new, "seqmanip/cogail/uniform": _res(0.6, 0.5),
               "fetchq/diayn/uniform": {"replay_success": _s(0.9)}}  # made before the protocol: no row
    paper.tables(results, ["seqmanip"], ["cogail"], tmp_path)
    text = (tmp_path / "validation.md").read_text()
    assert "| seqmanip/cogail/uniform/new | 300 | 50.0 | 45.0 | 35.0 | 30.0 | hands-over 25 %, opens 75 % |" in text
    assert "| seqmanip/cogail/uniform | - | 50.0 | - | - | - | - |" in text
    assert "fetchq/diayn" not in text


def test_shipped_labels_match_the_task_configs():
    """SHIPPED and BUDGETS name, per task and budget, the variant with the task's settings under that budget: keep
    them in step (the label's parts: train-varied-N, N-demos, policy-ema, init-std-S, bc-std, the budget)."""
    import math
    import re

    from cogail_envs import builtin_task_names, get_task

    runs = paper.shipped_runs()
    # every built-in task with a scripted team (the paper's tasks) has its shipped row; a task learned from people's
    # recordings (overcooked) is judged by the field's protocol instead and has none yet
    scripted = {t for t in builtin_task_names() if get_task(t).team is not None}
    assert {t for t, b, _ in runs if b == "paper"} == scripted
    for task, budget, label in runs:
        cfg = get_task(task).config(budget)
        varied = re.search(r"train-varied-(\d+)", label)
        assert cfg.get("train_varied", 0) == (int(varied.group(1)) if varied else 0), (task, label)
        demos = re.search(r"(\d+)-demos", label)
        assert cfg.get("num_demos", 0) == (int(demos.group(1)) if demos else 0), (task, label)
        assert bool(cfg.get("policy_ema")) == ("policy-ema" in label), (task, label)
        ema = re.search(r"policy-ema-(0\.\d+)", label)  # no value: the first average tried, 0.98
        assert cfg.get("policy_ema", 0) == (float(ema.group(1)) if ema else 0.98 if "policy-ema" in label else 0)
        std = re.search(r"init-std-([\d.]+)", label)
        assert (round(math.exp(cfg["init_log_std"]), 2) if "init_log_std" in cfg else None) == (
            float(std.group(1)) if std else None), (task, label)
        assert bool(cfg.get("bc_std")) == label.endswith("-bc-std"), (task, label)
        assert (budget == "paper") == (not label.startswith(budget)), (task, label)


def test_every_task_budget_is_a_valid_train_config():
    """`cogail train --task T --budget B` resolves the task's settings: every task and budget validates, a budget only
    overrides the task's defaults (it is not a copy of them), and an unknown budget is one sentence."""
    from cogail_envs import builtin_task_names, get_task
    from cogail_jax.algo.config import ConfigError, resolve

    for t in builtin_task_names():
        task = get_task(t)
        assert resolve(t).task == t
        for b, over in task.budgets.items():
            cfg, base = resolve(t, b), resolve(t)
            assert over and all(task.default_config().get(k) != v for k, v in over.items()), (t, b)
            assert {k for k in cfg.__dataclass_fields__ if getattr(cfg, k) != getattr(base, k)} == set(over), (t, b)
    with pytest.raises(ConfigError, match="no budget 'huge'"):
        resolve("fetchq", "huge")


def test_shard_and_gpu_slots():
    jobs = list(range(7))
    assert paper.shard_jobs(jobs, None) == jobs
    assert paper.shard_jobs(jobs, "1/3") == [1, 4]
    assert sorted(sum((paper.shard_jobs(jobs, f"{i}/3") for i in range(3)), [])) == jobs  # the shards cover the grid
    with pytest.raises(SystemExit, match="--shard 3/3"):
        paper.shard_jobs(jobs, "3/3")
    two = {"CUDA_VISIBLE_DEVICES": "2,5"}
    assert paper.gpu_slots("all", two) == ["2", "5"] and paper.gpu_slots("1", two) == ["2"]
    with pytest.raises(SystemExit, match="only 2 GPU"):
        paper.gpu_slots("3", two)
    assert paper.gpu_slots("all", {"CUDA_VISIBLE_DEVICES": ""}) == ["-"]  # none: one slot, in this process
    assert paper.job_slots(["2", "5"]) == ["2", "5"]
    assert paper.job_slots(["2", "5"], 2) == ["2:0", "5:0", "2:1", "5:1"]  # spread over the GPUs first
    assert [paper.slot_device(s) for s in paper.job_slots(["2", "5"], 2)] == ["2", "5", "2", "5"]
    with pytest.raises(SystemExit, match="--jobs-per-gpu 0"):
        paper.job_slots(["0"], 0)


@pytest.mark.parametrize("args,needle", [
    (["--tasks", "nope"], "--tasks: unknown task 'nope'"),
    (["--methods", "cogail,nope"], "--methods: no method 'nope'"),
    (["--seeds", "1,a"], "--seeds 1,a: give comma-separated integers"),
    (["--mixes", "uniform,D9"], "--mixes: no fetchq mixture 'D9'"),
    (["--jobs-per-gpu", "0"], "--jobs-per-gpu 0: give 1 or more"),
])
def test_a_grid_s_bad_options_end_before_anything_runs(args, needle, tmp_path):
    out = tmp_path / "grid"
    with pytest.raises(SystemExit) as e:
        paper.main([*args, "--out", str(out)])
    assert str(e.value).startswith(needle) and "\n" not in str(e.value)
    assert not out.exists()  # nothing made, nothing started


def test_jobs_run_one_per_slot_and_queue():
    class Proc:
        def __init__(self, job, slot, polls):
            self.job, self.slot, self.left = job, slot, polls

        def poll(self):
            self.left -= 1
            return None if self.left > 0 else (3 if self.job == "bad" else 0)

    running, most = {}, [0]

    def launch(job, slot):
        assert slot not in running.values()  # a slot runs one job at a time
        running[job] = slot
        most[0] = max(most[0], len(running))
        return Proc(job, slot, polls=2 + len(job))

    ended = []
    for job, code in paper.run_jobs(["a", "bb", "bad", "c", "dddd"], ["g0", "g1"], launch, poll=0):
        running.pop(job)
        ended.append((job, code))
    assert most[0] == 2 and sorted(ended) == sorted([("a", 0), ("bb", 0), ("bad", 3), ("c", 0), ("dddd", 0)])


def test_jobs_wait_for_what_they_need_and_skip_what_cannot_run():
    """``ready``: a job that must wait lets a later ready one take the free slot; one that never can run is
    yielded with exit code None without being launched."""
    class Proc:
        def __init__(self, job):
            self.job, self.left = job, 3

        def poll(self):
            self.left -= 1
            return None if self.left > 0 else (1 if self.job == "data-bad" else 0)

    done, launched = set(), []

    def ready(job):
        need = {"x": "data-ok", "y": "data-bad"}.get(job)
        if need is None or need == "data-ok" and need in done:
            return True
        return None if need == "data-bad" and need in done else False

    def launch(job, slot):
        launched.append(job)
        return Proc(job)

    ended = []
    for job, code in paper.run_jobs(["x", "y", "data-ok", "data-bad", "z"], ["g0"], launch, poll=0, ready=ready):
        done.add(job)
        ended.append((job, code))
    assert launched == ["data-ok", "x", "data-bad", "z"]  # one slot: x waits for data-ok, y for data-bad
    assert ("y", None) in ended and "y" not in launched and ("data-bad", 1) in ended


def test_a_task_s_jobs_are_capped_per_gpu():
    """``limit``: at most k jobs of a group side by side on one GPU, other jobs filling the free slots meanwhile
    (the first queued job that fits a free slot starts); ``task_caps`` reads ``--task-jobs-per-gpu``."""
    class Proc:
        def __init__(self):
            self.left = 3

        def poll(self):
            self.left -= 1
            return None if self.left > 0 else 0

    running, most, order = {}, {}, []

    def launch(job, slot):
        running[job] = paper.slot_device(slot)
        order.append(job)
        for gpu in set(running.values()):
            n = sum(j.startswith("mjx") and g == gpu for j, g in running.items())
            most[gpu] = max(most.get(gpu, 0), n)
        return Proc()

    jobs = ["mjx1", "mjx2", "mjx3", "mjx4", "mjx5", "f1", "f2", "f3"]
    limit = lambda job: ("mjx", 2) if job.startswith("mjx") else None  # noqa: E731
    for job, code in paper.run_jobs(jobs, paper.job_slots(["0", "1"], 3), launch, poll=0, limit=limit):
        running.pop(job)
        assert code == 0
    assert most == {"0": 2, "1": 2}  # two per GPU, never three, on both GPUs
    assert order[:6] == ["mjx1", "mjx2", "mjx3", "mjx4", "f1", "f2"]  # the capped jobs let the others start
    assert sorted(order) == sorted(jobs)
    caps = paper.task_caps(["handover=3", "overcooked=4"])
    assert caps["handover"] == ("handover", 3) and caps["overcooked_coordination_ring"] == ("overcooked", 4)
    with pytest.raises(SystemExit, match="no task 'nope'"):
        paper.task_caps(["nope=2"])
    with pytest.raises(SystemExit, match="TASK=K"):
        paper.task_caps(["handover"])


def test_data_only_makes_every_jobs_datasets_and_trains_nothing(tmp_path, monkeypatch):
    """``--data-only`` (a sweep's data job) makes the datasets of every task x method x mixture's config and the
    validation split's varied humans of each task and mixture, and trains nothing."""
    from cogail_jax.data import sets

    configs, val = [], []
    monkeypatch.setattr(sets, "make_datasets", lambda cfg: configs.append((cfg.task, cfg.method, cfg.mix)))
    monkeypatch.setattr(paper, "validation_robustness_sets", lambda t, mix: val.append((t, mix)))
    monkeypatch.setattr(paper, "run_one", lambda *a, **k: pytest.fail("--data-only trained"))
    assert paper.main(["--data-only", "--tasks", "fetchq", "--methods", "cogail,diayn", "--mixes", "uniform,D1",
                       "--out", str(tmp_path / "g")]) == 0
    assert sorted(configs) == sorted((("fetchq", m, x) for m in ("cogail", "diayn") for x in ("uniform", "D1")))
    assert val == [("fetchq", "uniform"), ("fetchq", "D1")] and not (tmp_path / "g" / "paper.json").exists()


def test_sweep_merges_each_jobs_results_as_it_ends(tmp_path, monkeypatch):
    """``--gpus 2``: every job a process of its own (here a stand-in that writes the job's paper.json; the ma_gail
    job fails), after its task's data job (a stand-in that leaves a file the jobs require), merged into
    <out>/paper.json with the tables rewritten; a failed job makes the exit code 1. ``--jobs-per-gpu`` runs several
    jobs on one GPU the same way."""
    import sys

    made, asked = tmp_path / "made", []

    def fake_data_argv(a, job):
        t, _, mixes, methods = job
        asked.append((t, mixes, methods))
        return [sys.executable, "-c", f"import time, pathlib; time.sleep(0.5); pathlib.Path({str(made)!r}).touch()"]

    def fake_argv(a, job, out):
        t, m, mix = job
        res = json.dumps({f"{t}/{m}/{mix}": _res(0.55, 0.6)})
        code = ("import sys; sys.exit(2)" if m == "ma_gail" else
                f"import pathlib, sys; pathlib.Path({str(made)!r}).exists() or sys.exit(5); "
                f"p = pathlib.Path({str(out)!r}); p.mkdir(parents=True, exist_ok=True); "
                f"(p / 'paper.json').write_text({res!r})")
        return [sys.executable, "-c", code]

    monkeypatch.setattr(paper, "job_argv", fake_argv)
    monkeypatch.setattr(paper, "data_argv", fake_data_argv)
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,1")  # two GPUs, whatever this machine has
    out = tmp_path / "sweep"
    rc = paper.main(["--tasks", "fetchq", "--methods", "cogail,ma_gail,diayn", "--out", str(out), "--gpus", "2"])
    assert rc == 1 and made.exists()
    made.unlink()
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0")
    one = tmp_path / "one-gpu"
    assert paper.main(["--tasks", "fetchq", "--methods", "cogail,diayn", "--out", str(one), "--gpus", "1",
                       "--jobs-per-gpu", "2"]) == 0
    assert set(json.loads((one / "paper.json").read_text())) == {"fetchq/cogail/uniform", "fetchq/diayn/uniform"}
    assert asked == [("fetchq", "uniform", "cogail,ma_gail,diayn"), ("fetchq", "uniform", "cogail,diayn")]
    merged = json.loads((out / "paper.json").read_text())
    assert set(merged) == {"fetchq/cogail/uniform", "fetchq/diayn/uniform"}
    assert "| cogail | 55.0 +- 1.0 | 60.0 +- 2.0 |" in (out / "table1_replay.md").read_text()
    assert (out / "jobs" / "fetchq-ma_gail-uniform.log").exists()


def test_run_one_evaluates_co_play_prepared_while_training(tmp_path, monkeypatch):
    """A grid row is evaluated as `cogail train --eval` evaluates: co-play included (the co-play table is filled
    from the grid), prepared while training runs, and paper.json keeps it."""
    from cogail_jax.apps import eval_runner, train_loop
    from cogail_jax.data import sets as data_sets

    seen = {}
    monkeypatch.setattr(data_sets, "make_datasets", lambda cfg: {})
    monkeypatch.setattr(paper, "validation_robustness_sets", lambda task, mix: {"val-robust-slow": "x.hdf5"})

    def fake_train(cfg, run, **kw):
        seen["train"] = kw
        Path(run).mkdir(parents=True, exist_ok=True)
        return Path(run)

    def fake_eval(run, **kw):
        seen["eval"] = kw
        return {**_res(0.5, 0.6), "coplay": _coplay(0.9, 0.6)} if kw.get("coplay") else _res(0.5, 0.6)

    monkeypatch.setattr(train_loop, "train_run", fake_train)
    monkeypatch.setattr(eval_runner, "eval_run", fake_eval)
    row = paper.run_one("fetchq", "cogail", "uniform", [300], tmp_path, {})
    assert "coplay" in row and seen["eval"]["coplay"] is True
    prep = seen["eval"]["prepared"]
    assert isinstance(prep, eval_runner.EvalPrep) and prep.coplay is not None
    assert seen["train"]["on_compiled"] == prep.start
    assert seen["eval"]["extra_sets"] == {"val-robust-slow": "x.hdf5"}


def test_compare_reports_each_figure_that_differs_from_a_reference_grid(tmp_path, capsys):
    """`--compare REF`: a re-run row is checked against the shipped one figure by figure as the tables print them
    (co-play included); a difference in the last digit is reported and fails, rows only in one grid are ignored."""
    row = {**_res(0.911, 0.917, 0.817, 0.88), "coplay": _coplay(0.98, 0.615)}
    ref, mine = tmp_path / "ref", tmp_path / "mine"
    ref.mkdir(), mine.mkdir()
    (ref / "paper.json").write_text(json.dumps({"handover/cogail/uniform": row, "handover/ma_gail/uniform": row,
                                                "seqmanip/cogail/uniform": row}))
    other = json.loads(json.dumps(row))
    other["coplay"]["learned"]["selected"]["success"]["proxy"]["mean"] = 0.616  # 61.6 against 61.5
    (mine / "paper.json").write_text(json.dumps({"handover/cogail/uniform": row, "handover/ma_gail/uniform": other}))
    assert paper.main(["--out", str(mine), "--compare", str(ref)]) == 1
    out = capsys.readouterr().out
    assert "same to the last digit: handover/cogail/uniform" in out
    assert "differs: handover/ma_gail/uniform: co-play with proxy: 61.6 +- 1.0 vs 61.5 +- 1.0" in out
    assert "seqmanip" not in out
    no_coplay = {k: v for k, v in row.items() if k != "coplay"}  # a row evaluated without co-play
    (mine / "paper.json").write_text(json.dumps({"handover/cogail/uniform": row, "seqmanip/cogail/uniform": no_coplay}))
    assert paper.main(["--out", str(mine), "--compare", str(ref)]) == 0
    no_coplay["selected"] = {**no_coplay["selected"], "checkpoint": 50}
    (mine / "paper.json").write_text(json.dumps({"seqmanip/cogail/uniform": no_coplay}))
    assert paper.main(["--out", str(mine), "--compare", str(ref)]) == 1
    assert "seqmanip/cogail/uniform: selected checkpoint: 50 vs 40" in capsys.readouterr().out


def test_the_readme_tables_are_generated_from_the_shipped_grid(tmp_path):
    """The README's results block is exactly what paper.py writes from docs/results/paper/paper.json."""
    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "docs" / "results" / "paper"
    out.mkdir(parents=True)
    shutil.copy(root / "docs/results/paper/paper.json", out / "paper.json")
    shipped = (root / "README.md").read_text()
    readme = tmp_path / "README.md"
    readme.write_text(shipped)
    assert paper.main(["--out", str(out), "--tables-only", "--readme", str(readme)]) == 0
    assert readme.read_text() == shipped, "regenerate it: python experiments/paper.py --out docs/results/paper " \
                                          "--tables-only --readme README.md"
    rows = [line for line in shipped.split(paper.BEGIN)[1].split(paper.END)[0].splitlines()
            if line.startswith(tuple(f"| {m} |" for m in paper.ORDER))]  # Tables 1, 2 and the co-play table
    assert len(rows) == 3 * len(paper.ORDER) and not [r for r in rows if "| - |" in r or r.endswith("| - |")]


def test_the_coplay_table_keeps_the_held_out_poses_apart_from_the_variations():
    """The grid's co-play table gives the held-out pose partner a column of its own: the worst variation is over the
    variations of timing and path, and a row without that partner reads -."""
    held = "pose_heldout"
    cp = {"partners": ["scripted", "slow", held, "proxy"],
          "learned": {"selected": {"success": {"scripted": {"mean": 0.9}, "slow": {"mean": 0.8},
                                               held: {"mean": 0.2}, "proxy": {"mean": 0.5}}}},
          "scripted_robot": {"scripted": 1.0, "slow": 0.95, held: 0.85, "proxy": 0.25}}
    old = {"partners": ["scripted", "slow", "proxy"],
           "learned": {"selected": {"success": {"scripted": {"mean": 0.9}, "slow": {"mean": 0.7},
                                                "proxy": {"mean": 0.5}}}}}
    rows = paper.coplay_rows({"handover/cogail/uniform": {"coplay": cp}, "handover/ma_gail/uniform": {"coplay": old}},
                             ["handover"], ["cogail", "ma_gail"])
    assert "held-out poses" in rows[0]
    cogail, ma_gail, ref = (r.split(" | ") for r in rows[2:5])
    assert cogail[3] == "80.0" and ref[3] == "95.0"  # the worst variation of timing and path, not the slice
    assert cogail[4].startswith("20.0") and ref[4] == "85.0" and ma_gail[4] == "-"


def test_training_and_evaluation_never_import_what_the_grid_leaves_out():
    """The grid's staleness check leaves the people-facing apps out of the code its figures depend on: training,
    evaluation and the grid itself must not import them."""
    import subprocess
    import sys

    left_out = [p.split("apps/")[1].split(".")[0] for p in paper.CODE if "exclude" in p]
    code = ("import sys; import cogail_jax.apps.train_loop, cogail_jax.apps.eval_runner, cogail_jax.apps.runs; "
            f"sys.path.insert(0, {str(paper.ROOT)!r}); import paper; "
            f"print(sorted(m for m in {sorted(set(left_out))!r} if 'cogail_jax.apps.' + m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]" and {"play", "collect", "controls", "video"} <= set(left_out)


def test_a_task_s_cross_play_is_a_job_started_as_its_last_job_ends(tmp_path, monkeypatch, capsys):
    """Side by side, each field task's cross-play is a process of its own, started once that task's last job has ended
    (so a grid cut off before its end keeps the cross-play of the tasks it finished) while the other tasks' jobs keep
    running; it reads only its task's rows, and its matrix is merged into the grid's crossplay.json. A task without
    field rows gets none. Each line of the grid's log carries the seconds since its start."""
    import sys

    def fake_data_argv(a, job):
        return [sys.executable, "-c", "pass"]

    def fake_argv(a, job, out):
        t, m, mix = job
        row = {**_res(0.55, 0.6), **({"field": {"selected": {"checkpoint": 1}}} if t == "handover" else {})}
        res = json.dumps({f"{t}/{m}/{mix}": row})
        slow = "import time; time.sleep(1.5); " if (t, m) == ("fetchq", "diayn") else ""
        return [sys.executable, "-c", f"{slow}import pathlib; p = pathlib.Path({str(out)!r}); p.mkdir(parents=True); "
                                      f"(p / 'paper.json').write_text({res!r})"]

    def fake_cross_argv(a, job, out):  # a matrix of the rows it was given, and the grid's own crossplay.json unseen
        code = ("import json, pathlib; p = pathlib.Path({o!r}); rows = json.loads((p / 'paper.json').read_text()); "
                "m = sorted(k.split('/')[1] for k in rows); cell = {{'reward': {{'mean': 1.0, 'se': 0.0}}}}; "
                "(p / 'crossplay.json').write_text(json.dumps({{{t!r}: {{a: {{b: cell for b in m}} for a in m}}}}))")
        return [sys.executable, "-c", code.format(o=str(out), t=job[0])]

    monkeypatch.setattr(paper, "job_argv", fake_argv)
    monkeypatch.setattr(paper, "data_argv", fake_data_argv)
    monkeypatch.setattr(paper, "crossplay_argv", fake_cross_argv)
    monkeypatch.setattr(paper, "crossplay", lambda *args, **kw: pytest.fail("the grid cross-played in its own process"))
    monkeypatch.setattr(paper, "tables", lambda *args, **kw: None)  # the field rows here are stubs
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0")
    out = tmp_path / "g"
    assert paper.main(["--tasks", "handover,fetchq", "--methods", "cogail,diayn", "--out", str(out),
                       "--gpus", "1", "--jobs-per-gpu", "2"]) == 0
    log = [line for line in capsys.readouterr().out.splitlines() if line.startswith("[")]
    assert json.loads((out / "crossplay.json").read_text()) == {
        "handover": {a: {b: {"reward": {"mean": 1.0, "se": 0.0}} for b in ("cogail", "diayn")} for a in
                     ("cogail", "diayn")}}  # handover's rows only; fetchq has no field rows, so no cross-play
    assert "| cogail | 1.0 +- 0.0 | 1.0 +- 0.0 |" in (out / "crossplay.md").read_text()
    order = [" ".join(line.split("] ", 1)[1].split(" (log")[0].split()) for line in log]
    started = order.index(next(x for x in order if x.startswith("handover cross-play") and "started" in x))
    assert order.index("fetchq diayn uniform done") > started  # it ran beside fetchq's last job
    assert "handover cross-play done" in order and not any(x.startswith("fetchq cross-play") for x in order)


def test_a_grid_job_trains_its_own_kitchen_only(tmp_path, monkeypatch):
    """`--tasks overcooked` stands for the five kitchens in a grid, but each of its job processes (and data jobs)
    gets one kitchen with --no-variants: the Cramped Room's job trains the Cramped Room alone, not all five again."""
    import argparse

    seen = []
    monkeypatch.setattr(paper, "make_data", lambda tasks, *rest: seen.append(list(tasks)))
    assert paper.main(["--tasks", "overcooked", "--methods", "cogail", "--out", str(tmp_path), "--data-only"]) == 0
    assert seen[-1][0] == "overcooked" and len(seen[-1]) == 5
    a = argparse.Namespace(seeds="300", eval_every=1, set=[], force=False, nondeterministic=False,
                           no_compile_cache=False, label=None, ckpt_batch=None)
    job = paper.job_argv(a, ("overcooked", "cogail", "uniform"), tmp_path)[2:]  # after python and the script
    data = paper.data_argv(a, ("overcooked", paper.DATA, "uniform", "cogail"))[2:]
    for argv in (job + ["--data-only"], data + ["--out", str(tmp_path)]):  # parsed as the job would, data only
        assert paper.main(argv) == 0
        assert seen[-1] == ["overcooked"]
