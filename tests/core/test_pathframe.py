"""The path frame (SPEC 7) on hand-built geometry: straight road, circle, path ends."""

from __future__ import annotations

import numpy as np
import pytest

from tap_bench.pathframe import Paths, path_frame

N = 50  # 5 s at 10 Hz
T = np.arange(N) / 10


def on_circle(track: int, radius: float, phase: float, speed: float, centre_radius=None):
    """A vehicle driving counter-clockwise on a circle about the origin."""
    centre_radius = centre_radius or radius
    angle = phase + speed / centre_radius * T  # same angular speed as the lane it follows
    return dict(track=np.full(N, track), x=radius * np.cos(angle), y=radius * np.sin(angle),
                heading=angle + np.pi / 2, speed=np.full(N, speed * radius / centre_radius),
                key=np.arange(N))


def straight(track: int, x0: float, y: float, speed: float):
    return dict(track=np.full(N, track), x=x0 + speed * T, y=np.full(N, y),
                heading=np.zeros(N), speed=np.full(N, speed), key=np.arange(N))


def scene(*tracks) -> Paths:
    cat = {k: np.concatenate([t[k] for t in tracks]) for k in tracks[0]}
    return Paths(scene=np.zeros(len(cat["key"]), np.int64), key=cat["key"],
                 track=cat["track"], x=cat["x"], y=cat["y"], heading=cat["heading"],
                 speed=cat["speed"], start=np.array([0]), stop=np.array([N]))


def of_track(frame, paths, track):
    mine = paths.track[frame.other] == track
    return frame.step[mine], frame.s[mine], frame.d[mine], frame.heading_rel[mine]


def test_circle_leader_ahead_on_the_arc_and_inner_lane_beside():
    R = 30.0
    paths = scene(on_circle(0, R, 0.0, 10.0),  # the ego
                  on_circle(1, R, 20 / R, 10.0),  # 20 m ahead on the arc
                  on_circle(2, R - 4, 0.3, 10.0, centre_radius=R),  # inner lane, 9 m ahead
                  on_circle(3, R, -10 / R, 10.0))  # 10 m behind
    frame = path_frame(paths)
    # while the leader is on the recorded path (the ego drives 49 m): s = 20, d = 0
    step, s, d, rel = of_track(frame, paths, 1)
    on_path = step <= 25
    assert s[on_path] == pytest.approx(20.0, abs=0.05)
    assert np.abs(d[on_path]).max() < 0.05
    assert np.abs(rel[on_path]).max() < 0.05
    # the inner lane is 4 m to the left of the ego's path, never in a 1.8 m corridor
    step, s, d, _ = of_track(frame, paths, 2)
    assert d[step <= 40] == pytest.approx(4.0, abs=0.1)
    assert s[0] == pytest.approx(0.3 * R, abs=0.3)
    # behind on the arc: negative s (on the back extension the chord departs from the arc)
    step, s, d, _ = of_track(frame, paths, 3)
    assert s[step >= 10] == pytest.approx(-10.0, abs=0.05)


def test_straight_road_lanes_and_sides():
    paths = scene(straight(0, 0, 0, 20), straight(1, 30, 0, 15), straight(2, 10, 4, 20),
                  straight(3, -5, -4, 25))
    frame = path_frame(paths, lateral=10)
    step, s, d, _ = of_track(frame, paths, 1)
    assert s == pytest.approx(30 - 5 * T[step])
    assert d == pytest.approx(0.0)
    _, s, d, _ = of_track(frame, paths, 2)
    assert s == pytest.approx(10.0) and d == pytest.approx(4.0)  # left is positive
    step, s, d, _ = of_track(frame, paths, 3)
    assert d == pytest.approx(-4.0)
    assert s == pytest.approx(-5 + 5 * T[step])  # it passes the ego: s goes - to +


def test_reach_prunes_and_own_track_is_never_an_other():
    paths = scene(straight(0, 0, 0, 20), straight(1, 150, 0, 20), straight(2, 5, 30, 20))
    frame = path_frame(paths, ahead=100, behind=30, lateral=10)
    assert len(frame) == 0  # 150 m ahead, 30 m to the side: both out of reach
    assert not np.any(paths.track[frame.other] == 0)


def test_stationary_ego_gets_a_line_along_its_heading():
    ego = straight(0, 0, 0, 0)
    ego["heading"] = np.full(N, np.pi / 2)  # facing +y
    paths = scene(ego, straight(1, 1.0, 12.0, 0))
    frame = path_frame(paths)
    _, s, d, _ = of_track(frame, paths, 1)
    assert s == pytest.approx(12.0) and d == pytest.approx(-1.0)  # +x is to the right


def test_bad_distances_are_refused():
    with pytest.raises(ValueError, match="ahead"):
        path_frame(scene(straight(0, 0, 0, 20)), ahead=-1)
