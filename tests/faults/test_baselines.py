"""Baselines and run folders: damaged or edited files are named errors (exit 2), and a run
that tested nothing never becomes a baseline."""

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
    """A finished run folder (a comparison of two policies on seeds 0-11) and its baseline,
    made once; tests get copies."""
    folder = tmp_path_factory.mktemp("made")
    a, b = folder / "a.parquet", folder / "b.parquet"
    label_table("a", range(12)).to_parquet(a)
    label_table("b", range(12)).to_parquet(b)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["compare", str(a), str(b), "-o", str(folder / "run"), "--resamples",
                     "100"]) == 0
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


def fail_episodes(run, which=lambda eps: slice(None)) -> None:
    eps = pd.read_parquet(run / "episodes.parquet")
    eps.loc[which(eps), "status"] = "error"
    eps.loc[which(eps), "error"] = "RuntimeError: the simulator broke"
    eps.to_parquet(run / "episodes.parquet")


def test_a_run_whose_episodes_all_failed_does_not_become_a_baseline(tmp_path, cli, run):
    fail_episodes(run)
    path = tmp_path / "base.json"
    code, _, err = cli("bench", "check", run, "--baseline", path, "--update-baseline")
    assert code == 2 and "no finished episode" in err and "Traceback" not in err
    assert not path.exists()


def test_a_run_with_a_policy_whose_episodes_all_failed_does_not_become_a_baseline(
        tmp_path, cli, run, baseline):
    before = baseline.read_bytes()
    fail_episodes(run, lambda eps: eps["policy"] == "b")
    code, _, err = cli("bench", "check", run, "--baseline", baseline, "--update-baseline")
    assert code == 2 and "cannot become a baseline" in err
    assert baseline.read_bytes() == before  # the old baseline stays


def test_one_cell_whose_episodes_all_failed_is_refused_below_the_failure_share(tmp_path):
    """21 (env, policy) cells of one episode, one failed: 1/21 is under the share of
    failures a baseline tolerates, but that cell would go untested."""
    from tap_bench.bench.gate.regression import write_baseline
    from tap_bench.errors import BaselineError

    eps = pd.DataFrame({"env": [f"e{i}" for i in range(21)], "policy": "p", "seed": 0,
                        "status": ["error"] + ["ok"] * 20, "sdl": "Straight",
                        "crashed": False, "mean_speed": 10.0, "min_headway_s": 1.0,
                        "min_ttc_s": 2.0, "rms_jerk": 0.5})
    with pytest.raises(BaselineError, match="every episode of e0/p failed"):
        write_baseline({"run": "r"}, eps, tmp_path / "b.json")
    assert not (tmp_path / "b.json").exists()


def test_a_run_of_zero_episodes_does_not_become_a_baseline(tmp_path, cli, run):
    eps = pd.read_parquet(run / "episodes.parquet")
    eps.iloc[:0].to_parquet(run / "episodes.parquet")
    code, _, err = cli("bench", "check", run, "--baseline", tmp_path / "b.json",
                       "--update-baseline")
    assert code == 2 and "no finished episode (0 episodes" in err


def _edit(path, fn) -> None:
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


BAD_BASELINES = {
    "binary": lambda p: p.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe"),
    "not JSON": lambda p: p.write_text("{'format': 'tap-bench-baseline'"),
    "a list": lambda p: p.write_text("[1, 2, 3]"),
    "n_permutations 5": lambda p: _edit(p, lambda d: d["gate"].update(n_permutations=5)),
    "alpha as text": lambda p: _edit(p, lambda d: d["gate"].update(alpha="0.05")),
    "n_permutations true": lambda p: _edit(p, lambda d: d["gate"].update(n_permutations=True)),
    "margins a list": lambda p: _edit(p, lambda d: d["gate"].update(margins=[1, 2])),
    "unknown margin": lambda p: _edit(p, lambda d: d["gate"]["margins"].update(speed=1)),
    "gate a string": lambda p: _edit(p, lambda d: d.update(gate="strict")),
    "rows a dict": lambda p: _edit(p, lambda d: d["episodes"].update(rows={"a": 1})),
    "a measure as text": lambda p: _edit(p, lambda d: d["episodes"]["rows"][0].__setitem__(
        5, "garbage")),
    "a seed as a float": lambda p: _edit(p, lambda d: d["episodes"]["rows"][0].__setitem__(
        2, 1.5)),
    "policy a number": lambda p: _edit(p, lambda d: d["episodes"]["rows"][1].__setitem__(
        1, 7)),
    # tampering that once passed silently (issue 23)
    "a removed cell": lambda p: _edit(p, lambda d: d["episodes"].update(rows=[
        r for r in d["episodes"]["rows"] if r[1] != "b"])),
    "a cell added": lambda p: _edit(p, lambda d: d["episodes"]["rows"].append(
        ["highway", "c", *d["episodes"]["rows"][0][2:]])),
    "a NaN margin": lambda p: _edit(p, lambda d: d["gate"].setdefault("margins", {}).update(
        label_tv=float("nan"))),
    "an infinite margin": lambda p: (
        _edit(p, lambda d: d["gate"].setdefault("margins", {}).update(label_tv=12345.5)),
        p.write_text(p.read_text().replace("12345.5", "1e999", 1))),
    "a measure that overflows to inf": lambda p: _overflow(p),
    "a future format version": lambda p: _edit(p, lambda d: d.update(format_version=99)),
    "format_version as text": lambda p: _edit(p, lambda d: d.update(format_version="2")),
    "duplicated rows": lambda p: _edit(p, lambda d: d["episodes"]["rows"].append(
        list(d["episodes"]["rows"][0]))),
    "cells a string": lambda p: _edit(p, lambda d: d.update(cells="all")),
}


def _overflow(path) -> None:
    doc = json.loads(path.read_text())
    col = doc["episodes"]["columns"].index("mean_speed")
    doc["episodes"]["rows"][0][col] = 12345.0
    path.write_text(json.dumps(doc).replace("12345.0", "1e999", 1))


@pytest.mark.parametrize("case", sorted(BAD_BASELINES))
def test_a_damaged_or_edited_baseline_is_a_named_error(cli, run, baseline, case):
    BAD_BASELINES[case](baseline)
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    assert code == 2, (out, err)
    assert "Traceback" not in err and str(baseline) in err and "error:" in err


def test_a_metric_the_baseline_holds_no_numbers_for_moves(cli, run, baseline):
    def null_speed(doc):
        col = doc["episodes"]["columns"].index("mean_speed")
        for row in doc["episodes"]["rows"]:
            row[col] = None

    eps = pd.read_parquet(run / "episodes.parquet")
    eps["mean_speed"] = 10.0  # the run has numbers for it
    eps.to_parquet(run / "episodes.parquet")
    _edit(baseline, null_speed)
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    assert code == 1, (out, err)


BAD_RUNS = {
    "summary a list": lambda r: (r / "summary.json").write_text("[1, 2]"),
    "summary binary": lambda r: (r / "summary.json").write_bytes(b"\xff\xfe\x00"),
    "suite a list": lambda r: _edit(r / "summary.json", lambda d: d.update(suite=[1])),
    "episodes cut": lambda r: (r / "episodes.parquet").write_bytes(
        (r / "episodes.parquet").read_bytes()[:200]),
    "episodes text": lambda r: (r / "episodes.parquet").write_text("env,policy\n"),
    "episodes of another table": lambda r: pd.DataFrame({"x": [1]}).to_parquet(
        r / "episodes.parquet"),
}


@pytest.mark.parametrize("case", sorted(BAD_RUNS))
def test_a_damaged_run_folder_is_a_named_error(cli, run, baseline, case):
    BAD_RUNS[case](run)
    code, out, err = cli("bench", "check", run, "--baseline", baseline)
    assert code == 2, (out, err)
    assert "Traceback" not in err and str(run) in err


def test_no_baseline_file_outside_the_project_points_to_the_shipped_one(
        cli, run, tmp_path, monkeypatch):
    """`bench check RUN --baseline results/baselines/default.json` run from another folder
    said only "no baseline file": it names the shipped baseline of the run's suite."""
    from fault_helpers import PROJECT_ROOT

    def name_suite(name: str) -> None:
        summary = json.loads((run / "summary.json").read_text())
        if isinstance(summary["suite"], dict):
            summary["suite"]["name"] = name
        else:
            summary["suite"] = name
        (run / "summary.json").write_text(json.dumps(summary))

    name_suite("default")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    code, _, err = cli("bench", "check", run, "--baseline", "results/baselines/default.json")
    assert code == 2
    shipped = (PROJECT_ROOT / "results" / "baselines" / "default.json").resolve()
    assert "results/baselines/default.json: no baseline file" in err
    assert f"the shipped baseline of suite 'default' is {shipped}" in err
    assert f"--baseline {shipped}" in err and "--update-baseline" in err
    # a suite without a shipped baseline: the way to make one, as before
    name_suite("mine")
    code, _, err = cli("bench", "check", run, "--baseline", tmp_path / "none.json")
    assert code == 2 and "no baseline file; make one from a run" in err
