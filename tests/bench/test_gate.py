"""The regression gate: quiet on noise, firing on a real change, a baseline that only moves
when asked; and on real rollouts, an injected IDM regression against a re-run with other
seeds."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from unittest import mock

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.gate.regression import (
    BaselineMismatchError,
    check,
    holm,
    read_baseline,
    write_baseline,
)
from tap_bench.bench.suite import GateConfig, gate_metrics
from tap_bench.cli import main
from tap_bench.errors import BaselineError, FileFormatError, ParameterError

from .conftest import make_episodes

SUMMARY = {"suite": {"name": "s", "version": 0, "gate": GateConfig(n_permutations=999)
                     .to_dict()}, "level": "maneuver", "thresholds": "paper", "run": "r"}


def synthetic(seed: int, *, speed: float = 20.0, crash: float = 0.05, n: int = 40,
              labels=("Straight | Maintain Speed", "Left Merge | Accelerate"),
              p=(0.7, 0.3)) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for policy in ("idm", "random"):
        for s in range(n):
            rows.append({"env": "highway", "policy": policy, "seed": 1000 * seed + s,
                         "sdl": labels[rng.choice(len(labels), p=p)],
                         "crashed": bool(rng.random() < crash),
                         "mean_speed": rng.normal(speed, 1.5),
                         # within the measures' ranges, as a run's values are
                         "min_headway_s": float(np.clip(rng.normal(1.5, 0.3), 0, 10)),
                         "min_ttc_s": float(np.clip(rng.normal(6, 2), 0, 10)),
                         "rms_jerk": rng.normal(3, 0.5)})
    return make_episodes(rows)


def baseline_of(episodes: pd.DataFrame, tmp_path: Path):
    path = write_baseline(SUMMARY, episodes, tmp_path / "baseline.json")
    return read_baseline(path)


def test_holm_by_hand():
    assert holm(np.array([0.01, 0.04, 0.03])) == pytest.approx([0.03, 0.06, 0.06])
    assert holm(np.array([0.5])) == pytest.approx([0.5])


def test_quiet_on_the_same_behaviour_with_other_seeds(tmp_path):
    doc, base = baseline_of(synthetic(0), tmp_path)
    for seed in (1, 2, 3):
        result = check(SUMMARY, synthetic(seed), doc, base)
        assert not result.moved, result.format()


def test_fires_on_a_slower_policy_and_names_what_moved(tmp_path):
    doc, base = baseline_of(synthetic(0), tmp_path)
    run = synthetic(1)
    run.loc[run["policy"] == "idm", "mean_speed"] -= 3.0
    result = check(SUMMARY, run, doc, base)
    assert result.moved
    moved = result.moved_rows()
    assert moved[["env", "policy", "metric"]].values.tolist() == [["highway", "idm",
                                                                   "mean_speed"]]
    assert moved.iloc[0]["change"] == pytest.approx(-3.0, abs=1.2)  # 3 m/s slower + noise
    assert "mean_speed" in result.format()


def test_fires_on_a_changed_label_distribution(tmp_path):
    doc, base = baseline_of(synthetic(0), tmp_path)
    run = synthetic(1, p=(0.2, 0.8))
    moved = check(SUMMARY, run, doc, base).moved_rows()
    assert set(moved["metric"]) == {"label_tv"}


def test_small_change_within_margin_does_not_fire(tmp_path):
    doc, base = baseline_of(synthetic(0, n=400), tmp_path)
    run = synthetic(1, n=400)
    run["mean_speed"] -= 0.5  # significant with 400 episodes, but inside the 1 m/s margin
    result = check(SUMMARY, run, doc, base)
    row = result.table.query("metric == 'mean_speed' and policy == 'idm'").iloc[0]
    assert row["p_adjusted"] < 0.05 and not row["moved"] and row["verdict"] == ""


def test_missing_cell_and_failed_episodes_move(tmp_path):
    doc, base = baseline_of(synthetic(0), tmp_path)
    run = synthetic(1)
    run = run[run["policy"] != "random"].copy()
    run.loc[run.index[0], ["status", "error"]] = ["error", "boom"]
    moved = check(SUMMARY, run, doc, base).moved_rows()
    assert set(zip(moved["policy"], moved["metric"], strict=True)) == {
        ("random", "episodes"), ("idm", "failed_episodes")}


def test_a_run_checked_against_its_own_baseline_has_no_change(tmp_path):
    episodes = synthetic(0)
    episodes["mean_speed"] += 1e-9 * np.arange(len(episodes))  # digits a rounding would lose
    doc, base = baseline_of(episodes, tmp_path)
    table = check(SUMMARY, episodes, doc, base).table
    assert (table["change"] == 0).all() and (table["p_value"] == 1).all()


def test_mismatched_settings_are_refused(tmp_path):
    doc, base = baseline_of(synthetic(0), tmp_path)
    other = {**SUMMARY, "level": "action"}
    with pytest.raises(BaselineMismatchError, match="level"):
        check(other, synthetic(1), doc, base)


def test_baseline_file_errors(tmp_path):
    with pytest.raises(FileFormatError, match="--update-baseline"):
        read_baseline(tmp_path / "none.json")
    (tmp_path / "x.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(FileFormatError, match="not a tap-bench baseline"):
        read_baseline(tmp_path / "x.json")


def _write_run(folder: Path, episodes: pd.DataFrame) -> Path:
    folder.mkdir(parents=True)
    episodes.to_parquet(folder / "episodes.parquet")
    (folder / "summary.json").write_text(json.dumps({**SUMMARY, "run": folder.name}))
    return folder


def test_cli_check_exit_codes_and_baseline_only_moves_when_asked(tmp_path, capsys):
    good = _write_run(tmp_path / "good", synthetic(1))
    bad_eps = synthetic(2)
    bad_eps.loc[bad_eps["policy"] == "idm", "crashed"] = True
    bad = _write_run(tmp_path / "bad", bad_eps)
    baseline = tmp_path / "baselines" / "b.json"
    assert main(["bench", "check", str(good), "--baseline", str(baseline)]) == 2  # none yet
    assert main(["bench", "check", str(good), "--baseline", str(baseline),
                 "--update-baseline"]) == 0
    before = baseline.read_bytes()
    assert main(["bench", "check", str(good), "--baseline", str(baseline)]) == 0
    capsys.readouterr()
    assert main(["bench", "check", str(bad), "--baseline", str(baseline),
                 "-o", str(tmp_path / "check.csv")]) == 1
    out = capsys.readouterr().out
    assert "crashed" in out and "FAIL" in out
    assert baseline.read_bytes() == before  # a failing check never touches the baseline
    assert pd.read_csv(tmp_path / "check.csv")["moved"].any()


# -- on real rollouts ------------------------------------------------------------------

def _tiny_suite(policy: str, seeds: str):
    from tap_bench.bench.suite import suite_from_dict

    return suite_from_dict({
        "name": "gate-test", "envs": ["highway"], "policies": [policy], "seeds": seeds,
        "reference_policy": policy,
        "env_overrides": {"highway": {"duration": 8, "config": {"vehicles_count": 10}}},
        "bootstrap": {"n_resamples": 200},
        "gate": {"n_permutations": 1999}}, check_names=False)


def test_gate_on_rollouts_fires_on_changed_idm_parameters_and_not_on_other_seeds(tmp_path):
    """The baseline is IDM on seeds 0-9. A re-run of the same IDM on seeds 10-19 stays
    quiet; an 'idm' whose parameters changed (it keeps a 3 s gap and wants 30 % less speed
    than traffic) fires on the same seeds 10-19."""
    from tap_bench.bench.run.runner import run_suite

    regressed = tmp_path / "policies" / "idm.json"
    regressed.parent.mkdir()
    regressed.write_text(json.dumps({
        "name": "idm", "kind": "idm", "description": "IDM with changed parameters",
        "params": {"time_wanted": 3.0, "distance_wanted": 10.0, "comfort_acc_max": 3.0,
                   "comfort_acc_min": -5.0, "delta": 4.0, "politeness": 0.0,
                   "lane_change_min_acc_gain": 0.2, "lane_change_max_braking_imposed": 2.0,
                   "lane_change_delay": 1.0, "target_speed_factor": 0.7}}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        base = run_suite(_tiny_suite("idm", "0-9"), tmp_path / "base", workers=1,
                         keep_trajectories=False, report=False, progress=False)
        rerun = run_suite(_tiny_suite("idm", "10-19"), tmp_path / "rerun", workers=1,
                          keep_trajectories=False, report=False, progress=False)
        changed = run_suite(_tiny_suite(str(regressed), "10-19"), tmp_path / "changed",
                            workers=1, keep_trajectories=False, report=False, progress=False)
    assert set(changed.episodes["policy"]) == {"idm"}
    baseline = tmp_path / "baseline.json"
    assert main(["bench", "check", str(base.folder), "--baseline", str(baseline),
                 "--update-baseline"]) == 0
    doc, base_eps = read_baseline(baseline)
    quiet = check(rerun.summary, rerun.episodes, doc, base_eps)
    assert not quiet.moved, quiet.format(all_rows=True)
    fired = check(changed.summary, changed.episodes, doc, base_eps)
    assert fired.moved, fired.format(all_rows=True)
    assert "mean_speed" in set(fired.moved_rows()["metric"])


def test_paired_seeds_flag_a_change_an_unpaired_test_misses(tmp_path):
    # issue 11: identical seeds, min TTC 2.7 s lower on average: the paired sign-flip test
    # on per-seed differences flags it; exchanging episodes (unpaired) does not
    base = synthetic(0, n=12)
    doc, base_eps = baseline_of(base, tmp_path)
    run = base.copy()
    shift = np.where(np.arange(len(run)) % 3 == 0, -1.0, -3.5)
    run.loc[run["policy"] == "idm", "min_ttc_s"] += shift[run["policy"] == "idm"]
    result = check(SUMMARY, run, doc, base_eps)
    row = result.table.query("policy == 'idm' and metric == 'min_ttc_s'").iloc[0]
    assert row["test"] == "paired" and row["moved"]
    others = result.table.query("policy == 'random' and metric != 'label_tv'")
    assert (others["p_value"] == 1).all() and not others["moved"].any()  # deterministic
    shifted = run.assign(seed=run["seed"] + 100)
    unpaired = check(SUMMARY, shifted, doc, base_eps).table
    assert set(unpaired["test"]) == {"unpaired"}


def test_a_gate_that_can_never_fire_is_refused_with_the_numbers(tmp_path):
    doc, base = baseline_of(synthetic(0), tmp_path)
    equal = {m: 1.0 for m in gate_metrics()}  # 6 metrics x 2 cells on other seeds
    with pytest.raises(ParameterError, match=r"tested at 0\.00417") as err:
        check(SUMMARY, synthetic(1), doc, base, GateConfig(n_permutations=99, weights=equal))
    assert "at least 239" in str(err.value)
    few = synthetic(0, n=3)  # paired on 3 seeds: a rate's exact p is at least 1/8
    with pytest.raises(ParameterError, match="seeds") as err:
        check(SUMMARY, few, doc, few)
    assert "at least 5 paired seeds" in str(err.value)


def test_a_refusing_check_still_lists_the_changed_definitions(tmp_path):
    prov = {"policies": {"idm": {"kind": "idm", "params": {"time_wanted": 1.5}}}}
    few = synthetic(0, n=3)
    changed = {**SUMMARY, "provenance": {"policies": {"idm": {"kind": "idm", "params": {
        "time_wanted": 2.5}}}}}
    with pytest.raises(ParameterError, match=r"policy 'idm': params.time_wanted: 1.5 -> 2.5"):
        check(changed, few, {**SUMMARY, "provenance": prov, "suite": "s", "suite_version": 0,
                             "level": "maneuver", "thresholds": "paper"}, few)


def test_a_baseline_that_could_never_fire_is_refused_when_made(tmp_path):
    with pytest.raises(BaselineError, match=r"3 seeds .* at least 5 seeds"):
        write_baseline(SUMMARY, synthetic(0, n=3), tmp_path / "b.json")
    assert not (tmp_path / "b.json").exists()
    write_baseline(SUMMARY, synthetic(0, n=5), tmp_path / "b.json")  # 1/32 < 0.65 x 0.05


def test_suite_gate_that_can_never_fire_is_refused():
    from tap_bench.bench.suite import suite_from_dict

    doc = {"name": "x", "envs": ["a", "b", "c", "d", "e"],
           "policies": ["p", "q", "r", "s", "t"], "seeds": "0-9",
           "gate": {"n_permutations": 999}}
    with pytest.raises(FileFormatError, match=r"25 cells .* could never fire.*at least 9999"):
        suite_from_dict(doc, check_names=False)


def test_runs_that_cannot_become_a_baseline(tmp_path):
    eps = synthetic(0)
    with pytest.raises(BaselineError, match="no finished episode"):
        write_baseline(SUMMARY, eps.assign(status="error"), tmp_path / "b.json")
    bad = eps.copy()
    bad.loc[bad.index[:6], "status"] = "error"  # 6 of 80 = 7.5 % > 5 %
    with pytest.raises(BaselineError, match="6 of 80"):
        write_baseline(SUMMARY, bad, tmp_path / "b.json")


def test_a_non_numeric_or_missing_baseline_metric_is_an_error(tmp_path):
    path = write_baseline(SUMMARY, synthetic(0), tmp_path / "b.json")
    doc = json.loads(path.read_text())
    col = doc["episodes"]["columns"].index("min_ttc_s")
    doc["episodes"]["rows"][3][col] = "fast"
    path.write_text(json.dumps(doc))
    with pytest.raises(BaselineError, match=r"row 3 .* min_ttc_s = 'fast'"):
        read_baseline(path)
    for row in doc["episodes"]["rows"]:
        del row[col]
    doc["episodes"]["columns"].remove("min_ttc_s")
    path.write_text(json.dumps(doc))
    with pytest.raises(BaselineError, match="lack min_ttc_s"):
        read_baseline(path)


def test_changed_definitions_are_named(tmp_path):
    prov = {"policies": {"idm": {"kind": "idm", "params": {"time_wanted": 1.5}},
                         "random": {"kind": "random", "params": {}}},
            "envs": {"highway": {"duration": 40, "config": {"lanes_count": 4}}}}
    summary = {**SUMMARY, "provenance": prov}
    doc, base = read_baseline(write_baseline(summary, synthetic(0), tmp_path / "b.json"))
    changed = json.loads(json.dumps(prov))
    changed["policies"]["idm"]["params"]["time_wanted"] = 3.0
    changed["envs"]["highway"]["config"]["lanes_count"] = 3
    result = check({**SUMMARY, "provenance": changed}, synthetic(1), doc, base)
    notes = " ".join(result.moved_rows()["note"])
    assert "policy 'idm' changed since the baseline: params.time_wanted: 1.5 -> 3.0" in notes
    assert "env 'highway' changed since the baseline: config.lanes_count: 4 -> 3" in notes


def test_weighted_holm_and_tarone_by_hand():
    from tap_bench.bench.gate.regression import weighted_holm

    # weights 3:1: thresholds 0.05 * 3/4 and 0.05 * 1/4 at the first step
    adj = weighted_holm(np.array([0.03, 0.02]), np.array([3.0, 1.0]))
    # order by p/w: 0.01 (test 0), 0.02 (test 1); test 0: 0.03 * 4/3 = 0.04; test 1: max(
    # 0.04, 0.02 * 1/1) = 0.04
    assert adj == pytest.approx([0.04, 0.04])
    # a test that cannot reach its share (p_min 0.5) is left out: the other gets all alpha
    adj = weighted_holm(np.array([0.04, 1.0]), np.ones(2), p_min=np.array([0.001, 0.5]))
    assert adj == pytest.approx([0.04, 1.0])
    assert weighted_holm(np.array([0.04, 1.0]), np.ones(2))[0] == pytest.approx(0.08)


@pytest.mark.parametrize("n, up, down", [(30, 6, 0), (30, 7, 1), (20, 3, 3), (12, 0, 2)])
def test_paired_rate_test_is_mcnemar_exact(n, up, down):
    from math import comb

    from tap_bench.bench.gate.regression import _sign_flip_test

    d = np.zeros(n)
    d[:up], d[up:up + down] = 1.0, -1.0
    test = _sign_flip_test(d, -1, GateConfig(), ("k",))  # crashes: lower is better
    k = up + down
    expect = sum(comb(k, i) for i in range(up, k + 1)) / 2 ** k if k else 1.0
    assert test.p_worse == pytest.approx(expect)
    assert test.p_min == pytest.approx(0.5 ** k if k else 1.0)


@pytest.mark.parametrize("n_b, n_r, c_b, c_r", [(30, 30, 1, 9), (30, 5, 2, 1), (10, 20, 0, 6)])
def test_unpaired_rate_test_is_fishers_exact(n_b, n_r, c_b, c_r):
    from math import comb

    from tap_bench.bench.gate.regression import _unpaired_test

    base = np.r_[np.ones(c_b), np.zeros(n_b - c_b)]
    run = np.r_[np.ones(c_r), np.zeros(n_r - c_r)]
    test = _unpaired_test(base, run, -1, GateConfig(), ("k",))
    ones, total = c_b + c_r, comb(n_b + n_r, n_r)
    expect = sum(comb(ones, x) * comb(n_b + n_r - ones, n_r - x)
                 for x in range(c_r, min(ones, n_r) + 1)) / total
    assert test.p_worse == pytest.approx(expect)


def test_improvements_are_reported_never_failures(tmp_path):
    base = synthetic(0, n=30)
    doc, base_eps = baseline_of(base, tmp_path)
    faster = base.copy()
    faster.loc[faster["policy"] == "idm", "mean_speed"] += 3.0  # better: higher is better
    faster.loc[faster["policy"] == "idm", "rms_jerk"] -= 2.0  # better: lower is better
    result = check(SUMMARY, faster, doc, base_eps)
    assert not result.moved, result.format()
    assert set(result.better_rows()["metric"]) == {"mean_speed", "rms_jerk"}
    assert "improved" in result.format()
    slower = base.copy()
    slower.loc[slower["policy"] == "idm", "mean_speed"] -= 3.0
    moved = check(SUMMARY, slower, doc, base_eps).moved_rows()
    assert moved[["policy", "metric", "verdict"]].values.tolist() == [
        ["idm", "mean_speed", "worse"]]


def _crash_cells(rng, n: int, base_rate: float, rise: float, cells: int = 25):
    """An episode table of ``cells`` (env, policy) cells on seeds 0..n-1 and a run in which
    only the first cell's crash rate rises (nested: the baseline's crashes stay)."""
    rows_b, rows_r = [], []
    for c in range(cells):
        u = rng.random(n)
        for s in range(n):
            row = {"env": f"e{c % 5}", "policy": f"p{c // 5}", "seed": s,
                   "sdl": "Straight | Maintain Speed", "crashed": bool(u[s] < base_rate),
                   "mean_speed": 20.0 + s % 7, "min_headway_s": 1.0 + s % 3,
                   "min_ttc_s": 5.0 + s % 4, "rms_jerk": 1.0 + s % 5 / 10}
            rows_b.append(row)
            rows_r.append({**row, "crashed": bool(u[s] < base_rate + rise)} if c == 0
                          else row)
    return make_episodes(rows_b), make_episodes(rows_r)


def test_a_crash_rate_rise_in_one_cell_of_a_large_suite_fails_the_check():
    """Issue 25: 25 cells, 30 paired seeds, one cell's crash rate 5 % -> 30 %: the check
    fails on that crash rate in most draws (Holm over all 150 tests almost never did)."""
    rng = np.random.default_rng(7)
    fails = 0
    for _ in range(20):
        base, run = _crash_cells(rng, 30, 0.05, 0.25)
        result = check(SUMMARY, run, {**SUMMARY, "suite": "s", "suite_version": 0,
                                      "level": "maneuver", "thresholds": "paper"}, base,
                       GateConfig(n_permutations=999), power=False)
        moved = result.moved_rows()
        fails += ((moved["metric"] == "crashed") & (moved["env"] == "e0")
                  & (moved["policy"] == "p0")).any()
        assert len(moved) <= 1  # nothing else changed, nothing else fails
    assert fails >= 14


@pytest.mark.parametrize("draws", [60, pytest.param(150, marks=pytest.mark.slow)])
def test_rate_power_is_the_rule_s_own_firing_rate(draws):
    """rule_power's exact figure for a crash rate equals the share of simulated checks
    that fail on it (the run drawn as the power model says), within 3.5 standard errors of
    ``draws`` checks (60 in the fast suite, 150 in the slow one)."""
    from tap_bench.bench.gate.power import rule_power

    config = GateConfig(n_permutations=999)
    rng = np.random.default_rng(3)
    for n, c0 in ((30, 0), (20, 2)):
        base = np.r_[np.ones(c0), np.zeros(n - c0)]
        exact = rule_power(base, "crashed", config, effect=0.25)
        q = 0.25 * n / (n - c0)  # each seed without a crash turns to one
        fired = 0
        for _ in range(draws):
            run = base.copy()
            run[c0:] = rng.random(n - c0) < q
            rows = [{"env": "e", "policy": "p", "seed": s, "sdl": "a", "crashed": v,
                     "mean_speed": 1.0, "min_headway_s": 1.0, "min_ttc_s": 1.0,
                     "rms_jerk": 1.0} for s, v in enumerate(base)]
            b = make_episodes(rows)
            # a changed policy changes every metric of the cell: all its tests in play
            noise = rng.normal(0, 0.1, (n, 4))
            r = make_episodes([{**row, "crashed": bool(v), "sdl": "ab"[s % 2],
                                "mean_speed": 1 + e[0], "min_headway_s": 1 + e[1],
                                "min_ttc_s": 1 + e[2], "rms_jerk": 1 + e[3]}
                               for s, (row, v, e) in enumerate(zip(rows, run, noise,
                                                                   strict=True))])
            res = check(SUMMARY, r, {**SUMMARY, "suite": "s", "suite_version": 0,
                                     "level": "maneuver", "thresholds": "paper"}, b, config,
                        power=False)
            fired += bool(res.moved_rows()["metric"].eq("crashed").any())
        se = np.sqrt(exact * (1 - exact) / draws)
        assert abs(fired / draws - exact) < 3.5 * se + 0.01, (n, c0, exact, fired / draws)


def test_the_power_s_binomial_laws_are_their_definitions():
    """The binomial probabilities every power figure is built from (the rate's outcomes,
    the label_tv trades, the permutations' count) equal the law's definition, C(n, k) p^k
    (1 - p)^(n - k) in exact integers and floats, over a grid of n and p, the ends (p 0 and
    1, k 0 and n) included, and so does their lower tail P(Bin(n, q) <= m) up to the 999
    permutations the label_tv test draws: a constant error in their logarithms, which the
    firing-rate tests above cannot see once a figure is near 0 or 1, fails here."""
    from tap_bench.bench.gate.power import _binomial_cdf_at_most, _binomial_pmf

    for n in (0, 1, 2, 5, 16, 30, 60):
        for p in (0.0, 1e-3, 0.05, 0.25, 0.5, 0.8, 1.0):
            want = [math.comb(n, k) * p ** k * (1 - p) ** (n - k) for k in range(n + 1)]
            got = _binomial_pmf(n, p)
            assert got.shape == (n + 1,)
            np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-300, err_msg=f"{n} {p}")
    for n, m, q in ((999, 49, 0.03), (999, 49, 0.05), (999, 9, 0.01), (999, 1, 0.002),
                    (40, 7, 0.2), (12, 11, 0.7), (5, 0, 0.5)):
        want = sum(math.comb(n, k) * q ** k * (1 - q) ** (n - k) for k in range(m + 1))
        assert _binomial_cdf_at_most(m, n, q) == pytest.approx(want, rel=1e-10), (n, m, q)
    assert _binomial_cdf_at_most(-1, 10, 0.5) == 0.0
    assert _binomial_cdf_at_most(10, 10, 0.5) == 1.0


def test_the_rate_power_s_fisher_p_is_the_gate_s_own():
    """The unpaired rate power's Fisher p (the upper tail's terms alone, each from the last
    by an integer step) is hypergeom_tails' P(X >= x), the gate's figure, to the last bit
    (the same terms summed in the same order), over every x of a grid of tables: runs
    shorter and longer than the baseline, no ones, all ones, tails empty and whole."""
    from tap_bench.bench.gate.power import _fisher_upper
    from tap_bench.bench.gate.statistics import hypergeom_tails

    checked = 0
    for n_run in (1, 2, 7, 30, 120):
        for n_b in (1, 3, 30, 80):
            comb_total = math.comb(n_run + n_b, n_run)
            for ones in sorted({0, 1, n_b // 2, n_b, n_run, n_run + n_b // 3,
                                n_run + n_b}):
                for x in range(n_run + 1):
                    assert _fisher_upper(x, n_run, n_b, ones, comb_total) == hypergeom_tails(
                        x, n_run, n_b, ones)[0], (x, n_run, n_b, ones)
                    checked += 1
    assert checked > 1000


def _tv_power_permuting(labels, effect, margin, level, n_run, paired, rng):
    """label_tv's power as first written: every permutation's code matrices built and
    their TV computed by gate_stats.tv (the reference the counted version must equal)."""
    from tap_bench.bench.gate.power import _TV_DRAWS, _TV_PERMUTATIONS
    from tap_bench.bench.gate.statistics import tv

    _, codes = np.unique(labels, return_inverse=True)
    k = int(codes.max()) + 2
    n_b = len(codes)
    fired = 0
    for _ in range(_TV_DRAWS):
        assert paired
        run = codes.copy()
        redraw = rng.random(n_b) < 0.5
        run[redraw] = rng.choice(codes, size=int(redraw.sum()))
        run[rng.random(n_b) < effect] = k - 1
        observed = tv(codes[None, :], run[None, :], k)[0]
        if observed <= margin:
            continue
        differ = np.flatnonzero(codes != run)
        flips = np.ones((_TV_PERMUTATIONS, n_b), bool)
        flips[:, differ] = rng.random((_TV_PERMUTATIONS, len(differ))) < 0.5
        perm = tv(np.where(flips, codes, run), np.where(flips, run, codes), k)
        exceed = (perm >= observed - 1e-12).sum()
        fired += (1 + exceed) / (1 + _TV_PERMUTATIONS) <= level
    return fired / _TV_DRAWS


def _all_swaps_share(codes, run, observed, k):
    """The share of all 2^d trades of the d seeds whose labels differ (each built as code
    matrices, TV by gate_stats.tv) whose TV reaches ``observed``."""
    import itertools

    from tap_bench.bench.gate.statistics import tv

    differ = np.flatnonzero(codes != run)
    flips = np.ones((2 ** len(differ), len(codes)), bool)
    flips[:, differ] = np.array(list(itertools.product((True, False), repeat=len(differ))))
    perm = tv(np.where(flips, codes, run), np.where(flips, run, codes), k)
    return float((perm >= observed - 1e-12).mean())


def test_label_tv_power_of_a_drawn_cell_is_the_binomial_law_of_its_permutations():
    """A drawn paired cell small enough to enumerate: the probability that the test fires
    over its 999 random permutations is P(Bin(999, q) <= m), q the share of all 2^d trades
    of its differing seeds (built one by one, as the gate builds them) at least as far
    apart as observed and m the most exceeding permutations that still fire; a cell too
    large to enumerate (its permutations drawn) fires as often, within 4 standard errors;
    a cell within the margin never fires."""
    from tap_bench.bench.gate.power import _TV_PERMUTATIONS, _swap_fires
    from tap_bench.bench.gate.statistics import tv

    gen = np.random.default_rng(11)
    P = _TV_PERMUTATIONS
    exact_seen = 0
    for case in range(30):
        n, k = int(gen.integers(3, 12)), int(gen.integers(2, 6))
        codes = gen.integers(0, k - 1, n)
        run = np.where(gen.random(n) < 0.6, gen.integers(0, k, n), codes)
        pairs = np.bincount(codes * k + run, minlength=k * k).reshape(k, k)
        observed = float(tv(codes[None, :], run[None, :], k)[0])
        level = float(gen.choice([0.002, 0.01, 0.05]))
        margin = 0.1 * float(gen.random())
        fires = _swap_fires(pairs, k, margin, level, 1, np.random.default_rng(case))
        if observed <= margin:
            assert fires == 0.0, case
            continue
        q = _all_swaps_share(codes, run, observed, k)
        m = max(x for x in range(P + 1) if (1 + x) / (1 + P) <= level)
        expected = sum(math.comb(P, x) * q ** x * (1 - q) ** (P - x) for x in range(m + 1))
        assert fires == pytest.approx(expected, abs=1e-9), (case, q, m)
        exact_seen += 0 < expected < 1
    assert exact_seen >= 3  # cells of every power, not only 0 and 1

    # 30 seeds of 3 labels against 4, 14 of them differing, 2 of each of 7 label pairs:
    # 3^7 trade counts, too many to enumerate, so the cell's permutations are drawn; 400
    # draws of them fire as often as the binomial law of its share q (all 2^14 trades) says,
    # at a level where the firing is in doubt
    codes = np.repeat([0, 1, 2], 10)
    run = codes.copy()
    for seeds, label in (([0, 1], 1), ([2, 3], 2), ([4, 5], 3), ([10, 11], 0),
                         ([12, 13], 3), ([20, 21], 0), ([22, 23], 3)):
        run[seeds] = label
    k = 4
    pairs = np.bincount(codes * k + run, minlength=k * k).reshape(k, k)
    observed = float(tv(codes[None, :], run[None, :], k)[0])
    q = _all_swaps_share(codes, run, observed, k)
    m = round(P * q)
    level = (1 + m) / (1 + P)
    expected = sum(math.comb(P, x) * q ** x * (1 - q) ** (P - x) for x in range(m + 1))
    assert 0.2 < expected < 0.8, expected
    fired = _swap_fires(pairs, k, 0.0, level, 400, np.random.default_rng(6)) / 400
    assert abs(fired - expected) < 4 * math.sqrt(expected * (1 - expected) / 400)


@pytest.mark.parametrize("n, labels, effect, level", [
    (16, 2, 0.5, 0.0085), (60, 5, 0.2, 0.002),
    *(pytest.param(*case, marks=pytest.mark.slow) for case in (
        (12, 4, 0.5, 0.0085), (24, 4, 0.5, 0.01), (120, 5, 0.2, 0.01)))])
def test_label_tv_power_is_the_firing_rate_of_the_rule_as_first_written(n, labels, effect,
                                                                        level):
    """The paired label_tv power (draws counted together, each drawn cell's permutations by
    their law) against the rule as first written (every draw's 999 permutations built as
    code matrices, TV by gate_stats.tv, 400 draws): equal within 4 standard errors of the
    two (cells whose drawn cells are enumerated, 16 seeds, and drawn, 60; three more in the
    slow suite)."""
    from tap_bench.bench.gate import power

    gen = np.random.default_rng(n)
    cell = np.array([f"l{j}" for j in gen.integers(0, labels, n)])
    args = (cell, effect, 0.2, level, n, True)
    got = power._tv_power(*args, np.random.default_rng(1))
    with mock.patch.object(power, "_TV_DRAWS", 400):
        reference = _tv_power_permuting(*args, np.random.default_rng(2))
    se = math.sqrt(max(reference * (1 - reference), 0.02) * (1 / 400 + 1 / 100))
    assert abs(got - reference) < 4 * se, (got, reference)


def _tv_power_shuffling(labels, effect, margin, level, n_run, rng):
    """The unpaired label_tv power as first written: every permutation a shuffle of the
    pooled episodes (argsort of uniforms), TV by gate_stats.tv on the code matrices."""
    from tap_bench.bench.gate.power import _TV_DRAWS, _TV_PERMUTATIONS
    from tap_bench.bench.gate.statistics import tv

    _, codes = np.unique(labels, return_inverse=True)
    k = int(codes.max()) + 2
    n_b = len(codes)
    fired = 0
    for _ in range(_TV_DRAWS):
        run = codes[rng.integers(0, n_b, size=n_run)]
        run[rng.random(n_run) < effect] = k - 1
        observed = tv(codes[None, :], run[None, :], k)[0]
        if observed <= margin:
            continue
        pooled = np.r_[codes, run]
        shuffled = pooled[np.argsort(rng.random((_TV_PERMUTATIONS, len(pooled))), axis=1)]
        exceed = (tv(shuffled[:, :n_b], shuffled[:, n_b:], k) >= observed - 1e-12).sum()
        fired += (1 + exceed) / (1 + _TV_PERMUTATIONS) <= level
    return fired / _TV_DRAWS


@pytest.mark.parametrize("n, n_run, labels, effect, level", [
    (30, 20, 4, 0.5, 0.01),
    pytest.param(60, 60, 6, 0.3, 0.002, marks=pytest.mark.slow)])
def test_unpaired_label_tv_power_is_the_firing_rate_of_the_shuffled_rule(n, n_run, labels,
                                                                         effect, level):
    """The unpaired label_tv power (each permutation's label counts drawn from their
    multivariate hypergeometric law) against every permutation a shuffle of the pooled
    episodes, 300 draws each: equal within 4 standard errors."""
    from tap_bench.bench.gate import power

    gen = np.random.default_rng(n)
    cell = np.array([f"l{j}" for j in gen.integers(0, labels, n)])
    with mock.patch.object(power, "_TV_DRAWS", 300):
        got = power._tv_power(cell, effect, 0.2, level, n_run, False,
                              np.random.default_rng(1))
        reference = _tv_power_shuffling(cell, effect, 0.2, level, n_run,
                                        np.random.default_rng(2))
    se = math.sqrt(max(reference * (1 - reference), 0.02) * 2 / 300)
    assert 0.1 < reference < 0.9, reference  # a cell whose firing is in doubt
    assert abs(got - reference) < 4 * se, (got, reference)


def test_fewer_seeds_than_the_baseline_is_underpowered_and_exits_3(tmp_path, capsys):
    base = synthetic(0, n=30)
    run_eps = base[base["seed"] % 1000 < 5]  # the first 5 of the baseline's 30 seeds
    folder = _write_run(tmp_path / "five", run_eps)
    baseline = tmp_path / "b.json"
    write_baseline(SUMMARY, base, baseline)
    assert main(["bench", "check", str(folder), "--baseline", str(baseline)]) == 3
    out = capsys.readouterr().out
    assert "UNDERPOWERED" in out and "crashed" in out
    assert main(["bench", "check", str(folder), "--baseline", str(baseline),
                 "--allow-underpowered"]) == 0
    capsys.readouterr()
    assert main(["bench", "check", str(folder), "--baseline", str(baseline),
                 "--format", "json"]) == 3
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["status"] == "underpowered" and verdict["underpowered"] > 0
    assert {r["metric"] for r in verdict["rows"]} >= set(gate_metrics())
    full = _write_run(tmp_path / "full", base)  # the baseline's own seeds: not flagged
    assert main(["bench", "check", str(full), "--baseline", str(baseline)]) == 0


def test_json_verdict_of_a_failing_check(tmp_path, capsys):
    base = synthetic(0, n=30)
    baseline = tmp_path / "b.json"
    write_baseline(SUMMARY, base, baseline)
    bad = base.copy()
    bad.loc[bad["policy"] == "idm", "crashed"] = True
    folder = _write_run(tmp_path / "bad", bad)
    assert main(["bench", "check", str(folder), "--baseline", str(baseline),
                 "--format", "json"]) == 1
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["status"] == "fail" and verdict["failed"] >= 1
    failed = [r for r in verdict["rows"] if r["moved"]]
    assert {(r["policy"], r["metric"], r["verdict"]) for r in failed} >= {
        ("idm", "crashed", "worse")}


def _real_scene_run(seed: int, *, hit: float, fault: float, n: int = 60) -> pd.DataFrame:
    """Episodes of recorded scenes (a crashed_at_fault column): a share ``hit`` of them
    crashed, a share ``fault`` of all at fault."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in range(n):
        u = rng.random()
        rows.append({"env": "womd", "policy": "idm", "seed": s,
                     "sdl": "Straight | Maintain Speed", "crashed": bool(u < hit),
                     "crashed_at_fault": float(u < fault), "mean_speed": 8.0,
                     "min_headway_s": 1.5, "min_ttc_s": 6.0, "rms_jerk": 3.0})
    return make_episodes(rows)


def test_on_real_scenes_the_crash_check_counts_at_fault_collisions(tmp_path):
    doc, base = baseline_of(_real_scene_run(0, hit=0.05, fault=0.05), tmp_path)
    # twice the collisions, all of them the other's fault (rear-ends, a stopped ego hit)
    hit = check(SUMMARY, _real_scene_run(0, hit=0.5, fault=0.05), doc, base)
    assert not hit.moved, hit.format()
    row = hit.table[hit.table["metric"] == "crashed"].iloc[0]
    assert row["run"] < 0.2 and "crashed_at_fault on recorded scenes" in row["note"]
    every = _real_scene_run(0, hit=0.5, fault=0.05)["crashed"].mean()
    assert f"all crashed in the run: {every:.3g}" in row["note"]  # all collisions beside
    # as many collisions, now the ego's fault
    blamed = check(SUMMARY, _real_scene_run(0, hit=0.5, fault=0.5), doc, base)
    assert blamed.moved
    assert blamed.moved_rows()["metric"].tolist() == ["crashed"]


def test_power_states_the_nested_model_and_the_power_of_crashes_drawn_afresh(tmp_path,
                                                                            capsys):
    episodes = synthetic(1, crash=0.2)
    run = _write_run(tmp_path / "run", episodes)
    baseline = tmp_path / "b.json"
    assert main(["bench", "check", str(run), "--baseline", str(baseline),
                 "--update-baseline"]) == 0
    capsys.readouterr()
    main(["bench", "check", str(run), "--baseline", str(baseline), "--power",
          "--allow-underpowered"])
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("crashed: the power above"))
    assert "(nested)" in line and "drawn afresh (not nested)" in line
    from tap_bench.bench.gate.power import afresh_rate_power
    from tap_bench.bench.suite import GateConfig

    config = GateConfig(n_permutations=999)
    figures = [afresh_rate_power(g["crashed"].to_numpy(float), 2.5 * 0.1, 0.1,
                                 config.alpha * config.share("crashed"))
               for _, g in episodes.groupby("policy")]
    assert f"{np.nanmin(figures):.3g} weakest" in line


def test_a_skipped_episode_is_not_a_failed_one(tmp_path):
    # a recorded scene without a route: the human replays it, a policy is skipped there
    doc, base = baseline_of(synthetic(0), tmp_path)
    run = synthetic(0)
    run.loc[run.index[0], "status"] = "skipped"
    run.loc[run.index[0], "error"] = "no route to follow"
    result = check(SUMMARY, run, doc, base)
    assert "failed_episodes" not in set(result.table["metric"]), result.format()
    run.loc[run.index[0], "status"] = "error"
    assert "failed_episodes" in set(check(SUMMARY, run, doc, base).table["metric"])


def _decide_as_first_written(table, config):
    """The gate's verdict table as first written (a pandas step per column): the
    reference the array version in regression._decide must equal."""
    from tap_bench.bench.gate.regression import weighted_holm

    metrics = set(gate_metrics())
    for col in ("baseline", "run", "change", "margin", "p_value", "p_better", "p_min",
                "n_baseline", "n_run", "test", "direction"):
        if col not in table.columns:
            table[col] = np.nan
    tested = table["p_value"].notna().to_numpy()
    weights = table["metric"].map(lambda m: config.share(m) if m in metrics
                                  else np.nan).to_numpy(float)
    table["p_adjusted"] = np.nan
    table.loc[tested, "p_adjusted"] = weighted_holm(
        table.loc[tested, "p_value"].to_numpy(float), weights[tested],
        table.loc[tested, "p_min"].to_numpy(float), config.alpha)
    sided = tested & (table["direction"].isin(["higher", "lower"])).to_numpy()
    better_adj = np.full(len(table), np.nan)
    better_adj[sided] = weighted_holm(table.loc[sided, "p_better"].to_numpy(float),
                                      weights[sided], table.loc[sided, "p_min"].to_numpy(float),
                                      config.alpha)
    sign = table["direction"].map({"higher": 1.0, "lower": -1.0, "none": 1.0}).to_numpy(float)
    change = table["change"].to_numpy(float)
    margin = table["margin"].to_numpy(float)
    worse_by = np.where(table["direction"] == "none", change, -sign * change)
    with np.errstate(invalid="ignore"):
        fails = (table["p_adjusted"].to_numpy(float) < config.alpha) & (worse_by > margin)
        better = (better_adj < config.alpha) & (-worse_by > margin)
    forced = table["forced"].fillna(False).to_numpy(bool)
    verdict = np.where(fails | forced, "worse", np.where(better, "better", ""))
    verdict = np.where((verdict == "worse") & (table["direction"] == "none").to_numpy()
                       & ~forced, "changed", verdict)
    table["verdict"] = verdict
    table["moved"] = fails | forced
    # an improvement shows the p-values of its side
    improved = verdict == "better"
    table.loc[improved, "p_value"] = table.loc[improved, "p_better"]
    table.loc[improved, "p_adjusted"] = better_adj[improved]
    table["note"] = table["note"].fillna("")
    table["test"] = table["test"].fillna("")
    table["direction"] = table["direction"].fillna("")
    return table.drop(columns=["forced", "p_better"])


def test_the_verdict_table_is_the_one_first_written(tmp_path):
    """regression._decide (each column read once as an array, one table built) gives the
    table of the pandas version first written, column for column and dtype for dtype, and
    check's table is in the order that version's stable pandas sort gives, on checks with
    every kind of row: unpaired and paired tests, failures, improvements, label changes,
    definition changes, missing cells, failed episodes, a measure defined on no episode
    and one defined on some seeds of one side only."""
    from tap_bench.bench.gate import regression

    fast, compared = regression._decide, []
    notes, powers, before = regression._stand_in_notes, regression._with_power, []

    def stand_in_notes(*args):
        before.append(notes(*args).assign(power=np.nan, underpowered=False))
        return before[-1].drop(columns=["power", "underpowered"])

    def with_power(*args):
        before[-1] = powers(*args)
        return before[-1]

    def check(*args, **kwargs):
        table = regression.check(*args, **kwargs).table
        t = before[-1][regression._COLUMNS]
        order = t["verdict"].map({"worse": 0, "changed": 0, "better": 1}).fillna(2)
        expected = t.assign(_order=order).sort_values(
            ["_order", "env", "policy"], kind="stable").drop(columns="_order").reset_index(
            drop=True)
        pd.testing.assert_frame_equal(table, expected)

    def both(table, config):
        expected = _decide_as_first_written(table.copy(), config)
        got = fast(table.copy(), config)
        pd.testing.assert_frame_equal(got, expected)
        compared.append(got)
        return got

    prov = {"policies": {"idm": {"kind": "idm", "params": {"time_wanted": 1.5}}}, "envs": {}}
    doc, base = read_baseline(write_baseline({**SUMMARY, "provenance": prov}, synthetic(0),
                                             tmp_path / "b.json"))
    changed = json.loads(json.dumps(prov))
    changed["policies"]["idm"]["params"]["time_wanted"] = 3.0
    slower, faster, labels = synthetic(1), synthetic(0), synthetic(1, p=(0.2, 0.8))
    slower.loc[slower["policy"] == "idm", "mean_speed"] -= 3.0
    faster.loc[faster["policy"] == "idm", "mean_speed"] += 3.0
    faster.loc[faster["policy"] == "idm", "rms_jerk"] -= 2.0
    missing = synthetic(1)
    missing = missing[missing["policy"] != "random"].copy()
    missing.loc[missing.index[0], ["status", "error"]] = ["error", "boom"]
    undefined = synthetic(0)
    undefined["min_ttc_s"] = np.nan  # defined on no episode of the run
    undefined.loc[undefined.index[:3], "min_headway_s"] = np.nan  # on some seeds only
    with (mock.patch.object(regression, "_decide", both),
          mock.patch.object(regression, "_stand_in_notes", stand_in_notes),
          mock.patch.object(regression, "_with_power", with_power)):
        check(SUMMARY, missing, doc, base)  # with each test's power (its own table step)
        for run in (synthetic(1), slower, faster, labels, undefined):
            check(SUMMARY, run, doc, base, power=False)
        check({**SUMMARY, "provenance": changed}, synthetic(1), doc, base, power=False)
        rng = np.random.default_rng(11)
        for _ in range(3):
            b, r = _crash_cells(rng, 30, 0.05, 0.25, cells=6)
            check(SUMMARY, r, {**SUMMARY, "suite": "s", "suite_version": 0,
                               "level": "maneuver", "thresholds": "paper"}, b,
                  GateConfig(n_permutations=999), power=False)
    seen = pd.concat(compared)
    assert set(seen["verdict"]) >= {"worse", "better", "changed", ""}
    assert set(seen["test"]) >= {"paired", "unpaired", ""}
    assert {"definition", "episodes", "failed_episodes"} <= set(seen["metric"])


@pytest.fixture(scope="module")
def a_baseline(tmp_path_factory):
    """synthetic(0)'s baseline (document, episodes), made once for the tests that read it."""
    return baseline_of(synthetic(0), tmp_path_factory.mktemp("baseline"))


@pytest.mark.parametrize("column, dtype, value, row, said", [
    ("crashed", float, 0.5, 5, "crashed = '0.5', not true, false, 0 or 1"),
    ("crashed", float, np.inf, 5, "crashed = 'inf'"),
    ("min_ttc_s", float, -5.0, 5, "min_ttc_s = '-5.0', not a number in [0, 10]"),
    ("min_headway_s", float, np.inf, 5, "min_headway_s = 'inf'"),
    ("min_headway_s", int, 11, 5, "min_headway_s = '11', not a number in [0, 10]"),
    ("mean_speed", bool, True, 0, "mean_speed = 'False', not a number"),
])
def test_a_run_value_its_measure_cannot_take_is_refused_from_a_numeric_column(
        a_baseline, column, dtype, value, row, said):
    """A column of numpy numbers or bools (checked at once as an array) with a value its
    measure cannot take is refused as value-by-value reading refuses it, naming the row."""
    import re

    doc, base = a_baseline
    run = synthetic(1)
    values = (np.zeros(len(run), dtype) if dtype is not float
              else run[column].to_numpy(float).copy())
    values[5] = value
    run[column] = values
    assert run[column].dtype == np.dtype(dtype)
    with pytest.raises(FileFormatError, match=f"row {row} .*{re.escape(said)}"):
        check(SUMMARY, run, doc, base)
