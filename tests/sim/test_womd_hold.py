"""The safety layer's hold (``SafetyLayer(predicted=True, lanes=True, hold=True)``): a road
user whose lanes were found to cross the ego's way stays braked for until it has passed or
left that way; hand-drawn maps and states."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_womd_predicted import Lanes, car, junction

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_observation import boxes_overlap
from tap_bench.sim.womd_safety import HOLD_MISSES, SafetyLayer, lane_conflict, safety_layer

# A road user with no meeting has an infinite entry: no arithmetic may be done on it (inf * 0
# is NaN, with a RuntimeWarning on an ego that points along an axis).
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LANES = {"predicted": True, "lanes": True}
HOLD = {**LANES, "hold": True}


class Road:
    def __init__(self, network: object) -> None:
        self.network = network


def _turn_path() -> np.ndarray:
    """The oncoming car's way on :func:`junction`: lane 1 west to (35, 8), lane 2's quarter
    turn left about (35, 0), then south along x = 27."""
    theta = np.radians(np.linspace(90.0, 180.0, 40))
    turn = np.c_[35.0 + 8.0 * np.cos(theta), 8.0 * np.sin(theta)]
    return np.vstack([[[60.0, 8.0]], turn, [[27.0, -40.0]]])


def _along(line: np.ndarray, d: float) -> tuple[np.ndarray, float]:
    seg = np.diff(line, axis=0)
    run = np.r_[0.0, np.cumsum(np.hypot(*seg.T))]
    k = min(int(np.searchsorted(run, d, side="right")) - 1, len(seg) - 1)
    u = seg[k] / np.hypot(*seg[k])
    return line[k] + (d - run[k]) * u, math.atan2(u[1], u[0])


def _left_turn(layer: dict) -> tuple[int | None, float]:
    """The ego at 12 m/s along y = 0 asking for 2 m/s^2; an oncoming car 25 m along
    :func:`_turn_path` creeps at 0.6 m/s for 0.5 s, then speeds up at 4 m/s^2 to 9 m/s as
    it turns across the ego's way (the lanes' prediction takes 1 m/s^2). Stepped at 10 Hz
    for 6 s: (the first step the two boxes overlap, or None; the ego's final x [m])."""
    line, d = _turn_path(), 25.0
    safety = SafetyLayer(**layer)
    ego = car(0.0, 0.0, speed=12.0)
    ego.road = Road(junction((2, 3, 4)))
    other = car(0.0, 0.0)
    hit = None
    for k in range(60):
        v = 0.6 if k < 5 else min(0.6 + 4.0 * (k * 0.1 - 0.5), 9.0)
        (x, y), h = _along(line, d)
        other.position, other.heading, other.speed = np.array([x, y]), h, v
        other.velocity = v * np.array([math.cos(h), math.sin(h)])
        ego.action["acceleration"] = 2.0
        safety.apply(ego, [other], step=k)
        touching = boxes_overlap(ego.position[None], np.zeros(1), 2.25, 1.0,
                                 other.position[None, None], np.array([h]),
                                 np.array([2.25]), np.array([1.0]))
        if hit is None and touching.any():
            hit = k
        ego.speed = max(ego.speed + 0.1 * ego.action["acceleration"], 0.0)
        ego.velocity = np.array([ego.speed, 0.0])
        ego.position = ego.position + np.array([0.1 * ego.speed, 0.0])
        d += 0.1 * v
    return hit, float(ego.position[0])


def test_an_oncoming_left_turner_is_held_where_the_lanes_layer_lets_go_and_is_hit():
    """The lanes layer brakes when it first foresees the car, then, the ego slowed and the
    predicted times apart, lets the ego speed up beside the turning car (hit 2.5 s in);
    held, the ego waits until the car has crossed and drives on past the junction."""
    hit, _ = _left_turn(LANES)
    assert hit is not None
    for hold in (HOLD, {**HOLD, "hold_point": True}):
        hit, x = _left_turn(hold)
        assert hit is None and x > 60.0


def _rotate(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.asarray(points, float) @ np.array([[c, s], [-s, c]])


def _crossing(angle: float) -> Lanes:
    """A junction's crossing road at x = 30 (a lane north, 1, and a lane south, 2, on the
    same line) across the ego's way y = 0, all turned by ``angle`` [rad] about the origin."""
    north = np.c_[np.full(9, 30.0), np.linspace(-40.0, 40.0, 9)]
    return Lanes({1: _rotate(north, angle), 2: _rotate(north[::-1], angle)}, {})


def _at(x: float, y: float, heading: float, speed: float, angle: float, moved=None):
    """A car at (x, y) heading ``heading`` at ``speed``, all turned by ``angle``; with
    ``moved``, that road user placed there (the same one, a step later)."""
    (px, py), = _rotate([[x, y]], angle)
    placed = car(px, py, heading=heading + angle, speed=speed)
    if moved is None:
        return placed
    moved.__dict__.update(placed.__dict__)
    return moved


@pytest.mark.parametrize("angle", np.radians(np.arange(0.0, 360.0, 45.0)).tolist())
@pytest.mark.parametrize("side", [1.0, -1.0])  # from the ego's right, from its left
def test_a_crossing_car_is_held_until_it_has_passed_then_released(angle, side):
    """Ego at 10 m/s heading ``angle``, asking for 1 m/s^2; a car on the crossing road
    coming from the ego's right (or left) at 6 m/s, 15 m from its line: braked for by both
    layers. Next it creeps at 0.6 m/s 14 m out (it would reach the ego's line in over
    4 s): the lanes layer lets the ego's acceleration through, the hold brakes. Then it is
    6 m past the line going on: held HOLD_MISSES - 1 steps more, then released."""
    network = _crossing(angle)
    heading = math.pi / 2 if side > 0 else -math.pi / 2
    layers = {name: SafetyLayer(**setting) for name, setting in (("lanes", LANES),
                                                                  ("hold", HOLD))}
    states = [(-15.0, 6.0), (-14.0, 0.6)] + [(6.0, 6.0)] * HOLD_MISSES
    asked = {name: [] for name in layers}
    other = None
    for step, (y, v) in enumerate(states):
        other = _at(30.0, side * y, heading, v, angle, other)
        for name, layer in layers.items():
            ego = _at(0.0, 0.0, 0.0, 10.0, angle)
            ego.road = Road(network)
            ego.action["acceleration"] = 1.0
            layer.apply(ego, [other], step=step)
            asked[name].append(ego.action["acceleration"])
        if step == 1:  # the premise: no timed conflict now
            assert not math.isfinite(lane_conflict(ego, [other], network, 1.0).gap)
    assert asked["lanes"][0] < 0 and asked["lanes"][1] == 1.0
    assert all(a < 0 for a in asked["hold"][:-1])
    assert asked["hold"][-1] == 1.0


def test_a_car_that_stops_short_is_released_one_stopped_at_the_edge_is_not():
    """The crossing car from the ego's right, held, then standing: 8 m short of the ego's
    line (its box more than min_gap, 2 m, clear of the ego's swept box): released; 3.5 m
    short (its box 1 m from the ego's): still braked for."""
    network = _crossing(0.0)
    for y, held in ((-8.0, False), (-3.5, True)):
        layer = SafetyLayer(**HOLD)
        other = None
        for step, (at, v) in enumerate([(-15.0, 6.0), (y, 0.0)]):
            other = _at(30.0, at, math.pi / 2, v, 0.0, other)
            ego = car(0.0, 0.0, speed=10.0)
            ego.road = Road(network)
            ego.action["acceleration"] = 1.0
            layer.apply(ego, [other], step=step)
        assert (ego.action["acceleration"] < 0) is held


def test_a_car_that_takes_a_branch_away_from_the_ego_s_way_is_released():
    """The oncoming car of :func:`junction`, braked for while its lanes may turn across the
    ego's way, then on lane 3 (straight on, west, at y = 8): released after HOLD_MISSES
    steps; gone from the road users: released at once."""
    network = junction((2, 3, 4))
    layer = SafetyLayer(**HOLD)
    turning = car(40.0, 8.0, heading=math.pi, speed=5.0)
    asked = []
    for step in range(1 + HOLD_MISSES):
        other = turning
        if step:
            other.position = np.array([30.0, 8.0])  # the same road user, on lane 3
        ego = car(0.0, 0.0, speed=10.0)
        ego.road = Road(network)
        ego.action["acceleration"] = 1.0
        layer.apply(ego, [other], step=step)
        asked.append(ego.action["acceleration"])
    assert all(a < 0 for a in asked[:-1]) and asked[-1] == 1.0
    layer = SafetyLayer(**HOLD)
    for step, others in enumerate([[turning], []]):
        turning.position = np.array([40.0, 8.0])
        ego = car(0.0, 0.0, speed=10.0)
        ego.road = Road(network)
        ego.action["acceleration"] = 1.0
        layer.apply(ego, others, step=step)
    assert ego.action["acceleration"] == 1.0


def test_no_braking_into_a_stop_in_the_crossing():
    """The ego at 16 m/s (a 16 m stop at 8 m/s^2), the crossing car's ground about 12 m
    ahead: the lanes layer brakes at 8 m/s^2 (it would stop in the crossing); the hold
    leaves the acceleration to the policy, and does so while the car stays in its way."""
    network = _crossing(0.0)
    asked = {}
    for name, setting in (("lanes", LANES), ("hold", HOLD)):
        layer = SafetyLayer(**setting)
        other = None
        for step in range(2):
            ego = car(14.0, 0.0, speed=16.0)
            ego.road = Road(network)
            ego.action["acceleration"] = 0.5
            other = _at(30.0, -8.0 + step, math.pi / 2, 6.0, 0.0, other)
            layer.apply(ego, [other], step=step)
            asked.setdefault(name, []).append(ego.action["acceleration"])
    assert asked["lanes"][0] == -8.0
    assert asked["hold"] == [0.5, 0.5]


def test_the_hold_setting_needs_the_lanes_prediction():
    assert safety_layer(HOLD).hold is True
    assert safety_layer(LANES).hold is False
    with pytest.raises(ParameterError, match="hold"):
        safety_layer({"predicted": True, "hold": True})
    with pytest.raises(ParameterError, match="hold"):
        safety_layer({**LANES, "hold": 1})
    assert safety_layer({**HOLD, "hold_point": True}).hold_point is True
    with pytest.raises(ParameterError, match="hold_point"):
        safety_layer({**LANES, "hold_point": True})


def _two_turns() -> Lanes:
    """:func:`junction`'s oncoming lane 1 (y = 8, westbound to x = 35), branching into 2
    (the left turn across the ego's line at x = 27), 3 (straight on west) and 5 (west to
    x = 20, then a left turn across the ego's line at x = 12)."""
    lines = {1: np.array([[60.0, 8.0], [35.0, 8.0]]),
             2: np.vstack([_quarter((35.0, 0.0)), [[27.0, -30.0]]]),
             3: np.array([[35.0, 8.0], [0.0, 8.0]]),
             5: np.vstack([[[35.0, 8.0]], _quarter((20.0, 0.0)), [[12.0, -30.0]]])}
    return Lanes(lines, {1: [2, 3, 5]})


def _quarter(centre: tuple[float, float]) -> np.ndarray:
    theta = np.radians(np.linspace(90.0, 180.0, 16))
    return np.c_[centre[0] + 8.0 * np.cos(theta), centre[1] + 8.0 * np.sin(theta)]


@pytest.mark.parametrize("hold_point", [False, True])
def test_a_nearer_branch_not_matched_in_time_lets_the_plain_hold_go(hold_point):
    """The ego at 12 m/s (a 9 m stop at 8 m/s^2) asking for 1 m/s^2; the oncoming car at
    (40, 8) at 8 m/s: its left turn at x = 27 meets the ego's way at a matched time and it
    is held. A step later the ground of all its branches is taken: the turn at x = 12 (not
    matched: the ego is there first) meets the ego's way within its stopping distance, and
    the plain hold counts the ego as unable to stop for the car and lets its acceleration
    through; with ``hold_point`` it brakes where it would have stopped for the turn at 27."""
    from tap_bench.sim.womd_safety import lane_meetings

    network = _two_turns()
    layer = SafetyLayer(**HOLD, hold_point=hold_point)
    other = car(40.0, 8.0, heading=math.pi, speed=8.0)
    asked = []
    for step in range(2):
        ego = car(1.2 * step, 0.0, speed=12.0)
        ego.road = Road(network)
        ego.action["acceleration"] = 1.0
        if step == 1:  # the premise: all branches' ground nearer than the stop, timed not
            timed, way = lane_meetings(ego, [other], network, 1.0, watched=[0])
            assert way[0] - 0.5 < 12.0**2 / 16 < timed[0] - 0.5
        layer.apply(ego, [other], step=step)
        asked.append(ego.action["acceleration"])
    assert asked[0] < 0
    assert (asked[1] < 0) is hold_point
