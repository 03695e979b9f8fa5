"""The road user in the ego's path ahead, in the RL observation of tap_bench/womd-v0
(``KinematicsRoute`` with ``leader``) and in its reward (``ttc_reward``): values worked out by
hand on a generated straight two-lane road, at any heading, with a closer car in the next
lane that must not count."""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pytest

from tap_bench.sim.womd_env import TTC_WARNING, make_womd_env
from tap_bench.sim.womd_observation import (
    CLOSING_SCALE,
    INVERSE_TTC_SCALE,
    LEADER_FEATURES,
    SPEED_SCALE,
)

LENGTH = 4.5  # [m] every car's
EGO_SPEED = 10.0  # [m/s]


def following(path: Path, *, angle: float, lead_at: float, lead_speed: float,
              side: int) -> str:
    """A ScenarioNet pickle: two neighbouring straight lanes heading ``angle`` [rad]; the
    ego drives the first at 10 m/s from lon 0; a car in the same lane at lon ``lead_at`` at
    ``lead_speed`` [m/s]; a car in the next lane (``side`` +1 left) 10 m behind that one
    (closer to the ego) at the same speed."""
    t = np.arange(91) * 0.1
    c, s = math.cos(angle), math.sin(angle)

    def rotate(lon, lat):
        return np.c_[lon * c - lat * s, lon * s + lat * c]

    def track(lon0, lat, speed):
        xy = rotate(lon0 + speed * t, np.full_like(t, lat))
        return {"type": "VEHICLE", "state": {
            "position": np.c_[xy, np.zeros(91)], "heading": np.full(91, angle),
            "velocity": np.c_[np.full(91, speed * c), np.full(91, speed * s)],
            "valid": np.ones(91, bool), "length": np.full(91, LENGTH),
            "width": np.full(91, 2.0)}}

    lon = np.arange(-20.0, 300.0, 1.0)
    lat2 = 3.7 * side
    features = {
        "1": {"type": "LANE_SURFACE_STREET", "polyline": rotate(lon, np.zeros_like(lon)),
              "entry_lanes": [], "exit_lanes": [],
              "left_neighbor" if side > 0 else "right_neighbor": [2]},
        "2": {"type": "LANE_SURFACE_STREET", "polyline": rotate(lon, np.full_like(lon, lat2)),
              "entry_lanes": [], "exit_lanes": [],
              "right_neighbor" if side > 0 else "left_neighbor": [1]}}
    tracks = {"ego": track(0.0, 0.0, EGO_SPEED), "lead": track(lead_at, 0.0, lead_speed),
              "beside": track(lead_at - 10.0, lat2, lead_speed)}
    meta = {"scenario_id": path.stem, "ts": t, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "tracks": tracks, "map_features": features,
                     "dynamic_map_states": {}}, f)
    return str(path)


def leader_part(obs: np.ndarray) -> dict[str, float]:
    return dict(zip(LEADER_FEATURES, obs[-len(LEADER_FEATURES):].tolist(), strict=True))


@pytest.mark.parametrize("angle", [0.0, 1.1, -2.5])
@pytest.mark.parametrize("side", [1, -1])
def test_the_car_ahead_in_the_lane_is_the_leader_not_the_closer_one_beside(tmp_path, angle,
                                                                           side):
    env = make_womd_env(following(tmp_path / "sd_follow.pkl", angle=angle, lead_at=30.0,
                                  lead_speed=6.0, side=side))
    obs, _ = env.reset(seed=0)
    # at the current time (1.0 s): ego at lon 10, leader at 36: gap 26 - 4.5, closing 4
    gap, closing = 36.0 - 10.0 - LENGTH, EGO_SPEED - 6.0
    horizon = env.unwrapped.observation_type.horizon
    got = leader_part(obs)
    assert got["speed"] == pytest.approx(EGO_SPEED / SPEED_SCALE, abs=1e-5)
    assert got["lead_gap"] == pytest.approx(gap / horizon, abs=1e-4)
    assert got["lead_closing"] == pytest.approx(closing / CLOSING_SCALE, abs=1e-4)
    assert got["lead_inverse_ttc"] == pytest.approx(closing / gap / INVERSE_TTC_SCALE,
                                                    abs=1e-4)


def test_no_leader_within_the_horizon_reads_as_a_free_road(tmp_path):
    env = make_womd_env(following(tmp_path / "sd_far.pkl", angle=0.4, lead_at=120.0,
                                  lead_speed=10.0, side=1))
    obs, _ = env.reset(seed=0)
    got = leader_part(obs)
    assert (got["lead_gap"], got["lead_closing"], got["lead_inverse_ttc"]) == (1.0, 0.0, 0.0)


def test_closing_on_a_stopped_car_costs_reward_by_the_time_to_collision(tmp_path):
    # a car stopped 30 m ahead: the same actions with and without the TTC term; the
    # difference per decision is ttc_reward * (1 - TTC / 3 s) from the observed leader
    path = following(tmp_path / "sd_stop.pkl", angle=0.7, lead_at=40.0, lead_speed=0.0,
                     side=-1)
    shaped = make_womd_env(path)
    plain = make_womd_env(path, config={"ttc_reward": 0.0})
    ttc_reward = shaped.unwrapped.config["ttc_reward"]
    assert ttc_reward < 0
    shaped.reset(seed=0)
    plain.reset(seed=0)
    punished = 0
    for _ in range(6):
        _, r1, done1, _, _ = shaped.step(1)  # keep lane and speed
        _, r0, done0, _, _ = plain.step(1)
        lead = shaped.unwrapped.observation_type.lead
        # a gap of 10 cm or less counts as 10 cm (the boxes touch: the largest penalty)
        ttc = max(lead.gap, 0.1) / lead.closing if lead.closing > 0 else math.inf
        expected = ttc_reward * max(0.0, 1.0 - ttc / TTC_WARNING)
        assert r1 - r0 == pytest.approx(expected, abs=1e-9)
        punished += expected < 0
        assert done1 == done0
        if done1:
            break
    assert punished >= 2


def test_the_reward_sees_the_leader_whatever_the_agent_observes(tmp_path):
    path = following(tmp_path / "sd_kin.pkl", angle=0.0, lead_at=25.0, lead_speed=0.0,
                     side=1)
    env = make_womd_env(path, config={"observation": {"type": "Kinematics"}})
    plain = make_womd_env(path, config={"observation": {"type": "Kinematics"},
                                        "ttc_reward": 0.0})
    env.reset(seed=0)
    plain.reset(seed=0)
    _, r1, *_ = env.step(1)
    _, r0, *_ = plain.step(1)
    assert r1 < r0


def test_a_leader_setting_that_is_not_a_flag_is_refused(tmp_path):
    path = following(tmp_path / "sd_bad.pkl", angle=0.0, lead_at=30.0, lead_speed=6.0,
                     side=1)
    with pytest.raises(ValueError, match="leader 'yes' must be true or false"):
        make_womd_env(path, config={"observation": {"type": "KinematicsRoute",
                                                    "leader": "yes"}})


def test_the_progress_gain_reward_sums_to_the_route_progress_of_the_episode(tmp_path):
    # only progress_gain_reward on: the rewards of an episode add up to that times the route
    # progress it reached, whatever the actions (faster, then slower)
    path = following(tmp_path / "sd_free.pkl", angle=0.3, lead_at=250.0, lead_speed=10.0,
                     side=1)
    env = make_womd_env(path, config={"collision_reward": 0.0, "off_road_reward": 0.0,
                                      "progress_reward": 0.0, "ttc_reward": 0.0,
                                      "progress_gain_reward": 2.0})
    assert make_womd_env(path).unwrapped.config["progress_gain_reward"] == 0.0
    for actions in ([3] * 40, [4] * 40):  # FASTER, SLOWER
        env.reset(seed=0)
        total = 0.0
        for action in actions:
            _, reward, terminated, truncated, _ = env.step(action)
            assert reward >= 0.0
            total += reward
            if terminated or truncated:
                break
        progress = env.unwrapped.route_progress
        assert 0.1 < progress and total == pytest.approx(2.0 * progress, abs=1e-9)


def test_a_collision_that_is_the_ego_s_fault_costs_the_at_fault_reward_more(tmp_path):
    # driving into a stopped car: the same episode with and without at_fault_reward; the
    # rewards differ by it at the collision only
    path = following(tmp_path / "sd_hit.pkl", angle=-0.4, lead_at=20.0, lead_speed=0.0,
                     side=1)
    plain = make_womd_env(path)
    judged = make_womd_env(path, config={"at_fault_reward": -2.0})
    plain.reset(seed=0)
    judged.reset(seed=0)
    for _ in range(20):
        _, r0, done0, _, _ = plain.step(3)  # FASTER into the stopped car
        _, r1, done1, _, _ = judged.step(3)
        assert done0 == done1
        if done1:
            break
        assert r1 == pytest.approx(r0, abs=1e-12)
    info = judged.episode_info()
    assert info["crash_at_fault"] and judged.unwrapped.vehicle.crashed
    assert r1 - r0 == pytest.approx(-2.0, abs=1e-9)
