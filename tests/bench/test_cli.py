"""The command line: compare, coverage, bench suites; the demo (slow)."""

from __future__ import annotations

import re
import time
import warnings
from decimal import Decimal

import numpy as np
import pandas as pd
import pytest

from tap_bench.cli import main


@pytest.fixture(scope="module")
def two_policies(tmp_path_factory):
    """IDM and aggressive IDM on the same four merge seeds, as trajectory tables."""
    import tap_bench
    from tap_bench.sim.scenario_env import get_scenario

    folder = tmp_path_factory.mktemp("cli")
    scenario = get_scenario("merge").with_overrides(duration=5)
    paths = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for policy in ("idm", "idm-aggressive"):
            traj, _ = tap_bench.rollout(scenario, policy, "0-3", progress=False)
            paths[policy] = folder / f"{policy}.parquet"
            traj.to_parquet(paths[policy])
    return folder, paths


def test_compare_trajectory_tables(two_policies, capsys):
    folder, paths = two_policies
    out = folder / "cmp"
    assert main(["compare", str(paths["idm-aggressive"]), str(paths["idm"]), "-o", str(out),
                 "--resamples", "200"]) == 0
    text = capsys.readouterr().out
    assert "4 seeds paired" in text and "mean_speed" in text and "P(idm-aggressive better)" in text
    paired = pd.read_parquet(out / "paired.parquet")
    assert paired[["policy_a", "policy_b", "n_pairs"]].values.tolist() == [
        ["idm-aggressive", "idm", 4]]
    assert (out / "report.html").is_file() and (out / "paired_measures.parquet").is_file()
    # again into the same folder: refused, then allowed with --overwrite
    assert main(["compare", str(paths["idm-aggressive"]), str(paths["idm"]), "-o",
                 str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_compare_label_tables_with_names(two_policies, capsys):
    folder, paths = two_policies
    for policy, path in paths.items():
        assert main(["label", str(path), "-o", str(folder / f"{policy}.labels.parquet"),
                     "--level", "all"]) == 0
    capsys.readouterr()
    out = folder / "cmp-labels"
    assert main(["compare", str(folder / "idm.labels.parquet"),
                 str(folder / "idm-aggressive.labels.parquet"), "-o", str(out),
                 "--names", "a", "b", "--metric", "levenshtein", "--d-sim", "1",
                 "--resamples", "200"]) == 0
    assert set(pd.read_parquet(out / "episodes.parquet")["policy"]) == {"a", "b"}


def test_compare_same_policy_twice_is_refused(two_policies, capsys):
    folder, paths = two_policies
    assert main(["compare", str(paths["idm"]), str(paths["idm"]), "-o",
                 str(folder / "same")]) == 2
    assert "--names" in capsys.readouterr().err


def test_coverage_against_a_corpus_and_the_vocabulary(two_policies, capsys):
    folder, paths = two_policies
    out = folder / "coverage.csv"
    assert main(["coverage", str(paths["idm-aggressive"]), "--reference", str(paths["idm"]),
                 "--reference-tracks", "ego", "--level", "maneuver", "--resamples", "200",
                 "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "coverage" in text and "unique manoeuvres" in text
    row = pd.read_csv(out).iloc[0]
    assert 0 <= row["coverage_low"] <= row["coverage"] <= row["coverage_high"] <= 1
    assert (folder / "coverage.novel.csv").is_file()
    assert main(["coverage", str(paths["idm"]), "--vocabulary", "--resamples", "200"]) == 0
    assert "single labels of the maneuver level" in capsys.readouterr().out


def test_bad_input_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    pd.DataFrame({"scenario_id": ["s"], "track_id": ["1"], "sdl": ["Straight | Stopped"]}
                 ).to_csv(bad)
    assert main(["coverage", str(bad), "--vocabulary"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "lateral, longitudinal" in err and "tap-bench label" in err


def test_bench_suites_lists_the_committed_suites(capsys):
    assert main(["bench", "suites"]) == 0
    out = capsys.readouterr().out
    assert "default" in out and "demo" in out


@pytest.mark.slow
def test_demo_runs_and_prints_the_report(tmp_path, capsys):
    start = time.perf_counter()
    assert main(["demo", "-o", str(tmp_path / "demo"), "--no-progress"]) == 0
    elapsed = time.perf_counter() - start
    out = capsys.readouterr().out
    assert f"report: {(tmp_path / 'demo' / 'report.html').resolve()}" in out
    assert "144 episodes" in out
    # issue 25: phases said off a terminal, intervals in the summary, the verdict printed
    assert "episodes done (" in out and "writing the tables" in out
    assert re.search(r"crash rate \d+% \[\d+%, \d+%\]", out)
    assert "random vs idm: LESS SAFE" in out
    # coverage beside the same-policy figure and the difference from it (issue 25), both
    # at the half sizes the difference is taken at: the shown figures subtract to it
    found = re.findall(r"coverage of idm rollouts \d+% \(halves: policy ([\d.]+)% vs same "
                       r"policy ([\d.]+)%: ([+-][\d.]+) pts \[[+-][\d.]+, [+-][\d.]+\]\)", out)
    assert len(found) == 3  # every policy but the reference
    for half, null, diff in found:
        assert Decimal(half) - Decimal(null) == Decimal(diff)
    print(f"demo wall time {elapsed:.0f} s")


def test_demo_line_shows_the_half_size_figures_that_subtract_to_the_difference():
    """The demo's coverage line compares at half sizes: it shows the policy's figure there
    beside the same-policy one, with as many decimals as the shown figures need to
    subtract to the shown difference; no "-0"; nothing without the null."""
    from tap_bench.cli.demo import _halves

    key = "coverage of idm rollouts"

    def row(half, null, diff, low, high):
        return {key: 0.41, f"{key}: policy at halves": half,
                f"{key}: same-policy figure": null, f"{key}: difference": diff,
                f"{key}: difference_low": low, f"{key}: difference_high": high}

    assert _halves(row(0.2833, 0.5012, -0.2179, -0.35, -0.09), key) == (
        " (halves: policy 28% vs same policy 50%: -22 pts [-35, -9])")
    # 28 - 51 is not -22: one decimal
    assert _halves(row(0.2840, 0.5060, -0.2220, -0.3504, -0.0049), key) == (
        " (halves: policy 28.4% vs same policy 50.6%: -22.2 pts [-35.0, -0.5])")
    assert _halves(row(0.5, 0.5, -0.002, -0.1, 0.1), key) == (
        " (halves: policy 50% vs same policy 50%: +0 pts [-10, +10])")
    gen = np.random.default_rng(5)
    for _ in range(500):
        half, null = (round(float(x), 4) for x in gen.random(2))
        text = _halves(row(half, null, round(half - null, 4), -1.0, 1.0), key)
        shown = re.fullmatch(r" \(halves: policy ([\d.]+)% vs same policy ([\d.]+)%: "
                             r"([+-][\d.]+) pts \[.*\]\)", text).groups()
        assert Decimal(shown[0]) - Decimal(shown[1]) == Decimal(shown[2]), (half, null, text)
    assert _halves({key: 0.41}, key) == ""


def test_coverage_cuts_long_episodes_into_windows_of_the_reference_s_track_length(
        two_policies, capsys):
    """Issue 25: against a corpus of short tracks (WOMD: 9.1 s) whole 30 s episodes scored
    0 % coverage; the episodes are cut into windows of the reference's track length, and
    every figure stands beside the same-policy one, on whole labels and on segments."""
    import tap_bench
    from tap_bench.sim.scenario_env import get_scenario

    folder, paths = two_policies  # 5 s rollouts: the reference's tracks
    long = folder / "long.parquet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj, _ = tap_bench.rollout(get_scenario("merge").with_overrides(duration=15),
                                    "idm-aggressive", "0-1", progress=False)
    traj.to_parquet(long)
    out = folder / "windows.csv"
    assert main(["coverage", str(long), "--reference", str(paths["idm"]), "--resamples",
                 "200", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "cut into 5.0 s windows" in text and "same-policy coverage" in text
    rows = pd.read_csv(out).set_index("unit")
    assert set(rows.index) == {"5.0 s windows", "5.0 s windows, segments"}
    assert rows.loc["5.0 s windows", "n"] == 6  # 2 episodes of 15 s, 3 windows each
    assert rows["null_coverage"].notna().all() and rows["coverage_diff_low"].notna().all()
    assert main(["coverage", str(long), "--reference", str(paths["idm"]), "--resamples",
                 "200", "--window", "none"]) == 0
    assert "2 episodes with an ego label" in capsys.readouterr().out
