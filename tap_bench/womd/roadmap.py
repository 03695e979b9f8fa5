"""A WOMD scenario's road map with its topology: what driving on it needs, not only drawing.

:mod:`tap_bench.maps` keeps polylines to draw; this module keeps, per scenario
(:class:`RoadMap`):

- lanes (:class:`Lane`): id, centre line, type, speed limit, entry and exit lanes, left and
  right neighbours with the index ranges over which they are neighbours (:class:`Neighbour`),
  and a width from the lane's boundary lines where the data gives them (else
  :data:`DEFAULT_LANE_WIDTH`);
- road edges (the drivable surface's border), crosswalks (polygons), stop signs with the
  lanes they control (:class:`StopSign`);
- traffic-signal states per time step (:class:`SignalStates`, from ``dynamic_map_states``).

Sources (the same three the trajectory readers know, :mod:`tap_bench.sources`):

- ``Scenario`` protos: ``map_features`` and ``dynamic_map_states`` (map.proto) read with
  :data:`tap_bench.womd.proto.ScenarioMapView`;
- ScenarioNet pickles: ``map_features`` (``entry_lanes``, ``exit_lanes``, ``left_neighbor``,
  ``right_neighbor``, ``left_boundaries``, ``right_boundaries``) and ``dynamic_map_states``;
- motion ``tf.Example`` records: ``roadgraph_samples/*`` points grouped by ``id`` (lane
  centre lines, lines, edges, crosswalks, stop signs); they carry no topology, and
  ``traffic_light_state/*`` (up to 16 signals per step).

Where a source gives no topology (the tf.Example roadgraph, or a map whose lanes name no
entry or exit lane at all), successors are inferred: lane A precedes lane B when A's last
point and B's first point are within :data:`JOIN_DISTANCE` and their headings there within
:data:`JOIN_HEADING` (:func:`infer_successors`); :attr:`RoadMap.topology` then says
``"inferred"`` and :attr:`RoadMap.inferred_links` how many links were made.

Coordinates are WOMD's (y to the left, heading counter-clockwise) [m]; speeds [m/s].
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path
from typing import Any

import numba
import numpy as np
from google.protobuf.message import DecodeError

from tap_bench.errors import FileFormatError

__all__ = [
    "CAUTION_STATES",
    "DEFAULT_LANE_WIDTH",
    "JOIN_DISTANCE",
    "JOIN_HEADING",
    "LANE_STATES",
    "STOP_STATES",
    "Lane",
    "Neighbour",
    "RoadMap",
    "SignalStates",
    "StopSign",
    "infer_successors",
    "split_rows",
    "map_point_lists",
    "map_points",
]


def split_rows(values: np.ndarray, counts: Sequence[int] | np.ndarray) -> list[np.ndarray]:
    """``values`` cut along its first axis into consecutive pieces of ``counts`` rows (the
    views ``numpy.split`` gives at ``cumsum(counts)[:-1]``, sliced directly: numpy.split
    costs a few microseconds a piece)."""
    ends = np.cumsum(np.asarray(counts, dtype=np.int64)).tolist()
    return [values[a:b] for a, b in zip([0, *ends[:-1]][:len(ends)], ends, strict=True)]

DEFAULT_LANE_WIDTH = 3.7  # [m] width of a lane whose boundaries the data does not give
MIN_LANE_WIDTH = 2.5  # [m] narrowest width taken from boundary lines (a bike lane is ~1.5)
MAX_LANE_WIDTH = 6.0  # [m] widest width taken from boundary lines
JOIN_DISTANCE = 0.5  # [m] lane ends this close meet (inferred successors)
JOIN_HEADING = np.pi / 4  # [rad] ... with headings this close
MPH = 0.44704  # [m/s] one mile per hour

LANE_TYPES = {0: "undefined", 1: "freeway", 2: "surface_street", 3: "bike_lane"}
"""LaneCenter.LaneType -> name."""
LANE_STATES = ("unknown", "arrow_stop", "arrow_caution", "arrow_go", "stop", "caution", "go",
               "flashing_stop", "flashing_caution")
"""TrafficSignalLaneState.State, by number (0 unknown ... 8 flashing caution)."""
STOP_STATES = frozenset({1, 4})
"""Signal states that are red (arrow stop, stop): IDM stops at the stop point, crossing it is
a red-light violation. A flashing red is a stop sign, not a red light."""
CAUTION_STATES = frozenset({2, 5})
"""Signal states that are yellow: IDM stops at the stop point when it can."""


@dataclass(frozen=True)
class Neighbour:
    """A lane beside another over a range of points.

    Attributes:
        lane: the neighbouring lane's id.
        self_start, self_end: the range of this lane's points (inclusive) along which it is
            a neighbour.
        start, end: the matching range of the neighbour's points.
    """

    lane: int
    self_start: int
    self_end: int
    start: int = 0
    end: int = 0


@dataclass(frozen=True)
class Lane:
    """One lane (its centre line) of a WOMD map.

    Attributes:
        id: the map feature id.
        centre: (n, 2) centre-line points [m], in driving order (n >= 1).
        type: ``freeway``, ``surface_street``, ``bike_lane`` or ``undefined``.
        speed_limit: [m/s]; NaN when the data does not say.
        entry, exit: ids of the lanes that lead into it and that it leads to.
        left, right: its neighbours on each side (driver's view).
        width: [m], from its boundary lines where the data gives them, else
            :data:`DEFAULT_LANE_WIDTH`.
        width_measured: whether ``width`` comes from boundary lines.
    """

    id: int
    centre: np.ndarray
    type: str = "undefined"
    speed_limit: float = float("nan")
    entry: tuple[int, ...] = ()
    exit: tuple[int, ...] = ()
    left: tuple[Neighbour, ...] = ()
    right: tuple[Neighbour, ...] = ()
    width: float = DEFAULT_LANE_WIDTH
    width_measured: bool = False

    @property
    def length(self) -> float:
        """Length of the centre line [m]."""
        return (float(np.hypot(*np.diff(self.centre, axis=0).T).sum()) if len(self.centre) > 1
            else 0.0)


@dataclass(frozen=True)
class StopSign:
    """A stop sign: where it stands [m] and the lanes it controls."""

    id: int
    position: np.ndarray
    lanes: tuple[int, ...] = ()


@dataclass(frozen=True)
class SignalStates:
    """Traffic-signal states per time step.

    Attributes:
        lane: (k,) the controlled lanes' ids.
        state: (n_steps, k) int8, :data:`LANE_STATES` numbers (0 where the step does not
            report the lane).
        stop_point: (k, 2) [m] where traffic on the lane stops.
    """

    lane: np.ndarray
    state: np.ndarray
    stop_point: np.ndarray

    @classmethod
    def empty(cls, n_steps: int = 0) -> SignalStates:
        """No signals."""
        return cls(np.zeros(0, np.int64), np.zeros((n_steps, 0), np.int8), np.zeros((0, 2)))

    @property
    def red(self) -> np.ndarray:
        """(n_steps, k) bool: the lane's signal is red (:data:`STOP_STATES`)."""
        return np.isin(self.state, list(STOP_STATES))

    @property
    def red_or_yellow(self) -> np.ndarray:
        """(n_steps, k) bool: red or yellow (IDM stops)."""
        return np.isin(self.state, list(STOP_STATES | CAUTION_STATES))


@dataclass(frozen=True)
class RoadMap:
    """A scenario's road map with topology (see the module docstring).

    Attributes:
        scenario_id: the scenario.
        lanes: id -> :class:`Lane`, in the source's order.
        road_edges: (n_i, 2) polylines [m].
        crosswalks: (n_i, 2) polygons [m].
        stop_signs: the stop signs.
        signals: signal states per step.
        topology: ``"given"`` (the source names entry and exit lanes), ``"inferred"``
            (successors inferred from lane ends that meet) or ``"none"`` (no lanes).
        inferred_links: successor links inferred.
        source: the file it came from.
    """

    scenario_id: str
    lanes: dict[int, Lane]
    road_edges: tuple[np.ndarray, ...] = ()
    crosswalks: tuple[np.ndarray, ...] = ()
    stop_signs: tuple[StopSign, ...] = ()
    signals: SignalStates = field(default_factory=SignalStates.empty)
    topology: str = "given"
    inferred_links: int = 0
    source: str = ""

    def successors(self, lane_id: int) -> tuple[int, ...]:
        """The exit lanes of a lane that exist in this map."""
        return tuple(i for i in self.lanes[lane_id].exit if i in self.lanes)


def infer_successors(lanes: dict[int, Lane], *, distance: float = JOIN_DISTANCE,
                     heading: float = JOIN_HEADING) -> tuple[dict[int, Lane], int]:
    """Lanes with entry and exit lanes inferred from lane ends that meet.

    Lane A precedes lane B (A != B) when A's last point is within ``distance`` [m] of B's
    first point and A's heading at its end is within ``heading`` [rad] of B's at its start.
    Links already given are kept.

    Returns:
        the lanes with the links added, and how many links were added.
    """
    ids = [i for i, lane in lanes.items() if len(lane.centre) >= 2]
    if not ids:
        return dict(lanes), 0
    first = np.array([lanes[i].centre[0] for i in ids])
    last = np.array([lanes[i].centre[-1] for i in ids])
    start_dir = np.array([_direction(lanes[i].centre, 0) for i in ids])
    end_dir = np.array([_direction(lanes[i].centre, -1) for i in ids])
    gap = np.hypot(last[:, None, 0] - first[None, :, 0], last[:, None, 1] - first[None, :, 1])
    turn = np.abs(np.angle(np.exp(1j * (start_dir[None, :] - end_dir[:, None]))))
    meet = (gap <= distance) & (turn <= heading)
    np.fill_diagonal(meet, False)
    exits: dict[int, list[int]] = {i: list(lanes[i].exit) for i in lanes}
    entries: dict[int, list[int]] = {i: list(lanes[i].entry) for i in lanes}
    added = 0
    for a, b in zip(*np.nonzero(meet), strict=True):
        ia, ib = ids[a], ids[b]
        if ib not in exits[ia]:
            exits[ia].append(ib)
            added += 1
        if ia not in entries[ib]:
            entries[ib].append(ia)
    out = {i: _replace(lane, entry=tuple(entries[i]), exit=tuple(exits[i]))
           for i, lane in lanes.items()}
    return out, added


def _replace(lane: Lane, **changes) -> Lane:
    from dataclasses import replace

    return replace(lane, **changes)


def _direction(points: np.ndarray, at: int) -> float:
    """Heading [rad] of a polyline at its first (``at=0``) or last (``at=-1``) point, from
    the nearest pair of distinct points."""
    pts = points if at == 0 else points[::-1]
    if len(pts) > 1 and np.hypot(pts[1, 0] - pts[0, 0], pts[1, 1] - pts[0, 1]) > 1e-6:
        dx, dy = pts[1] - pts[0]  # the next point is distinct (the usual case)
    else:
        d = pts[1:] - pts[0]
        moved = np.flatnonzero(np.hypot(d[:, 0], d[:, 1]) > 1e-6)
        if not len(moved):
            return 0.0
        dx, dy = d[moved[0]]
    return float(np.arctan2(dy, dx) if at == 0 else np.arctan2(-dy, -dx))


def _segment_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """(m,) distance [m] from each point to a polyline (k >= 1 points)."""
    if len(line) == 1:
        return np.hypot(*(points - line[0]).T)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
    line = np.ascontiguousarray(line, dtype=np.float64).reshape(-1, 2)
    return _polyline_distances(points, np.array([0, len(points)]), line,
                               np.array([0, len(line)]))


_CHUNK = 16  # segments of a polyline grouped under one bounding box


@numba.njit(cache=True, nogil=True)
def _segment_square(px, py, lines, k):  # pragma: no cover - compiled
    """(squared distance, dx, dy) from (px, py) to the nearest point of segment k."""
    ax, ay = lines[k, 0], lines[k, 1]
    abx, aby = lines[k + 1, 0] - ax, lines[k + 1, 1] - ay
    norm2 = max(abx * abx + aby * aby, 1e-12)
    u = min(max(((px - ax) * abx + (py - ay) * aby) / norm2, 0.0), 1.0)
    dx, dy = px - (ax + u * abx), py - (ay + u * aby)
    return dx * dx + dy * dy, dx, dy


@numba.njit(cache=True, nogil=True)
def _polyline_distances(points, point_offsets, lines, line_offsets
                        ):  # pragma: no cover - compiled
    """Distance [m] from each point to its polyline: points
    ``point_offsets[j]:point_offsets[j + 1]`` (of (m, 2)) to the polyline
    ``line_offsets[j]:line_offsets[j + 1]`` (of (k, 2); two points or more): to the
    nearest point of its nearest segment, ``hypot`` of the offset.

    Segments are grouped by ``_CHUNK`` under bounding boxes, and a group farther than the
    nearest segment found so far is skipped. The distance is the smallest ``hypot`` over
    the segments within rounding of the nearest by squared distance, so that it does not
    depend on how the squares round."""
    out = np.empty(points.shape[0])
    for j in range(point_offsets.shape[0] - 1):
        a, b = line_offsets[j], line_offsets[j + 1]
        n_chunks = (b - a - 1 + _CHUNK - 1) // _CHUNK
        box = np.empty((n_chunks, 4))  # min x, max x, min y, max y of each group's points
        for c in range(n_chunks):
            lo, hi = a + c * _CHUNK, min(a + (c + 1) * _CHUNK, b - 1)
            box[c, 0] = box[c, 1] = lines[lo, 0]
            box[c, 2] = box[c, 3] = lines[lo, 1]
            for k in range(lo + 1, hi + 1):
                box[c, 0] = min(box[c, 0], lines[k, 0])
                box[c, 1] = max(box[c, 1], lines[k, 0])
                box[c, 2] = min(box[c, 2], lines[k, 1])
                box[c, 3] = max(box[c, 3], lines[k, 1])
        apart = np.empty(n_chunks)
        for i in range(point_offsets[j], point_offsets[j + 1]):
            px, py = points[i, 0], points[i, 1]
            first = 0
            for c in range(n_chunks):
                gx = max(box[c, 0] - px, 0.0, px - box[c, 1])
                gy = max(box[c, 2] - py, 0.0, py - box[c, 3])
                apart[c] = gx * gx + gy * gy
                if apart[c] < apart[first]:
                    first = c
            nearest = np.inf
            for step in range(n_chunks + 1):  # the closest box first, then all in order
                c = first if step == 0 else step - 1
                if (step > 0 and c == first) or apart[c] > nearest * (1.0 + 1e-6):
                    continue
                for k in range(a + c * _CHUNK, min(a + (c + 1) * _CHUNK, b - 1)):
                    nearest = min(nearest, _segment_square(px, py, lines, k)[0])
            reach = nearest * (1.0 + 1e-9) + 1e-300
            best = np.inf
            for c in range(n_chunks):
                if apart[c] > reach * (1.0 + 1e-6):
                    continue
                for k in range(a + c * _CHUNK, min(a + (c + 1) * _CHUNK, b - 1)):
                    square, dx, dy = _segment_square(px, py, lines, k)
                    if square <= reach:
                        best = min(best, math.hypot(dx, dy))
            out[i] = best
    return out


def _side_points(centre: np.ndarray, segments: list[tuple[int, int, int]],
                 lines: dict[int, np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(points of the lane, boundary line) pairs of one side: ~20 points of the lane along
    each boundary segment."""
    pairs = []
    for start, end, line_id in segments:
        line = lines.get(line_id)
        if line is None or len(line) == 0:
            continue
        lo, hi = max(0, start), min(len(centre) - 1, end)
        if hi < lo:
            continue
        pairs.append((centre[lo:hi + 1][:: max(1, (hi - lo + 1) // 20)], line))
    return pairs


def _widths(lanes: list[tuple[np.ndarray, list, list]], lines: dict[int, np.ndarray]
            ) -> list[tuple[float, bool]]:
    """(width [m], measured) of each lane (centre, left boundaries, right boundaries):
    twice the median distance from its points to the boundary lines of a side, or the sum
    of both sides' medians, clipped to [MIN_LANE_WIDTH, MAX_LANE_WIDTH];
    :data:`DEFAULT_LANE_WIDTH` where neither side gives one. All distances in one compiled
    pass, all medians in one sort."""
    sides = [_side_points(centre, segs, lines) for centre, left, right in lanes
             for segs in (left, right)]
    pairs = [pair for side in sides for pair in side]
    distances: list[np.ndarray] = [np.hypot(*(p - line[0]).T) if len(line) == 1 else None
                                   for p, line in pairs]
    polylines = [k for k, (_, line) in enumerate(pairs) if len(line) > 1]
    if polylines:
        points = np.concatenate([pairs[k][0] for k in polylines])
        point_offsets = np.zeros(len(polylines) + 1, dtype=np.int64)
        np.cumsum([len(pairs[k][0]) for k in polylines], out=point_offsets[1:])
        line_offsets = np.zeros(len(polylines) + 1, dtype=np.int64)
        np.cumsum([len(pairs[k][1]) for k in polylines], out=line_offsets[1:])
        flat = _polyline_distances(
            np.ascontiguousarray(points, dtype=np.float64), point_offsets,
            np.ascontiguousarray(np.concatenate([pairs[k][1] for k in polylines]),
                                 dtype=np.float64), line_offsets)
        for k, values in zip(polylines, split_rows(flat, np.diff(point_offsets)),
                             strict=True):
            distances[k] = values
    side = np.repeat(np.arange(len(sides)), [len(found) for found in sides])
    medians = _group_medians(distances, side, len(sides)).reshape(-1, 2)
    ok = np.isfinite(medians) & (medians > 0)
    width = np.where(ok.all(axis=1), medians.sum(axis=1, where=ok),
                     2 * np.where(ok[:, 0], medians[:, 0], medians[:, 1]))
    with np.errstate(invalid="ignore"):
        width = np.clip(width, MIN_LANE_WIDTH, MAX_LANE_WIDTH)
    measured = ok.any(axis=1)
    return [(float(w), True) if m else (DEFAULT_LANE_WIDTH, False)
            for w, m in zip(width.tolist(), measured.tolist(), strict=True)]


def _group_medians(values: list[np.ndarray], group: np.ndarray, n_groups: int
                   ) -> np.ndarray:
    """(n_groups,) the median of the values of each group (``values[i]`` belongs to group
    ``group[i]``, groups in order): the middle value, or the mean of the two middle ones;
    NaN for a group with no value or with a NaN (as :func:`numpy.median`)."""
    out = np.full(n_groups, np.nan)
    if not len(values):
        return out
    flat = np.concatenate(values)
    member = np.repeat(group, [len(v) for v in values])
    ordered = flat[np.lexsort((flat, member))]  # by group, then value (NaN last)
    count = np.bincount(member, minlength=n_groups)
    start = np.cumsum(count) - count
    has = count > 0
    lo = ordered[(start + (count - 1) // 2)[has]]
    hi = ordered[(start + count // 2)[has]]
    middle = np.where(count[has] % 2 == 1, lo, (lo + hi) / 2)
    nan = np.bincount(member, weights=np.isnan(flat), minlength=n_groups) > 0
    out[has] = np.where(nan[has], np.nan, middle)
    return out


def _finite_rows(lines: Sequence[Any]) -> list[np.ndarray]:
    """Each line as (n_i, 2) float points [m] without its points that are not finite (new
    arrays), all lines at once."""
    arrays = [np.asarray(line, dtype=float).reshape(-1, 2) for line in lines]
    if not arrays:
        return []
    flat = np.concatenate(arrays)
    finite = np.isfinite(flat).all(axis=1)
    owner = np.repeat(np.arange(len(arrays)), [len(a) for a in arrays])
    return split_rows(flat[finite], np.bincount(owner[finite], minlength=len(arrays)))


def _finish(scenario_id: str, raw: list[dict], lines: dict[int, np.ndarray], edges, crosswalks,
            stops, signals: SignalStates, source: str, topology_given: bool) -> RoadMap:
    """Build the :class:`RoadMap` from lanes read as dicts (id, centre, type, speed_limit,
    entry, exit, left, right, left_b, right_b)."""
    columns = _LaneColumns(
        ids=[int(r["id"]) for r in raw], types=[r.get("type", "undefined") for r in raw],
        speed_limits=[float(r.get("speed_limit", np.nan)) for r in raw],
        entries=[tuple(r.get("entry", ())) for r in raw],
        exits=[tuple(r.get("exit", ())) for r in raw],
        lefts=[tuple(r.get("left", ())) for r in raw],
        rights=[tuple(r.get("right", ())) for r in raw],
        left_bounds=[r.get("left_b", ()) for r in raw],
        right_bounds=[r.get("right_b", ()) for r in raw])
    centres = _finite_rows([r["centre"] for r in raw])
    return _finish_columns(scenario_id, columns, centres, lines, edges, crosswalks, stops,
                           signals, source, topology_given)


@dataclass
class _LaneColumns:
    """A map's lanes as lists, one item per lane: ids, types, speed limits [m/s], entry and
    exit ids (tuples), left and right neighbours (tuples of :class:`Neighbour`), left and
    right boundary segments ((start, end, line id) each)."""

    ids: list[int]
    types: list[str]
    speed_limits: list[float]
    entries: list[tuple[int, ...]]
    exits: list[tuple[int, ...]]
    lefts: list[tuple[Neighbour, ...]]
    rights: list[tuple[Neighbour, ...]]
    left_bounds: list
    right_bounds: list


def _finish_columns(scenario_id: str, raw: _LaneColumns, centres: list[np.ndarray],
                    lines: dict[int, np.ndarray], edges, crosswalks, stops,
                    signals: SignalStates, source: str, topology_given: bool) -> RoadMap:
    """:func:`_finish` of lanes as columns, their centre lines already without points that
    are not finite."""
    lanes: dict[int, Lane] = {}
    widths = _widths(list(zip(centres, raw.left_bounds, raw.right_bounds, strict=True)),
                     lines)
    for (lane_id, centre, lane_type, speed, entry, exit_, left, right,
         (width, measured)) in zip(raw.ids, centres, raw.types, raw.speed_limits, raw.entries,
                                   raw.exits, raw.lefts, raw.rights, widths, strict=True):
        lanes[lane_id] = Lane(id=lane_id, centre=centre, type=lane_type, speed_limit=speed,
                              entry=entry, exit=exit_, left=left, right=right, width=width,
                              width_measured=measured)
    has_links = any(lane.entry or lane.exit for lane in lanes.values())
    topology, added = "given", 0
    if not lanes:
        topology = "none"
    elif not (topology_given and has_links):
        lanes, added = infer_successors(lanes)
        topology = "inferred"
    return RoadMap(scenario_id, lanes, tuple(edges), tuple(crosswalks), tuple(stops), signals,
                   topology, added, source)


# ------------------------------------------------------------------ Scenario protos


_POINT_TAGS = {0x09: 0, 0x11: 1, 0x19: 2}
"""The tag bytes of MapPoint's fields (x 1, y 2, z 3; fixed64) -> their axis."""


def map_points(points: Sequence[bytes]) -> np.ndarray:
    """(n, 2) x, y [m] of serialized ``MapPoint`` messages (map.proto: x 1, y 2, z 3, all
    double); see :func:`map_point_lists`.

    Raises:
        DecodeError: a point's bytes are not a MapPoint.
    """
    return map_point_lists([points])[0]


def map_point_lists(lists: Sequence[Sequence[bytes]]) -> list[np.ndarray]:
    """The (n_i, 2) x, y [m] of each list of serialized ``MapPoint`` messages (map.proto:
    x 1, y 2, z 3, all double).

    When every point holds the same fields, each once, in the same order (as WOMD's files
    do), all lists are read in one numpy pass; otherwise each list is read alone, by
    protobuf point by point where its points differ, with protobuf's rules (an absent field
    is 0, a repeated one keeps its last value).

    Raises:
        DecodeError: a point's bytes are not a MapPoint.
    """
    counts = [len(points) for points in lists]
    flat = list(chain.from_iterable(lists))
    xy = _uniform_points(flat)
    if xy is not None:
        return split_rows(xy, counts)
    if len(lists) > 1:
        return [map_point_lists([points])[0] for points in lists]
    from tap_bench.womd.proto import MapPointView

    return [np.array([(p.x, p.y) for p in map(MapPointView.FromString, flat)],
                     dtype=np.float64).reshape(-1, 2)]


def _uniform_points(points: list[bytes]) -> np.ndarray | None:
    """(n, 2) x, y of serialized MapPoints that all hold the same fields once each in the
    same order (one tag byte and 8 value bytes per field), else None."""
    n = len(points)
    if not n:
        return np.zeros((0, 2))
    sizes = np.fromiter(map(len, points), np.int64, n)
    size = int(sizes[0])
    fields = size // 9
    if size != 9 * fields or not 1 <= fields <= 3 or (sizes != size).any():
        return None
    cells = np.frombuffer(b"".join(points), np.uint8).reshape(n, fields, 9)
    tags = cells[0, :, 0].tolist()
    if (len(set(tags)) != fields or not set(tags) <= _POINT_TAGS.keys()
            or (cells[:, :, 0] != cells[0, :, 0]).any()):
        return None
    values = np.ascontiguousarray(cells[:, :, 1:]).view("<f8")[:, :, 0]
    xy = np.zeros((n, 2))
    for k, tag in enumerate(tags):
        if _POINT_TAGS[tag] < 2:
            xy[:, _POINT_TAGS[tag]] = values[:, k]
    return xy


def _scenario_signals(view, n_steps: int) -> SignalStates:
    states = view.dynamic_map_states
    lanes: dict[int, int] = {}
    stop_points: list[tuple[float, float]] = []
    cells: list[tuple[int, int, int]] = []
    for step, dms in enumerate(states):
        for ls in dms.lane_states:
            k = lanes.get(ls.lane)
            if k is None:
                k = lanes[ls.lane] = len(lanes)
                stop_points.append((ls.stop_point.x, ls.stop_point.y))
            cells.append((step, k, ls.state))
    grid = np.zeros((max(n_steps, len(states)), len(lanes)), np.int8)
    for step, k, state in cells:
        grid[step, k] = state if 0 <= state < len(LANE_STATES) else 0
    return SignalStates(np.array(list(lanes), np.int64), grid,
                        np.array(stop_points, float).reshape(-1, 2))


def _neighbours(items) -> tuple[Neighbour, ...]:
    return tuple(Neighbour(int(n.feature_id), int(n.self_start_index), int(n.self_end_index),
                           int(n.neighbor_start_index), int(n.neighbor_end_index))
                 for n in items)


def _bounds(items) -> list[tuple[int, int, int]]:
    return [(int(b.lane_start_index), int(b.lane_end_index), int(b.boundary_feature_id))
            for b in items]


def scenario_road_map(data: bytes, *, source: str = "<record>") -> RoadMap:
    """The road map of one serialized ``Scenario`` proto.

    Raises:
        FileFormatError: the bytes are not a Scenario.
    """
    from tap_bench.womd import proto
    from tap_bench.womd.map_wire import read_map_wire

    wire = read_map_wire(data)
    if wire is not None:
        return _wire_road_map(wire, source)
    try:  # what the compiled reader leaves to protobuf (malformed bytes among them)
        view = proto.ScenarioMapPointsView.FromString(data)
        return _scenario_road_map(view, source)
    except DecodeError as err:
        raise FileFormatError(f"{source}: not a serialized WOMD Scenario proto (protobuf: "
                              f"{err}).") from None


def _wire_road_map(wire: Any, source: str) -> RoadMap:
    """The road map of a Scenario's map read from its wire format
    (:class:`tap_bench.womd.map_wire.MapWire`): what :func:`_scenario_road_map` makes of
    the same record read by protobuf."""
    ids = wire.ids.tolist()
    neighbours = [Neighbour(*row) for row in wire.neighbours.tolist()]
    bounds = [tuple(row) for row in wire.boundaries.tolist()]
    features = wire.features
    kind = features[:, 1]
    lane_rows = np.flatnonzero(kind == 1)
    (lane_ids, p0, p1, lane_types, has_speed, e0, e1, x0, x1, l0, l1, r0, r1, lb0, lb1, rb0,
     rb1) = features[lane_rows][:, [0, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16,
                                    17]].T.tolist()
    mph = (wire.speed_limit_mph[lane_rows] * MPH).tolist()
    columns = _LaneColumns(
        ids=lane_ids, types=[LANE_TYPES.get(k, "undefined") for k in lane_types],
        speed_limits=[v if has else np.nan for v, has in zip(mph, has_speed, strict=True)],
        entries=[tuple(ids[a:b]) for a, b in zip(e0, e1, strict=True)],
        exits=[tuple(ids[a:b]) for a, b in zip(x0, x1, strict=True)],
        lefts=[tuple(neighbours[a:b]) for a, b in zip(l0, l1, strict=True)],
        rights=[tuple(neighbours[a:b]) for a, b in zip(r0, r1, strict=True)],
        left_bounds=[bounds[a:b] for a, b in zip(lb0, lb1, strict=True)],
        right_bounds=[bounds[a:b] for a, b in zip(rb0, rb1, strict=True)])
    centres = _finite_slices(wire.points, np.asarray(p0, np.int64), np.asarray(p1, np.int64))
    points = wire.points
    lines, edges, crosswalks, stops = {}, [], [], []
    for k, (fid, kind_k, a, b) in enumerate(features[:, :4].tolist()):
        if kind_k in (2, 3):  # a road line, a road edge
            pts = points[a:b]
            lines[fid] = pts
            if kind_k == 3 and len(pts) >= 2:
                edges.append(pts)
        elif kind_k == 4:  # a crosswalk
            if b - a >= 3:
                crosswalks.append(points[a:b])
        elif kind_k == 5:  # a stop sign
            s0, s1 = int(features[k, 18]), int(features[k, 19])
            stops.append(StopSign(fid, wire.stop_position[k].copy(), tuple(ids[s0:s1])))
    return _finish_columns(wire.scenario_id, columns, centres, lines, edges, crosswalks,
                           stops, _wire_signals(wire), source, topology_given=True)


def _finite_slices(points: np.ndarray, starts: np.ndarray, ends: np.ndarray
                   ) -> list[np.ndarray]:
    """:func:`_finite_rows` of ``points[starts[i]:ends[i]]`` for each i, all at once."""
    counts = ends - starts
    total = int(counts.sum())
    at = np.repeat(starts - (np.cumsum(counts) - counts), counts) + np.arange(total)
    flat = points[at]
    finite = np.isfinite(flat).all(axis=1)
    if finite.all():
        return split_rows(flat, counts)
    owner = np.repeat(np.arange(len(counts)), counts)
    return split_rows(flat[finite], np.bincount(owner[finite], minlength=len(counts)))


def _wire_signals(wire: Any) -> SignalStates:
    """:func:`_scenario_signals` of a map read from its wire format: the lanes in the order
    first met, each one's first stop point, a step's last state of a lane kept."""
    lane, step = wire.signal_lane, wire.signal_step
    values, first, which = np.unique(lane, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # lanes in the order first met
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    column = rank[which]
    state = np.where((wire.signal_state >= 0) & (wire.signal_state < len(LANE_STATES)),
                     wire.signal_state, 0).astype(np.int8)
    grid = np.zeros((max(wire.n_timestamps, wire.n_map_states), len(values)), np.int8)
    cell = step * max(len(values), 1) + column
    if len(np.unique(cell)) == len(cell):
        grid[step, column] = state
    else:  # a lane reported twice in a step: its last state, as read one by one
        for i, k, value in zip(step.tolist(), column.tolist(), state.tolist(), strict=True):
            grid[i, k] = value
    return SignalStates(values[order].astype(np.int64), grid,
                        wire.signal_stop[first[order]].reshape(-1, 2))


def _scenario_road_map(view: Any, source: str) -> RoadMap:
    """The road map of a parsed :data:`~tap_bench.womd.proto.ScenarioMapPointsView`."""
    raw, stops = [], []
    shapes: list[tuple[str, int]] = []  # (kind, feature id) of each list of points
    point_lists: list = []  # ... decoded all at once
    for f in view.map_features:
        if f.HasField("lane"):
            lane = f.lane
            raw.append({"id": f.id,
                        "type": LANE_TYPES.get(lane.type, "undefined"),
                        "speed_limit": (lane.speed_limit_mph * MPH
                                        if lane.HasField("speed_limit_mph") else np.nan),
                        "entry": tuple(int(i) for i in lane.entry_lanes),
                        "exit": tuple(int(i) for i in lane.exit_lanes),
                        "left": _neighbours(lane.left_neighbors),
                        "right": _neighbours(lane.right_neighbors),
                        "left_b": _bounds(lane.left_boundaries),
                        "right_b": _bounds(lane.right_boundaries)})
            shapes.append(("lane", f.id))
            point_lists.append(lane.polyline)
        elif f.HasField("road_line"):
            shapes.append(("road_line", f.id))
            point_lists.append(f.road_line.polyline)
        elif f.HasField("road_edge"):
            shapes.append(("road_edge", f.id))
            point_lists.append(f.road_edge.polyline)
        elif f.HasField("crosswalk"):
            shapes.append(("crosswalk", f.id))
            point_lists.append(f.crosswalk.polygon)
        elif f.HasField("stop_sign"):
            p = f.stop_sign.position
            stops.append(StopSign(int(f.id), np.array([p.x, p.y]),
                                  tuple(int(i) for i in f.stop_sign.lane)))
    lines, edges, crosswalks = {}, [], []
    lanes = iter(raw)
    for (kind, feature_id), pts in zip(shapes, map_point_lists(point_lists), strict=True):
        if kind == "lane":
            next(lanes)["centre"] = pts
        elif kind == "crosswalk":
            if len(pts) >= 3:
                crosswalks.append(pts)
        else:
            lines[int(feature_id)] = pts
            if kind == "road_edge" and len(pts) >= 2:
                edges.append(pts)
    signals = _scenario_signals(view, len(view.timestamps_seconds))
    return _finish(view.scenario_id, raw, lines, edges, crosswalks, stops, signals, source,
                   topology_given=True)


# ------------------------------------------------------------------ ScenarioNet pickles

_SN_LANE_TYPES = {"LANE_FREEWAY": "freeway", "LANE_SURFACE_STREET": "surface_street",
                  "LANE_BIKE_LANE": "bike_lane"}


def _points(values) -> np.ndarray:
    """(n, 2) points [m] from ScenarioNet's (n, 2) or (n, 3) arrays."""
    pts = np.asarray(values, dtype=float)
    return pts[:, :2] if pts.ndim == 2 and pts.shape[1] >= 2 else pts.reshape(-1, 2)


def _sn_neighbours(items) -> tuple[Neighbour, ...]:
    out = []
    for n in items or ():
        if isinstance(n, dict):
            out.append(Neighbour(int(n["feature_id"]), int(n.get("self_start_index", 0)),
                                 int(n.get("self_end_index", 0)),
                                 int(n.get("neighbor_start_index", 0)),
                                 int(n.get("neighbor_end_index", 0))))
        else:  # an id alone: a neighbour along the whole lane
            out.append(Neighbour(int(n), 0, 1 << 30))
    return tuple(out)


def _sn_bounds(items) -> list[tuple[int, int, int]]:
    return [(int(b.get("lane_start_index", 0)), int(b.get("lane_end_index", 0)),
             int(b.get("boundary_feature_id", -1))) for b in items or ()
            if isinstance(b, dict)]


def scenarionet_road_map(scenario: dict, *, source: str = "<scenario>") -> RoadMap:
    """The road map of an unpickled ScenarioNet scenario
    (:func:`tap_bench.sources.scenarionet.load_scenarionet`).

    Raises:
        FileFormatError: ``map_features`` or ``dynamic_map_states`` is not ScenarioNet's.
    """
    meta = scenario.get("metadata", {}) if isinstance(scenario, dict) else {}
    sid = str(meta.get("scenario_id", scenario.get("id", Path(source).stem)))
    features = scenario.get("map_features") or {}
    if not isinstance(features, dict):
        raise FileFormatError(f"{source}: map_features is a {type(features).__name__}, where "
                              "a dict of features belongs.")
    raw, lines, edges, crosswalks, stops = [], {}, [], [], []
    try:
        for key, f in features.items():
            kind = str(f.get("type", ""))
            if kind.startswith("LANE"):
                mph = f.get("speed_limit_mph")
                raw.append({"id": int(key),
                            "centre": _points(f.get("polyline", [])),
                            "type": _SN_LANE_TYPES.get(kind, "undefined"),
                            "speed_limit": float(mph) * MPH if mph is not None else np.nan,
                            "entry": tuple(int(i) for i in f.get("entry_lanes", []) or []),
                            "exit": tuple(int(i) for i in f.get("exit_lanes", []) or []),
                            "left": _sn_neighbours(f.get("left_neighbor")),
                            "right": _sn_neighbours(f.get("right_neighbor")),
                            "left_b": _sn_bounds(f.get("left_boundaries")),
                            "right_b": _sn_bounds(f.get("right_boundaries"))})
            elif kind.startswith(("ROAD_LINE", "ROAD_EDGE")):
                pts = _points(f.get("polyline", []))
                lines[int(key)] = pts
                if kind.startswith("ROAD_EDGE") and len(pts) >= 2:
                    edges.append(pts)
            elif kind == "CROSSWALK":
                pts = _points(f.get("polygon", []))
                if len(pts) >= 3:
                    crosswalks.append(pts)
            elif kind == "STOP_SIGN":
                pos = np.asarray(f.get("position", [np.nan, np.nan]), float).ravel()[:2]
                stops.append(StopSign(int(key), pos,
                                      tuple(int(i) for i in f.get("lane", []) or [])))
    except (TypeError, ValueError, AttributeError) as err:
        raise FileFormatError(f"{source}: a map feature is malformed ({type(err).__name__}: "
                              f"{err}); is it a ScenarioNet scenario?") from None
    n_steps = len(np.asarray(meta.get("ts", []), float).ravel())
    signals = _sn_signals(scenario.get("dynamic_map_states") or {}, n_steps, source)
    return _finish(sid, raw, lines, edges, crosswalks, stops, signals, source,
                   topology_given=True)


def _sn_signals(states: dict, n_steps: int, source: str) -> SignalStates:
    names = {f"LANE_STATE_{name.upper()}": i for i, name in enumerate(LANE_STATES)}
    lanes, grid_cols, points = [], [], []
    for key, s in states.items():
        try:
            series = list((s.get("state") or {}).get("object_state", []))
            lane = int(s.get("lane", key))
            stop = np.asarray(s.get("stop_point", [np.nan, np.nan]), float).ravel()[:2]
        except (TypeError, ValueError, AttributeError) as err:
            raise FileFormatError(f"{source}: dynamic_map_states[{key!r}] is malformed "
                                  f"({err}).") from None
        col = np.zeros(max(n_steps, len(series)), np.int8)
        col[:len(series)] = [names.get(str(v), 0) for v in series]
        lanes.append(lane)
        grid_cols.append(col)
        points.append(stop)
    if not lanes:
        return SignalStates.empty(n_steps)
    n = max(len(c) for c in grid_cols)
    grid = np.zeros((n, len(lanes)), np.int8)
    for k, col in enumerate(grid_cols):
        grid[:len(col), k] = col
    return SignalStates(np.array(lanes, np.int64), grid, np.array(points, float))


# ------------------------------------------------------------------ tf.Example roadgraph

_RG_LANES = {1: "freeway", 2: "surface_street", 3: "bike_lane"}
_RG_EDGES = {15, 16}
_RG_STOP_SIGN = 17
_RG_CROSSWALK = 18


def tf_example_road_map(data: bytes, *, source: str = "<record>") -> RoadMap | None:
    """The road map of one motion ``tf.Example`` (None when it has no roadgraph). Its lanes
    carry no topology: successors are inferred and there are no neighbours."""
    from tap_bench.womd.tf_example import Example

    try:
        features = Example.FromString(data).features.feature
    except DecodeError as err:
        raise FileFormatError(f"{source}: not a serialized tf.Example ({err}).") from None
    if "roadgraph_samples/xyz" not in features:
        return None

    def values(key, dtype=float):
        f = features[key]
        kind = f.WhichOneof("kind")
        return np.array(getattr(f, kind).value if kind else [], dtype=dtype)

    sid = (features["scenario/id"].bytes_list.value[0].decode()
           if "scenario/id" in features else source)
    xyz = values("roadgraph_samples/xyz").reshape(-1, 3)
    kind = values("roadgraph_samples/type", np.int64)
    ids = values("roadgraph_samples/id", np.int64)
    valid = values("roadgraph_samples/valid", np.int64) > 0
    if not (len(xyz) == len(kind) == len(ids) == len(valid)):
        raise FileFormatError(f"{source}: roadgraph_samples/* features differ in length.")
    xyz, kind, ids = xyz[valid], kind[valid], ids[valid]
    cut = np.flatnonzero((ids[1:] != ids[:-1]) | (kind[1:] != kind[:-1])) + 1
    raw, edges, crosswalks, stops = [], [], [], []
    for part in np.split(np.arange(len(ids)), cut):
        if not len(part):
            continue
        k, pts = int(kind[part[0]]), xyz[part, :2]
        if k in _RG_LANES:
            raw.append({"id": int(ids[part[0]]), "centre": pts, "type": _RG_LANES[k]})
        elif k in _RG_EDGES and len(pts) >= 2:
            edges.append(pts)
        elif k == _RG_CROSSWALK and len(pts) >= 3:
            crosswalks.append(pts)
        elif k == _RG_STOP_SIGN:
            stops.append(StopSign(int(ids[part[0]]), pts[0]))
    signals = SignalStates.empty(91)
    if "traffic_light_state/current/state" in features:
        parts = [(p, values(f"traffic_light_state/{p}/state", np.int64)) for p in
                 ("past", "current", "future")]
        state = np.concatenate([v.reshape(-1, 16) for _, v in parts if len(v)], axis=0)
        lane = np.concatenate([values(f"traffic_light_state/{p}/id", np.int64).reshape(-1, 16)
                               for p, v in parts if len(v)], axis=0)
        x = np.concatenate([values(f"traffic_light_state/{p}/x").reshape(-1, 16)
                            for p, v in parts if len(v)], axis=0)
        y = np.concatenate([values(f"traffic_light_state/{p}/y").reshape(-1, 16)
                            for p, v in parts if len(v)], axis=0)
        ok = (lane >= 0) & (state > 0)
        uniq = np.unique(lane[ok])
        grid = np.zeros((state.shape[0], len(uniq)), np.int8)
        points = np.zeros((len(uniq), 2))
        for k, lid in enumerate(uniq):
            hit = ok & (lane == lid)
            rows, cols = np.nonzero(hit)
            grid[rows, k] = state[rows, cols]
            points[k] = (x[rows[0], cols[0]], y[rows[0], cols[0]])
        signals = SignalStates(uniq.astype(np.int64), grid, points)
    return _finish(sid, raw, {}, edges, crosswalks, stops, signals, source,
                   topology_given=False)
