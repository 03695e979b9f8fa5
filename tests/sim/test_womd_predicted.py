"""The safety layer's predicted conflicts (``predicted_conflict``; ``SafetyLayer(predicted=
True)``): the ego's box along its way and a crossing or oncoming road user's box along its
own velocity, compared at matched times; values worked out by hand."""

from __future__ import annotations

import math
import pickle
from types import SimpleNamespace

import numpy as np
import pytest

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_observation import (
    SWEPT_STEP,
    predicted_conflict,
    swept_leader,
)
from tap_bench.sim.womd_safety import SafetyLayer, safety_layer

CUT = math.radians(210.0)  # 150 degrees off the ego's heading (0): oncoming, to its right


def car(x: float, y: float, heading: float = 0.0, speed: float = 0.0,
        length: float = 4.5, width: float = 2.0) -> SimpleNamespace:
    return SimpleNamespace(position=np.array([x, y]), heading=heading, speed=speed,
                           velocity=speed * np.array([math.cos(heading), math.sin(heading)]),
                           LENGTH=length, WIDTH=width,
                           action={"steering": 0.0, "acceleration": 0.0})


def cutting_across(arrival: float = 2.0) -> SimpleNamespace:
    """An oncoming car at 10 m/s, heading 210 degrees, whose centre crosses the ego's line
    (y = 0) at x = 20 at time ``arrival`` [s]."""
    vx, vy = 10.0 * math.cos(CUT), 10.0 * math.sin(CUT)
    return car(20.0 - vx * arrival, -vy * arrival, heading=CUT, speed=10.0)


def test_an_oncoming_car_cutting_across_the_ego_s_way_is_a_predicted_conflict():
    """Ego at 10 m/s along x; the car now at (37.3, 10), 150 degrees off, reaches (20, 0)
    when the ego's centre does (t = 2 s). Now its box (y >= 10 - 2.25 sin 30 - cos 30 = 8.0)
    is far from the swept box (|y| <= 1.25): the swept test names nothing. Its zone (its box
    from -1 s to 4 s: the strip of half width 1 m about its line x = 20 + sqrt(3) y) is
    first met by the ego's front right corner (y = -1.25) when the front reaches
    20 - 1.25 sqrt(3) - 1 / sin(30) = 15.835: the centre at 13.585 m; it stands still, so
    the closing speed is the ego's."""
    ego = car(0.0, 0.0, speed=10.0)
    other = cutting_across(2.0)
    assert not math.isfinite(swept_leader(ego, [other]).gap)
    conflict = predicted_conflict(ego, [other])
    expected = 20.0 - 1.25 * math.sqrt(3.0) - 2.0 - 2.25
    assert expected - SWEPT_STEP - 1e-9 <= conflict.gap <= expected + 1e-9
    assert conflict.closing == pytest.approx(10.0)


def test_the_new_layer_brakes_for_it_and_the_old_one_does_not():
    """The same car: the fifth version's layer (swept box only) lets the policy's
    acceleration through; with ``predicted`` the cap is IDM's for a standing obstacle at
    the zone (s* = 2 + 10 + 100 / 6 = 28.7 m against a gap of about 13.5 m: the most
    braking, 8 m/s^2), counted as foreseen."""
    old, new = SafetyLayer(), SafetyLayer(predicted=True)
    for layer in (old, new):
        ego = car(0.0, 0.0, speed=10.0)
        ego.action["acceleration"] = 1.0
        layer.apply(ego, [cutting_across(2.0)], step=1)
        layer.result = ego.action["acceleration"]
    assert old.result == 1.0 and (old.capped, old.foreseen) == (0, 0)
    gap = predicted_conflict(car(0.0, 0.0, speed=10.0), [cutting_across(2.0)], 1.0).gap
    assert new.result == pytest.approx(new.cap(10.0, gap, 10.0)) == -8.0
    assert (new.steps, new.capped, new.braked, new.foreseen) == (1, 1, 1, 1)


@pytest.mark.parametrize("arrival", [5.5, -1.5])
def test_a_car_crossing_well_before_or_after_the_ego_is_not_braked_for(arrival):
    """The same line crossed 5.5 s from now (the ego's centre passes x = 20 at 2 s: more
    than the 1 s tolerance apart, and beyond the 3 s horizon), or 1.5 s ago (gone): no
    conflict, though its zone may lie across the ego's way."""
    ego = car(0.0, 0.0, speed=10.0)
    assert not math.isfinite(predicted_conflict(ego, [cutting_across(arrival)]).gap)


def test_an_oncoming_car_in_its_own_lane_passing_by_is_not_braked_for():
    """An oncoming car 3.5 m to the ego's left (its own lane), heading straight back at
    10 m/s: at every matched time its box (y 2.5 to 4.5) stays clear of the ego's (y up to
    1.25); nothing is capped."""
    ego = car(0.0, 0.0, speed=10.0)
    ego.action["acceleration"] = 1.0
    passing = car(40.0, 3.5, heading=math.pi, speed=10.0)
    assert not math.isfinite(predicted_conflict(ego, [passing], 1.0).gap)
    layer = SafetyLayer(predicted=True)
    layer.apply(ego, [passing], step=1)
    assert ego.action["acceleration"] == 1.0 and layer.capped == 0
    # 60 m ahead drifting 1 m nearer the ego's line each second (5.7 degrees): at 3 s,
    # when they meet, its box reaches down to y = 0.5 - 1.2: then braked for (its zone
    # still ends 15 m ahead of the ego)
    drift = car(60.0, 3.5, heading=math.pi + math.atan2(1.0, 10.0), speed=10.0)
    assert math.isfinite(predicted_conflict(ego, [drift], 1.0).gap)


def test_what_braking_cannot_clear_and_road_users_going_the_ego_s_way_are_left_out():
    """A car coming from behind at an angle whose zone covers the ego where it is now
    (braking cannot clear it), a faster car behind in the ego's lane and a slower one ahead
    (the swept box's, less than 15 degrees off): no predicted conflict. A standing ego that
    asks for no acceleration goes nowhere: no conflict either; asking for 3 m/s^2 it meets
    a car crossing 6 m ahead 2 s from now (it covers 6 m in 2 s)."""
    ego = car(0.0, 0.0, speed=10.0)
    behind_angle = car(-12.0, -6.0, heading=math.atan2(6.0, 12.0), speed=13.4)
    behind = car(-15.0, 0.0, speed=20.0)
    ahead = car(15.0, 0.3, heading=0.05, speed=5.0)
    assert not math.isfinite(predicted_conflict(ego, [behind_angle, behind, ahead]).gap)
    standing = car(0.0, 0.0, speed=0.0)
    crosser = car(6.0 + 2.25, -20.0, heading=math.pi / 2, speed=10.0)  # y = 0 at t = 2
    assert not math.isfinite(predicted_conflict(standing, [crosser], 0.0).gap)
    assert math.isfinite(predicted_conflict(standing, [crosser], 3.0).gap)


def test_the_predicted_setting_is_a_flag_with_a_positive_tolerance():
    assert safety_layer({"predicted": True}) == SafetyLayer(predicted=True)
    assert safety_layer(True).predicted is False  # the fifth version's layer
    assert safety_layer({"predicted": True, "tolerance": 0.5}).tolerance == 0.5
    with pytest.raises(ParameterError, match="predicted"):
        safety_layer({"predicted": "yes"})
    with pytest.raises(ParameterError, match="tolerance"):
        SafetyLayer(predicted=True, tolerance=0.0)


def _cut_across(path) -> str:
    """A ScenarioNet pickle: one straight lane along x (WOMD axes, lat + left); the ego
    drives it at 10 m/s from lon 0 (at lon 10 at the current time, 1 s); a car, logged at
    10 m/s heading 210 degrees (oncoming, cutting across from the ego's left), reaches
    (40, 0) at 4 s, when the ego would."""
    t = np.arange(91) * 0.1

    def track(x, y, vx, vy, heading):
        return {"type": "VEHICLE", "state": {
            "position": np.c_[x, y, np.zeros(91)], "heading": np.full(91, heading),
            "velocity": np.c_[np.full(91, vx), np.full(91, vy)],
            "valid": np.ones(91, bool), "length": np.full(91, 4.5),
            "width": np.full(91, 2.0)}}

    vx, vy = 10.0 * math.cos(CUT), 10.0 * math.sin(CUT)
    lon = np.arange(-20.0, 300.0, 1.0)
    features = {"1": {"type": "LANE_SURFACE_STREET", "polyline": np.c_[lon, np.zeros_like(lon)],
                      "entry_lanes": [], "exit_lanes": []}}
    tracks = {"ego": track(10.0 * t, np.zeros(91), 10.0, 0.0, 0.0),
              "cutter": track(40.0 + vx * (t - 4.0), vy * (t - 4.0), vx, vy, CUT)}
    meta = {"scenario_id": path.stem, "ts": t, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "tracks": tracks, "map_features": features,
                     "dynamic_map_states": {}}, f)
    return str(path)


class KeepSpeed:
    """Always IDLE (keep the lane and the target speed), with an action config of its own."""

    def __init__(self, layer: object) -> None:
        self.name = f"keep-{layer}"
        self.observation = {"type": "KinematicsRoute", "leader": True, "leader_swept": True}
        self.action = {"type": "DiscreteMetaAction",
                       "target_speeds": [0.0, 5.0, 10.0], "safety_layer": layer}

    def reset(self, env: object, *, seed: int) -> None:
        pass

    def act(self, observation: object) -> int:
        return 1


def test_through_rollout_the_new_layer_lets_the_cutting_car_pass_and_the_old_one_does_not(
        tmp_path):
    """Rolled out (the policy's own action config builds the env): at 10 m/s without a
    layer and with the fifth version's the ego meets the car that cuts across its lane
    (the swept box sees it less than a second before); with ``predicted`` it brakes from
    the start, lets it pass and drives on, and the layer counts foreseen steps."""
    import importlib

    from tap_bench.sim.womd_scene import WomdScenes

    rollouts = importlib.import_module("tap_bench.sim.rollout")  # the module, not the function

    scenes = WomdScenes((_cut_across(tmp_path / "sd_cut.pkl"),))
    rows = {}
    lanes = {"predicted": True, "lanes": True}
    for layer in (False, True, {"predicted": True}, lanes):
        rollouts._ENVS.clear()
        result = rollouts.rollout(scenes, KeepSpeed(layer), "all", record=False)
        (env,) = rollouts._ENVS.values()
        rows[str(layer)] = (result.episodes.iloc[0], env.unwrapped.vehicle.safety)
    for layer in ("False", "True"):
        assert rows[layer][0]["status"] == "ok" and rows[layer][0]["crashed"]
    for layer in ({"predicted": True}, lanes):  # on no lane, the car goes straight on
        row, safety = rows[str(layer)]
        assert row["status"] == "ok" and not row["crashed"]
        assert safety.foreseen > 0 and safety.braked > 0
        assert row["route_progress"] > 0.5  # it drove on once the car had passed


class Lanes:
    """A map of hand-drawn lanes (highway-env's frame): what :func:`lane_paths` asks of a
    network (the closest lane, a lane, its successors)."""

    def __init__(self, lines: dict[int, np.ndarray], exits: dict[int, list[int]]) -> None:
        from tap_bench.sim.womd_lanes import FastPolyLane, LaneIndex

        self.lanes = {k: FastPolyLane(points, 3.5) for k, points in lines.items()}
        self.exits = exits
        self.lookup = LaneIndex(list(self.lanes.items()))

    def get_closest_lane_index(self, position, heading=None):
        return self.lookup.closest(position, heading)

    def get_lane(self, index):
        return self.lanes[index]

    def successors(self, index):
        return self.exits.get(index, [])


def _arc(centre, radius, start, stop, then):
    """Points of a quarter turn about ``centre`` from angle ``start`` to ``stop`` [deg],
    then straight to ``then``."""
    theta = np.radians(np.linspace(start, stop, 16))
    points = np.c_[centre[0] + radius * np.cos(theta), centre[1] + radius * np.sin(theta)]
    return np.vstack([points, then])


def junction(turns: tuple[int, ...]) -> Lanes:
    """An oncoming lane (1) at y = 8, westbound from x = 60 to 35, where it branches: 2 turns
    left (south) across the ego's line y = 0 at x = 27 (a quarter circle of 8 m about
    (35, 0)), 3 goes straight on west, 4 turns right (north, away from the ego)."""
    lines = {1: np.array([[60.0, 8.0], [35.0, 8.0]]),
             2: _arc((35.0, 0.0), 8.0, 90.0, 180.0, [[27.0, -30.0]]),
             3: np.array([[35.0, 8.0], [0.0, 8.0]]),
             4: _arc((35.0, 16.0), 8.0, -90.0, -180.0, [[27.0, 46.0]])}
    return Lanes(lines, {1: list(turns)})


def test_lane_paths_follow_every_branch_of_the_lane_under_a_road_user():
    from tap_bench.sim.womd_safety import lane_paths

    paths = lane_paths(junction((2, 3, 4)), np.array([40.0, 8.0]), math.pi, 20.0)
    ends = np.array(sorted(tuple(line[-1]) for line in paths))  # sampled every metre
    assert ends.ravel() == pytest.approx([0.0, 8.0, 27.0, -30.0, 27.0, 46.0], abs=1.0)
    for line in paths:  # from its position, each at least 20 m long
        assert tuple(line[0]) == (40.0, 8.0)
        assert np.hypot(*np.diff(line, axis=0).T).sum() >= 20.0
    # off every lane (12 m from lane 1's centre): straight on along its heading
    (line,) = lane_paths(junction((2,)), np.array([40.0, 20.0]), math.pi, 20.0)
    assert line[-1] == pytest.approx([20.0, 20.0])


def test_a_car_whose_next_lane_turns_across_the_ego_s_way_is_braked_for():
    """The ego at 10 m/s along y = 0; an oncoming car at (40, 8) at 5 m/s on lane 1, whose
    successor 2 turns left across the ego's line at x = 27: along that lane it gets there
    (about 17.6 m on) between 2.7 s (at 1 m/s^2 more speed each second) and 3.5 s, less or
    more the 1 s tolerance, when the ego's front does (2.5 s). At its velocity and heading
    (the sixth version's prediction) it goes on west at y = 8 and meets nothing. The gap is
    to where the ego's box first meets the turning lane's ground: before the ego's centre
    reaches x = 27 - 1 - 2.25 (the car's half width, the ego's half length)."""
    from tap_bench.sim.womd_safety import lane_conflict

    ego = car(0.0, 0.0, speed=10.0)
    turning = car(40.0, 8.0, heading=math.pi, speed=5.0)
    assert not math.isfinite(predicted_conflict(ego, [turning]).gap)
    conflict = lane_conflict(ego, [turning], junction((2, 3, 4)))
    assert 15.0 < conflict.gap < 27.0 - 1.0 - 2.25
    assert conflict.closing == pytest.approx(10.0)
    # through the layer: braked for with lanes, not with the velocity-and-heading prediction
    for lanes in (False, True):
        layer = SafetyLayer(predicted=True, lanes=lanes)
        ego = car(0.0, 0.0, speed=10.0)
        ego.road = SimpleNamespace(network=junction((2, 3, 4)))
        ego.action["acceleration"] = 1.0
        layer.apply(ego, [turning], step=1)
        assert (ego.action["acceleration"] < 0) is lanes
        assert (layer.capped, layer.foreseen) == ((1, 1) if lanes else (0, 0))


def test_a_car_whose_lanes_never_meet_the_ego_s_way_is_not_braked_for():
    """The same car where lane 1 goes on only straight west (3) or turns right, away from
    the ego (4); and with the turn across, a car that gets there well after the ego (at
    1 m/s, 17 s away)."""
    from tap_bench.sim.womd_safety import lane_conflict

    ego = car(0.0, 0.0, speed=10.0)
    assert not math.isfinite(lane_conflict(
        ego, [car(40.0, 8.0, heading=math.pi, speed=5.0)], junction((3, 4))).gap)
    assert not math.isfinite(lane_conflict(
        ego, [car(40.0, 8.0, heading=math.pi, speed=1.0)], junction((2, 3, 4)),
        other_acceleration=0.0).gap)
    with pytest.raises(ParameterError, match="other_acceleration"):
        safety_layer({"predicted": True, "lanes": True, "other_acceleration": -1.0})
    assert safety_layer({"predicted": True, "lanes": True}).lanes is True
