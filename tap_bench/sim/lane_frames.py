"""Lane coordinates of many points on many lanes at once, from the lanes' geometry.

A lane's frame gives a point its longitudinal coordinate ``s`` (distance along the lane from
its start) and lateral offset ``r`` (to the left of its centre line, highway-env's sign).
For highway-env's three lane shapes the frames follow from the shape's parameters:

- straight (``start``, unit ``direction`` and its normal ``direction_lateral``): ``s`` and
  ``r`` are the projections of ``p - start`` on the two unit vectors;
- sine (a straight lane whose centre line is offset by ``A sin(omega s + phi)``): the
  straight frame, ``r`` measured from the offset centre line;
- circular (``center``, ``radius``, ``start_phase``, turning ``direction`` +1 or -1): the
  point's polar angle relative to the start phase (wrapped to [-pi, pi)) times the radius
  gives ``s``, its distance inside the circle gives ``r``.

Any other lane (a user's class, or one of these whose frame methods a subclass or the
instance changes) is asked point by point through its public ``local_coordinates``,
``heading_at`` and ``width_at``.

:class:`LaneSet` holds the lanes of a road network as arrays and answers for all (point,
lane) pairs at once; :meth:`LaneSet.closest` is highway-env's
``RoadNetwork.get_closest_lane_index`` for many (position, heading) pairs: each lane's
distance (lateral offset, plus how far beyond either end, plus the heading's angle to the
lane), where two lanes are within :data:`TIE` of each other the network itself is asked.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

__all__ = ["TIE", "LaneSet", "lane_coordinates", "lane_heading", "lane_shape"]

TIE = 1e-9
"""Distance [m + rad] within which two lanes count as equally close (then the network's own
``get_closest_lane_index`` decides)."""

_STRAIGHT, _SINE, _CIRCULAR, _OTHER = 0, 1, 2, 3
_SHAPES = {"straight": _STRAIGHT, "sine": _SINE, "circular": _CIRCULAR, None: _OTHER}


@functools.cache
def _shape_of_class(cls: type) -> str | None:
    from highway_env.road.lane import CircularLane, SineLane, StraightLane

    for shape, base in (("sine", SineLane), ("straight", StraightLane),
                        ("circular", CircularLane)):
        if issubclass(cls, base) and all(
                getattr(cls, name) is getattr(base, name)
                for name in ("local_coordinates", "heading_at", "width_at", "position")):
            return shape
    return None


def lane_shape(lane: Any) -> str | None:
    """``"straight"``, ``"sine"`` or ``"circular"``: the frame of ``lane`` follows from that
    shape's parameters; None: ask the lane (its class or the instance defines its own)."""
    shape = _shape_of_class(type(lane))
    if shape is not None and {"local_coordinates", "heading_at", "width_at"} & vars(lane).keys():
        return None
    return shape


class LaneSet:
    """Lanes as arrays: their frames and headings for many points at once.

    Args:
        lanes: (index, lane) pairs, e.g. every lane of a network in the network's order.
    """

    def __init__(self, lanes: list[tuple[Any, Any]]) -> None:
        self.lanes = lanes
        self.column = {id(lane): j for j, (_, lane) in enumerate(lanes)}
        m = len(lanes)
        self.kind = np.array([_SHAPES[lane_shape(lane)] for _, lane in lanes], dtype=int)
        flat = np.flatnonzero(self.kind <= _SINE)
        circular = np.flatnonzero(self.kind == _CIRCULAR)
        self.flat, self.circular = flat, circular
        self.other = np.flatnonzero(self.kind == _OTHER).tolist()
        self.sine = np.flatnonzero(self.kind == _SINE)
        self.straight_only = bool((self.kind == _STRAIGHT).all())
        p = np.zeros((m, 12))  # the parameters of each shape, 0 where not used
        for j, (_, lane) in enumerate(lanes):
            if self.kind[j] <= _SINE:
                p[j, :7] = (*lane.start, *lane.direction, *lane.direction_lateral, lane.heading)
                if self.kind[j] == _SINE:
                    p[j, 7:10] = (lane.amplitude, lane.pulsation, lane.phase)
            elif self.kind[j] == _CIRCULAR:
                p[j, :5] = (*lane.center, lane.radius, lane.start_phase, lane.direction)
        self._p = p
        self.length = np.array([float(lane.length) for _, lane in lanes])
        self._kinds, self._params, self._lengths = (self.kind.tolist(), p.tolist(),
                                                    self.length.tolist())
        self._boxes = [_box(kind, params, length) for kind, params, length
                       in zip(self._kinds, self._params, self._lengths, strict=True)]
        self.width = np.array([float(lane.width) if k != _OTHER else np.nan
                               for (_, lane), k in zip(lanes, self.kind, strict=True)])

    def coordinates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, m) longitudinal and (n, m) lateral coordinates [m] of ``points`` (n, 2) on
        every lane."""
        n, m = len(points), len(self.lanes)
        s, r = np.empty((n, m)), np.empty((n, m))
        x, y = points[:, :1], points[:, 1:2]
        if len(self.flat):
            p = self._p[self.flat]
            dx, dy = x - p[:, 0], y - p[:, 1]
            s[:, self.flat] = dx * p[:, 2] + dy * p[:, 3]
            r[:, self.flat] = dx * p[:, 4] + dy * p[:, 5]
            if len(self.sine):
                q = self._p[self.sine]
                r[:, self.sine] -= q[:, 7] * np.sin(q[:, 8] * s[:, self.sine] + q[:, 9])
        if len(self.circular):
            p = self._p[self.circular]
            dx, dy = x - p[:, 0], y - p[:, 1]
            turned = np.remainder(np.arctan2(dy, dx) - p[:, 3] + np.pi, 2 * np.pi) - np.pi
            s[:, self.circular] = p[:, 4] * turned * p[:, 2]
            r[:, self.circular] = p[:, 4] * (p[:, 2] - np.hypot(dx, dy))
        for j in self.other:
            lane = self.lanes[j][1]
            sr = np.array([lane.local_coordinates(point) for point in points],
                          dtype=float).reshape(n, 2)
            s[:, j], r[:, j] = sr[:, 0], sr[:, 1]
        return s, r

    def heading(self, columns: np.ndarray, s: np.ndarray) -> np.ndarray:
        """The heading [rad] of lane ``columns[i]`` at ``s[i]`` (both of one shape, any
        dimensions)."""
        if self.straight_only:
            return self._p[columns, 6] + 0.0 * s
        kind, p = self.kind[columns], self._p[columns]
        out = np.where(kind == _CIRCULAR, p[..., 4] * s / np.where(kind == _CIRCULAR,
                                                                   p[..., 2], 1.0)
                       + p[..., 3] + np.pi / 2 * p[..., 4], p[..., 6])
        sine = kind == _SINE
        if sine.any():
            out = out + np.where(sine, np.arctan(p[..., 7] * p[..., 8]
                                                 * np.cos(p[..., 8] * s + p[..., 9])), 0.0)
        other = kind == _OTHER
        if other.any():
            for i in zip(*np.nonzero(other), strict=True):
                out[i] = self.lanes[int(columns[i])][1].heading_at(float(s[i]))
        return out

    def widths(self, column: int, s: np.ndarray) -> np.ndarray | float:
        """Lane ``column``'s width [m] at ``s`` (a number for the three shapes)."""
        if self.kind[column] != _OTHER:
            return float(self.width[column])
        lane = self.lanes[column][1]
        return np.array([lane.width_at(v) for v in s], dtype=float)

    def closest(self, network: Any, positions: np.ndarray, headings: np.ndarray) -> list[Any]:
        """The index of the lane closest to each (position, heading), as the network's
        ``get_closest_lane_index(position, heading)`` answers it (``self``: every lane of
        ``network`` in its order)."""
        n = len(positions)
        if n == 0:
            return []
        s, r = self.coordinates(positions)
        columns = np.broadcast_to(np.arange(len(self.lanes)), s.shape)
        angle = np.abs(np.remainder(headings[:, None] - self.heading(columns, s) + np.pi,
                                    2 * np.pi) - np.pi)
        distance = (np.abs(r) + np.maximum(s - self.length, 0) + np.maximum(-s, 0) + angle)
        nearest = distance.argmin(axis=1)
        best = distance[np.arange(n), nearest]
        ties = ((distance <= best[:, None] + TIE).sum(axis=1) > 1) | ~np.isfinite(best)
        out = [self.lanes[j][0] for j in nearest.tolist()]
        for k in np.flatnonzero(ties).tolist():
            out[k] = network.get_closest_lane_index(positions[k], headings[k])
        return out


    # -- the same, one lane or one point at a time, in plain floats (small roads) ---------
    def frame_one(self, column: int, xs: list[float],
                  ys: list[float]) -> tuple[list[float], list[float]]:
        """The longitudinal and lateral coordinates [m] of the points ``(xs[i], ys[i])``
        on lane ``column``, as lists (:meth:`coordinates`' column ``column``)."""
        kind, p = self._kinds[column], self._params[column]
        if kind <= _SINE:
            x0, y0, ux, uy, nx, ny = p[:6]
            s = [(x - x0) * ux + (y - y0) * uy for x, y in zip(xs, ys, strict=True)]
            r = [(x - x0) * nx + (y - y0) * ny for x, y in zip(xs, ys, strict=True)]
            if kind == _SINE:
                amplitude, pulsation, phase = p[7:10]
                r = [r_i - amplitude * math.sin(pulsation * s_i + phase)
                     for s_i, r_i in zip(s, r, strict=True)]
            return s, r
        if kind == _CIRCULAR:
            cx, cy, radius, start, direction = p[:5]
            s, r = [], []
            for x, y in zip(xs, ys, strict=True):
                dx, dy = x - cx, y - cy
                turned = (math.atan2(dy, dx) - start + math.pi) % (2 * math.pi) - math.pi
                s.append(direction * turned * radius)
                r.append(direction * (radius - math.hypot(dx, dy)))
            return s, r
        lane = self.lanes[column][1]
        sr = [lane.local_coordinates(np.array((x, y))) for x, y in zip(xs, ys, strict=True)]
        return [float(a) for a, _ in sr], [float(b) for _, b in sr]

    def point_frame(self, column: int, x: float, y: float) -> tuple[float, float]:
        """The longitudinal and lateral coordinate [m] of the point (x, y) on lane
        ``column``."""
        kind, p = self._kinds[column], self._params[column]
        if kind == _STRAIGHT:
            dx, dy = x - p[0], y - p[1]
            return dx * p[2] + dy * p[3], dx * p[4] + dy * p[5]
        if kind == _CIRCULAR:
            dx, dy = x - p[0], y - p[1]
            turned = (math.atan2(dy, dx) - p[3] + math.pi) % (2 * math.pi) - math.pi
            return p[4] * turned * p[2], p[4] * (p[2] - math.hypot(dx, dy))
        (s,), (r,) = self.frame_one(column, [x], [y])
        return s, r

    def heading_one(self, column: int, s: float) -> float:
        """:meth:`heading` of one lane at one longitudinal coordinate ``s`` [m]."""
        kind, p = self._kinds[column], self._params[column]
        if kind == _STRAIGHT:
            return p[6]
        if kind == _CIRCULAR:
            return p[4] * s / p[2] + p[3] + math.pi / 2 * p[4]
        if kind == _SINE:
            return p[6] + math.atan(p[7] * p[8] * math.cos(p[8] * s + p[9]))
        return float(self.lanes[column][1].heading_at(s))

    def closest_one(self, network: Any, x: float, y: float, heading: float) -> Any:
        """:meth:`closest` of one (position, heading) [m, rad].

        A lane's distance is at least the point's distance to the box around the lane's
        centre line (:func:`_box`; a lane's distance holds its lateral offset plus how far
        beyond an end, at least the Euclidean distance to its centre line), so the lanes are
        taken nearest box first and the search stops at the first box farther than the best
        distance found plus :data:`TIE`."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return network.get_closest_lane_index(np.array((x, y)), heading)
        bounds = []
        for x0, x1, y0, y1 in self._boxes:
            dx = x0 - x if x < x0 else x - x1 if x > x1 else 0.0
            dy = y0 - y if y < y0 else y - y1 if y > y1 else 0.0
            bounds.append(math.hypot(dx, dy))
        best = second = math.inf
        nearest = -1
        kinds, params, lengths = self._kinds, self._params, self._lengths
        for j in sorted(range(len(bounds)), key=bounds.__getitem__):
            if bounds[j] > best + TIE:
                break
            kind, p, length = kinds[j], params[j], lengths[j]
            if kind == _STRAIGHT:
                dx, dy = x - p[0], y - p[1]
                s, r, lane_heading = dx * p[2] + dy * p[3], dx * p[4] + dy * p[5], p[6]
            else:
                s, r = self.point_frame(j, x, y)
                lane_heading = self.heading_one(j, s)
            angle = abs((heading - lane_heading + math.pi) % (2 * math.pi) - math.pi)
            distance = (abs(r) + (s - length if s > length else 0.0) + (-s if s < 0 else 0.0)
                        + angle)
            if distance < best:
                best, second, nearest = distance, best, j
            elif distance < second:
                second = distance
            elif distance != distance:  # NaN
                best = math.nan
                break
        if not second > best + TIE or not math.isfinite(best):
            return network.get_closest_lane_index(np.array((x, y)), heading)
        return self.lanes[nearest][0]


def _box(kind: int, p: list[float], length: float) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) [m] of a box holding every point of a lane's centre
    line (for a sine lane, of the straight line it winds around, widened by the amplitude;
    for a circular lane, of 16 chords of its arc, widened by the chords' largest distance to
    the arc); infinite for a lane of another kind."""
    if kind <= _SINE:
        x0, y0, ux, uy = p[:4]
        xs, ys = [x0, x0 + ux * length], [y0, y0 + uy * length]
        pad = abs(p[7]) if kind == _SINE else 0.0
    elif kind == _CIRCULAR:
        cx, cy, radius, start, direction = p[:5]
        sweep = length / radius if radius > 0 else 0.0
        phases = [start + direction * sweep * i / 16 for i in range(17)]
        xs = [cx + radius * math.cos(phase) for phase in phases]
        ys = [cy + radius * math.sin(phase) for phase in phases]
        pad = radius * (1 - math.cos(min(sweep / 32, math.pi / 2)))
    else:
        return (-math.inf, math.inf, -math.inf, math.inf)
    pad += 1e-6 * (1 + max(map(abs, xs + ys)))  # rounding
    return (min(xs) - pad, max(xs) + pad, min(ys) - pad, max(ys) + pad)


def lane_coordinates(lane: Any, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) longitudinal and (n,) lateral coordinates [m] of ``points`` (n, 2) on ``lane``."""
    s, r = LaneSet([(None, lane)]).coordinates(np.asarray(points, dtype=float).reshape(-1, 2))
    return s[:, 0], r[:, 0]


def lane_heading(lane: Any, s: np.ndarray) -> np.ndarray:
    """(n,) the lane's heading [rad] at longitudinal coordinates ``s`` (n,)."""
    s = np.asarray(s, dtype=float)
    return LaneSet([(None, lane)]).heading(np.zeros(len(s), dtype=int), s)
