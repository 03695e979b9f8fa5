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


# -- beyond the ends of the record (SPEC 7, issue 21) ----------------------------------------

def _road_paths(table):
    """Paths of a road_scene table: the ego's rows are the path."""
    ego = table["is_ego"].to_numpy()
    order = np.r_[np.flatnonzero(ego), np.flatnonzero(~ego)]
    t = table.iloc[order]
    track = pd_codes(t["track_id"])
    n_ego = int(ego.sum())
    return Paths(scene=np.zeros(len(t), np.int64), key=np.rint(t["t"].to_numpy() * 10)
                 .astype(np.int64), track=track, x=t["x"].to_numpy(), y=t["y"].to_numpy(),
                 heading=t["heading"].to_numpy(), speed=t["speed"].to_numpy(),
                 start=np.array([0]), stop=np.array([n_ego])), t


def pd_codes(values):
    import pandas as pd
    return pd.factorize(values)[0].astype(np.int64)


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("radius", [30.0, 60.0, 200.0, np.inf])
@pytest.mark.parametrize("speed", [5.0, 10.0, 20.0])
def test_a_car_stopped_beyond_either_end_of_the_record_lies_on_the_line(radius, side, speed):
    # the ego drives a curve of `radius` for up to 9.1 s (at most a third of its circle:
    # a path that comes back over itself has no single foot point); one car stands 25 m
    # beyond its last position along the road, one 25 m before its first: both on the line
    # (d ~ 0) at their distance along the road (s), as on a straight road
    from tap_bench.synthetic import road_scene
    n = int(min(91, 1 + 10 * radius * 2 * np.pi / 3 / speed))
    v = np.full(n, speed)
    travel = speed * (n - 1) / 10
    table = road_scene(radius, side, ego_speed=v,
                       others={"ahead": (travel + 25.0, np.zeros(n), 0.0),
                               "behind": (-25.0, np.zeros(n), 0.0)})
    paths, t = _road_paths(table)
    frame = path_frame(paths, ahead=200.0, behind=200.0, lateral=3.0)
    tracks = t["track_id"].to_numpy()
    for name, expect_s in (("ahead", lambda step: travel + 25.0 - speed * step / 10),
                           ("behind", lambda step: -25.0 - speed * step / 10)):
        mine = tracks[frame.other] == name
        step = frame.step[mine]
        # the arc beyond each end turns at most 90 degrees: within reach of that turn
        near = np.abs(expect_s(step)) <= min(60.0, radius * np.pi / 2)
        assert near.sum() >= 1, name
        assert np.abs(frame.d[mine][near]).max() < 0.25, name
        assert frame.s[mine][near] == pytest.approx(expect_s(step[near]), abs=0.3)


def test_the_line_goes_on_along_the_lane_of_a_map():
    # the road curves (60 m, left) for the record, then goes straight on: with the lane in a
    # map the line follows it; an arc of the last curvature would leave it
    from tap_bench.pathframe import LaneMap
    from tap_bench.synthetic import on_road, road_scene
    n = 61
    v = np.full(n, 10.0)
    travel = 60.0  # the record ends where the curve ends
    # the lane: the curve, then straight on along its end tangent
    arc = np.arange(0.0, travel + 0.01, 2.0)
    cx, cy, ch = on_road(arc, 60.0, 1)
    straight = np.arange(2.0, 80.0, 2.0)
    lx = np.r_[cx, cx[-1] + straight * np.cos(ch[-1])]
    ly = np.r_[cy, cy[-1] + straight * np.sin(ch[-1])]
    table = road_scene(60.0, 1, ego_speed=v)
    # a car stopped 40 m on along the straight
    car = dict(scenario_id="road", track_id="car", t=table["t"][:n].to_numpy(),
               x=np.full(n, cx[-1] + 40 * np.cos(ch[-1])),
               y=np.full(n, cy[-1] + 40 * np.sin(ch[-1])), heading=np.full(n, ch[-1]),
               speed=np.zeros(n), object_type="vehicle", is_ego=False)
    import pandas as pd
    table = pd.concat([table, pd.DataFrame(car)], ignore_index=True)
    paths, _ = _road_paths(table)
    lanes = LaneMap(scene=np.array([0]), start=np.array([0]), stop=np.array([len(lx)]),
                    x=lx, y=ly)
    on_lane = path_frame(paths, ahead=100.0, lateral=3.0, lanes=lanes)
    last = on_lane.step == n - 1
    assert on_lane.d[last] == pytest.approx(0.0, abs=0.1)
    assert on_lane.s[last] == pytest.approx(40.0, abs=0.2)
    # without the map the arc curves on to the left, and the car lies off the corridor
    arc_only = path_frame(paths, ahead=100.0, lateral=3.0)
    assert not np.any(arc_only.step == n - 1) or abs(arc_only.d[arc_only.step == n - 1][0]) > 1.8


def test_line_cells_of_many_scenes_and_paths_stay_in_order():
    """(cell, path) pairs sorted as one int64 key overflowed past 2^63 for a table of
    many scenes and paths (interactions='all' of 25,900 tracks in one call raised
    'repeats may not contain negative values'): the pairs of 5,000 lines in scenes 300-599 are
    those of the same lines 300 scenes lower (no overflow), their keys shifted by 300
    scenes."""
    from tap_bench.pathframe import _cell_key, _line_cells

    n = 5000
    ys = np.arange(n) * 100.0
    vx = np.tile([0.0, 50.0], n)
    vy = np.repeat(ys, 2)
    vs = np.tile([0.0, 50.0], n)
    first, count = np.arange(n) * 2, np.full(n, 2)
    lo, hi = np.zeros(n), np.full(n, 50.0)
    cell = 15.0
    scenes = np.arange(n) % 300
    low = _line_cells(vx, vy, vs, first, count, lo, hi, scenes, cell)
    high = _line_cells(vx, vy, vs, first, count, lo, hi, scenes + 300, cell)
    shift = _cell_key(300, 0, 0) - _cell_key(0, 0, 0)
    assert np.all(np.diff(high[0]) >= 0)
    assert np.array_equal(high[0] - shift, low[0])
    for a, b in zip(high[1:], low[1:], strict=True):
        assert np.array_equal(a, b)
    # the one-key order is the two-key order (lexsort, stable) where it does not overflow
    keys, paths = low[0], low[1]
    order = np.lexsort((paths, keys))
    assert np.array_equal(order, np.arange(len(keys)))
