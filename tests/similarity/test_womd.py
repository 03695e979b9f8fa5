"""The whole similarity chain on the real WOMD samples in ../shared/data/womd."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import tap_bench as tb
from tap_bench.similarity import (
    brute_force_nearest,
    evaluate,
    rank_scenarios,
    scenario_set,
    search_like,
    unique_labels,
)
from tap_bench.sources.ingest import read_womd

pytestmark = pytest.mark.womd


@pytest.fixture(scope="module")
def womd(request, womd_dir):
    files = sorted(womd_dir.glob("*.tfrecord")) + sorted(womd_dir.glob("*.pkl"))
    table = read_womd(files)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", tb.ShortSegmentWarning)
        labels = tb.label(table, "paper", level="action")
    return table, labels


def test_evaluate_on_real_scenarios_matches_brute_force(womd):
    table, labels = womd
    ev = evaluate(table, labels, segments="all", progress=False, timing_trajectories=50)
    s = ev.summary
    vehicles = labels[labels["object_type"] == "vehicle"]
    assert s["data"]["trajectories"] == len(vehicles) > 300
    assert s["data"]["scenarios"] == 4
    assert s["data"]["points_max"] == 199  # the ScenarioNet sample lasts 20 s
    ade = brute_force_nearest(ev.shapes, metric="ade")
    np.testing.assert_array_equal(ev.neighbours["ade_neighbour"], ade.neighbour)
    sample = np.arange(0, len(ev.shapes), 17)
    dtw = brute_force_nearest(ev.shapes, sample, metric="dtw")
    np.testing.assert_array_equal(ev.neighbours["dtw_neighbour"].to_numpy()[sample],
                                  dtw.neighbour)
    code = ev.labels.code
    found = ade.neighbour >= 0
    assert s["ade"]["different_label"] == int((code[found] != code[ade.neighbour[found]]).sum())
    assert 0 < s["ade"]["share_different"] < 1
    assert s["sdl_exact"]["unique_labels"] == len(unique_labels(ev.labels))
    assert s["timing"]["dtw_ms_per_1000"] > 0


def test_evaluate_full_length_moving_and_stationary_apart(womd):
    table, labels = womd
    ev = evaluate(table, labels, progress=False, timing_trajectories=20)
    s = ev.summary
    # full length: valid over the whole scenario (91 steps, 199 for the 20 s pickle)
    assert s["data"]["segments"] == "full"
    assert set(ev.shapes.lengths) == {91, 199}
    assert 50 < s["data"]["trajectories"] < s["data"]["segments_before_selection"]
    for m in ("ade", "dtw"):
        moving, still = s[m]["moving"], s[m]["stationary"]
        assert moving["queries"] + still["queries"] == s["data"]["queries"]
        assert moving["different_label"] + still["different_label"] == s[m]["different_label"]
        assert still["queries"] > 0 and moving["queries"] > 0
        # parked cars find parked neighbours a few cm away; moving ones do not
        assert still["median_distance"] < 0.5 < moving["median_distance"]
    stationary = ev.neighbours["stationary"].to_numpy()
    reach = [np.hypot(*ev.shapes[i].T).max() for i in range(len(ev.shapes))]
    assert (stationary == (np.array(reach) < 1.0)[ev.neighbours["query"]]).all()


def test_search_and_scenarios_on_real_scenarios(womd):
    table, labels = womd
    first = labels.iloc[0]
    like = search_like(labels, first["scenario_id"], first["track_id"], int(first["segment"]))
    assert (like["sdl"] == first["sdl"]).all()
    scenarios = scenario_set(labels, table, radius=30.0)
    assert len(scenarios) == 4
    for sid in scenarios.scenario_ids:
        d = scenarios.description(sid)
        assert any(a.startswith("ego: ") for a in d.actions)  # every WOMD scenario has an SDC
    ranked = rank_scenarios(str(scenarios.scenario_ids[0]), scenarios)
    assert len(ranked) == 3 and (np.diff(ranked["distance"]) >= 0).all()
