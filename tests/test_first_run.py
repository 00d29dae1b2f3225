"""experiments/first_run.py's options: checked before anything runs, and nothing it did not make is deleted."""
import importlib.util
from pathlib import Path

import pytest

_loader = importlib.util.spec_from_file_location("first_run", Path(__file__).parents[1] / "experiments" / "first_run.py")
first_run = importlib.util.module_from_spec(_loader)
_loader.loader.exec_module(first_run)


@pytest.mark.parametrize("args,needle", [
    (["--tasks", "nope"], "--tasks: unknown task 'nope'"),
    (["--tasks", ","], "--tasks is empty"),
    (["--cases", "cold,bogus"], "--cases: no case 'bogus'"),
    ([], "holds a cache/ or data/ that this script did not make"),
])
def test_bad_options_and_a_folder_of_yours_end_before_anything_runs(args, needle, tmp_path):
    out = tmp_path / "out"
    (out / "data").mkdir(parents=True)
    (out / "data" / "yours.hdf5").write_text("kept")
    with pytest.raises(SystemExit) as e:
        first_run.main([*args, "--out", str(out)])
    assert needle in str(e.value) and "\n" not in str(e.value)
    assert (out / "data" / "yours.hdf5").read_text() == "kept" and not (out / ".first_run").exists()
