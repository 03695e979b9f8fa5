"""The human everywhere (SPEC section 8, issue 32): a recorded scene whose ego leaves the
mapped lanes (into a parking area) has no route; the human still replays it (route progress
NaN with the reason) and a policy that drives is skipped there, counted apart from
failures. Generated scenes, every heading."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from tap_bench.sim.rollout import rollout
from tap_bench.sim.womd_env import make_womd_env

from .test_road_edges import HEADINGS, ROAD_LANES, drive, vehicle, write_scene

T = np.arange(91) * 0.1


def into_a_car_park(tmp_path, theta: float) -> str:
    # on its lane at 1.0 s, then 25 m to the right of the road by 3 s: a car park
    x = 5.0 * T
    y = np.where(T < 1.0, 5.5, np.maximum(5.5 - 15.0 * (T - 1.0), -25.0))
    return write_scene(tmp_path / "car_park.pkl", theta, {"ego": vehicle(np.c_[x, y], theta)},
                       ROAD_LANES, [])


@pytest.mark.parametrize("theta", HEADINGS[::2])
def test_the_human_replays_a_scene_without_a_route(tmp_path, theta):
    path = into_a_car_park(tmp_path, theta)
    env, info, terminated = drive(path, "log")
    assert not terminated and env.unwrapped.clock[0] == 90
    assert np.isnan(info["route_progress"])
    assert "leaves the mapped lanes" in info["route_missing"]
    assert info["log_ade"] == 0.0


@pytest.mark.parametrize("theta", HEADINGS[::2])
def test_a_policy_that_needs_a_route_is_skipped_not_failed(tmp_path, theta):
    path = into_a_car_park(tmp_path, theta)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        trajectories, episodes = rollout(make_womd_env(path), "idm", [0])
    row = episodes.iloc[0]
    assert row["status"] == "skipped" and "no route to follow" in row["error"]
    assert len(trajectories) == 0
    assert any("skipped" in str(w.message) for w in caught)
    human_table, human = rollout(make_womd_env(path), "log", [0])
    assert human.iloc[0]["status"] == "ok" and len(human_table)


def test_the_episode_table_of_a_recorded_scene_keeps_its_scenario_id(tmp_path):
    from tap_bench.bench.episodes import episode_table
    from tap_bench.labelling import label

    from .test_road_edges import ROAD_EDGES, straight

    path = write_scene(tmp_path / "kerb.pkl", 0.3, {"ego": vehicle(straight(2.0), 0.3)},
                       ROAD_LANES, ROAD_EDGES)
    trajectories, episodes = rollout(make_womd_env(path), "idm", [0])
    table = episode_table(labels=label(trajectories), trajectories=trajectories,
                          episodes=episodes)
    assert table["scenario_id"].tolist() == ["kerb"]


def test_a_suite_counts_skipped_scenes_apart(tmp_path):
    import json

    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    from .test_road_edges import ROAD_EDGES, straight

    good = write_scene(tmp_path / "kerb.pkl", 0.0, {"ego": vehicle(straight(5.5), 0.0)},
                       ROAD_LANES, ROAD_EDGES)
    park = into_a_car_park(tmp_path, 0.0)
    suite = suite_from_dict({"name": "womd-skip", "envs": [{"womd": [good, park],
                                                            "traffic": "log"}],
                             "policies": ["log", "idm"], "reference_policy": "log",
                             "seeds": "all", "bootstrap": {"n_resamples": 200}})
    result = run_suite(suite, tmp_path / "run", workers=1, progress=False,
                       report=False)  # the tables and summary only: no page or viewer read
    eps = result.episodes
    status = dict(zip(eps["policy"] + "/" + eps["seed"].astype(str), eps["status"],
                      strict=True))
    assert status == {"log/0": "ok", "log/1": "ok", "idm/0": "ok", "idm/1": "skipped"}
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["n_failed"] == 0 and summary["n_skipped"] == 1
