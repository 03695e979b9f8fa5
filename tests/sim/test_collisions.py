"""Collisions with their cause (SPEC section 8, issue 32): the overlap of oriented boxes,
the agent the ego hit (the largest overlap, not the nearest centre) and the ego's fault, on
generated scenes turned to every heading: a rear-end by log traffic beside a parked car, a
stopped ego hit head-on, a pedestrian walking into a stopped ego, an ego that drives into a
stopped car, and boxes that overlap in the record at the current time."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tap_bench.sim.collisions import Box, box_gap, collision_partner, fault, overlap_area

from .test_road_edges import (
    HEADINGS,
    ROAD_EDGES,
    ROAD_LANES,
    drive,
    straight,
    turn,
    vehicle,
    write_scene,
)


def box(x: float, y: float, heading: float, theta: float, *, speed: float = 5.0,
        length: float = 4.0, width: float = 2.0, kind: str = "vehicle") -> Box:
    """A box described in the scene's frame, turned by ``theta``."""
    p = turn([x, y], theta)
    return Box(float(p[0]), float(p[1]), heading + theta, speed, length, width, kind)


@pytest.mark.parametrize("theta", HEADINGS)
def test_the_overlap_of_two_boxes(theta):
    a = box(0.0, 0.0, 0.0, theta)
    assert overlap_area(a, box(3.0, 1.0, 0.0, theta)) == pytest.approx(1.0 * 1.0)
    assert overlap_area(a, box(0.0, 0.0, 0.0, theta)) == pytest.approx(8.0)
    assert overlap_area(a, box(5.0, 0.0, 0.0, theta)) == 0.0
    # a 2 x 2 square turned 45 deg with its corner 0.5 m into the box's front: a triangle
    r = math.sqrt(2.0)
    tip = box(2.0 - 0.5 + r, 0.0, math.pi / 4, theta, length=2.0, width=2.0)
    assert overlap_area(a, tip) == pytest.approx(0.25)
    gap, mid = box_gap(a, box(7.0, 0.0, 0.0, theta))
    assert gap == pytest.approx(3.0)
    back = turn(mid, -theta)  # between the facing sides (any point of them is nearest)
    assert back[0] == pytest.approx(3.5) and abs(back[1]) <= 1.0 + 1e-9


@pytest.mark.parametrize("theta", HEADINGS)
def test_the_partner_is_the_largest_overlap_not_the_nearest_centre(theta):
    ego = box(0.0, 0.0, 0.0, theta)
    beside = box(0.0, 2.6, 0.0, theta)  # centre 2.6 m away, 0.6 m clear
    behind = box(-3.8, 0.0, 0.0, theta)  # centre 3.8 m away, 0.2 m into the ego
    assert collision_partner(ego, [beside, behind]) == 1
    assert collision_partner(ego, [beside, box(-4.3, 0.0, 0.0, theta)]) == 1  # no overlap:
    assert collision_partner(ego, []) is None  # the nearest box (0.3 m against 0.6 m)


@pytest.mark.parametrize("theta", HEADINGS)
def test_the_rules_of_fault(theta):
    moving = box(0.0, 0.0, 0.0, theta, speed=5.0)
    stopped = box(0.0, 0.0, 0.0, theta, speed=0.2)
    rear_ender = box(-3.8, 0.3, 0.1, theta, speed=9.0)
    assert fault(moving, rear_ender).reason == "hit from behind"
    assert not fault(moving, rear_ender).at_fault
    head_on = box(3.8, 0.0, math.pi, theta, speed=8.0)
    assert fault(moving, head_on) == fault(moving, head_on)
    assert fault(moving, head_on).at_fault and fault(moving, head_on).reason == "at fault"
    assert fault(stopped, head_on).reason == "hit while stopped"
    walker = box(0.5, 1.2, -math.pi / 2, theta, speed=1.4, length=0.5, width=0.5,
                 kind="pedestrian")
    assert fault(stopped, walker).reason == "walker into stopped ego"
    assert fault(moving, walker).at_fault  # a moving ego that meets a walker is at fault
    # reversing into the ego's rear, or the ego backing its rear into a car's side: at fault
    assert fault(moving, box(-3.8, 0.0, math.pi, theta, speed=2.0)).at_fault
    assert fault(moving, box(-3.0, 1.5, math.pi / 2, theta, speed=2.0)).at_fault


# ------------------------------------------------------------------ generated scenes


def parked(x: float, y: float) -> np.ndarray:
    return np.c_[np.full(91, x), np.full(91, y)]


@pytest.mark.parametrize("theta", HEADINGS)
def test_a_rear_end_by_log_traffic_names_the_car_behind_and_is_not_the_egos_fault(
        tmp_path, theta):
    # the human at 5 m/s, a replayed car behind at 10 m/s catches it at ~3.1 s, beside a
    # car parked 3.2 m to the right (its centre nearer the ego's than the rear-ender's)
    tracks = {"ego": vehicle(straight(5.5, speed=5.0), theta),
              "7": vehicle(straight(5.5, speed=10.0, x0=-20.0), theta),
              "8": vehicle(parked(15.4, 2.3), theta)}
    path = write_scene(tmp_path / "rear_end.pkl", theta, tracks, ROAD_LANES, ROAD_EDGES)
    _, info, _ = drive(path, "log")
    assert info["crash_with"] == "7"
    assert not info["crash_at_fault"] and info["crash_fault"] == "hit from behind"
    assert info["crash_from_behind_by_log"]


@pytest.mark.parametrize("theta", HEADINGS)
def test_a_stopped_ego_hit_head_on_is_not_at_fault(tmp_path, theta):
    tracks = {"ego": vehicle(parked(20.0, 5.5), theta),
              "7": vehicle(straight(5.5, speed=-8.0, x0=70.0), theta)}  # the wrong way
    path = write_scene(tmp_path / "head_on.pkl", theta, tracks, ROAD_LANES, ROAD_EDGES)
    _, info, _ = drive(path, "log")
    assert info["crash_with"] == "7"
    assert not info["crash_at_fault"] and info["crash_fault"] == "hit while stopped"


@pytest.mark.parametrize("theta", HEADINGS)
def test_an_ego_that_drives_into_a_stopped_car_is_at_fault(tmp_path, theta):
    tracks = {"ego": vehicle(straight(5.5, speed=8.0), theta),
              "7": vehicle(parked(40.0, 5.5), theta),
              "8": vehicle(parked(36.0, 2.3), theta)}  # nearer by centre when it hits
    path = write_scene(tmp_path / "into.pkl", theta, tracks, ROAD_LANES, ROAD_EDGES)
    _, info, _ = drive(path, "log")
    assert info["crash_with"] == "7"
    assert info["crash_at_fault"] and info["crash_fault"] == "at fault"
    assert not info["crash_from_behind_by_log"]


@pytest.mark.parametrize("theta", HEADINGS)
def test_a_pedestrian_walking_into_a_stopped_ego_is_not_its_fault(tmp_path, theta):
    walk = np.c_[np.full(91, 20.5), 10.0 - 1.4 * np.arange(91) * 0.1]  # across the lane
    tracks = {"ego": vehicle(parked(20.0, 5.5), theta),
              "9": vehicle(walk, theta, length=0.5, width=0.5, kind="PEDESTRIAN")}
    path = write_scene(tmp_path / "walker.pkl", theta, tracks, ROAD_LANES, ROAD_EDGES)
    _, info, _ = drive(path, "log")
    assert info["crash_with"] == "9"
    assert not info["crash_at_fault"] and info["crash_fault"] == "walker into stopped ego"


@pytest.mark.parametrize("theta", HEADINGS)
def test_boxes_overlapping_in_the_record_at_the_start_are_not_a_collision(tmp_path, theta):
    # a car parked 0.3 m into the ego's box at 1.0 s (the record's boxes): the ego drives
    # off, nothing is a collision and no policy ends at its first decision
    tracks = {"ego": vehicle(straight(5.5, speed=0.0, x0=20.0), theta),
              "7": vehicle(parked(15.7, 5.5), theta)}
    path = write_scene(tmp_path / "overlap.pkl", theta, tracks, ROAD_LANES, ROAD_EDGES)
    env, info, terminated = drive(path, "idm")
    assert not terminated and info["crash_with"] == "" and not info["crash_at_fault"]
    assert env.unwrapped.clock[0] == 90


def test_an_episode_ended_by_a_crash_has_no_ade_and_a_scene_without_signals_no_red_light(
        tmp_path):
    from tap_bench.bench.measures import ego_measures
    from tap_bench.sim.rollout import rollout
    from tap_bench.sim.womd_env import make_womd_env

    # a replayed car comes the wrong way down the ego's lane: IDM cannot avoid it
    tracks = {"ego": vehicle(straight(5.5, speed=8.0), 0.0),
              "7": vehicle(straight(5.5, speed=-8.0, x0=60.0), 0.0)}
    path = write_scene(tmp_path / "wrong_way.pkl", 0.0, tracks, ROAD_LANES, ROAD_EDGES)
    trajectories, episodes = rollout(make_womd_env(path), "idm", [0])
    row = episodes.iloc[0]
    assert row["crashed"] and row["terminated"] and row["duration_s"] < 4.0
    # ADE and FDE over the same horizon for every episode: this one ended early, it has none
    assert np.isnan(row["log_ade"]) and np.isnan(row["log_fde"])
    measures = ego_measures(trajectories)
    assert np.isnan(measures["log_ade"].iloc[0]) and np.isnan(measures["log_fde"].iloc[0])
    # the scene records no signal states: a red light is not a number, not "never"
    assert np.isnan(row["ran_red_light"]) and not row["signal_states"]
    assert np.isnan(measures["ran_red_light"].iloc[0])
    human_table, human = rollout(make_womd_env(path), "log", [0])
    assert human.iloc[0]["log_ade"] == 0.0  # the human runs to the end
    assert ego_measures(human_table)["log_ade"].iloc[0] == 0.0


def test_a_run_report_names_crashed_real_episodes_by_scene_partner_and_fault(tmp_path):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    # slow enough, and far enough, that IDM has come to a stop when it is hit (idm's
    # comfortable braking is still rolling at about 0.5 m/s against a car at 8 m/s from 60 m)
    tracks = {"ego": vehicle(straight(5.5, speed=8.0), 0.0),
              "7": vehicle(straight(5.5, speed=-4.0, x0=90.0), 0.0)}
    path = write_scene(tmp_path / "wrong_way.pkl", 0.0, tracks, ROAD_LANES, ROAD_EDGES)
    suite = suite_from_dict({"name": "womd-crash", "envs": [{"womd": [path], "traffic": "log"}],
                             "policies": ["log", "idm"], "reference_policy": "log",
                             "seeds": "all", "bootstrap": {"n_resamples": 200}})
    result = run_suite(suite, tmp_path / "run", workers=1, progress=False)
    # IDM stops for the car coming at it, which runs into it: a crash, not IDM's fault
    idm = result.episodes[result.episodes["policy"] == "idm"].iloc[0]
    assert idm["crashed"] and idm["crashed_at_fault"] == 0.0
    page = (tmp_path / "run" / "report.html").read_text()
    table = page[page.index('id="crashed-'):]
    table = table[:table.index("</table>")]
    assert "wrong_way" in table and ">7<" in table and "hit while stopped" in table
