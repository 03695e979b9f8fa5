"""The gate decides with the suite's settings, never a baseline file's: a baseline whose gate
settings differ is refused, as suite, level and thresholds are; impossible baseline values
are refused; whatever breaks the checker is one line and exit 2 (never 1, the code of a
regression), with ``{"status": "error"}`` under ``--format json``; ``--update-baseline``
writes only a new path or over a tap-bench baseline."""

from __future__ import annotations

import contextlib
import io
import json
import shutil

import pandas as pd
import pytest
from fault_helpers import label_table

from tap_bench.cli import main


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A run whose 12 paired episodes per policy never crash at 20 m/s, and its baseline;
    tests get copies."""
    folder = tmp_path_factory.mktemp("gate")
    a, b = folder / "a.parquet", folder / "b.parquet"
    label_table("a", range(12)).to_parquet(a)
    label_table("b", range(12)).to_parquet(b)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["compare", str(a), str(b), "-o", str(folder / "run"), "--resamples",
                     "100"]) == 0
    eps = pd.read_parquet(folder / "run" / "episodes.parquet")
    eps["crashed"] = False
    eps["mean_speed"] = 20.0
    eps.to_parquet(folder / "run" / "episodes.parquet")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["bench", "check", str(folder / "run"), "--baseline",
                     str(folder / "baseline.json"), "--update-baseline"]) == 0
    return folder


@pytest.fixture
def run(tmp_path, made):
    shutil.copytree(made / "run", tmp_path / "run")
    return tmp_path / "run"


@pytest.fixture
def baseline(tmp_path, made):
    shutil.copy(made / "baseline.json", tmp_path / "baseline.json")
    return tmp_path / "baseline.json"


def crash_everything(run) -> None:
    eps = pd.read_parquet(run / "episodes.parquet")
    eps["crashed"] = True
    eps.to_parquet(run / "episodes.parquet")


def edit(path, change) -> None:
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def one_error(code: int, out: str, err: str, *words: str) -> None:
    assert code == 2, (code, out, err)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for word in words:
        assert word in err, err


def test_a_crash_rate_from_0_to_100_percent_fails(cli, run, baseline):
    crash_everything(run)
    code, _, _ = cli("bench", "check", run, "--baseline", baseline)
    assert code == 1


@pytest.mark.parametrize("field, value", [("margins", {"crashed": 1e300}), ("alpha", 1e-9),
                                          ("n_permutations", 99), ("weights", {"crashed": 1e-9}),
                                          ("detect", 100.0)])
def test_a_baseline_whose_gate_settings_differ_is_refused(cli, run, baseline, field, value):
    crash_everything(run)
    edit(baseline, lambda d: d["gate"].update({field: value}))
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    one_error(code, out, err, "gate settings differ", field)
    code, out, err = cli("bench", "check", run, "--baseline", baseline, "--format", "json")
    assert code == 2 and json.loads(out)["status"] == "error"


def _row(doc, column, value, row=0):
    doc["episodes"]["rows"][row][doc["episodes"]["columns"].index(column)] = value


@pytest.mark.parametrize("column, value", [("crashed", 5), ("crashed", 0.5),
                                           ("crashed", "yes"), ("mean_speed", True),
                                           ("seed", -1), ("seed", 2 ** 70),
                                           ("seed", int("9" * 4000)),
                                           ("min_ttc_s", -1.0), ("min_headway_s", 11.0),
                                           ("min_ttc_s", 1e300)],
                         ids=["crashed 5", "crashed 0.5", "crashed text", "mean_speed true",
                              "seed -1", "seed 2^70", "seed of 4000 digits",
                              "min TTC -1 s", "min headway above its cap",
                              "min TTC 1e300 s"])
def test_impossible_baseline_values_are_refused(cli, run, baseline, column, value):
    edit(baseline, lambda d: _row(d, column, value))
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    one_error(code, out, err, column)


def test_a_gate_alpha_no_test_can_reach_is_an_error_not_a_crash(cli, run, baseline):
    edit(run / "summary.json",
         lambda d: d.setdefault("suite", {}).setdefault("gate", {}).update({"alpha": 1e-300}))
    edit(baseline, lambda d: d["gate"].update({"alpha": 1e-300}))
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    one_error(code, out, err, "alpha")
    code, out, _ = cli("bench", "check", run, "--baseline", baseline, "--format", "json")
    assert code == 2 and json.loads(out)["status"] == "error"


@pytest.mark.parametrize("damage", ["nested", "digits"])
def test_a_baseline_that_breaks_the_json_reader_is_one_error(cli, run, baseline, damage):
    text = baseline.read_text()
    if damage == "nested":
        baseline.write_text('{"format": "tap-bench-baseline", "x": ' + "[" * 100_000
                            + "]" * 100_000 + "}")
    else:
        baseline.write_text(text.replace('"seed": 0', '"seed": ' + "7" * 5000, 1))
    for fmt in ("text", "json"):
        code, out, err = cli("bench", "check", run, "--baseline", baseline, "--format", fmt)
        one_error(code, out, err)
        if fmt == "json":
            assert json.loads(out)["status"] == "error"


def test_a_run_summary_that_breaks_the_json_reader_is_one_error(cli, run, baseline):
    (run / "summary.json").write_text("[" * 100_000 + "]" * 100_000)
    code, out, err = cli("bench", "check", run, "--baseline", baseline, "--format", "json")
    one_error(code, out, err)
    assert json.loads(out)["status"] == "error"


def test_update_baseline_writes_only_over_a_baseline_or_a_new_path(cli, run, baseline,
                                                                  tmp_path):
    folder = tmp_path / "a-folder"
    folder.mkdir()
    code, out, err = cli("bench", "check", run, "--baseline", folder, "--update-baseline")
    one_error(code, out, err)
    assert folder.is_dir() and not any(folder.iterdir())
    notes = tmp_path / "notes.json"
    notes.write_text("my notes on the baselines, not a baseline\n")
    code, out, err = cli("bench", "check", run, "--baseline", notes, "--update-baseline")
    one_error(code, out, err, "not a tap-bench baseline")
    assert notes.read_text() == "my notes on the baselines, not a baseline\n"
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "something-else", "rows": []}))
    code, _, _ = cli("bench", "check", run, "--baseline", other, "--update-baseline")
    assert code == 2 and json.loads(other.read_text())["format"] == "something-else"
    code, _, _ = cli("bench", "check", run, "--baseline", baseline, "--update-baseline")
    assert code == 0
    code, _, _ = cli("bench", "check", run, "--baseline", tmp_path / "new.json",
                     "--update-baseline")
    assert code == 0 and (tmp_path / "new.json").is_file()


def test_check_help_prints_a_single_percent_sign(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "check", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "80% power" in out and "%%" not in out


@pytest.mark.parametrize("column, value", [("crashed", 7), ("crashed", "False"),
                                           ("min_ttc_s", -1.0), ("mean_speed", "fast")],
                         ids=["crashed 7", "crashed text", "min TTC -1 s", "speed text"])
def test_a_run_whose_episodes_hold_impossible_values_is_an_error(cli, run, baseline, column,
                                                                 value):
    """The run folder is checked as the baseline is: a value its measure cannot take is
    one error naming the row, never a verdict."""
    eps = pd.read_parquet(run / "episodes.parquet")
    eps[column] = value  # the whole column: Parquet holds one type a column
    eps.to_parquet(run / "episodes.parquet")
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    one_error(code, out, err, column, "episodes.parquet")


@pytest.mark.parametrize("kind", ["folder", "device"])
def test_a_baseline_path_that_is_no_file_is_named_as_such(cli, run, tmp_path, kind):
    """A folder (or a device) given as the baseline: said as such, not "no baseline file;
    make one with --update-baseline", which would then refuse that path."""
    where = tmp_path / "base"
    if kind == "folder":
        where.mkdir()
    else:
        where.symlink_to("/dev/null")
    code, out, err = cli("bench", "check", run, "--baseline", where)
    one_error(code, out, err, "not a baseline file")
    assert "--update-baseline" not in err


def test_an_impossible_value_is_named_by_its_row_in_the_file(cli, run, baseline):
    """Rows of failed episodes before it count: the row named is the file's."""
    eps = pd.read_parquet(run / "episodes.parquet")
    eps.loc[0, "status"] = "error"
    eps.loc[2, "min_ttc_s"] = -1.0
    eps.to_parquet(run / "episodes.parquet")
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    one_error(code, out, err, "row 2 (", "min_ttc_s")


def test_a_value_beyond_its_bound_by_rounding_is_possible():
    """A measure's registration lets values 1e-9 beyond its bounds pass; bench check
    takes the same values."""
    from tap_bench.bench.gate.regression import _possible
    from tap_bench.bench.measures import BOUND_TOLERANCE, MEASURES

    m = next(m for m in MEASURES if m.kind != "rate" and m.bounds is not None
             and all(abs(b) < float("inf") for b in m.bounds))
    assert _possible(m, m.bounds[1] + BOUND_TOLERANCE / 2)
    assert _possible(m, m.bounds[0] - BOUND_TOLERANCE / 2)
    assert not _possible(m, m.bounds[1] + 1e-6)
