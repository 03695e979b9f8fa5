"""WOMD lanes as highway-env lanes, with their frames and the lane lookup computed here from
the lanes' geometry.

A WOMD lane centre line becomes a :class:`FastPolyLane`: highway-env's
``PolyLaneFixedWidth``, which samples the line every metre into poses (a point ``p_k``, the
unit tangent ``t_k`` of the segment that starts there, the arc length ``s_k``). The lane's
frame is piecewise linear over those poses:

- a point ``q`` belongs to the last pose ``k >= 1`` that it lies at or beyond along that
  pose's tangent (``t_k . (q - p_k) >= 0``), or to the first pose when there is none; its
  longitudinal coordinate is ``s_k + t_k . (q - p_k)`` and its lateral coordinate
  ``n_k . (q - p_k)``, ``n_k`` the left normal (:meth:`FastPolyLane.local_coordinates`);
- the lane's heading at ``s`` is the tangent's angle at the last pose with ``s_k <= s`` (the
  first pose before the lane's start).

:class:`LaneIndex` looks up the lane closest to a position and heading (the lateral offset,
plus how far beyond either end, plus the heading's angle to the lane: the distance
highway-env's ``get_closest_lane_index`` minimises) over every lane of a scene in one
compiled pass; where two lanes are within :data:`TOLERANCE`, the lanes' own
``distance_with_heading`` decides, the first minimum in the network's order.
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
from collections.abc import Sequence
from typing import Any

import numba
import numpy as np
from highway_env.road.lane import PolyLaneFixedWidth
from highway_env.road.spline import LinearSpline2D

from tap_bench.womd.roadmap import split_rows

__all__ = ["MIN_LANE_LENGTH", "TOLERANCE", "FastPolyLane", "LaneIndex", "lane_points",
           "lanes_points", "project_positions"]

MIN_LANE_LENGTH = 1.0
"""[m] highway-env samples a poly lane every metre and cannot build one shorter than this:
shorter WOMD lanes (short connectors) are extended along their direction to this length."""

TOLERANCE = 1e-6
"""[m] lanes whose distance is this close to the smallest are compared again."""


@numba.njit(cache=True, nogil=True)
def _owner(px, py, tx, ty, x, y):  # pragma: no cover - compiled
    """The pose the point (x, y) belongs to (see the module docstring): the last one after
    the first whose normal line it is on or ahead of, else the first (looked for from the
    end)."""
    for k in range(px.shape[0] - 1, 0, -1):
        if tx[k] * (x - px[k]) + ty[k] * (y - py[k]) >= 0:
            return k
    return 0


@numba.njit(cache=True, nogil=True)
def _frame(px, py, tx, ty, s, x, y):  # pragma: no cover - compiled
    """(longitudinal, lateral) [m] of the point (x, y) in the frame of one lane's poses."""
    k = _owner(px, py, tx, ty, x, y)
    dx, dy = x - px[k], y - py[k]
    return s[k] + tx[k] * dx + ty[k] * dy, tx[k] * dy - ty[k] * dx


@numba.njit(cache=True, nogil=True)
def _frames(px, py, tx, ty, s, xs, ys):  # pragma: no cover - compiled
    lon = np.empty(xs.shape[0])
    lat = np.empty(xs.shape[0])
    for i in range(xs.shape[0]):
        lon[i], lat[i] = _frame(px, py, tx, ty, s, xs[i], ys[i])
    return lon, lat


@numba.njit(cache=True, nogil=True)
def _pose_at(s, a, b, lon):  # pragma: no cover - compiled
    """The last pose ``k`` of ``a:b`` with ``s[k] <= lon`` after the first (arc lengths
    ``s`` non-decreasing; ``a`` when there is none, ``b - 1`` for a NaN ``lon``), by
    bisection."""
    if not lon == lon:  # not a number: the last pose
        return b - 1
    lo, hi = a + 1, b  # the first pose after a with s > lon is in lo..hi
    while lo < hi:
        mid = (lo + hi) // 2
        if s[mid] <= lon:
            lo = mid + 1
        else:
            hi = mid
    return lo - 1


@numba.njit(cache=True, nogil=True)
def _lane_distances(offsets, px, py, tx, ty, s, lengths, x, y, heading, use_heading
                    ):  # pragma: no cover - compiled
    """Distance of the point to every lane: |lateral| + overshoot beyond either end (+ the
    heading's angle to the lane at that point). Lane j's poses are offsets[j]:offsets[j+1]
    of the concatenated arrays."""
    out = np.empty(offsets.shape[0] - 1)
    for j in range(out.shape[0]):
        a, b = offsets[j], offsets[j + 1]
        lon, lat = _frame(px[a:b], py[a:b], tx[a:b], ty[a:b], s[a:b], x, y)
        d = abs(lat) + max(lon - lengths[j], 0.0) + max(-lon, 0.0)
        if use_heading:
            k = _pose_at(s, a, b, lon)
            turn = (heading - math.atan2(ty[k], tx[k]) + math.pi) % (2 * math.pi) - math.pi
            d += abs(turn)
        out[j] = d
    return out


@numba.njit(cache=True, nogil=True)
def _bounds_into(boxes, reach, x, y, bound):  # pragma: no cover - compiled
    """Fill ``bound`` (n_lanes,) with a lower bound of each lane's distance to the point
    (x, y) (:func:`_near_lane_distances`): the distance to the box of its poses less
    ``reach[j]``, or with seven columns of ``boxes`` the larger of that and the bound of
    :meth:`LaneIndex._wedges`. Returns the first lane of the smallest bound."""
    wedges = boxes.shape[1] >= 7
    first = 0
    for j in range(boxes.shape[0]):
        dx = max(boxes[j, 0] - x, x - boxes[j, 2], 0.0)
        dy = max(boxes[j, 1] - y, y - boxes[j, 3], 0.0)
        box = np.sqrt(dx * dx + dy * dy)
        bound[j] = box - reach[j]
        if wedges:
            bound[j] = max(bound[j], min((box - boxes[j, 4]) / (1.0 + boxes[j, 5]),
                                         box - boxes[j, 6], box))
        if bound[j] < bound[first]:
            first = j
    return first


@numba.njit(cache=True, nogil=True)
def _bounds(boxes, reach, xs, ys):  # pragma: no cover - compiled
    """(n_points, n_lanes) :func:`_bounds_into` of every point."""
    out = np.empty((xs.shape[0], boxes.shape[0]))
    for q in range(xs.shape[0]):
        _bounds_into(boxes, reach, xs[q], ys[q], out[q])
    return out


@numba.njit(cache=True, nogil=True)
def _near_lane_distances(offsets, px, py, tx, ty, s, lengths, boxes, reach, xs, ys, headings
                         ):  # pragma: no cover - compiled
    """(n_points, n_lanes) :func:`_lane_distances` with the heading, +inf for the lanes
    that surely cannot be within :data:`TOLERANCE` of the nearest.

    A lane's distance is at least the distance from the point to the bounding box of its
    poses (``boxes[j]``: x min, y min, x max, y max) minus ``reach[j]`` (the larger of its
    length and its last arc length; arc lengths start at 0 and do not decrease): the
    point is ``sqrt(lon'^2 + lateral^2)`` from its pose, ``lon'`` its longitudinal offset
    there, and whatever of ``lon'`` the lateral part does not cover is overshoot beyond an
    end, up to ``reach[j]``. Where ``boxes`` has seven columns, the larger of that and the
    bound of :meth:`LaneIndex._wedges` (columns 4-6: slack, slope, tail) is taken. A lane
    whose bound is beyond the nearest distance found so far + TOLERANCE + 1e-6 m
    (rounding) is not measured; the lane of the smallest bound is measured first."""
    n_lanes = offsets.shape[0] - 1
    out = np.full((xs.shape[0], n_lanes), np.inf)
    bound = np.empty(n_lanes)
    for q in range(xs.shape[0]):
        x, y = xs[q], ys[q]
        first = _bounds_into(boxes, reach, x, y, bound)
        best = np.inf
        for step in range(n_lanes + 1):
            j = first if step == 0 else step - 1
            if (step > 0 and j == first) or bound[j] > best + TOLERANCE + 1e-6:
                continue
            a, b = offsets[j], offsets[j + 1]
            lon, lat = _frame(px[a:b], py[a:b], tx[a:b], ty[a:b], s[a:b], x, y)
            d = abs(lat) + max(lon - lengths[j], 0.0) + max(-lon, 0.0)
            k = _pose_at(s, a, b, lon)
            turn = ((headings[q] - math.atan2(ty[k], tx[k]) + math.pi) % (2 * math.pi)
                - math.pi)
            d += abs(turn)
            out[q, j] = d
            if d < best:
                best = d
    return out


@numba.njit(cache=True, nogil=True)
def _nearest_lane(offsets, px, py, tx, ty, s, lengths, boxes, reach, x, y, heading
                  ):  # pragma: no cover - compiled
    """(the lane of the smallest :func:`_near_lane_distances` of the point (x, y) and
    heading, the first such; how many lanes are within :data:`TOLERANCE` of it), or (-1, 0)
    where no distance is finite or one is NaN."""
    d = _near_lane_distances(offsets, px, py, tx, ty, s, lengths, boxes, reach,
                             np.full(1, x), np.full(1, y), np.full(1, heading))[0]
    best = np.inf
    j = -1
    for k in range(d.shape[0]):
        if d[k] != d[k]:
            return -1, 0
        if d[k] < best:
            best = d[k]
            j = k
    if j < 0:
        return -1, 0
    n = 0
    for k in range(d.shape[0]):
        if d[k] <= best + TOLERANCE:
            n += 1
    return j, n


def lane_points(centre: np.ndarray) -> np.ndarray | None:
    """A centre line (n, 2) [m] highway-env can build a lane on: repeated points dropped,
    extended along its last direction to :data:`MIN_LANE_LENGTH` when shorter; None for a
    line of a single distinct point (no direction)."""
    pts = np.asarray(centre, dtype=np.float64).reshape(-1, 2)
    if len(pts) < 2:
        return None
    step = np.hypot(*np.diff(pts, axis=0).T)
    pts = pts[np.concatenate(([True], step > 1e-6))]
    if len(pts) < 2:
        return None
    length = float(np.hypot(*np.diff(pts, axis=0).T).sum())
    if length < MIN_LANE_LENGTH + 1e-9:
        d = pts[-1] - pts[-2]
        d = d / np.hypot(*d)
        pts = np.vstack([pts, pts[-1] + d * (MIN_LANE_LENGTH + 1e-6 - length)])
    return pts


def lanes_points(centres: Sequence[np.ndarray]) -> list[np.ndarray | None]:
    """:func:`lane_points` of many centre lines (n_i, 2) [m] at once (the same arrays)."""
    lines = [np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in centres]
    out: list[np.ndarray | None] = [None] * len(lines)
    many = [k for k, pts in enumerate(lines) if len(pts) >= 2]
    if not many:
        return out
    sizes = np.array([len(lines[k]) for k in many])
    starts = np.cumsum(sizes) - sizes
    points = np.concatenate([lines[k] for k in many])
    step = np.hypot(*np.diff(points, axis=0).T)
    keep = np.r_[True, step > 1e-6]
    keep[starts] = True  # every line's first point (the step before it is another line's)
    kept = np.add.reduceat(keep, starts)
    moved = np.where(keep[1:], step, 0.0)
    moved[starts[1:] - 1] = 0.0  # no step between two lines
    rough = np.add.reduceat(np.r_[moved, 0.0], starts)  # each line's length, to ~1e-12
    parts = split_rows(points[keep], kept)
    for k, count, length, pts in zip(many, kept.tolist(), rough.tolist(), parts, strict=True):
        if count < 2:
            continue
        # near or under the shortest lane: the single-line rule decides, exactly
        out[k] = lane_points(lines[k]) if length < MIN_LANE_LENGTH + 1e-6 else pts
    return out


def _poses(lane: PolyLaneFixedWidth) -> tuple[np.ndarray, ...]:
    """(px, py, tx, ty, s): the poses of a highway-env poly lane as arrays."""
    poses = lane.curve.poses
    p = np.array([pose.position for pose in poses], dtype=np.float64).reshape(-1, 2)
    t = np.array([pose.normal for pose in poses], dtype=np.float64).reshape(-1, 2)
    return (np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1]),
            np.ascontiguousarray(t[:, 0]), np.ascontiguousarray(t[:, 1]),
            np.asarray(lane.curve.s_samples, dtype=np.float64))


@numba.njit(cache=True, nogil=True)
def _lane_poses(x, y, offsets):  # pragma: no cover - compiled
    """The arc lengths and the poses of many polylines at once.

    Polyline j is the points ``offsets[j]:offsets[j + 1]`` of ``x``, ``y`` [m] (two or more
    distinct points). Its poses are every metre of arc length from its start
    (``s = 0, 1, ... floor(length)``), each point linearly interpolated on the segment it
    falls on (the end point itself where ``s`` lands on one), with the unit tangent of the
    chord to the next pose (the last pose keeps the one before it).

    Returns:
        arc (n_points,) cumulative arc length [m] at each point; starts (n_lanes + 1,) lane
        j's poses are ``starts[j]:starts[j + 1]`` of px, py (points [m]), tx, ty (unit
        tangents) and s (arc lengths [m]).
    """
    n_lanes = offsets.shape[0] - 1
    arc = np.empty(x.shape[0])
    starts = np.zeros(n_lanes + 1, np.int64)
    for j in range(n_lanes):
        a, b = offsets[j], offsets[j + 1]
        arc[a] = 0.0
        total = 0.0
        for i in range(a + 1, b):
            dx, dy = x[i] - x[i - 1], y[i] - y[i - 1]
            total += np.sqrt(dx * dx + dy * dy)
            arc[i] = total
        starts[j + 1] = starts[j] + int(np.floor(total)) + 1
    px, py = np.empty(starts[n_lanes]), np.empty(starts[n_lanes])
    tx, ty = np.empty(starts[n_lanes]), np.empty(starts[n_lanes])
    s = np.empty(starts[n_lanes])
    for j in range(n_lanes):
        a, n = offsets[j], offsets[j + 1] - offsets[j]
        c, m = starts[j], starts[j + 1] - starts[j]
        k = 0  # the segment [k, k + 1] the pose lies on
        for i in range(m):
            at = float(i)
            while k + 1 < n and arc[a + k + 1] <= at:
                k += 1
            s[c + i] = at
            if k == n - 1 or arc[a + k] == at:
                px[c + i], py[c + i] = x[a + k], y[a + k]
            else:
                run = arc[a + k + 1] - arc[a + k]
                px[c + i] = (x[a + k + 1] - x[a + k]) / run * (at - arc[a + k]) + x[a + k]
                py[c + i] = (y[a + k + 1] - y[a + k]) / run * (at - arc[a + k]) + y[a + k]
        for i in range(m):
            if m < 2:  # shorter than a metre: no chord (refused by the caller)
                tx[c + i], ty[c + i] = np.nan, np.nan
                continue
            q = c + min(i, m - 2)
            dx, dy = px[q + 1] - px[q], py[q + 1] - py[q]
            norm = np.sqrt(dx * dx + dy * dy)
            tx[c + i], ty[c + i] = dx / norm, dy / norm
    return arc, starts, px, py, tx, ty, s


def _frames_of(lines: Sequence[np.ndarray]) -> tuple[Any, ...]:
    """:func:`_lane_poses` of centre lines (n_i, 2) [m]: (arc, offsets, starts, (px, py,
    tx, ty, s), s as a list, the poses' headings [rad] as a list)."""
    offsets = np.zeros(len(lines) + 1, dtype=np.int64)
    np.cumsum([len(points) for points in lines], out=offsets[1:])
    points = np.concatenate(lines) if len(lines) else np.zeros((0, 2))
    arc, starts, px, py, tx, ty, s = _lane_poses(np.ascontiguousarray(points[:, 0]),
                                                 np.ascontiguousarray(points[:, 1]), offsets)
    return (arc, offsets, starts, (px, py, tx, ty, s), s.tolist(),
            np.arctan2(ty, tx).tolist())


class FastPolyLane(PolyLaneFixedWidth):
    """highway-env's ``PolyLaneFixedWidth`` with its poses, frame, heading and positions
    computed here from the centre line (see the module docstring). highway-env's own curve
    object (``curve``) is built only when something asks for it.

    Attributes:
        womd_id: the WOMD lane id.
        arrays: (px, py, tx, ty, s) of the lane's poses: points [m], unit tangents, arc
            lengths [m].
    """

    def __init__(self, lane_points: Sequence[Sequence[float]], width: float, *,
                 womd_id: int = -1, speed_limit: float = 20.0,
                 line_types: tuple[Any, Any] | None = None, forbidden: bool = False,
                 priority: int = 0) -> None:
        points = np.asarray(lane_points, dtype=np.float64).reshape(-1, 2)
        self._frame_from(points, *_frames_of([points]), 0, width, womd_id, speed_limit,
                         line_types, forbidden, priority)

    @classmethod
    def many(cls, lines: Sequence[np.ndarray], widths: Sequence[float], *,
             womd_ids: Sequence[int], speed_limits: Sequence[float],
             line_types: Sequence[tuple[Any, Any] | None]) -> list[FastPolyLane]:
        """One lane per centre line (n_i, 2) [m] (each of two or more distinct points, at
        least :data:`MIN_LANE_LENGTH` long: :func:`lane_points`), their poses computed in
        one compiled pass; the other arguments per lane as in the constructor."""
        frames = _frames_of(lines)
        out = []
        for j, points in enumerate(lines):
            lane = cls.__new__(cls)
            lane._frame_from(points, *frames, j, widths[j], womd_ids[j], speed_limits[j],
                             line_types[j], False, 0)
            out.append(lane)
        return out

    def _frame_from(self, points: np.ndarray, arc: np.ndarray, offsets: np.ndarray,
                    starts: np.ndarray, poses: tuple[np.ndarray, ...], s_list: list[float],
                    headings: list[float], j: int, width: float, womd_id: int,
                    speed_limit: float, line_types: tuple[Any, Any] | None, forbidden: bool,
                    priority: int) -> None:
        """Set the lane from line ``j`` of :func:`_frames_of`'s arrays (its own slices of
        them are taken when first asked for: most lanes of a scene are never asked)."""
        a, b = int(offsets[j]), int(offsets[j + 1])
        c, d = int(starts[j]), int(starts[j + 1])
        if d - c < 2:
            raise ValueError(f"a lane needs a centre line of at least {MIN_LANE_LENGTH} m "
                             f"of two distinct points; this one is {arc[b - 1]:.3f} m long")
        self._points = points
        self._shared = (arc, poses, s_list, headings, a, b, c, d)
        self.length = arc[b - 1]
        self.width = width
        self.line_types = line_types
        self.forbidden = forbidden
        self.speed_limit = speed_limit
        self.priority = priority
        self.womd_id = int(womd_id)

    @functools.cached_property
    def arrays(self) -> tuple[np.ndarray, ...]:
        """(px, py, tx, ty, s) of the lane's poses: points [m], unit tangents, arc lengths
        [m]."""
        _, poses, _, _, _, _, c, d = self._shared
        return tuple(values[c:d] for values in poses)

    @functools.cached_property
    def _arc(self) -> np.ndarray:
        arc, _, _, _, a, b, _, _ = self._shared
        return arc[a:b]

    @functools.cached_property
    def _s_list(self) -> list[float]:
        _, _, s_list, _, _, _, c, d = self._shared
        return s_list[c:d]

    @functools.cached_property
    def _headings(self) -> list[float]:
        _, _, _, headings, _, _, c, d = self._shared
        return headings[c:d]

    @functools.cached_property
    def curve(self) -> LinearSpline2D:
        """highway-env's curve of the centre line (built at the first use)."""
        return LinearSpline2D(self._points.tolist())

    def _along(self, longitudinal: float) -> tuple[float, float]:
        """The centre line's point [m] at arc length ``longitudinal`` [m], continued
        straight along the first and last segments beyond the ends."""
        arc, pts = self._arc, self._points
        end = 0 if longitudinal < arc[0] else -2 if longitudinal > arc[-1] else None
        if end is not None:  # beyond an end: the interpolation would be thrown away
            run = arc[end + 1] - arc[end]
            x = pts[end, 0] + (pts[end + 1, 0] - pts[end, 0]) / run * (longitudinal - arc[end])
            y = pts[end, 1] + (pts[end + 1, 1] - pts[end, 1]) / run * (longitudinal - arc[end])
            return x, y
        return (float(np.interp(longitudinal, arc, pts[:, 0])),
                float(np.interp(longitudinal, arc, pts[:, 1])))

    def position(self, longitudinal: float, lateral: float) -> np.ndarray:
        """The point [m] ``lateral`` [m] left of the centre line at arc length
        ``longitudinal`` [m], across the heading of the pose there."""
        yaw = self.heading_at(longitudinal)
        left = np.array([-np.sin(yaw), np.cos(yaw)])
        return np.array(self._along(longitudinal)) + lateral * left

    def centre_points(self, longitudinals: np.ndarray) -> np.ndarray:
        """(k, 2) :meth:`position` (lateral 0) of each of ``longitudinals`` (k,) [m], the
        same values to the bit, the centre line interpolated for all of them at once."""
        arc, pts = self._arc, self._points
        along = np.asarray(longitudinals, dtype=np.float64).reshape(-1)
        out = np.empty((len(along), 2))
        x, y = out[:, 0], out[:, 1]
        x[:], y[:] = np.interp(along, arc, pts[:, 0]), np.interp(along, arc, pts[:, 1])
        first, last = float(arc[0]), float(arc[-1])
        values = along.tolist()
        for i, value in enumerate(values):
            if value < first or value > last:
                x[i], y[i] = self._along(value)  # beyond an end: straight on
        # position adds 0 x the left normal: it changes nothing but the sign of a zero
        # coordinate (-0.0 + 0.0 is 0.0), so only there is the heading looked up
        if x.all() and y.all():  # no zero coordinate (the usual case): nothing to do
            return out
        for i in np.flatnonzero((x == 0.0) | (y == 0.0)).tolist():
            yaw = np.array([self.heading_at(values[i])], dtype=np.float64)
            x[i] = (x[i:i + 1] + 0.0 * -np.sin(yaw))[0]
            y[i] = (y[i:i + 1] + 0.0 * np.cos(yaw))[0]
        return out

    _last_frame: tuple[float, float, tuple[float, float]] | None = None  # the last asked

    def local_coordinates(self, position: np.ndarray) -> tuple[float, float]:
        x, y = float(position[0]), float(position[1])
        # the same point asked again (a vehicle's decision asks about its own place on its
        # lane four times or so): the answer kept, where no zero can carry its sign into it
        last = self._last_frame
        if last is not None and last[0] == x and last[1] == y and x != 0.0 and y != 0.0:
            return last[2]
        found = _frame(*self.arrays, x, y)
        self._last_frame = (x, y, found)
        return found

    def heading_at(self, longitudinal: float) -> float:
        if longitudinal != longitudinal:  # not a number: the last pose
            return self._headings[-1]
        return self._headings[max(bisect.bisect_right(self._s_list, longitudinal) - 1, 0)]

    def project(self, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(longitudinal, lateral) [m] of many positions at once."""
        return _frames(*self.arrays, np.ascontiguousarray(xs, dtype=np.float64),
                       np.ascontiguousarray(ys, dtype=np.float64))


def project_positions(lane: FastPolyLane, positions: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(longitudinal, lateral) [m] of positions (n, 2) on ``lane``."""
    return lane.project(positions[:, 0], positions[:, 1])


def _shared_poses(lanes: Sequence[Any]) -> tuple[np.ndarray, tuple[np.ndarray, ...]] | None:
    """(offsets, (px, py, tx, ty, s)) when ``lanes`` are all the lanes of one
    :meth:`FastPolyLane.many` call, in its order: the arrays they are slices of, equal to
    their concatenation; else None."""
    if not lanes or not all(isinstance(lane, FastPolyLane) for lane in lanes):
        return None
    first = lanes[0]._shared
    poses = first[1]
    ends = [lane._shared[6:8] for lane in lanes]
    if (any(lane._shared[1] is not poses for lane in lanes) or ends[0][0] != 0
            or ends[-1][1] != len(poses[0])
            or any(a[1] != b[0] for a, b in itertools.pairwise(ends))):
        return None
    offsets = np.array([0] + [d for _, d in ends], dtype=np.int64)
    return offsets, tuple(poses)


class LaneIndex:
    """The lane closest to a position (and heading) among the lanes of one network.

    Args:
        lanes: (lane index, lane) in the network's order; every lane a
            ``PolyLaneFixedWidth`` (a :class:`FastPolyLane` or highway-env's own).
    """

    def __init__(self, lanes: Sequence[tuple[Any, PolyLaneFixedWidth]]) -> None:
        self.indexes = [index for index, _ in lanes]
        self.lanes = [lane for _, lane in lanes]
        shared = _shared_poses(self.lanes)
        if shared is not None:  # lanes built together, in order: their arrays as they are
            self.offsets, (self.px, self.py, self.tx, self.ty, self.s) = shared
        else:
            arrays = [lane.arrays if isinstance(lane, FastPolyLane) else _poses(lane)
                      for lane in self.lanes]
            self.offsets = np.zeros(len(arrays) + 1, dtype=np.int64)
            np.cumsum([len(a[0]) for a in arrays], out=self.offsets[1:])
            self.px, self.py, self.tx, self.ty, self.s = (
                np.concatenate([a[i] for a in arrays]) if arrays else np.zeros(0)
                for i in range(5))
        self.lengths = np.array([lane.length for lane in self.lanes], dtype=np.float64)
        # each lane's bounding box of poses and how much its distance can fall short of
        # the distance to that box (_near_lane_distances); no bound (inf) for arc lengths
        # that do not start at 0 or that decrease
        self.boxes = np.zeros((len(self.lanes), 4))
        self.reach = np.full(len(self.lanes), np.inf)
        if len(self.lanes):
            starts = self.offsets[:-1]
            self.boxes = np.ascontiguousarray(np.c_[
                np.minimum.reduceat(self.px, starts), np.minimum.reduceat(self.py, starts),
                np.maximum.reduceat(self.px, starts), np.maximum.reduceat(self.py, starts)])
            step = np.diff(self.s)
            step[self.offsets[1:-1] - 1] = 0.0  # from one lane to the next
            falls = np.add.reduceat(np.r_[step < 0, False], starts) > 0
            ordered = (self.s[starts] == 0.0) & ~falls
            last = self.s[self.offsets[1:] - 1]
            self.reach = np.where(ordered, np.maximum(self.lengths, last), np.inf)
            self.boxes = np.ascontiguousarray(np.c_[self.boxes, self._wedges(ordered, last)])

    def _wedges(self, ordered: np.ndarray, last: np.ndarray) -> np.ndarray:
        """(n_lanes, 3) per lane (slack [m], slope, tail [m]) of the tighter lower bound of
        its distance that :func:`_near_lane_distances` takes with the box's.

        A point belongs to pose k before the last when it is ahead of pose k's normal line
        and behind pose k + 1's (module docstring). In pose k's frame (longitudinal lon,
        lateral lat), with e the step to pose k + 1 and theta the turn from tangent k to
        tangent k + 1 (under 90 degrees), behind the next normal line means
        lon < e_lon + (e_lat - lat) tan(theta) <= slack + |lat| slope, so the point's
        distance to the pose is at most slack + |lat| (1 + slope), and the lane's
        distance (|lat| at least) is at least (D - slack) / (1 + slope), D the distance to
        the box of the poses. A point of the last pose is ``lon - s_last`` beyond it, at
        least D - (length - s_last) = D - tail; one behind the first pose's normal line is
        |lon| behind its start: D.
        A lane with a turn of 90 degrees or more between poses, with tangents that are not
        unit vectors or with arc lengths that do not start at 0 or decrease gets slack
        inf (no bound beyond the box's reach)."""
        n = len(self.lanes)
        out = np.zeros((n, 3))
        out[:, 0] = np.inf
        out[:, 2] = self.lengths - last
        starts, ends = self.offsets[:-1], self.offsets[1:]
        px, py, tx, ty = self.px, self.py, self.tx, self.ty
        if not n or len(px) < 2 or not (ends > starts).all():  # a lane without poses
            out[:, 1] = 0.0
            out[:, 2] = np.inf
            return out
        with np.errstate(invalid="ignore", divide="ignore"):
            # pose i and pose i + 1 (of the next lane at each lane's last pose: left out)
            ex, ey = px[1:] - px[:-1], py[1:] - py[:-1]
            e_lon, e_lat = tx[:-1] * ex + ty[:-1] * ey, tx[:-1] * ey - ty[:-1] * ex
            cos = tx[:-1] * tx[1:] + ty[:-1] * ty[1:]
            sin = tx[:-1] * ty[1:] - ty[:-1] * tx[1:]
            slope = np.where(cos > 0, np.abs(sin) / cos, np.inf)
            slack = e_lon + np.abs(e_lat) * slope
            slope = np.r_[np.where(np.isnan(slope), np.inf, slope), 0.0]
            slack = np.r_[np.where(np.isnan(slack), np.inf, slack), -np.inf]
            slope[ends - 1] = 0.0  # each lane's last pose: nothing ahead of it
            slack[ends - 1] = -np.inf
            worst_slope = np.maximum.reduceat(slope, starts)
            worst_slack = np.maximum.reduceat(slack, starts)
            unit = np.abs(tx * tx + ty * ty - 1.0) <= 1e-12
            all_unit = np.add.reduceat(~unit, starts) == 0
            good = (ordered & all_unit & (ends - starts >= 2) & np.isfinite(worst_slope)
                    & np.isfinite(worst_slack) & np.isfinite(out[:, 2]))
        out[good, 0] = np.maximum(worst_slack[good], 0.0)
        out[good, 1] = worst_slope[good]
        out[~good, 1] = 0.0
        out[~good, 2] = np.inf
        return out

    def distances(self, position: np.ndarray, heading: float | None = None) -> np.ndarray:
        """(n_lanes,) each lane's distance [m (+ rad)] to the position (and heading)."""
        return _lane_distances(self.offsets, self.px, self.py, self.tx, self.ty, self.s,
                               self.lengths, float(position[0]), float(position[1]),
                               0.0 if heading is None else float(heading), heading is not None)

    def closest_many(self, positions: np.ndarray, headings: np.ndarray) -> list[Any]:
        """:meth:`closest` of many positions (n, 2) [m] with their headings (n,) [rad], the
        distances in one compiled pass."""
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        headings = np.asarray(headings, dtype=np.float64).reshape(-1)
        if not len(self.lanes):
            return [None] * len(positions)
        distance = _near_lane_distances(
            self.offsets, self.px, self.py, self.tx, self.ty, self.s, self.lengths,
            self.boxes, self.reach, np.ascontiguousarray(positions[:, 0]),
            np.ascontiguousarray(positions[:, 1]), np.ascontiguousarray(headings))
        best = distance.min(axis=1)
        alone = (distance <= best[:, None] + TOLERANCE).sum(axis=1) == 1
        nearest = distance.argmin(axis=1)
        return [None if not math.isfinite(b) else self.indexes[j] if one
                else self.closest(p, h)  # a tie: the lanes' own distance decides
                for b, one, j, p, h in zip(best.tolist(), alone.tolist(), nearest.tolist(),
                                           positions, headings.tolist(), strict=True)]

    def closest(self, position: np.ndarray, heading: float | None = None) -> Any:
        """The index of the closest lane (None where no distance is finite)."""
        if heading is None or not len(self.lanes):
            distance = self.distances(position, heading)
        else:  # the lanes that cannot be the closest not measured
            j, near = _nearest_lane(self.offsets, self.px, self.py, self.tx, self.ty,
                                    self.s, self.lengths, self.boxes, self.reach,
                                    float(position[0]), float(position[1]), float(heading))
            if near == 1:  # one nearest (the usual case): no tie to break
                return self.indexes[j]
            if j < 0:
                return None
            distance = _near_lane_distances(
                self.offsets, self.px, self.py, self.tx, self.ty, self.s, self.lengths,
                self.boxes, self.reach, np.array([float(position[0])]),
                np.array([float(position[1])]), np.array([float(heading)]))[0]
        best = float(distance.min()) if len(distance) else math.inf
        if not math.isfinite(best):
            return None
        near = np.flatnonzero(distance <= best + TOLERANCE).tolist()
        if len(near) == 1:
            return self.indexes[near[0]]
        mine = [PolyLaneFixedWidth.distance_with_heading(self.lanes[j], position, heading)
                for j in near]  # ties: the lanes' own distance, the first smallest
        return self.indexes[near[int(np.argmin(mine))]]
