"""The road users whose way crosses the ego's path (``KinematicsRoute`` with ``crossing``) and
the leader by the corners of its box (``leader_corners``), in the RL observation of
tap_bench/womd-v0: values worked out by hand on a generated straight road, at any heading."""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pytest

from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_observation import (
    CROSS_HORIZON,
    CROSSING_COUNT,
    CROSSING_FEATURES,
    LEADER_FEATURES,
)

LENGTH, WIDTH = 4.5, 2.0  # [m] every car's
EGO_SPEED = 10.0  # [m/s]


def scene(path: Path, angle: float, others: dict[str, tuple[float, float, float, float]]
          ) -> str:
    """A ScenarioNet pickle: one straight lane heading ``angle`` [rad], the ego on it at
    10 m/s from lon 0; ``others``: name -> (lon, lat [m] at time 0, heading off the lane's
    [rad], speed [m/s]), each driving straight on at that speed."""
    t = np.arange(91) * 0.1
    c, s = math.cos(angle), math.sin(angle)

    def rotate(lon, lat):
        return np.c_[lon * c - lat * s, lon * s + lat * c]

    def track(lon0, lat0, off, speed):
        h = angle + off
        xy = rotate(lon0 + speed * math.cos(off) * t, lat0 + speed * math.sin(off) * t)
        return {"type": "VEHICLE", "state": {
            "position": np.c_[xy, np.zeros(91)], "heading": np.full(91, h),
            "velocity": np.c_[np.full(91, speed * math.cos(h)), np.full(91, speed * math.sin(h))],
            "valid": np.ones(91, bool), "length": np.full(91, LENGTH),
            "width": np.full(91, WIDTH)}}

    lon = np.arange(-20.0, 300.0, 1.0)
    features = {"1": {"type": "LANE_SURFACE_STREET", "polyline": rotate(lon, 0 * lon),
                      "entry_lanes": [], "exit_lanes": []}}
    tracks = {"ego": track(0.0, 0.0, 0.0, EGO_SPEED),
              **{name: track(*values) for name, values in others.items()}}
    meta = {"scenario_id": path.stem, "ts": t, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "tracks": tracks, "map_features": features,
                     "dynamic_map_states": {}}, f)
    return str(path)


def observe(path: str, **observation: bool) -> tuple[np.ndarray, object]:
    env = make_womd_env(path, config={"observation": {
        "type": "KinematicsRoute", "leader": True, **observation}})
    obs, _ = env.reset(seed=0)
    return obs, env.unwrapped.observation_type


def crossing_part(obs: np.ndarray) -> np.ndarray:
    n = CROSSING_COUNT * len(CROSSING_FEATURES)
    return obs[-n:].reshape(CROSSING_COUNT, len(CROSSING_FEATURES))


@pytest.mark.parametrize("angle", [0.0, 1.1, -2.5])
@pytest.mark.parametrize("side", [1, -1])
def test_a_car_coming_from_the_side_is_seen_where_and_when_it_crosses(tmp_path, angle, side):
    # at the current time (1.0 s) the ego is at lon 10; a car 20 m to the side of lon 40
    # comes at 8 m/s straight across (its way: 40 m in 5 s), another 30 m to the side of
    # lon 25 at 10 m/s; a car ahead in the next lane's place driving along does not cross
    others = {"near": (40.0, side * 28.0, -side * math.pi / 2, 8.0),
              "far": (25.0, -side * 40.0, side * math.pi / 2, 10.0),
              "along": (20.0, side * 3.7, 0.0, 12.0)}
    obs, observation = observe(scene(tmp_path / "sd_cross.pkl", angle, others),
                               crossing=True)
    horizon = observation.horizon
    got = crossing_part(obs)
    # nearest crossing point first: lon 25 (15 m ahead), then lon 40 (30 m ahead)
    for row, (ahead, other_time) in zip(got, [(15.0, 30.0 / 10.0), (30.0, 20.0 / 8.0)],
                                        strict=True):
        assert row[0] == pytest.approx(ahead / horizon, abs=1e-4)
        ego_time = (ahead - LENGTH / 2) / EGO_SPEED
        assert row[1] == pytest.approx(ego_time / CROSS_HORIZON, abs=1e-4)
        assert row[2] == pytest.approx(other_time / CROSS_HORIZON, abs=1e-4)
    # the leader part is where it was, before the crossing part
    n = CROSSING_COUNT * len(CROSSING_FEATURES)
    lead = obs[-n - len(LEADER_FEATURES):-n]
    assert lead[0] == pytest.approx(EGO_SPEED / 30.0, abs=1e-5)


def test_no_crossing_reads_as_ones_and_a_car_too_far_to_arrive_is_none(tmp_path):
    # a car 60 m to the side at 5 m/s gets 25 m in 5 s: it does not reach the path
    others = {"slow": (30.0, 60.0, -math.pi / 2, 5.0), "parked": (30.0, -8.0, math.pi / 2, 0.0)}
    obs, observation = observe(scene(tmp_path / "sd_none.pkl", 0.3, others), crossing=True)
    assert crossing_part(obs).tolist() == [[1.0, 1.0, 1.0]] * CROSSING_COUNT
    assert observation.crossings(np.array([[0.0, 0.0], [1.0, 0.0]])) == []


def test_without_crossing_the_vector_is_as_before(tmp_path):
    path = scene(tmp_path / "sd_same.pkl", 0.8, {"near": (40.0, 20.0, -math.pi / 2, 8.0)})
    plain, _ = observe(path)
    crossing, _ = observe(path, crossing=True)
    assert len(crossing) == len(plain) + CROSSING_COUNT * len(CROSSING_FEATURES)
    np.testing.assert_array_equal(crossing[:len(plain)], plain)


@pytest.mark.parametrize("angle", [0.0, 2.0])
def test_a_parked_car_reaching_into_the_lane_is_the_leader_by_its_corner(tmp_path, angle):
    # parked 2.4 m beside the lane centre at lon 40, turned 30 degrees towards the lane: its
    # centre is outside the path (2.4 > (2 + 2) / 2 m) but its front corner reaches to
    # 2.4 - 2.25 sin 30 - 1 cos 30 = 0.409 m from the centre line, 40 + 2.25 cos 30
    # - 1 sin 30 = 41.449 m along
    tilt = math.radians(30.0)
    for side in (1, -1):
        path = scene(tmp_path / f"sd_corner{side}.pkl", angle,
                     {"parked": (40.0, side * 2.4, -side * tilt, 0.0)})
        plain, _ = observe(path)
        corners, _ = observe(path, leader_corners=True)
        gap_plain = plain[-len(LEADER_FEATURES) + 1]
        gap_corner = corners[-len(LEADER_FEATURES) + 1]
        horizon = 50.0
        assert gap_plain == 1.0  # no leader: its centre is not in the path
        corner_along = 40.0 + 2.25 * math.cos(tilt) - 1.0 * math.sin(tilt)
        assert gap_corner == pytest.approx((corner_along - 10.0 - LENGTH / 2) / horizon,
                                           abs=1e-4)
