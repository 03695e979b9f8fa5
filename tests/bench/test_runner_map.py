"""The runner labels and measures a highway-env episode along its scenario's road (SPEC 7: the
path beyond the record goes on along the ego's lane where there is a map), and the label
cache key says so (issue 21)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.cache import ROAD_MAP, label_key
from tap_bench.bench.measures import ego_measures
from tap_bench.bench.run import tasks as run_tasks
from tap_bench.bench.run.plan import _Task, _tasks, plan_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.sim.rollout import resolve_policy
from tap_bench.sim.scenario_env import make_env
from tap_bench.sim.scenario_format import load_scenario
from tap_bench.thresholds import resolve_thresholds

SPEED = 10.0


@pytest.fixture(scope="module")
def track(tmp_path_factory):
    """A racetrack scenario (highway-env's racetrack-v0): a 58 m straight (lane a-b) that
    runs into a quarter circle of 20 m radius (lane b-c)."""
    path = tmp_path_factory.mktemp("track") / "track.json"
    path.write_text(json.dumps({"name": "track", "version": 0,
                                "highway_env_id": "racetrack-v0", "duration": 5,
                                "config": {}}))
    scenario = load_scenario(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = make_env(scenario, record=False)
        env.reset(seed=0)
        network = env.unwrapped.road.network
        straight, curve = network.get_lane(("a", "b", 0)), network.get_lane(("b", "c", 0))
        env.close()
    return scenario, straight, curve


def _at(lane, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions and headings along a highway-env lane, in Waymo axes (y to the left)."""
    xy = np.array([lane.position(float(si), 0.0) for si in np.atleast_1d(s)])
    heading = np.array([lane.heading_at(float(si)) for si in np.atleast_1d(s)])
    return xy[:, 0], -xy[:, 1], -heading


def _episode(track, gap: float) -> pd.DataFrame:
    """The ego drives the straight at 10 m/s and its record ends 5 m before the curve; a car
    stands `gap` m beyond the record's end along the road (`gap` - 5 m into the curve)."""
    _, straight, curve = track
    n = 46
    s = straight.length - 5.0 - SPEED * (n - 1) / 10 + SPEED * np.arange(n) / 10
    x, y, h = _at(straight, s)
    cx, cy, ch = _at(curve, np.array([gap - 5.0]))
    t = np.arange(n) / 10
    ids = {"scenario_id": "track/idm/s0", "env": "track", "policy": "idm", "seed": 0,
           "object_type": "vehicle", "valid": True, "crashed": False}
    ego = pd.DataFrame({"track_id": "0", "t": t, "x": x, "y": y, "heading": h,
                        "speed": SPEED, "is_ego": True, **ids})
    car = pd.DataFrame({"track_id": "1", "t": t, "x": cx[0], "y": cy[0], "heading": ch[0],
                        "speed": 0.0, "is_ego": False, **ids})
    return pd.concat([ego, car], ignore_index=True)


def _label_in_the_runner(track, table: pd.DataFrame) -> dict:
    scenario = track[0]
    task = _Task("track", scenario, "idm", resolve_policy("idm"), 0,
                 resolve_thresholds("paper"), "maneuver", False)
    row = {"env": "track", "policy": "idm", "seed": 0, "return": 0.0, "length": 5,
           "duration_s": 4.6, "crashed": False, "mean_speed": SPEED, "terminated": False,
           "truncated": True, "status": "ok", "error": ""}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_tasks._label_together((task,), [(table, row, False, 1.0, None)])[0]


@pytest.mark.parametrize("gap", [20.0, 25.0, 35.0])
def test_a_leader_on_the_curve_beyond_the_record_is_found_along_the_road(track, gap):
    # the record ends on the straight, so the arc beyond it goes straight on and misses a
    # car standing in the curve (9-15 m off that line): no leader, no minimum. Along the
    # road's lanes (the runner's map) it is the leader: bumper gap `gap` - 5 m at the last
    # step, closing at 10 m/s: TTC and headway (gap - 5) / 10 s, and the ego is Following it
    table = _episode(track, gap)
    alone = ego_measures(table).iloc[0]
    assert np.isnan(alone["min_ttc_s"]) and np.isnan(alone["min_headway_s"])
    result = _label_in_the_runner(track, table)
    episode = result["episodes"].iloc[0]
    assert episode["min_ttc_s"] == pytest.approx((gap - 5.0) / SPEED, abs=0.05)
    assert episode["min_headway_s"] == pytest.approx((gap - 5.0) / SPEED, abs=0.05)
    labels = result["labels"]
    ego = labels[labels["track_id"].astype(str) == "0"]
    assert ego["interaction"].str.contains("Following (1)", regex=False).all()


def test_the_runners_road_is_the_scenarios_under_the_episodes_env(track):
    table = _episode(track, 25.0)
    task = _Task("track", track[0], "idm", resolve_policy("idm"), 0,
                 resolve_thresholds("paper"), "maneuver", False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        road = run_tasks._road(task, table)
    assert set(road["map_id"]) == {"track"}
    assert (road["kind"] == "lane").sum() >= 2
    # a table without an env column (not a rollout) is measured along the arc
    assert run_tasks._road(task, table.drop(columns="env")) is None


def test_the_label_cache_key_says_the_road_was_used():
    # labels made along the arc (older runs) are never read for a run along the road
    key = "0" * 64
    th = resolve_thresholds("paper").to_dict()
    along_road, doc = label_key(key, th, "maneuver", {"code": "x"}, ROAD_MAP)
    along_arc, _ = label_key(key, th, "maneuver", {"code": "x"})
    assert along_road != along_arc and doc["map"] == ROAD_MAP
    suite = suite_from_dict({"name": "keys", "envs": ["highway"], "policies": ["idm"],
                             "seeds": "0"}, check_names=False)

    class _NoCache:
        root = None

    tasks = _tasks(plan_suite(suite), False, _NoCache())
    assert tasks[0].label_doc["map"] == ROAD_MAP


def test_an_env_whose_road_cannot_be_drawn_fails_its_episodes_not_the_run(tmp_path,
                                                                          monkeypatch):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.sim import roads

    drawn = roads.road_table

    def no_merge_road(scenario):
        if scenario.name == "merge":
            raise RuntimeError("no road for merge")
        return drawn(scenario)

    monkeypatch.setattr(roads, "road_table", no_merge_road)
    suite = suite_from_dict({"name": "tiny", "envs": ["merge", "highway"],
                             "policies": ["idm"], "seeds": "0",
                             "env_overrides": {"merge": {"duration": 1},
                                               "highway": {"duration": 1}}},
                            check_names=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, tmp_path / "run", workers=1, progress=False, report=False)
    status = result.episodes.set_index("env")["status"]
    assert status["highway"] == "ok" and status["merge"] != "ok"
    assert "no road for merge" in result.episodes.set_index("env")["error"]["merge"]
    maps = pd.read_parquet(tmp_path / "run" / "roads.parquet")
    assert set(maps["map_id"].astype(str)) == {"highway"}
