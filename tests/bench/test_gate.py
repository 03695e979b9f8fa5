"""The regression gate: quiet on noise, firing on a real change, a baseline that only moves
when asked; and on real rollouts, an injected IDM regression against a re-run with other
seeds."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.gate import (
    BaselineMismatchError,
    check,
    holm,
    read_baseline,
    write_baseline,
)
from tap_bench.bench.suite import GateConfig
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
                         "min_headway_s": rng.normal(1.5, 0.3),
                         "min_ttc_s": rng.normal(6, 2), "rms_jerk": rng.normal(3, 0.5)})
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
    run["mean_speed"] += 0.5  # significant with 400 episodes, but inside the 1 m/s margin
    result = check(SUMMARY, run, doc, base)
    row = result.table.query("metric == 'mean_speed' and policy == 'idm'").iloc[0]
    assert row["p_holm"] < 0.05 and not row["moved"]


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
    from tap_bench.bench.runner import run_suite

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
    with pytest.raises(ParameterError, match=r"12/100 = 0\.12") as err:
        check(SUMMARY, synthetic(1), doc, base, GateConfig(n_permutations=99))
    assert "at least 240" in str(err.value)
    few = synthetic(0, n=3)
    doc, base = baseline_of(few, tmp_path)
    with pytest.raises(ParameterError, match="seeds"):
        check(SUMMARY, few, doc, base)


def test_suite_gate_that_can_never_fire_is_refused():
    from tap_bench.bench.suite import suite_from_dict

    doc = {"name": "x", "envs": ["a", "b", "c", "d", "e"],
           "policies": ["p", "q", "r", "s", "t"], "seeds": "0-9",
           "gate": {"n_permutations": 999}}
    with pytest.raises(FileFormatError, match=r"150 tests .* 0\.15 >= alpha 0\.05"):
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


def test_power_names_the_seeds_a_margin_needs():
    from tap_bench.bench.power import power_table

    eps = synthetic(0, n=10)
    table = power_table(eps, GateConfig()).set_index(["policy", "metric"])
    speed = table.loc[("idm", "mean_speed")]
    sd = eps.loc[eps["policy"] == "idm", "mean_speed"].std()
    # 12 tests: (z_{1 - 0.05/24} + z_0.8) sd sqrt(2/10) = (2.8653 + 0.8416) sd 0.4472
    assert speed["mde"] == pytest.approx((2.8653 + 0.8416) * sd * np.sqrt(0.2), rel=1e-3)
    assert speed["too_small"] == (speed["mde"] > 1.0)
    # seeds for a change of the 1 m/s margin: 2 ((z + z) sd / 1)^2
    assert speed["seeds_for_margin"] == np.ceil(2 * ((2.8653 + 0.8416) * sd) ** 2)
    assert table["too_small"].dtype == bool
