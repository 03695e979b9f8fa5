"""Off-road from the road edges (SPEC section 8, issue 32): the signed distance of a box to
the drivable area, and ``tap_bench/womd-v0``'s off-road on generated scenes (kerbside
parking, a car between the last lane and the kerb, curve cutting, leaving across the kerb,
a scene without edges), each turned to every heading."""

from __future__ import annotations

import itertools
import math
import pickle
from pathlib import Path

import numpy as np
import pytest

from tap_bench.sim.policies import load_policy
from tap_bench.sim.road_edges import (
    JOIN_DISTANCE,
    LEAVE_MARGIN,
    OFF_ROAD_TOLERANCE,
    RoadEdges,
    box_corners,
    left_road,
)
from tap_bench.sim.womd_env import make_womd_env

T = np.arange(91) * 0.1
HEADINGS = [math.radians(10.0 + 45.0 * k) for k in range(8)]  # the whole scene turned


def turn(xy: np.ndarray, theta: float) -> np.ndarray:
    """Points (..., 2) turned by ``theta`` [rad] about the origin."""
    c, s = math.cos(theta), math.sin(theta)
    xy = np.asarray(xy, float)
    return np.stack([c * xy[..., 0] - s * xy[..., 1], s * xy[..., 0] + c * xy[..., 1]], -1)


# ------------------------------------------------------------------ geometry


@pytest.mark.parametrize("theta", HEADINGS)
def test_the_road_is_left_of_an_edge_and_the_distance_is_signed(theta):
    edges = RoadEdges.from_polylines([turn([[-50.0, 0.0], [0.0, 0.0], [50.0, 0.0]], theta)])
    points = turn([[10.0, 2.0], [10.0, -3.0], [-20.0, 0.5], [0.0, -1.0]], theta)
    np.testing.assert_allclose(edges.signed_distance(points), [-2.0, 3.0, -0.5, 1.0],
                               atol=1e-9)
    # nothing within reach: no answer (the lanes decide)
    assert np.isnan(edges.signed_distance(turn([[0.0, 40.0]], theta))[0])


@pytest.mark.parametrize("theta", HEADINGS)
def test_open_ends_and_gaps_are_road_joined_ends_are_not(theta):
    # a kerb with a 6 m driveway gap: both ends at the gap are open
    kerb = [turn([[-50.0, 0.0], [0.0, 0.0]], theta), turn([[6.0, 0.0], [50.0, 0.0]], theta)]
    edges = RoadEdges.from_polylines(kerb)
    driveway = turn([[3.0, -4.0], [1.0, -1.0]], theta)
    assert (edges.signed_distance(driveway) < 0).all()
    beside = turn([[-10.0, -2.0], [20.0, -2.0]], theta)  # behind the kerb, not in the gap
    np.testing.assert_allclose(edges.signed_distance(beside), [2.0, 2.0], atol=1e-9)
    # the same kerb drawn as two edges that meet: no gap, off the road behind the joint
    joined = RoadEdges.from_polylines([turn([[-50.0, 0.0], [0.0, 0.0]], theta),
                                       turn([[0.0, 0.0], [0.0, -30.0]], theta)])
    assert not joined.open_end[0] and not joined.open_start[1]
    assert joined.signed_distance(turn([[2.0, 1.0]], theta))[0] < 0  # inside the corner
    assert joined.signed_distance(turn([[-2.0, -2.0]], theta))[0] > 0  # behind both kerbs


@pytest.mark.parametrize("theta", HEADINGS)
def test_the_far_line_decides_at_a_corner(theta):
    # the road turns sharply left (135 deg): the road is the narrow wedge inside the corner
    edge = RoadEdges.from_polylines([turn([[-10.0, 0.0], [0.0, 0.0], [-7.0, 7.0]], theta)])
    outside, inside = turn([[0.5, 0.1]], theta), turn([[-1.0, 0.3]], theta)
    assert edge.signed_distance(outside)[0] == pytest.approx(math.hypot(0.5, 0.1))
    assert edge.signed_distance(inside)[0] < 0


@pytest.mark.parametrize("theta", HEADINGS)
def test_a_median_island_drawn_closed_is_off_the_road_inside(theta):
    square = [[0.0, 0.0], [0.0, 4.0], [20.0, 4.0], [20.0, 0.0], [0.0, 0.0]]  # clockwise
    island = RoadEdges.from_polylines([turn(square, theta)])
    assert not island.open_start.any() and not island.open_end.any()
    d = island.signed_distance(turn([[10.0, 2.0], [10.0, 6.0], [-3.0, 2.0]], theta))
    np.testing.assert_allclose(d, [2.0, -2.0, -3.0], atol=1e-9)


@pytest.mark.parametrize("theta", HEADINGS)
def test_a_box_is_off_the_road_when_a_corner_is(theta):
    edges = RoadEdges.from_polylines([turn([[-50.0, 0.0], [50.0, 0.0]], theta)])
    corners = box_corners(0.0, 0.0, 0.0, 4.0, 2.0)
    np.testing.assert_allclose(corners, [[2, 1], [-2, 1], [-2, -1], [2, -1]])

    def box(x: float, y: float, heading: float) -> float:
        p = turn([x, y], theta)
        return edges.box_distance(p[0], p[1], heading + theta, 4.6, 2.0)

    assert box(0.0, 1.2, 0.0) == pytest.approx(-0.2)  # parked at the kerb, 0.2 m off it
    assert box(0.0, 0.8, 0.0) == pytest.approx(0.2)  # a wheel on the kerb
    # nose out of a parking space: the front right corner 0.3 m over, the centre 2 m in
    heading = -math.atan2(2.3 + 0.3 - 1.0, 2.3)
    c = box_corners(0.0, 2.0, heading, 4.6, 2.0)
    assert box(0.0, 2.0, heading) == pytest.approx(-c[:, 1].min())


@pytest.mark.parametrize("theta", HEADINGS[:3])
def test_a_box_distance_is_its_largest_corner_distance_everywhere(theta):
    # a curved kerb with a driveway gap and a closed island: boxes of every size, heading
    # and place, near and beyond the edges' reach (NaN), against the definition
    arc = np.linspace(0.0, math.pi / 2, 40)
    kerb = turn(np.c_[30.0 * np.cos(arc), 30.0 * np.sin(arc)], theta)
    island = turn([[5.0, 5.0], [5.0, 9.0], [15.0, 9.0], [15.0, 5.0], [5.0, 5.0]], theta)
    far_kerb = turn([[-40.0, -5.0], [-10.0, -5.0]], theta)
    edges = RoadEdges.from_polylines([kerb, island, far_kerb])
    rng = np.random.default_rng(11)
    for _ in range(400):
        x, y = rng.uniform(-60.0, 60.0, 2)
        heading, length, width = rng.uniform(-4.0, 4.0), rng.uniform(0.5, 15.0), \
            rng.uniform(0.5, 3.0)
        got = edges.box_distance(x, y, heading, length, width)
        if np.isnan(edges.signed_distance([[x, y]])[0]):
            assert np.isnan(got)
            continue
        corners = box_corners(x, y, heading, length, width)
        want = np.max(edges.signed_distance(corners, 15.0 + math.hypot(length, width)))
        assert got == pytest.approx(want, abs=1e-12)

def test_leaving_the_road_is_judged_against_where_the_ego_started():
    tol, margin = OFF_ROAD_TOLERANCE, LEAVE_MARGIN
    assert not left_road(tol, -2.0) and left_road(tol + 0.01, -2.0)
    assert not left_road(float("nan"), -2.0)
    assert left_road(tol + 0.01, float("nan"))
    # the human parked 0.5 m over the kerb: a policy there is off only 1 m farther out
    assert not left_road(0.5 + margin, 0.5) and left_road(0.5 + margin + 0.01, 0.5)


# ------------------------------------------------------------------ generated scenes


def vehicle(xy: np.ndarray, theta: float, *, length: float = 4.6, width: float = 2.0,
            kind: str = "VEHICLE", valid: np.ndarray | None = None, facing: float = 0.0
            ) -> dict:
    """A ScenarioNet track along positions ``xy`` (91, 2) (headings and velocities from the
    path; ``facing`` [rad] where it stands still), the whole turned by ``theta``."""
    xy = turn(xy, theta)
    v = np.gradient(xy, T, axis=0)
    speed = np.hypot(v[:, 0], v[:, 1])
    heading = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    still = speed < 1e-6
    if still.any():  # a parked car keeps the heading it is given by its first two points
        heading[still] = theta + facing if not (~still).any() else heading[~still][0]
    return {"type": kind, "state": {
        "position": np.c_[xy, np.zeros(91)], "heading": heading, "velocity": v,
        "valid": np.ones(91, bool) if valid is None else valid,
        "length": np.full(91, length), "width": np.full(91, width)}}


def write_scene(path: Path, theta: float, tracks: dict, lanes: list, edges: list) -> str:
    """A ScenarioNet pickle of ``tracks`` (``"ego"`` the SDC), lane centre lines and road
    edges (``ROAD_EDGE_BOUNDARY``, the road on their left), turned by ``theta``."""
    features = {}
    for i, centre in enumerate(lanes):
        features[str(100 + i)] = {"type": "LANE_SURFACE_STREET", "entry_lanes": [],
                                  "exit_lanes": [], "polyline": turn(centre, theta)}
    for i, edge in enumerate(edges):
        features[str(500 + i)] = {"type": "ROAD_EDGE_BOUNDARY", "polyline": turn(edge, theta)}
    meta = {"scenario_id": path.stem, "ts": T, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "map_features": features, "dynamic_map_states": {},
                     "tracks": tracks}, f)
    return str(path)


def straight(y0: float, y1: float | None = None, speed: float = 8.0, x0: float = 0.0,
             turn_at: float = 6.0) -> np.ndarray:
    """(91, 2) along +x from (x0, y0) at ``speed``; moving to ``y1`` over the last
    ``8.0 - turn_at`` seconds when given."""
    x = x0 + speed * T
    y = np.full(91, y0)
    if y1 is not None:
        k = T > turn_at
        y[k] = y0 + (y1 - y0) * np.minimum((T[k] - turn_at) / (9.0 - turn_at), 1.0)
    return np.c_[x, y]


ROAD_LANES = [np.c_[np.linspace(-60, 200, 521), np.full(521, 5.5)],
              np.c_[np.linspace(-60, 200, 521), np.full(521, 9.2)]]
"""Two lanes along +x, 3.7 m wide; between the last lane (y 3.65) and the kerb (y 0): a
3.65 m parking strip."""
ROAD_EDGES = [np.c_[np.linspace(-60, 200, 261), np.zeros(261)],  # the kerb, road on its left
              np.c_[np.linspace(200, -60, 261), np.full(261, 11.1)]]


def drive(path: str, policy: str, traffic: str = "log"):
    env = make_womd_env(path, traffic=traffic)
    p = load_policy(policy)
    obs, _ = env.reset(seed=0)
    p.reset(env, seed=0)
    done = terminated = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(p.act(obs))
        done = terminated or truncated
    return env, env.episode_info(), terminated


@pytest.mark.parametrize("theta", HEADINGS)
@pytest.mark.parametrize("case", ["kerbside parking", "between the last lane and the kerb"])
def test_a_car_beside_the_kerb_is_on_the_road(tmp_path, theta, case):
    ego = straight(1.2, speed=0.0, x0=20.0) if case == "kerbside parking" else straight(2.0)
    path = write_scene(tmp_path / "kerb.pkl", theta, {"ego": vehicle(ego, theta)},
                       ROAD_LANES, ROAD_EDGES)
    env, human, _ = drive(path, "log")
    assert not human["off_road"] and human["off_road_rule"] == "road edge"
    assert human["max_off_road_distance_m"] < 0  # inside the kerb all along
    env, idm, terminated = drive(path, "idm")
    assert not idm["off_road"] and not terminated  # not ended at its first decision
    assert env.unwrapped.clock[0] == 90


def arc(radius: float, start: float, stop: float, n: int) -> np.ndarray:
    a = np.linspace(start, stop, n)
    return np.c_[radius * np.cos(a), radius * np.sin(a)]


@pytest.mark.parametrize("theta", HEADINGS)
def test_a_car_cutting_a_curve_inside_the_kerbs_is_on_the_road(tmp_path, theta):
    # a bend of radius 30 m (lane centre), kerbs at 25 and 35 m; the human keeps 3 m
    # inside the lane centre (1.15 m beyond the old rule's half width + 0.5 m)
    angle = 0.1 + 8.0 / 27.0 * T
    ego = np.c_[27.0 * np.cos(angle), 27.0 * np.sin(angle)]
    lanes = [arc(30.0, -0.6, 3.6, 300)]
    edges = [arc(25.0, 3.6, -0.6, 300), arc(35.0, -0.6, 3.6, 300)]  # road on their left
    path = write_scene(tmp_path / "curve.pkl", theta, {"ego": vehicle(ego, theta)}, lanes,
                       edges)
    _, human, _ = drive(path, "log")
    assert not human["off_road"] and human["off_road_rule"] == "road edge"
    assert -1.5 < human["max_off_road_distance_m"] < -0.5  # ~1 m inside the inner kerb


@pytest.mark.parametrize("theta", HEADINGS)
def test_a_car_that_crosses_the_kerb_leaves_the_road(tmp_path, theta):
    ego = straight(5.5, -4.0, turn_at=7.0)  # from its lane over the kerb in its last 2 s
    path = write_scene(tmp_path / "leave.pkl", theta, {"ego": vehicle(ego, theta)},
                       ROAD_LANES, ROAD_EDGES)
    _, human, _ = drive(path, "log")
    assert human["off_road"] and human["off_road_rule"] == "road edge"
    assert human["max_off_road_distance_m"] > 3.0


@pytest.mark.parametrize("theta", HEADINGS)
def test_without_edges_the_lanes_decide_and_say_so(tmp_path, theta):
    beside = write_scene(tmp_path / "beside.pkl", theta, {"ego": vehicle(straight(2.0), theta)},
                         ROAD_LANES, [])
    _, human, _ = drive(beside, "log")
    # 3.5 m from the lane centre from the start: off by the lane rule, but the start is
    # the human's, and nobody is judged for it
    assert human["off_road_rule"] == "lane centre"
    assert human["max_off_road_distance_m"] > 0 and not human["off_road"]
    _, idm, terminated = drive(beside, "idm")
    assert not terminated and not idm["off_road"]
    away = write_scene(tmp_path / "away.pkl", theta,
                       {"ego": vehicle(straight(5.5, -6.0, turn_at=7.0), theta)},
                       ROAD_LANES, [])
    _, human, _ = drive(away, "log")
    assert human["off_road"] and human["off_road_rule"] == "lane centre"


def _edges_one_by_one(lines):
    """RoadEdges of polylines cleaned one polyline at a time (the definition)."""
    polys = []
    for line in lines:
        p = np.asarray(line, float)[:, :2]
        p = p[np.isfinite(p).all(axis=1)]
        if len(p) >= 2:
            p = p[np.r_[True, np.hypot(*np.diff(p, axis=0).T) > 1e-6]]
        if len(p) >= 2:
            polys.append(p)
    if not polys:
        return None
    a = np.concatenate([p[:-1] for p in polys])
    b = np.concatenate([p[1:] for p in polys])
    owner = np.concatenate([np.full(len(p) - 1, i) for i, p in enumerate(polys)])
    first = np.r_[0, np.cumsum([len(p) - 1 for p in polys])[:-1]]
    last = np.cumsum([len(p) - 1 for p in polys]) - 1
    open_start, open_end = np.zeros(len(a), bool), np.zeros(len(a), bool)
    for i, p in enumerate(polys):
        if np.hypot(*(p[0] - p[-1])) <= JOIN_DISTANCE:
            continue
        others = [q for j, q in enumerate(polys) if j != i]
        for end, flags, at in ((p[0], open_start, first[i]), (p[-1], open_end, last[i])):
            near = min((_segment_distance(end, q) for q in others), default=np.inf)
            if not near <= JOIN_DISTANCE:
                flags[at] = True
    return a, b, owner, open_start, open_end


def _segment_distance(point, line):
    """Distance [m] from a point to a polyline (n, 2), segment by segment."""
    best = np.inf
    for p, q in itertools.pairwise(line):
        d = q - p
        u = min(max(np.dot(point - p, d) / np.dot(d, d), 0.0), 1.0)
        best = min(best, float(np.hypot(*(point - p - u * d))))
    return best


@pytest.mark.parametrize("seed", range(5))
def test_edges_of_many_polylines_equal_each_polyline_cleaned_alone(seed):
    """Edge polylines cleaned together: NaN points, points repeated (in a row, and the
    next polyline starting on the last point of the one before), polylines of one point
    or of one repeated point, closed islands, ends that meet another polyline within 1 m
    and ends that do not."""
    rng = np.random.default_rng(seed)
    lines = []
    for k in range(48):
        kind = k % 8
        n = int(rng.integers(2, 15))  # each polyline in its own place, 300 m apart
        line = np.array([300.0 * k, 0.0]) + np.cumsum(rng.normal(0, 4, (n, 2)), axis=0)
        if kind == 1:  # NaN points
            line[rng.integers(0, n, 2)] = np.nan
        elif kind == 2:  # repeated points (exactly, and within 1e-6 m)
            line = np.repeat(line, rng.integers(1, 3, n), axis=0)
            line[1] = line[0] + 3e-7
        elif kind == 3:  # one point, or one point again and again
            line = np.repeat(line[:1], int(rng.integers(1, 4)), axis=0)
        elif kind == 4:  # closed: an island
            line = np.vstack([line, line[:1]])
        elif kind == 6:  # starts 0.5 m from where the one before ends
            line = np.vstack([lines[-1][-1] + [0.3, 0.4], line + lines[-1][-1] - line[0]])
        elif kind == 7:  # starts exactly where the one before ends
            line = np.vstack([lines[-1][-1], line + lines[-1][-1] - line[0] + 1.0])
        lines.append(line)
    lines.append(np.zeros((0, 2)))
    lines.append(np.c_[lines[0], np.ones(len(lines[0]))])  # a z column, left out
    edges = RoadEdges.from_polylines(lines)
    a, b, owner, open_start, open_end = _edges_one_by_one(lines)
    assert np.array_equal(edges.a, a) and np.array_equal(edges.b, b)
    assert np.array_equal(edges.owner, owner)
    assert np.array_equal(edges.open_start, open_start)
    assert np.array_equal(edges.open_end, open_end)
    assert open_start.any() and not open_start.all()
    assert len(RoadEdges.from_polylines([np.full((3, 2), np.nan), np.ones((2, 2))])) == 0


def grid_by_sorting(a: np.ndarray, b: np.ndarray) -> tuple:
    """The edge grid as numpy built it before the counting sort (every (segment, cell) entry
    listed, sorted stably by cell, each cell's start found by searchsorted)."""
    from tap_bench.sim.road_edges import EDGE_CELL

    lo_xy, hi_xy = np.minimum(a, b), np.maximum(a, b)
    lo = lo_xy.min(axis=0) - EDGE_CELL
    lo_cell = np.floor((lo_xy - lo) / EDGE_CELL).astype(np.int64)
    hi_cell = np.floor((hi_xy - lo) / EDGE_CELL).astype(np.int64)
    nx, ny = int(hi_cell[:, 0].max()) + 2, int(hi_cell[:, 1].max()) + 2
    span = hi_cell - lo_cell + 1
    count = span[:, 0] * span[:, 1]
    seg = np.repeat(np.arange(len(a)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    cell = ((lo_cell[seg, 0] + local // span[seg, 1]) * ny + lo_cell[seg, 1]
            + local % span[seg, 1])
    order = np.argsort(cell, kind="stable")
    start = np.searchsorted(cell[order], np.arange(nx * ny + 1)).astype(np.int64)
    return (start, seg[order].astype(np.int64), lo.astype(float), nx, ny)


@pytest.mark.parametrize("seed", range(3))
def test_the_edge_grid_is_the_sorted_one(seed):
    """The grid's buckets (a counting sort) are those of sorting every (segment, cell) pair
    by cell: the same offsets and segment ids, ids in order within a cell; segments long
    and short, on cell lines, of one point, one segment alone."""
    from tap_bench.sim.road_edges import EDGE_CELL, _build_grid

    rng = np.random.default_rng(seed)
    for m in (1, 2, 7, 300):
        a = rng.uniform(-200.0, 200.0, (m, 2))
        b = a + rng.normal(0.0, rng.choice([0.5, 5.0, 40.0]), (m, 2))
        snap = rng.random(m) < 0.2
        a[snap] = np.round(a[snap] / EDGE_CELL) * EDGE_CELL  # on the cell lines
        point = rng.random(m) < 0.1
        b[point] = a[point]  # a segment of one point
        got, want = _build_grid(a, b), grid_by_sorting(a, b)
        assert got[0].dtype == want[0].dtype and got[1].dtype == want[1].dtype
        assert got[0].tolist() == want[0].tolist()
        assert got[1].tolist() == want[1].tolist()
        assert got[2].tobytes() == want[2].tobytes() and got[3:] == want[3:]


@pytest.mark.parametrize("seed", range(3))
def test_the_grid_search_finds_what_every_segment_measured_finds(seed):
    """The nearest-edge search over the grid (rings of cells, segments whose bounding box
    is farther than the nearest found skipped) gives each point the signed distance of
    measuring every segment: the nearest, ties at a shared vertex to the line the point is
    farthest from, open ends beyond them road; NaN beyond the reach. Points on, beside and
    far from wiggly polylines, closed and open, in dense and sparse places."""
    rng = np.random.default_rng(seed)
    lines = []
    for k in range(12):
        n = int(rng.integers(2, 40))
        step = rng.normal(0.0, rng.choice([0.3, 2.0, 8.0]), (n, 2))
        line = rng.uniform(-60.0, 60.0, 2) + np.cumsum(step, axis=0)
        if k % 4 == 0:
            line = np.vstack([line, line[:1]])  # closed
        lines.append(line)
    edges = RoadEdges.from_polylines(lines)
    points = np.vstack([rng.uniform(-90.0, 90.0, (150, 2)),
                        edges.a[:40] + rng.normal(0.0, 0.05, (40, 2)),  # near vertices
                        edges.a[:15]])  # on them
    a, d = edges.a, edges.b - edges.a
    n2 = np.maximum((d * d).sum(axis=1), 1e-12)
    nearest = []  # (distance, signed distance) by measuring every segment
    for p in points:
        u = ((p - a) * d).sum(axis=1) / n2
        dist = np.hypot(*(p - a - np.clip(u, 0.0, 1.0)[:, None] * d).T)
        cross = (d[:, 0] * (p[1] - a[:, 1]) - d[:, 1] * (p[0] - a[:, 0])) / np.sqrt(n2)
        best, pick = np.inf, -1
        for k in np.flatnonzero(dist <= dist.min() + 1e-6):  # the rest never decide
            if dist[k] < best - 1e-9 or (dist[k] <= best + 1e-9
                                         and abs(cross[k]) > abs(cross[pick])):
                best, pick = min(dist[k], best), k
        beyond = ((edges.open_start[pick] and u[pick] < 0)
                  or (edges.open_end[pick] and u[pick] > 1))
        nearest.append((best, best if cross[pick] < 0 and not beyond else -best))
    for reach in (3.0, 15.0, 500.0):
        want = np.array([s if b <= reach else np.nan for b, s in nearest])
        got = edges.signed_distance(points, reach)
        assert np.allclose(got, want, rtol=0, atol=1e-9, equal_nan=True)
        assert np.isnan(got).any() == (reach < 100)
