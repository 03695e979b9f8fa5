"""``bench run`` scores the interaction contexts through the same path as ``tap-bench
contexts`` (issue 22: one scoring path), from the labelling it does anyway."""

from __future__ import annotations

import warnings

import pandas as pd

from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.scores.contexts import context_occurrences, context_scores
from tap_bench.bench.suite import suite_from_dict


def test_a_run_scores_contexts_as_the_contexts_command_does(tmp_path):
    suite = suite_from_dict({"name": "ctx", "envs": ["cut_in"],
                             "policies": ["idm", "idm-aggressive"], "seeds": "0-5",
                             "reference_policy": "idm",
                             "env_overrides": {"cut_in": {"duration": 8}},
                             "bootstrap": {"n_resamples": 100}}, check_names=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, tmp_path / "run", workers=1, progress=False, report=True,
                           cache=None)
    run = result.scores.contexts
    assert len(run) and set(run["policy_a"]) == {"idm-aggressive"}
    assert set(run["policy_b"]) == {"idm"}
    assert "Cut-in" in set(run["context"])  # the scenario's cut-in is met
    folder = result.folder
    assert pd.read_parquet(folder / "contexts.parquet").shape == run.shape
    assert "contexts" in result.summary["methods"]
    page = (folder / "report.html").read_text()
    assert 'id="context-comparison"' in page and "idm-aggressive vs idm" in page
    # the command's path on the run's own trajectories and roads gives the same table
    trajectories = pd.read_parquet(folder / "trajectories.parquet")
    roads = pd.read_parquet(folder / "roads.parquet")
    occurrences = context_occurrences(trajectories, "paper", map_table=roads)
    alone = context_scores(occurrences, ["idm", "idm-aggressive"], "idm",
                           config=suite.bootstrap)
    pd.testing.assert_frame_equal(run.reset_index(drop=True), alone.reset_index(drop=True),
                                  check_dtype=False)
