"""Scenario-level SDL and the Scenario2Vector weighted set distance, worked by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from similarity_helpers import CRUISE, LEFT_MERGE, STOP_AND_GO, label_rows, table_from_points

from tap_bench.errors import LabelTableError
from tap_bench.similarity import (
    ScenarioDescription,
    ScenarioSet,
    distance_vector,
    rank_scenarios,
    scenario_distance,
    scenario_set,
)

D = ScenarioDescription.of


def test_the_papers_worked_example():
    # S_A = {Forward, Turn} is the query, S_B = {Turn, Stop}: Forward is missing from S_B,
    # Stop is extra: D = <0, 0, 1, 1, 0, 0>, wD = <0, 0, 18, 9, 0, 0>, d = sqrt(405).
    a, b = D(actions=["Forward", "Turn"]), D(actions=["Turn", "Stop"])
    assert distance_vector(a, b).tolist() == [0, 0, 1, 1, 0, 0]
    assert scenario_distance(a, b) == pytest.approx(math.sqrt(18**2 + 9**2))
    assert scenario_distance(a, b) == pytest.approx(20.1246, abs=1e-4)


@pytest.mark.parametrize(("query", "other", "expected"), [
    (D(actors=["car"]), D(), 6.0),              # one missing actor
    (D(), D(actors=["car"]), 3.0),              # one extra actor
    (D(actions=["Turn"]), D(), 18.0),           # one missing action
    (D(), D(actions=["Turn"]), 9.0),            # one extra action
    (D(elements=["stop sign"]), D(), 2.0),      # one missing element
    (D(), D(elements=["stop sign"]), 1.0),      # one extra element
    # two missing actors, one extra element: sqrt(12^2 + 1^2)
    (D(actors=["car", "cyclist"], elements=["a"]), D(elements=["a", "b"]), math.sqrt(145)),
    # everything at once: <1,1,1,1,1,1> weighted: sqrt(36+9+324+81+4+1)
    (D(["car"], ["Turn"], ["light"]), D(["bus"], ["Stop"], ["sign"]), math.sqrt(455)),
])
def test_each_weight_and_combinations(query, other, expected):
    assert scenario_distance(query, other) == pytest.approx(expected)


def test_the_distance_is_not_symmetric():
    a, b = D(actions=["Forward", "Turn"]), D(actions=["Turn"])
    assert scenario_distance(a, b) == 18.0  # Forward missing
    assert scenario_distance(b, a) == 9.0   # Forward extra


def test_sets_ignore_repeats_and_multisets_count_them():
    a = D(actors=["car", "car", "car"])
    assert a.actors == {"car": 1}
    m = D(actors=["car", "car", "car"], multiset=True)
    assert scenario_distance(m, D(actors=["car"], multiset=True)) == 12.0  # 2 missing cars


def test_ties_rank_the_same_action_set_first():
    # The query: a car going Forward and turning. "far_actions" misses Turn (18);
    # "same_actions" has six extra actors (6 x 3 = 18): a tie, broken by the action set.
    query = D(actors=["car"], actions=["Forward", "Turn"])
    candidates = ScenarioSet.from_descriptions({
        "far_actions": D(actors=["car"], actions=["Forward"]),
        "same_actions": D(actors=["car", "bus", "truck", "van", "bike", "walker", "dog"],
                          actions=["Forward", "Turn"]),
        "nearest": D(actors=["car"], actions=["Forward", "Turn"], elements=["sign"]),
    })
    ranked = rank_scenarios(query, candidates)
    assert ranked["scenario_id"].tolist() == ["nearest", "same_actions", "far_actions"]
    assert ranked["distance"].tolist() == pytest.approx([1.0, 18.0, 18.0])
    assert ranked["same_actions"].tolist() == [True, True, False]
    assert ranked[["extra_actors", "missing_actions"]].values.tolist() == [[0, 0], [6, 0],
                                                                           [0, 1]]
    assert ranked["rank"].tolist() == [1, 2, 3]
    assert rank_scenarios(query, candidates, top=1)["scenario_id"].tolist() == ["nearest"]


def test_query_items_no_candidate_has_count_as_missing():
    candidates = ScenarioSet.from_descriptions({"a": D(actions=["Turn"])})
    ranked = rank_scenarios(D(actions=["Turn", "Hover"]), candidates)
    assert ranked[["missing_actions", "same_actions"]].values.tolist() == [[1, False]]


def test_scenarios_read_from_the_label_table():
    labels = label_rows(
        [("s1", "ego", LEFT_MERGE), ("s1", "7", CRUISE), ("s1", "8", CRUISE),
         ("s2", "ego", CRUISE), ("s2", "3", STOP_AND_GO)],
        object_type=["vehicle", "vehicle", "pedestrian", "vehicle", "cyclist"],
        is_ego=[True, False, False, True, False], env=["merge"] * 3 + [None, None])
    scen = scenario_set(labels)
    assert scen.scenario_ids.tolist() == ["s1", "s2"]
    s1 = scen.description("s1")
    assert set(s1.actors) == {"vehicle", "pedestrian"}  # the ego is not an actor of itself
    assert set(s1.actions) == {"ego: Straight", "ego: Left Merge", "ego: Maintain Medium Speed",
                               "vehicle: Straight", "vehicle: Maintain Medium Speed",
                               "pedestrian: Straight", "pedestrian: Maintain Medium Speed"}
    assert set(s1.elements) == {"env=merge"}
    s2 = scen.description("s2")
    assert set(s2.actors) == {"cyclist"} and not s2.elements
    # s2 against s1: missing actors {vehicle, pedestrian} (2); extra {cyclist} (1);
    # missing actions: ego Left Merge, vehicle x2, pedestrian x2 = 5;
    # extra: cyclist Straight/Decelerate Slow/Stopped/Accelerate Slow = 4; element 1 missing
    assert distance_vector(s1, s2).tolist() == [2, 1, 5, 4, 1, 0]
    ranked = rank_scenarios("s1", scen)
    assert ranked["scenario_id"].tolist() == ["s2"]
    assert ranked["distance"].iloc[0] == pytest.approx(
        math.sqrt(12**2 + 3**2 + 90**2 + 36**2 + 2**2))
    assert rank_scenarios("s1", scen, include_query=True)["distance"].iloc[0] == 0.0


def test_radius_keeps_only_the_tracks_near_the_ego():
    t = np.arange(20) * 0.1
    line = np.stack([10 * t, 0 * t], axis=1)
    tracks = {("s", "ego"): line, ("s", "near"): line + np.array([5.0, 3.0]),
              ("s", "far"): line + np.array([0.0, 80.0])}
    trajectories = table_from_points(tracks)
    trajectories["is_ego"] = trajectories["track_id"] == "ego"
    trajectories["object_type"] = np.where(trajectories["track_id"] == "far", "cyclist",
                                           "vehicle")
    labels = label_rows([("s", "ego", CRUISE), ("s", "near", CRUISE), ("s", "far", CRUISE)],
                        is_ego=[True, False, False],
                        object_type=["vehicle", "vehicle", "cyclist"])
    near = scenario_set(labels, trajectories, radius=10.0).description("s")
    assert set(near.actors) == {"vehicle"}
    assert scenario_set(labels, trajectories, radius=100.0).description("s").actors == {
        "vehicle": 1, "cyclist": 1}
    with pytest.raises(LabelTableError, match="radius needs the trajectory table"):
        scenario_set(labels, radius=10.0)


def test_weights_are_checked():
    with pytest.raises(ValueError, match="six finite numbers"):
        scenario_distance(D(), D(), weights=(1, 2, 3))
