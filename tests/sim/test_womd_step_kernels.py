"""The compiled pieces of the WOMD closed-loop step equal their plain definitions (numpy or
one point at a time, as the step computed them before) on generated inputs: lanes straight
and curved at every heading, movers ahead, behind, beside and across, at the kerb, far."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tap_bench.sim.traffic import near_pairs_of, shapes_of, swept_apart
from tap_bench.sim.womd_lanes import FastPolyLane, LaneIndex
from tap_bench.sim.womd_road import (
    CONFLICT_LOOKAHEAD,
    CORRIDOR_MARGIN,
    LEADER_LOOKAHEAD,
    PATH_MARGIN,
    WALKER_ALONG,
    WALKER_CLEARANCE,
    WALKER_LOOKAHEAD,
    WALKER_STILL,
    _ahead_in_one,
    _any_within,
    _approach_rows,
    _conflict_gap_on,
    _corridor,
    _front_rear,
    _lane_members,
    _lane_members_into,
    _lane_members_near,
    _Layout,
    _leader_ahead_on,
    _leader_on,
    _member_limit,
    _Movers,
    _movers_into,
    _movers_now,
    _pairs_of_movers,
    _pairs_packed,
    _pairs_to_check,
    _walkers_on_lane,
)


def lane(rng: np.random.Generator) -> FastPolyLane:
    """A lane 5-120 m long, straight or bending either way (up to 180 deg), any heading,
    anywhere."""
    n = int(rng.integers(2, 40))
    length = rng.uniform(5.0, 120.0)
    turn = rng.choice([0.0, rng.uniform(-math.pi, math.pi)])
    a = rng.uniform(0.0, 2 * math.pi) + np.linspace(0.0, turn, n)
    step = length / (n - 1) if n > 1 else length
    xy = np.cumsum(np.c_[step * np.cos(a), step * np.sin(a)], axis=0) + rng.uniform(-500, 500, 2)
    return FastPolyLane(xy, rng.uniform(2.5, 4.5))


def movers(rng: np.random.Generator, around: np.ndarray, m: int) -> tuple[np.ndarray, ...]:
    """m movers near points of ``around`` (n, 2): on it, beside, far; any heading; some
    standing."""
    at = around[rng.integers(len(around), size=m)]
    spread = rng.choice([0.0, 1.0, 3.0, 30.0], size=m)
    xy = at + rng.normal(0.0, 1.0, (m, 2)) * spread[:, None]
    heading = rng.uniform(-math.pi, math.pi, m)
    speed = np.where(rng.random(m) < 0.3, 0.0, rng.uniform(0.0, 15.0, m))
    speed[rng.random(m) < 0.2] = WALKER_STILL  # the boundary of standing
    length = rng.choice([0.5, 4.5, 12.0], size=m)
    width = np.where(length < 1.0, 0.5, rng.uniform(1.8, 2.6, m))
    return xy, heading, speed, length, width


def centre(ln: FastPolyLane) -> np.ndarray:
    px, py, *_ = ln.arrays
    return np.c_[px, py]


@pytest.mark.parametrize("seed", range(4))
def test_lane_members_are_highway_envs_on_lane_point_by_point(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        ln = lane(rng)
        xy, *_ = movers(rng, centre(ln), int(rng.integers(1, 60)))
        half, lo, hi = ln.width / 2 + 1.0, -ln.VEHICLE_LENGTH, ln.length + ln.VEHICLE_LENGTH
        members, lon = _lane_members(*ln.arrays, half, lo, hi, np.ascontiguousarray(xy[:, 0]),
                                     np.ascontiguousarray(xy[:, 1]))
        want = []
        for i, p in enumerate(xy):
            s, d = ln.local_coordinates(p)
            assert lon[i] == s
            if ln.on_lane(p, s, d, margin=1):
                want.append(i)
        assert members.tolist() == want


@pytest.mark.parametrize("seed", range(4))
def test_lane_members_with_the_lanes_bound_are_the_members_found_afresh(seed):
    """_lane_members_near (the give-way pass's tables) leaves out the movers whose lower
    bound of the lane distance (the lane index's box and wedge) is beyond what a member can
    have, and finds the same members with the same longitudinal coordinates as
    _lane_members: lanes of every shape built together (one set of pose arrays, as a
    network's), movers on, beside, at the ends, far, without a position."""
    rng = np.random.default_rng(90 + seed)
    left_out = kept = 0
    for _ in range(30):
        lanes = [lane(rng) for _ in range(int(rng.integers(1, 6)))]
        built = FastPolyLane.many([centre(ln) for ln in lanes], [ln.width for ln in lanes],
                                  womd_ids=list(range(len(lanes))),
                                  speed_limits=[20.0] * len(lanes),
                                  line_types=[None] * len(lanes))
        index = LaneIndex([((str(j), f"{j}>", 0), ln) for j, ln in enumerate(built)])
        for j, ln in enumerate(built):
            a, b = int(index.offsets[j]), int(index.offsets[j + 1])
            poses = [x[a:b] for x in (index.px, index.py, index.tx, index.ty, index.s)]
            half, lo, hi = (ln.width / 2 + 1.0, -ln.VEHICLE_LENGTH,
                            ln.length + ln.VEHICLE_LENGTH)
            xy, *_ = movers(rng, centre(ln), int(rng.integers(1, 60)))
            # some exactly at the edges of membership: half across, at lo and at hi
            edge = rng.random(len(xy)) < 0.2
            at = rng.uniform(lo, hi, len(xy))
            pick = rng.random(len(xy)) < 0.3
            at[pick] = rng.choice([lo, hi], int(pick.sum()))
            for i in np.flatnonzero(edge):
                p = ln.position(float(at[i]), float(rng.choice([-half, half])))
                xy[i] = p
            xy[rng.random(len(xy)) < 0.05] = np.nan
            xs, ys = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
            bound = np.array([*index.boxes[j, :7], index.reach[j],
                              _member_limit(half, lo, hi, float(index.lengths[j]))])
            want, lon_all = _lane_members(*poses, half, lo, hi, xs, ys)
            got, lon = _lane_members_near(*poses, half, lo, hi, xs, ys, bound)
            assert got.tolist() == want.tolist()
            assert lon[got].tolist() == lon_all[want].tolist()
            far = np.isnan(lon) & ~np.isnan(xs)
            left_out += int(far.sum())
            kept += int((~np.isnan(lon)).sum())
    assert left_out > 100 and kept > 100, (left_out, kept)


def corridor_plain(positions, boxes, x, y, heading, length, width, reach, mine):
    """The corridor's definition in numpy (every mover at once)."""
    c, s_ = math.cos(heading), math.sin(heading)
    d = positions - np.array([x, y])
    lon = d[:, 0] * c + d[:, 1] * s_
    lat = -d[:, 0] * s_ + d[:, 1] * c
    hs, vs, ls, ws = boxes.T
    dh = hs - heading
    along = np.abs(np.cos(dh)) * ls / 2 + np.abs(np.sin(dh)) * ws / 2
    across = np.abs(np.sin(dh)) * ls / 2 + np.abs(np.cos(dh)) * ws / 2
    gap = lon - length / 2 - along
    inside = (np.abs(lat) < width / 2 + across + CORRIDOR_MARGIN) & (lon > 0) \
        & (gap < reach) & (gap > -along)
    if mine >= 0:
        inside[mine] = False
    if not inside.any():
        return None
    k = int(np.flatnonzero(inside)[np.argmin(gap[inside])])
    return k, float(gap[k]), float(vs[k] * math.cos(dh[k]))


@pytest.mark.parametrize("seed", range(4))
def test_corridor_is_its_numpy_definition(seed):
    rng = np.random.default_rng(10 + seed)
    found = 0
    for _ in range(300):
        x, y = rng.uniform(-500, 500, 2)
        heading = rng.uniform(-math.pi, math.pi)
        ahead = np.array([x, y]) + np.outer(np.linspace(-10, 40, 30),
                                            [math.cos(heading), math.sin(heading)])
        m = int(rng.integers(1, 40))
        xy, hs, vs, ls, ws = movers(rng, ahead, m)
        if rng.random() < 0.2:  # two at the same gap: the first one
            xy[-1], hs[-1], ls[-1], ws[-1] = xy[0], hs[0], ls[0], ws[0]
        boxes = np.c_[hs, vs, ls, ws]
        mine = int(rng.integers(-1, m))
        length, width = rng.uniform(3.5, 5.5), rng.uniform(1.7, 2.2)
        reach = 6.0 + 1.5 * rng.uniform(0.0, 20.0)
        want = corridor_plain(xy, boxes, x, y, heading, length, width, reach, mine)
        k, gap, speed = _corridor(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
                                  hs, vs, ls, ws, x, y, heading, length, width, reach, mine)
        assert (None if k < 0 else (k, gap, speed)) == want
        found += want is not None
    assert found > 50


def walkers_plain(ln, headings_at, base, half, xs, ys, hs, vs):
    """The walker search's definition on one lane (numpy, then one by one)."""
    lon, lat = ln.project(xs, ys)
    d = base + lon
    near = (np.abs(lat) <= half) & (lon >= 0) & (lon <= ln.length) & (d > 0) \
        & (d <= WALKER_LOOKAHEAD)
    best = None
    for i in np.flatnonzero(near):
        along = abs(math.cos(hs[i] - headings_at(lon[i])))
        if vs[i] >= WALKER_STILL and along > WALKER_ALONG:
            continue
        best = d[i] if best is None else min(best, float(d[i]))
    return best


@pytest.mark.parametrize("seed", range(4))
def test_walkers_on_a_lane_are_their_definition(seed):
    rng = np.random.default_rng(20 + seed)
    found = 0
    for _ in range(200):
        ln = lane(rng)
        xy, hs, vs, *_ = movers(rng, centre(ln), int(rng.integers(1, 20)))
        # some walk along the lane, some across, some stand
        _, _, tx, ty, _ = ln.arrays
        along = rng.random(len(hs)) < 0.4
        hs[along] = np.arctan2(ty[0], tx[0]) + rng.choice([0.0, math.pi], along.sum())
        base = rng.uniform(-20.0, 40.0)
        half = rng.uniform(1.5, 2.5)
        xs, ys = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
        want = walkers_plain(ln, ln.heading_at, base, half, xs, ys, hs, vs)
        got = _walkers_on_lane(*ln.arrays, np.arctan2(ty, tx), base, half, ln.length, xs, ys,
                               hs, vs, math.nan)
        assert (None if math.isnan(got) else got) == want
        found += want is not None
    assert found > 20


@pytest.mark.parametrize("seed", range(4))
def test_pairs_to_check_are_the_near_pairs_and_the_swept_apart_ones(seed):
    # boxes in a crowd, touching, overlapping, far; any heading and speed; few or many
    # checking collisions; some with their own test; a NaN position now and then
    rng = np.random.default_rng(30 + seed)
    for _ in range(60):
        m = int(rng.integers(2, 200))
        xy = rng.uniform(-1.0, 1.0, (m, 2)) * rng.choice([5.0, 30.0, 300.0])
        length, width = rng.uniform(0.5, 12.0, m), rng.uniform(0.5, 2.6, m)
        heading = rng.uniform(-math.pi, math.pi, m)
        speed = np.where(rng.random(m) < 0.3, 0.0, rng.uniform(0.0, 30.0, m))
        checks = rng.random(m) < rng.choice([0.02, 0.3, 1.0])
        own = rng.random(m) < 0.02
        if rng.random() < 0.1:
            xy[int(rng.integers(m))] = np.nan
        diagonal = np.hypot(length, width)
        shapes = shapes_of(xy, diagonal, length, width, heading, speed, checks, own)
        near = near_pairs_of(shapes, m, 0.1)
        i, j = np.nonzero(np.triu(near | near.T, 1))
        first, second, apart = _pairs_to_check(
            np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), diagonal, length,
            width, heading, speed, checks, own, 0.1)
        np.testing.assert_array_equal(first, i)
        np.testing.assert_array_equal(second, j)
        np.testing.assert_array_equal(apart, swept_apart(shapes, i, j, 0.1))


def approaching_plain(ln, members, lon, hs, ls, walker, s_point, offset, width, mine, seen):
    """Movers approaching a point along a lane, one by one (the definition)."""
    out = []
    for i in members:
        if i == mine or i in seen or walker[i]:
            continue
        d = s_point + offset - lon[i]
        if d < -(ls[i] + width) or d > CONFLICT_LOOKAHEAD * 2:
            continue
        if math.cos(hs[i] - ln.heading_at(lon[i])) < 0.5:
            continue
        seen.add(i)
        out.append((i, d))
    return out


@pytest.mark.parametrize("seed", range(4))
def test_movers_approaching_a_conflict_are_their_definition(seed):
    # lanes bending either way at every heading; movers along the lane, against it, across,
    # walkers, one already seen on an earlier lane, the vehicle itself
    rng = np.random.default_rng(40 + seed)
    found = 0
    for _ in range(100):
        ln = lane(rng)
        xy, hs, _, ls, _ = movers(rng, centre(ln), int(rng.integers(1, 50)))
        _, _, tx, ty, s = ln.arrays
        headings = np.arctan2(ty, tx)
        along = rng.random(len(hs)) < 0.5
        hs[along] = headings[rng.integers(len(headings), size=along.sum())] \
            + rng.normal(0.0, 0.3, along.sum())
        xs, ys = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
        members, lon = _lane_members(*ln.arrays, ln.width / 2 + 1.0, -ln.VEHICLE_LENGTH,
                                     ln.length + ln.VEHICLE_LENGTH, xs, ys)
        walker = rng.random(len(hs)) < 0.1
        m = len(hs)
        mine = int(rng.integers(-1, m))
        seen = np.zeros(m, bool)
        seen[rng.random(m) < 0.1] = True
        s_point, offset = rng.uniform(0.0, ln.length), rng.choice([0.0, rng.uniform(5, 60)])
        width = rng.uniform(1.7, 2.2)
        want = approaching_plain(ln, members.tolist(), lon, hs, ls, walker, s_point, offset,
                                 width, mine, set(np.flatnonzero(seen).tolist()))
        rows, dist = _approach_rows(members, lon, hs, ls, walker, s, headings, s_point,
                                    offset, width, mine, seen)
        assert list(zip(rows.tolist(), dist.tolist(), strict=True)) == want
        assert set(rows.tolist()) <= set(np.flatnonzero(seen).tolist())  # marked seen
        found += len(want)
    assert found > 100


def road_columns(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """A road's n vehicles as the step lays them out: some not collidable, speeds that are
    negative, -0.0 or NaN among them."""
    xy = rng.uniform(-50.0, 50.0, (n, 2))
    speed = rng.choice([-1.0, -0.0, 0.0, np.nan, 3.0, 12.0], size=n)
    length = rng.choice([0.5, 4.5, 12.0], size=n)
    return {"collidable": rng.random(n) < 0.7, "position": xy,
            "heading": rng.uniform(-math.pi, math.pi, n), "speed": speed, "length": length,
            "width": np.where(length < 1.0, 0.5, 2.0), "walker": rng.random(n) < 0.2,
            "path": rng.random(n) < 0.3, "diagonal": np.hypot(length, 2.0),
            "checks": rng.random(n) < 0.3, "own": rng.random(n) < 0.1}


@pytest.mark.parametrize("seed", range(4))
def test_movers_now_are_the_collidable_rows_columns(seed):
    """The act's movers in one pass: the rows, columns and margins numpy took one by one
    (speed as np.maximum(speed, 0): NaN kept, -0.0 kept, negatives 0)."""
    rng = np.random.default_rng(seed)
    c = road_columns(rng, int(rng.integers(0, 30)))
    (rows, xy, xs, ys, heading, speed, length, width, boxes, walker, path, margins,
     walkers) = _movers_now(c["collidable"], c["position"], c["heading"], c["speed"],
                            c["length"], c["width"], c["walker"], c["path"],
                            WALKER_CLEARANCE, PATH_MARGIN)
    want = np.flatnonzero(c["collidable"])
    assert rows.tolist() == want.tolist()
    columns = (c["heading"][want], np.maximum(c["speed"][want], 0.0), c["length"][want],
               c["width"][want])
    for got, expected in ((xy, c["position"][want]), (xs, c["position"][want, 0]),
                          (ys, c["position"][want, 1]), (heading, columns[0]),
                          (speed, columns[1]), (length, columns[2]), (width, columns[3]),
                          (boxes, np.stack(columns, axis=1)), (walker, c["walker"][want]),
                          (path, c["path"][want]),
                          (margins, np.where(c["walker"][want], WALKER_CLEARANCE,
                                             PATH_MARGIN))):
        assert got.dtype == expected.dtype and got.shape == expected.shape
        assert got.tobytes() == expected.tobytes()  # copies and comparisons: exact
    assert walkers == int(c["walker"][want].sum())


@pytest.mark.parametrize("seed", range(4))
def test_pairs_of_movers_are_the_pairs_of_their_columns(seed):
    """The road step's pairs in one pass: the collidable rows, and _pairs_to_check of their
    columns taken by numpy."""
    rng = np.random.default_rng(seed)
    c = road_columns(rng, int(rng.integers(0, 30)))
    rows, first, second, apart = _pairs_of_movers(
        c["collidable"], c["position"], c["diagonal"], c["length"], c["width"], c["heading"],
        c["speed"], c["checks"], c["own"], 0.1)
    m = np.flatnonzero(c["collidable"])
    want = _pairs_to_check(c["position"][m, 0].copy(), c["position"][m, 1].copy(),
                           c["diagonal"][m], c["length"][m], c["width"][m], c["heading"][m],
                           c["speed"][m], c["checks"][m], c["own"][m], 0.1)
    assert rows.tolist() == m.tolist()
    for got, expected in zip((first, second, apart), want, strict=True):
        assert got.tolist() == expected.tolist()


def lane_table(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(members: sorted rows of n movers, lon: every mover's coordinate [m]) with ties,
    -0.0 beside 0.0, NaN, and sometimes no member."""
    lon = rng.uniform(-20.0, 80.0, n)
    special = rng.random(n) < 0.45
    lon[special] = rng.choice([0.0, -0.0, 5.0, 5.0, np.nan], size=int(special.sum()))
    members = np.flatnonzero(rng.random(n) < rng.choice([0.0, 0.5, 1.0]))
    return members.astype(np.int64), lon


def front_rear_plain(members, lon, s, mine):
    """:meth:`WomdRoad.neighbour_vehicles`' search as it was written over a list."""
    front = rear = None
    s_front = s_rear = None
    for i in members.tolist():
        if i == mine:
            continue
        sv = lon[i]
        if s <= sv and (s_front is None or sv <= s_front):
            s_front, front = sv, i
        if sv < s and (s_rear is None or sv > s_rear):
            s_rear, rear = sv, i
    return (-1 if front is None else front), (-1 if rear is None else rear)


@pytest.mark.parametrize("seed", range(3))
def test_front_and_rear_are_the_list_search(seed):
    rng = np.random.default_rng(40 + seed)
    found = 0
    for _ in range(400):
        n = int(rng.integers(0, 12))
        members, lon = lane_table(rng, n)
        s = float(rng.choice([rng.uniform(-10.0, 60.0), 0.0, -0.0, 5.0, np.nan]))
        mine = int(rng.integers(-1, n)) if n else -1
        want = front_rear_plain(members, lon, s, mine)
        assert _front_rear(members, lon, s, mine) == want
        found += want != (-1, -1)
    assert found > 100


def leader_plain(tables, hs, mine, heading, reach):
    """:meth:`WomdRoad.leader_ahead`'s search over the next lanes as it was written (one
    mover at a time, the first lane with a leader ends it)."""
    best, best_d = None, math.inf
    for members, lon, base in tables:
        for i in members.tolist():
            d = base + lon[i]
            if i == mine or d <= 0 or d >= best_d or d > reach:
                continue
            if math.cos(hs[i] - heading) < 0:
                continue
            best, best_d = i, d
        if best is not None:
            break
    return (-1 if best is None else best), best_d


@pytest.mark.parametrize("seed", range(3))
def test_leader_on_the_next_lanes_is_the_one_by_one_search(seed):
    rng = np.random.default_rng(50 + seed)
    found = 0
    for _ in range(300):
        n = int(rng.integers(0, 12))
        hs = rng.choice([rng.uniform(-math.pi, math.pi), math.pi / 2, 0.0], size=n)
        hs = np.where(rng.random(n) < 0.7, rng.uniform(-math.pi, math.pi, n), hs)
        heading = float(rng.choice([0.0, rng.uniform(-math.pi, math.pi)]))
        tables = [(*lane_table(rng, n), float(rng.choice([-5.0, 0.0, 20.0, 59.0])))
                  for _ in range(int(rng.integers(0, 4)))]
        mine = int(rng.integers(-1, n)) if n else -1
        want = leader_plain(tables, hs, mine, heading, 60.0)
        best, best_d = -1, math.inf
        for members, lon, base in tables:
            best, best_d = _leader_on(members, lon, hs, base, mine, heading, best_d, 60.0)
            if best >= 0:
                break
        assert best == want[0]
        assert best_d == want[1] or (math.isnan(best_d) and math.isnan(want[1]))
        found += want[0] >= 0
    assert found > 50


@pytest.mark.parametrize("seed", range(3))
def test_the_kernels_writing_into_arrays_give_what_their_definitions_return(seed):
    """_movers_into, _pairs_packed and _lane_members_into: the same rows and columns, to the
    bit, as _movers_now, _pairs_of_movers and _lane_members (NaN, -0.0 and negative speeds,
    nobody collidable, nobody on the lane among them)."""
    rng = np.random.default_rng(60 + seed)
    on_lanes = 0
    for n in (0, 1, *rng.integers(2, 40, 6).tolist()):
        c = road_columns(rng, n)
        if rng.random() < 0.2:
            c["collidable"][:] = False
        args = (c["collidable"], c["position"], c["heading"], c["speed"], c["length"],
                c["width"], c["walker"], c["path"], WALKER_CLEARANCE, PATH_MARGIN)
        want = _movers_now(*args)
        m = int(np.count_nonzero(c["collidable"]))
        rows, xy, columns = np.empty(m, np.int64), np.empty((m, 2)), np.empty((7, m))
        boxes, flags = np.empty((m, 4)), np.empty((2, m), bool)
        walkers = _movers_into(*args, rows, xy, columns, boxes, flags)
        got = (rows, xy, *columns[:6], boxes, flags[0], flags[1], columns[6])
        assert walkers == want[-1]
        for a, b in zip(got, want[:-1], strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()

        pairs = _pairs_of_movers(c["collidable"], c["position"], c["diagonal"], c["length"],
                                 c["width"], c["heading"], c["speed"], c["checks"], c["own"],
                                 0.1)
        packed, m, p = _pairs_packed(c["collidable"], c["position"], c["diagonal"],
                                     c["length"], c["width"], c["heading"], c["speed"],
                                     c["checks"], c["own"], 0.1)
        assert (m, p) == (len(pairs[0]), len(pairs[1]))
        parts = (packed[:m], packed[m:m + p], packed[m + p:m + 2 * p], packed[m + 2 * p:])
        assert len(packed) == m + 3 * p
        for a, b in zip(parts, pairs, strict=True):
            assert a.tolist() == b.astype(np.int64).tolist()

        ln = lane(rng)
        near, *_ = movers(rng, centre(ln), n)
        xs, ys = np.ascontiguousarray(near[:, 0]), np.ascontiguousarray(near[:, 1])
        xs[rng.random(n) < 0.1] = np.nan
        limits = (ln.width / 2 + 1.0, -ln.VEHICLE_LENGTH, ln.length + ln.VEHICLE_LENGTH)
        members, lon = _lane_members(*ln.arrays, *limits, xs, ys)
        got_members, got_lon = np.full(n, -7, np.int64), np.full(n, 7.0)
        k = _lane_members_into(*ln.arrays, *limits, xs, ys, got_members, got_lon)
        assert got_members[:k].tolist() == members.tolist()
        assert got_lon.tobytes() == lon.tobytes()
        on_lanes += k
    assert on_lanes > 20


@pytest.mark.parametrize("seed", range(2))
def test_walkers_within_reach_is_the_numpy_test(seed):
    """The walkers' reach test (one compiled pass) answers as the numpy expression it
    replaced: points on the circle's edge (their squared distance as the reach), inside,
    outside, not a number, none."""
    rng = np.random.default_rng(70 + seed)
    seen = set()
    for _ in range(400):
        m = int(rng.integers(0, 12))
        x, y = rng.uniform(-300, 300, 2)
        xy = np.array([x, y]) + rng.normal(0.0, 1.0, (m, 2)) * rng.choice([1.0, 20.0, 80.0])
        xy[rng.random(m) < 0.1] = np.nan
        if m and rng.random() < 0.5:  # the reach exactly at one of them
            k = int(rng.integers(m))
            d = xy[k] - (x, y)
            r2 = d[0] ** 2 + d[1] ** 2
        else:
            r2 = rng.uniform(0.0, 60.0) ** 2
        position = np.array([x, y])
        delta = xy - position
        want = bool((delta[:, 0] ** 2 + delta[:, 1] ** 2 <= r2).any())
        got = _any_within(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
                          float(x), float(y), float(r2))
        assert got == want
        seen.add(want)
    assert seen == {True, False}


def test_a_movers_index_is_the_sorted_search_of_its_row():
    """_Movers.index_of (a bisection of the rows as a list) finds a vehicle's place as
    numpy's search of the sorted rows did: the movers' index of its layout row, ``default``
    for a vehicle of the layout that is not a mover or not of the layout, each answer kept."""
    from types import SimpleNamespace

    rng = np.random.default_rng(5)
    for _ in range(50):
        n = int(rng.integers(0, 30))
        vehicles = tuple(object() for _ in range(n))
        layout = SimpleNamespace(vehicles=vehicles,
                                 row_of={id(v): i for i, v in enumerate(vehicles)})
        rows = np.flatnonzero(rng.random(n) < 0.6).astype(np.int64)
        movers = _Movers(layout, rows)
        for v in (*vehicles, object()):
            row = layout.row_of.get(id(v))
            k = int(np.searchsorted(rows, row)) if row is not None else None
            want = k if k is not None and k < len(rows) and rows[k] == row else None
            assert movers.index_of(v, -1) == (-1 if want is None else want)
            assert movers.index_of(v) == want  # kept: the same again
            if want is not None:
                assert movers[want] is v


@pytest.mark.parametrize("seed", range(2))
def test_the_leader_over_the_next_lanes_in_one_pass_is_the_lane_by_lane_search(seed):
    """_leader_ahead_on (the lanes' tables and searches in one compiled pass over the
    network's pose arrays) finds the leader and distance that each lane's _lane_members and
    _leader_on, lane after lane until one has a leader, found: lanes of every shape, movers
    on them, beside and far, oncoming, the vehicle among them or not, no lane."""
    rng = np.random.default_rng(90 + seed)
    found = 0
    for _ in range(150):
        lanes = [lane(rng) for _ in range(int(rng.integers(0, 4)))]
        around = np.concatenate([centre(ln) for ln in lanes]) if lanes else np.zeros((1, 2))
        n = int(rng.integers(0, 15))
        xy, hs, *_ = movers(rng, around, n)
        xs, ys = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
        xs[rng.random(n) < 0.05] = np.nan
        heading = float(rng.uniform(-math.pi, math.pi))
        mine = int(rng.integers(-1, n)) if n else -1
        bases = np.sort(rng.uniform(-5.0, 70.0, len(lanes)))
        reach = float(rng.choice([30.0, 60.0]))
        want, want_d = -1, math.inf
        for ln, base in zip(lanes, bases, strict=True):
            limits = (ln.width / 2 + 1.0, -ln.VEHICLE_LENGTH, ln.length + ln.VEHICLE_LENGTH)
            members, lon = _lane_members(*ln.arrays, *limits, xs, ys)
            want, want_d = _leader_on(members, lon, hs, float(base), mine, heading, want_d,
                                      reach)
            if want >= 0:
                break
        poses = [np.concatenate([ln.arrays[k] for ln in lanes]) if lanes else np.zeros(0)
                 for k in range(5)]
        ends = np.cumsum([0] + [len(ln.arrays[0]) for ln in lanes])
        table = np.array([(float(ends[j]), float(ends[j + 1]), ln.width / 2 + 1.0,
                           -ln.VEHICLE_LENGTH, ln.length + ln.VEHICLE_LENGTH)
                          for j, ln in enumerate(lanes)]).reshape(-1, 5)
        got, got_d = _leader_ahead_on(*poses, table, bases, xs, ys, hs, mine, heading, reach)
        assert (got, got_d) == (want, want_d)
        found += want >= 0
    assert found > 20


def test_the_comfortable_braking_at_conflicts_follows_each_drivers_parameters():
    """_Layout.conflict_braking: each yielding vehicle's comfortable braking from its
    driver's parameters as they are when asked (kept while every driver is the same object,
    made again when one changes), NaN for the others."""
    from types import SimpleNamespace

    from tap_bench.sim.womd_road import DriverParameters

    soft, firm = DriverParameters(comfortable_braking=1.5), DriverParameters()
    cars = [SimpleNamespace(parameters=lambda p=p: p) for p in (soft, firm, soft)]
    layout = SimpleNamespace(vehicles=(cars[0], object(), cars[1], cars[2]),
                             yielder_rows=[0, 2, 3], _braking=None)
    want = [1.5, math.nan, 2.0, 1.5]
    got = _Layout.conflict_braking(layout)
    np.testing.assert_array_equal(got, want)
    assert _Layout.conflict_braking(layout) is got  # the same drivers: kept
    cars[1].parameters = lambda: soft
    np.testing.assert_array_equal(_Layout.conflict_braking(layout), [1.5, math.nan, 1.5, 1.5])


@pytest.mark.parametrize("seed", range(3))
def test_the_obstacles_ahead_in_one_pass_are_the_searches_one_by_one(seed):
    """_ahead_in_one gives what WomdRoad's searches gave one after the other: the leader on
    the next lanes (_leader_ahead_on over lanes 1 to the leader's cut), the corridor's
    leader (_corridor, two movers or more), the walkers (_any_within, then
    _walkers_on_lane on each lane of the walkers' cut with the lane's own headings, where
    they are and where they will be), the give-way gap (_conflict_gap_on on each lane's own
    conflict table until a lane starts beyond the look ahead, the smallest). Lanes of every
    shape starting exactly at the look aheads, movers without a position, no walkers, no
    conflicts, no movers."""
    rng = np.random.default_rng(70 + seed)
    counts = {"leader": 0, "corridor": 0, "walker": 0, "conflict": 0}
    for _ in range(200):
        k = int(rng.integers(1, 5))
        lanes = [lane(rng) for _ in range(k)]
        poses = [np.concatenate([ln.arrays[q] for ln in lanes]) for q in range(5)]
        hd = np.arctan2(poses[3], poses[2])
        ends = np.cumsum([0] + [len(ln.arrays[0]) for ln in lanes])
        rows = np.array([(float(ends[j]), float(ends[j + 1]), ln.width / 2 + 1.0,
                          -ln.VEHICLE_LENGTH, ln.length + ln.VEHICLE_LENGTH, float(ln.length))
                         for j, ln in enumerate(lanes)])
        edges = [CONFLICT_LOOKAHEAD, WALKER_LOOKAHEAD, LEADER_LOOKAHEAD]
        bases = np.sort(np.r_[rng.uniform(-30.0, 10.0), [
            float(rng.choice(edges)) if rng.random() < 0.3 else rng.uniform(-5.0, 65.0)
            for _ in range(k - 1)]])
        if rng.random() < 0.1:
            bases[0] = CONFLICT_LOOKAHEAD + rng.choice([0.0, 1.0])  # its search ends at once
        cut = {look: 1 + int(np.sum(bases[1:] <= look))
               for look in (CONFLICT_LOOKAHEAD, WALKER_LOOKAHEAD, LEADER_LOOKAHEAD)}
        n = int(rng.choice([0, 1, 2, int(rng.integers(3, 25))]))
        around = np.concatenate([centre(ln) for ln in lanes])
        xy, hs, vs, ls, ws = movers(rng, around, n)
        xy[rng.random(n) < 0.05] = np.nan
        xs, ys = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
        walker = rng.random(n) < 0.3
        yielder = rng.random(n) < 0.5
        braking_j = np.where(yielder, rng.uniform(1.5, 3.0, n), np.nan)
        row_j = rng.integers(-1, 30, n)
        mine = int(rng.integers(-1, n)) if n else -1
        at_ego = around[rng.integers(len(around))] + rng.normal(0.0, 2.0, 2)
        ego = np.array((at_ego[0], at_ego[1], rng.uniform(-math.pi, math.pi), 4.8, 2.0,
                        rng.choice([0.0, rng.uniform(0.0, 15.0)]), rng.uniform(1.5, 3.0),
                        rng.uniform(2.5, 3.5), rng.uniform(6.0, 30.0), 0.0,
                        2.0 / 2 + WALKER_CLEARANCE))
        if n >= 2 and rng.random() < 0.5:  # one in the corridor ahead
            ahead = rng.uniform(3.0, 20.0)
            xs[int(mine == 0)] = ego[0] + ahead * math.cos(ego[2])
            ys[int(mine == 0)] = ego[1] + ahead * math.sin(ego[2])
        # the conflicts of each lane within the conflicts' look ahead, as _conflict_table's
        n_conf = 0 if bases[0] > CONFLICT_LOOKAHEAD else cut[CONFLICT_LOOKAHEAD]
        tables = []
        for j in range(n_conf):
            m = int(rng.integers(0, 4))
            others = [int(u) for u in rng.integers(0, k, int(rng.integers(1, 3)))]
            conf = np.array([(rng.uniform(0.0, lanes[j].length), rng.uniform(
                0.0, lanes[others[0]].length)) for _ in range(m)]).reshape(-1, 2)
            at = np.arange(m + 1, dtype=np.int64) * len(others)
            approach = np.tile(np.arange(len(others), dtype=np.int64), m)
            offsets = np.tile([0.0 if q == 0 else float(lanes[u].length)
                               for q, u in enumerate(others)], m).astype(float)
            clanes = rows[others, :5].copy()
            tables.append((conf, at, approach, offsets, clanes))
        sections, q, a, r, u = [], 0, 0, 0, 0
        for conf, at, approach, _, cl in tables:
            sections.append((q, q + len(conf), a, r, r + len(approach), u, u + len(cl)))
            q, a, r, u = q + len(conf), a + len(at), r + len(approach), u + len(cl)
        joined = (np.concatenate([t[0] for t in tables] or [np.zeros((0, 2))]),
                  np.concatenate([t[1] for t in tables] or [np.zeros(0, np.int64)]),
                  np.concatenate([t[2] for t in tables] or [np.zeros(0, np.int64)]),
                  np.concatenate([t[3] for t in tables] or [np.zeros(0)]),
                  np.concatenate([t[4] for t in tables] or [np.zeros((0, 5))]),
                  np.array(sections, np.int64).reshape(-1, 7))
        # walkers: some of the movers, where they are and where they will be
        w = np.flatnonzero(walker)
        walkers = bool(len(w)) and rng.random() < 0.8
        wx0, wy0 = xs[w].copy(), ys[w].copy()
        wx1, wy1 = wx0 + 1.5 * vs[w] * np.cos(hs[w]), wy0 + 1.5 * vs[w] * np.sin(hs[w])
        ego[9] = rng.choice([0.0, 30.0, 80.0]) ** 2
        whd = hd.copy()

        got = _ahead_in_one(*poses, hd, whd, rows, bases, xs, ys, hs, vs, ls, ws, walker,
                            yielder, braking_j, row_j, *joined, wx0, wy0, wx1, wy1,
                            hs[w].copy(), vs[w].copy(), ego, mine, 7,
                            (cut[LEADER_LOOKAHEAD], cut[WALKER_LOOKAHEAD]), walkers)

        want_leader = (-1, math.inf)
        if cut[LEADER_LOOKAHEAD] > 1:
            want_leader = _leader_ahead_on(*poses, rows[1:cut[LEADER_LOOKAHEAD], :5].copy(),
                                           bases[1:cut[LEADER_LOOKAHEAD]].copy(), xs, ys, hs,
                                           mine, ego[2], LEADER_LOOKAHEAD)
        want_corridor = (-1, math.nan, math.nan)
        if n >= 2:
            want_corridor = _corridor(xs, ys, hs, vs, ls, ws, ego[0], ego[1], ego[2], ego[3],
                                      ego[4], ego[8], mine)
        want_walker = math.nan
        if walkers and _any_within(wx0, wy0, ego[0], ego[1], ego[9]):
            for j in range(cut[WALKER_LOOKAHEAD]):
                _, _, tx, ty, _ = lanes[j].arrays
                for wx, wy in ((wx0, wy0), (wx1, wy1)):
                    want_walker = _walkers_on_lane(
                        *lanes[j].arrays, np.arctan2(ty, tx), bases[j], ego[10],
                        lanes[j].length, wx, wy, hs[w].copy(), vs[w].copy(), want_walker)
        want_gap = None
        for j, (conf, at, approach, offsets, cl) in enumerate(tables):
            if bases[j] > CONFLICT_LOOKAHEAD:
                break
            if not len(conf):
                continue
            g = _conflict_gap_on(float(bases[j]), conf, at, approach, offsets, cl, *poses, hd,
                                 xs, ys, hs, ls, ws, vs, walker, yielder, braking_j, row_j,
                                 mine, 7, ego[3], ego[4], ego[5], ego[6], ego[7])
            if g == g:
                want_gap = g if want_gap is None else min(want_gap, g)
        want = (*want_leader, *want_corridor, want_walker,
                math.nan if want_gap is None else want_gap)
        assert len(got) == len(want)
        assert all(a == b or (a != a and b != b) for a, b in zip(got, want, strict=True))
        counts["leader"] += want[0] >= 0
        counts["corridor"] += want[2] >= 0
        counts["walker"] += want[5] == want[5]
        counts["conflict"] += want[6] == want[6]
    assert min(counts.values()) >= 2, counts


def test_a_lanes_frame_asked_again_is_the_frame_found_afresh():
    """FastPolyLane.local_coordinates keeps the last point's answer: asking again, after
    other points, at the same x or the same y only, at zeros of either sign and NaN, gives
    what the compiled frame gives afresh, to the bit (the sign of a zero included)."""
    from tap_bench.sim.womd_lanes import _frame

    rng = np.random.default_rng(11)
    for _ in range(40):
        ln = lane(rng)
        px, py, *_ = ln.arrays
        points = [(float(px[0]), float(py[0])), (0.0, float(py[0])), (-0.0, float(py[0])),
                  (float(px[-1]), 0.0), (float(px[-1]), -0.0), (math.nan, 1.0)]
        points += [tuple(map(float, rng.uniform(-600.0, 600.0, 2))) for _ in range(6)]
        for i in rng.integers(0, len(points), 60).tolist():
            x, y = points[i]
            for q in ((x, y), (x, float(py[-1])), (float(px[-1]), y)):
                got = ln.local_coordinates(np.array(q))
                want = _frame(*ln.arrays, *q)
                assert np.array(got).tobytes() == np.array(want).tobytes()
