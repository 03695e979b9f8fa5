"""Cross-data-set matching on the real WOMD files (``../shared/data/womd``, skipped when
absent): highway-env episodes beside their nearest WOMD scenarios by scenario-level SDL."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from tap_bench.bench.scores.scenarios import match_scenarios
from tap_bench.labelling import tap

pytestmark = pytest.mark.womd


@pytest.fixture(scope="module")
def womd(womd_dir):
    files = sorted(womd_dir.glob("*.tfrecord")) + sorted(womd_dir.glob("*.pkl"))
    from tap_bench.sources import read_womd

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj = read_womd([str(f) for f in files])
        labels = tap(traj, "paper").labels("all")
    return files, traj, labels


@pytest.fixture(scope="module")
def highway():
    import tap_bench
    from tap_bench.sim.scenario_env import get_scenario

    scenario = get_scenario("highway").with_overrides({"vehicles_count": 8}, duration=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj, _ = tap_bench.rollout(scenario, "idm", "0-1", progress=False)
        labels = tap(traj, "paper").labels("all")
    return traj, labels


def test_every_womd_scenario_is_its_own_nearest(womd):
    _, traj, labels = womd
    out = match_scenarios(labels, traj, labels, traj, level="maneuver", top=2)
    first = out[out["rank"] == 1]
    assert len(first) == labels["scenario_id"].nunique() == 4
    assert (first["womd_scenario_id"] == first["scenario_id"]).all()
    assert (first["distance"] == 0).all()
    assert (out.groupby("scenario_id")["distance"].apply(lambda d: d.is_monotonic_increasing)
            ).all()


def test_highway_episodes_beside_their_nearest_womd_scenarios(womd, highway):
    from tap_bench.similarity.scenario_sdl import scenario_distance, scenario_set

    _, w_traj, w_labels = womd
    h_traj, h_labels = highway
    out = match_scenarios(h_labels, h_traj, w_labels, w_traj, level="maneuver", top=3)
    assert len(out) == 2 * 3  # two episodes, three matches each
    assert set(out["womd_scenario_id"]) <= set(w_labels["scenario_id"])
    assert list(out["policy"].unique()) == ["idm"] and set(out["seed"]) == {0, 1}
    assert out["ego_sdl"].notna().all() and out["womd_ego_sdl"].notna().all()
    for _, group in out.groupby("scenario_id"):
        assert list(group["rank"]) == [1, 2, 3]
        assert group["distance"].is_monotonic_increasing
    # the distance is similarity's Scenario2Vector distance, from the same descriptions
    row = out.iloc[0]
    sim = scenario_set(h_labels, h_traj, level="maneuver", radius=50.0)
    real = scenario_set(w_labels, w_traj, level="maneuver", radius=50.0)
    d = scenario_distance(sim.description(row["scenario_id"]),
                          real.description(row["womd_scenario_id"]))
    assert row["distance"] == pytest.approx(d)
    # highway-env's env=highway element is never in WOMD: one missing element each
    assert (out["missing_elements"] == 1).all()


def test_bench_run_with_a_womd_reference(womd, tmp_path):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    files, _, _ = womd
    suite = suite_from_dict({"name": "womd-test", "envs": ["merge"],
                             "policies": ["idm", "lane-keeping"], "seeds": "0-1",
                             "env_overrides": {"merge": {"duration": 4}},
                             "bootstrap": {"n_resamples": 200}}, check_names=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, tmp_path / "run", workers=1, womd=files, progress=False)
    cov = result.scores.coverage
    assert {"idm rollouts", "WOMD"} <= set(cov["reference"])
    womd_rows = cov[cov["reference"] == "WOMD"]
    assert set(womd_rows["policy"]) == {"idm", "lane-keeping"}  # WOMD covers both
    assert np.isfinite(womd_rows["coverage"]).all()
    matches = result.scores.scenario_matches
    assert len(matches) == 4 * 3 and (tmp_path / "run" / "scenario_matches.parquet").is_file()
    assert "scenario_matches" in (tmp_path / "run" / "report.html").read_text()
    assert result.summary["references"] == {"WOMD": [str(f) for f in files]}
    # the sim-to-real gap of each policy from the real vehicles, in the tables and the report
    gap = result.scores.gap.set_index("policy")
    assert "idm" in gap.index
    for policy in {"idm", "lane-keeping"} - set(gap.index):  # nothing comparable: said why
        assert f"{policy} vs WOMD" in result.scores.methods["gap skipped"]
    assert ((gap["gap_low"] <= gap["gap"]) & (gap["gap"] <= gap["gap_high"])).all()
    assert ((gap["gap"] > 0) & (gap["gap"] <= 1)).all() and (gap["floor"] >= 0).all()
    assert (tmp_path / "run" / "gap.parquet").is_file()
    assert "gap to WOMD" in (tmp_path / "run" / "report.html").read_text()
    labels = result.scores.gap_labels
    assert {"lateral", "longitudinal", "interaction"} <= set(labels["axis"])
