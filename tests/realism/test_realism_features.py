"""Every realism feature against a case worked out by hand (SPEC section 9)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tap_bench.realism.features import (
    EDGE_SEARCH,
    MAX_TTC,
    box_signed_distance,
    kinematic_features,
    nearest_object_distance,
    overlapping_pairs,
    red_light_violations,
    road_edge_distance,
    time_to_collision,
)
from tap_bench.sim.road_edges import RoadEdges, box_corners

DT = 0.1


def _box(x, y, heading, length=4.0, width=2.0):
    return box_corners(np.array([x]), np.array([y]), np.array([heading]), np.array([length]),
                       np.array([width]))


@pytest.mark.parametrize(("other", "expected"), [
    ((5.0, 0.0, 0.0), 1.0),  # nose to tail: 5 - 2 - 2
    ((3.5, 0.0, 0.0), -0.5),  # overlapping by 0.5 m along x
    ((0.0, 4.0, math.pi / 2), 1.0),  # crosswise above: its back at y = 2, ours at y = 1
    ((0.0, 1.5, 0.0), -0.5),  # side by side, overlapping 0.5 m across
    ((5.0, 4.0, 0.0), math.hypot(1.0, 2.0)),  # diagonal: corner (2, 1) to corner (3, 3)
])
def test_two_boxes_that_meet(other, expected):
    a = _box(0.0, 0.0, 0.0)
    b = _box(*other)
    assert box_signed_distance(a, b)[0] == pytest.approx(expected, abs=1e-9)
    assert box_signed_distance(b, a)[0] == pytest.approx(expected, abs=1e-9)


def test_a_box_driving_into_a_parked_one_collides_when_they_touch():
    # car 0 drives +x at 10 m/s (1 m per step) from x = 0; car 1 stands at x = 10:
    # the gap is 10 - 4 - k = 6 - k m at step k, overlap from step 7 on (up to step 8 the
    # overlap along x, k - 6, is at most the 2 m across, so the depth is k - 6)
    t = 9
    x = np.array([np.arange(t, dtype=float), np.full(t, 10.0)])
    y = np.zeros((2, t))
    h = np.zeros((2, t))
    valid = np.ones((2, t), bool)
    size = np.array([4.0, 4.0]), np.array([2.0, 2.0])
    d = nearest_object_distance(x, y, h, valid, *size)
    assert d[0] == pytest.approx(6.0 - np.arange(t))
    assert d[1] == pytest.approx(d[0])
    pairs = overlapping_pairs(x, y, h, valid, *size)
    assert pairs[:, 0].tolist() == [7, 8]
    assert (pairs[:, 1:] == [0, 1]).all()
    # time to collision: car 0 follows car 1 (standing) at 10 m/s
    speed = np.array([np.full(t, 10.0), np.zeros(t)])
    ttc = time_to_collision(x, y, h, valid, *size, speed)
    expected = np.where(6.0 - np.arange(t) > 0, (6.0 - np.arange(t)) / 10.0, MAX_TTC)
    assert ttc[0] == pytest.approx(expected)
    assert (ttc[1] == MAX_TTC).all()  # the parked car follows nobody


def test_time_to_collision_needs_a_leader_in_the_trail_and_closing():
    x = np.array([[0.0], [20.0], [20.0], [20.0]])
    y = np.array([[0.0], [0.0], [5.0], [0.0]])
    h = np.array([[0.0], [0.0], [0.0], [math.pi]])
    valid = np.array([[True], [True], [True], [False]])
    length, width = np.full(4, 4.0), np.full(4, 2.0)
    # 10 m/s behind a 5 m/s leader 16 m ahead (20 - 2 - 2): 3.2 s; the car 5 m to the side
    # is not in the trail; the oncoming one is invalid
    ttc = time_to_collision(x, y, h, valid, length, width, np.array([[10.0], [5.0], [0.0],
                                                                      [0.0]]))
    assert ttc[0, 0] == pytest.approx(3.2)
    # the leader faster: the gap opens
    ttc = time_to_collision(x, y, h, valid, length, width, np.array([[5.0], [10.0], [0.0],
                                                                      [0.0]]))
    assert ttc[0, 0] == MAX_TTC
    assert np.isnan(ttc[3, 0])


def test_a_constant_speed_agent_has_that_speed_and_no_acceleration():
    t = np.arange(20)
    x = 10.0 * t * DT
    feats = kinematic_features(x[None], np.zeros((1, 20)), np.zeros((1, 20)),
                               np.ones((1, 20), bool), DT)
    speed = feats["linear_speed"][0]
    assert np.isnan(speed[0]) and np.isnan(speed[-1])
    assert speed[1:-1] == pytest.approx(10.0)
    acc = feats["linear_acceleration"][0]
    assert np.isnan(acc[:2]).all() and np.isnan(acc[-2:]).all()
    assert acc[2:-2] == pytest.approx(0.0)


def test_turning_at_a_constant_rate_and_a_gap():
    # heading grows 0.05 rad per step through +-pi: angular speed 0.5 rad/s everywhere,
    # wrapped the short way; an invalid step voids the differences across it
    h = np.pi - 0.2 + 0.05 * np.arange(10)
    h = (h + np.pi) % (2 * np.pi) - np.pi
    valid = np.ones((1, 10), bool)
    valid[0, 6] = False
    feats = kinematic_features(np.zeros((1, 10)), np.zeros((1, 10)), h[None], valid, DT)
    w = feats["angular_speed"][0]
    assert np.isnan(w[[0, 5, 7, 9]]).all()
    assert w[[1, 2, 3, 4, 8]] == pytest.approx(0.5)
    assert feats["angular_acceleration"][0][[2, 3]] == pytest.approx(0.0)


def signed_edge_distance(points, edges):
    """The merged rule's signed distance (road_edges.RoadEdges), as the score reads it."""
    return RoadEdges.from_polylines(edges).signed_distance(points, EDGE_SEARCH)


def test_an_agent_that_crosses_an_edge():
    # the edge runs +x along y = 0: the road is on its left (y > 0)
    edge = [np.array([[-50.0, 0.0], [0.0, 0.0], [50.0, 0.0]])]
    assert signed_edge_distance(np.array([[3.0, 2.0], [3.0, -1.5], [0.0, 0.5]]), edge) == \
        pytest.approx([-2.0, 1.5, -0.5])
    # a 4 x 2 car heading +x drifts from y = 5 to y = -2 (1 m per step): its most off-road
    # corner is 1 m below its centre
    y = np.arange(5.0, -3.0, -1.0)[None]
    d = road_edge_distance(np.zeros_like(y), y, np.zeros_like(y), np.ones_like(y, bool),
                           np.array([4.0]), np.array([2.0]), edge)
    assert d[0] == pytest.approx(-(y[0] - 1.0))
    assert (d[0] > 0).tolist() == [False] * 5 + [True] * 3  # off road once y < 1


def test_edge_sign_outside_a_convex_and_a_concave_corner():
    # a road square [0, 10] x [0, 10] drawn counter-clockwise (road on the left, inside)
    square = [np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [0.0, 0.0]])]
    points = np.array([[11.0, -1.0], [9.0, 1.0], [5.0, 5.0], [-2.0, 5.0]])
    assert signed_edge_distance(points, square) == pytest.approx(
        [math.sqrt(2), -1.0, -5.0, 2.0])
    # the same square drawn clockwise is a hole (road outside): signs flip
    hole = [square[0][::-1]]
    assert signed_edge_distance(points, hole) == pytest.approx(
        [-math.sqrt(2), 1.0, 5.0, -2.0])


def test_no_edge_gives_nan():
    assert np.isnan(signed_edge_distance(np.zeros((2, 2)), [])).all()


def test_running_a_red_light():
    lane = [np.array([[0.0, 0.0], [50.0, 0.0]])]
    stop = np.array([[20.0, 0.0]])
    t = 21
    # along the lane at 1 m per step from x = 10: passes x = 20 between steps 9 and 10;
    # a car crossing the lane at x = 20 (heading +y) and one stopping at x = 19 do not run it
    x = np.array([10.0 + np.arange(t), np.full(t, 20.0), np.minimum(10.0 + np.arange(t),
                                                                   19.0)])
    y = np.array([np.zeros(t), -10.0 + np.arange(t), np.zeros(t)])
    h = np.array([np.zeros(t), np.full(t, math.pi / 2), np.zeros(t)])
    valid = np.ones((3, t), bool)
    red = np.ones((t, 1), bool)
    v = red_light_violations(x, y, h, valid, lane, [3.7], stop, red)
    assert np.flatnonzero(v[0]).tolist() == [10]
    assert not v[1:].any()
    green = red_light_violations(x, y, h, valid, lane, [3.7], stop, np.zeros((t, 1), bool))
    assert not green.any()
