"""Nothing tap-bench did not write is replaced: ``train -o`` keeps a user's model,
definition and curve files; ``export -o DIR`` writes a new folder (a scenario called
``package`` cannot replace anyone's ``package.json``); ``--overwrite`` replaces a folder
only when everything in it is tap-bench's (a file added by hand is kept, the run refused);
long scenario ids still make file names."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from fault_helpers import label_table

from tap_bench.tableio import FOLDER_MARKER


def snapshot(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*")
            if p.is_file()}


@pytest.mark.parametrize("existing", ["m.zip", "m.json", "m.curve.csv", "m.curve.png"])
def test_train_never_replaces_a_users_files(tmp_path, cli, existing):
    (tmp_path / existing).write_bytes(b"the user's own file")
    before = snapshot(tmp_path)
    args = ("train", "--algo", "dqn", "--env", "highway", "--timesteps", "10",
            "-o", tmp_path / "m.zip")
    code, _, err = cli(*args)
    assert code == 2 and "--overwrite" in err and existing in err and "Traceback" not in err
    code, _, err = cli(*args, "--overwrite")  # not train's files: refused even so
    assert code == 2 and "not written by tap-bench" in err
    assert snapshot(tmp_path) == before


def test_train_overwrite_is_allowed_on_its_own_outputs():
    from tap_bench.rl.training import _trained_here

    # the shipped agents were written by tap-bench train: --overwrite may replace them
    from tap_bench.sim.policies import get_definition

    model = get_definition("dqn-highway").path.with_suffix(".zip")
    assert _trained_here(model)


def _segments(ids):
    rows = []
    for sid in ids:
        rows.append({"scenario_id": sid, "track_id": "ego", "level": "maneuver",
                     "axis": "lateral", "label": "Straight", "t_start": 0.0, "t_end": 2.0})
    return pd.DataFrame(rows)


def test_export_writes_a_new_folder_and_never_replaces_a_users_file(tmp_path, cli):
    table = tmp_path / "segments.parquet"
    _segments(["package", "scene-b"]).to_parquet(table)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "package.json").write_text('{"name": "my project"}')
    before = snapshot(mine)
    code, _, err = cli("export", table, "-o", mine)
    assert code == 2 and "not written by tap-bench" in err and "Traceback" not in err
    code, _, err = cli("export", table, "-o", mine, "--overwrite")
    assert code == 2 and snapshot(mine) == before
    out = tmp_path / "exported"
    assert cli("export", table, "-o", out)[0] == 0
    assert sorted(p.name for p in out.iterdir()) == [FOLDER_MARKER, "package.json",
                                                   "scene-b.json"]
    code, _, err = cli("export", table, "-o", out)
    assert code == 2 and "--overwrite" in err
    assert cli("export", table, "-o", out, "--overwrite")[0] == 0
    (out / "notes.txt").write_text("my notes")
    code, _, err = cli("export", table, "-o", out, "--overwrite")
    assert code == 2 and "notes.txt" in err and "did not write" in err
    assert (out / "notes.txt").read_text() == "my notes"
    single = tmp_path / "one.json"
    _segments(["only"]).to_parquet(table)
    single.write_text("user's")
    code, _, err = cli("export", table, "-o", single)
    assert code == 2 and "--overwrite" in err and single.read_text() == "user's"


def test_scenario_ids_over_255_bytes_export_and_view(tmp_path, cli):
    long_ids = ["x" * 300, "x" * 299 + "y", "é" * 200]
    table = tmp_path / "segments.parquet"
    _segments(long_ids).to_parquet(table)
    code, _, err = cli("export", table, "-o", tmp_path / "out")
    assert code == 0, err
    names = [p.name for p in (tmp_path / "out").glob("*.json")]
    assert len(names) == 3 and all(len(n.encode()) <= 255 for n in names)
    from tap_bench.openlabel import read_openlabel

    assert set(read_openlabel(tmp_path / "out")["scenario_id"]) == set(long_ids)


def test_overwrite_keeps_a_file_added_inside_a_run_folder(tmp_path, cli):
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    label_table("a", range(6)).to_parquet(a)
    label_table("b", range(6)).to_parquet(b)
    out = tmp_path / "run"
    assert cli("compare", a, b, "-o", out, "--resamples", "100")[0] == 0
    marker = json.loads((out / FOLDER_MARKER).read_text())
    assert "summary.json" in marker["files"]
    (out / "my-analysis.ipynb").write_text("{}")
    (out / "plots" / "mine.png").parent.mkdir(exist_ok=True)
    (out / "plots" / "mine.png").write_bytes(b"png")
    code, _, err = cli("compare", a, b, "-o", out, "--resamples", "100", "--overwrite")
    assert code == 2 and "my-analysis.ipynb" in err and "plots/mine.png" in err
    assert (out / "my-analysis.ipynb").is_file() and (out / "plots" / "mine.png").is_file()
    (out / "my-analysis.ipynb").unlink()
    (out / "plots" / "mine.png").unlink()
    assert cli("compare", a, b, "-o", out, "--resamples", "100", "--overwrite")[0] == 0
