"""Scenario envs: Gymnasium conformance, the recorded table, determinism, isolation."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from gymnasium.utils.env_checker import check_env
from highway_env.vehicle.behavior import IDMVehicle

import tap_bench
from tap_bench.errors import TapBenchError
from tap_bench.sim import episode_trajectories, make_env, registered_ids
from tap_bench.sim.policies import CHEAP_OBSERVATION as CHEAP
from tap_bench.sim.vehicles import LANE_CHANGE_SETTINGS

IDS = registered_ids()


def test_import_registers_every_scenario_of_the_suite():
    assert {"tap_bench/highway-v0", "tap_bench/merge-v0", "tap_bench/roundabout-v0",
            "tap_bench/intersection-v0", "tap_bench/exit-v1"} <= set(IDS)


@pytest.mark.parametrize("env_id", IDS)
def test_every_registered_env_passes_gymnasiums_checker(env_id):
    env = gym.make(env_id, duration=2)
    check_env(env.unwrapped)
    check_env(env, skip_render_check=True)
    env.close()


def scripted(env_id: str, actions, seed: int = 0, **kwargs) -> pd.DataFrame:
    env = gym.make(env_id, **kwargs)
    env.reset(seed=seed)
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    return episode_trajectories(env)


def test_the_table_has_every_vehicle_every_step_in_the_contract():
    env = gym.make("tap_bench/highway-v0", duration=3, config={"observation": CHEAP})
    env.reset(seed=4)
    n_vehicles = len(env.unwrapped.road.vehicles)
    for _ in range(3):
        env.step(1)
    table = episode_trajectories(env)
    clean = tap_bench.validate_trajectories(table)
    assert len(clean) == len(table) == n_vehicles * 31  # 0 .. 3.0 s at 10 Hz
    ego = table[table["is_ego"]]
    assert set(ego["track_id"]) == {"ego"} and len(ego) == 31
    np.testing.assert_allclose(np.diff(ego["t"]), 0.1)
    assert table["scenario_id"].iloc[0] == "highway/s4"
    assert (table["source"] == "highway-env").all() and (table["seed"] == 4).all()
    # highway-env's y points right, lane 0 at y = 0: after the flip the road lies at y <= 0
    # (half a lane width of 2 m is the road's edge)
    assert table["y"].max() < 2.0 and table["y"].min() < -6.0
    inner = env.unwrapped.vehicle
    last = ego.iloc[-1]
    assert last["x"] == pytest.approx(inner.position[0])
    assert last["y"] == pytest.approx(-inner.position[1])
    assert last["heading"] == pytest.approx(-inner.heading)


def test_a_left_lane_change_moves_left_and_turns_counter_clockwise():
    # lane 1 of 3, LANE_LEFT (action 0) at the third decision
    table = scripted("tap_bench/highway-v0", [1, 1, 0, 1, 1, 1, 1, 1], duration=8,
                     config={"vehicles_count": 0, "initial_lane_id": 1, "observation": CHEAP})
    ego = table[table["is_ego"]]
    assert ego["y"].iloc[-1] - ego["y"].iloc[0] == pytest.approx(4.0, abs=0.2)
    yaw_rate = np.diff(np.unwrap(ego["heading"].to_numpy())) / 0.1
    assert yaw_rate.argmax() < yaw_rate.argmin()  # left first, then the counter-steer
    assert yaw_rate.max() > 0.05


def test_left_lane_change_is_labelled_left_merge():
    table = scripted("tap_bench/highway-v0", [1, 1, 0, 1, 1, 1, 1, 1, 1, 1], duration=10,
                     config={"vehicles_count": 0, "initial_lane_id": 1, "observation": CHEAP})
    labels = tap_bench.label(table[table["is_ego"]], level="maneuver")
    assert labels["lateral"].tolist() == ["Straight > Left Merge > Straight"]


def test_right_lane_change_is_labelled_right_merge():
    table = scripted("tap_bench/highway-v0", [1, 1, 2, 1, 1, 1, 1, 1, 1, 1], duration=10,
                     config={"vehicles_count": 0, "initial_lane_id": 1, "observation": CHEAP})
    labels = tap_bench.label(table[table["is_ego"]], level="maneuver")
    assert labels["lateral"].tolist() == ["Straight > Right Merge > Straight"]


def peak_yaw_rate(lane_change: str) -> float:
    table = scripted("tap_bench/highway-v0", [1, 1, 0, 1, 1, 1], duration=6,
                     lane_change=lane_change,
                     config={"vehicles_count": 0, "initial_lane_id": 1, "observation": CHEAP})
    ego = table[table["is_ego"]]
    return float(np.abs(np.diff(np.unwrap(ego["heading"].to_numpy())) / 0.1).max())


def test_realistic_lane_changes_turn_far_slower_than_highway_envs():
    assert peak_yaw_rate("default") > 1.0  # highway-env's ~1.35 rad/s
    assert peak_yaw_rate("realistic") < 0.2


def test_same_seed_same_table_and_another_seed_another():
    kwargs = {"duration": 4, "config": {"observation": CHEAP}}
    first = scripted("tap_bench/merge-v0", [1, 0, 3, 1], seed=7, **kwargs)
    again = scripted("tap_bench/merge-v0", [1, 0, 3, 1], seed=7, **kwargs)
    other = scripted("tap_bench/merge-v0", [1, 0, 3, 1], seed=8, **kwargs)
    pd.testing.assert_frame_equal(first, again)
    assert not first[["x", "y"]].reset_index(drop=True).equals(
        other[["x", "y"]].reset_index(drop=True))


def test_reset_without_seed_continues_and_is_named_by_episode():
    env = gym.make("tap_bench/roundabout-v0", duration=1, config={"observation": CHEAP})
    env.reset(seed=3)
    env.reset()
    env.step(1)
    table = episode_trajectories(env)
    assert table["scenario_id"].iloc[0] == "roundabout/s3/e1"
    assert (table["episode"] == 1).all()


def test_truncation_counts_decisions():
    env = gym.make("tap_bench/exit-v1", duration=3, config={"observation": CHEAP})
    env.reset(seed=0)
    ends = [env.step(1)[3] for _ in range(3)]
    assert ends == [False, False, True]
    assert env.unwrapped.steps == 30


def test_reset_options_are_validated_and_may_change_the_decision_rate():
    env = gym.make("tap_bench/merge-v0", duration=2, config={"observation": CHEAP})
    env.reset(seed=0)
    with pytest.raises(tap_bench.FileFormatError, match="Did you mean 'policy_frequency'"):
        env.reset(seed=0, options={"config": {"policy_frequncy": 2}})
    env.reset(seed=0, options={"config": {"policy_frequency": 2}})
    ends = [env.step(1)[3] for _ in range(4)]
    assert ends == [False, False, False, True]


def test_intersection_does_not_change_idm_vehicle_for_other_envs():
    before = {k: v for k, v in vars(IDMVehicle).items() if k.isupper()}
    env = gym.make("tap_bench/intersection-v0", duration=1)
    env.reset(seed=1)
    env.step(1)
    assert {k: v for k, v in vars(IDMVehicle).items() if k.isupper()} == before


def test_an_env_that_changes_highway_env_classes_is_stopped_and_restored():
    before = IDMVehicle.DISTANCE_WANTED
    with pytest.raises(TapBenchError, match=r"IDMVehicle\.DISTANCE_WANTED"):
        make_env("intersection", config={
            "other_vehicles_type": "highway_env.vehicle.behavior.IDMVehicle"})
    assert IDMVehicle.DISTANCE_WANTED == before


def test_realistic_setting_reaches_vehicles_that_enter_later():
    env = make_env("intersection", lane_change="realistic", duration=6,
                   config={"observation": CHEAP, "spawn_probability": 1.0})
    env.reset(seed=0)
    first = {id(v) for v in env.unwrapped.road.vehicles}
    for _ in range(6):
        env.step(1)
    setting = LANE_CHANGE_SETTINGS["realistic"]
    later = [v for v in env.unwrapped.road.vehicles if id(v) not in first]
    assert later, "the intersection spawned no vehicle; the test needs one"
    for vehicle in env.unwrapped.road.vehicles:
        assert vehicle.KP_HEADING == pytest.approx(1 / setting.tau_heading)


def test_the_recorder_writes_road_and_lane():
    # lane 1 of 3, LANE_LEFT at the third decision: lane 1, then 0 once the ego is closer to it
    table = scripted("tap_bench/highway-v0", [1, 1, 0, 1, 1, 1, 1, 1], duration=8,
                     config={"vehicles_count": 0, "initial_lane_id": 1, "observation": CHEAP})
    ego = table[table["is_ego"]]
    assert set(ego["road"]) == {"0>1"}
    lane = ego["lane"].to_numpy()
    assert lane[0] == 1 and lane[-1] == 0
    assert np.count_nonzero(np.diff(lane)) == 1  # one lane change, to the left


def test_two_lane_changes_in_a_row_are_two_merges():
    # right at the third decision, back left at the sixth: the recorder sees both
    table = scripted("tap_bench/highway-v0", [1, 1, 2, 1, 1, 0, 1, 1, 1, 1, 1, 1], duration=12,
                     config={"vehicles_count": 0, "initial_lane_id": 1, "observation": CHEAP})
    ego = table[table["is_ego"]]
    assert np.diff(ego["lane"].to_numpy()).tolist().count(1) == 1
    assert np.diff(ego["lane"].to_numpy()).tolist().count(-1) == 1
    labels = tap_bench.label(ego, level="maneuver")
    # trend: Right, Left (the end of the first and the start of the second), Right
    assert labels["lateral"].tolist() == ["Straight > Right Merge > Left Merge > Straight"]
