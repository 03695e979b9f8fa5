"""Lane coordinates of many points at once, from the lanes' geometry.

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

Any other lane (a user's class, or one of these whose frame methods a subclass changes) is
asked point by point through its public ``local_coordinates`` and ``heading_at``.

:func:`closest_lanes` is highway-env's ``RoadNetwork.get_closest_lane_index`` for many
(position, heading) pairs: each lane's distance (lateral offset, plus how far beyond either
end, plus the heading's angle to the lane) computed for all pairs at once; where two lanes
are within :data:`TIE` of each other, the network itself is asked.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

__all__ = ["TIE", "closest_lanes", "lane_coordinates", "lane_heading", "lane_shape"]

TIE = 1e-9
"""Distance [m + rad] within which two lanes count as equally close (then the network's own
``get_closest_lane_index`` decides)."""


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


def lane_coordinates(lane: Any, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) longitudinal and (n,) lateral coordinates [m] of ``points`` (n, 2) on ``lane``."""
    shape = lane_shape(lane)
    if shape == "straight" or shape == "sine":
        dx = points[:, 0] - lane.start[0]
        dy = points[:, 1] - lane.start[1]
        s = dx * lane.direction[0] + dy * lane.direction[1]
        r = dx * lane.direction_lateral[0] + dy * lane.direction_lateral[1]
        if shape == "sine":
            r = r - lane.amplitude * np.sin(lane.pulsation * s + lane.phase)
        return s, r
    if shape == "circular":
        dx = points[:, 0] - lane.center[0]
        dy = points[:, 1] - lane.center[1]
        turned = np.remainder(np.arctan2(dy, dx) - lane.start_phase + np.pi, 2 * np.pi) - np.pi
        return (lane.direction * turned * lane.radius,
                lane.direction * (lane.radius - np.hypot(dx, dy)))
    if len(points) == 0:
        return np.zeros(0), np.zeros(0)
    sr = np.array([lane.local_coordinates(p) for p in points], dtype=float)
    return sr[:, 0], sr[:, 1]


def lane_heading(lane: Any, s: np.ndarray) -> np.ndarray:
    """(n,) the lane's heading [rad] at longitudinal coordinates ``s`` (n,)."""
    shape = lane_shape(lane)
    if shape == "straight":
        return np.full(len(s), float(lane.heading))
    if shape == "sine":
        return lane.heading + np.arctan(lane.amplitude * lane.pulsation
                                        * np.cos(lane.pulsation * s + lane.phase))
    if shape == "circular":
        return lane.direction * s / lane.radius + lane.start_phase + np.pi / 2 * lane.direction
    return np.array([lane.heading_at(v) for v in s], dtype=float)


def lane_widths(lane: Any, s: np.ndarray) -> np.ndarray | float:
    """The lane's width [m] at ``s`` (a number for the three constant-width shapes)."""
    if lane_shape(lane) is not None:
        return float(lane.width)
    return np.array([lane.width_at(v) for v in s], dtype=float)


def closest_lanes(network: Any, lanes: list[tuple[Any, Any]], positions: np.ndarray,
                  headings: np.ndarray) -> list[Any]:
    """The index of the lane closest to each (position, heading), as the network's
    ``get_closest_lane_index(position, heading)`` answers it.

    Args:
        network: the road network (asked where two lanes tie within :data:`TIE`).
        lanes: (index, lane) of every lane of the network, in the network's order.
        positions: (n, 2) [m]; headings: (n,) [rad].
    """
    n = len(positions)
    if n == 0:
        return []
    distance = np.empty((n, len(lanes)))
    for j, (_, lane) in enumerate(lanes):
        s, r = lane_coordinates(lane, positions)
        angle = np.abs(np.remainder(headings - lane_heading(lane, s) + np.pi, 2 * np.pi)
                       - np.pi)
        distance[:, j] = (np.abs(r) + np.maximum(s - lane.length, 0) + np.maximum(-s, 0)
                          + angle)
    nearest = distance.argmin(axis=1)
    best = distance[np.arange(n), nearest]
    ties = ((distance <= best[:, None] + TIE).sum(axis=1) > 1) | ~np.isfinite(best)
    out = [lanes[j][0] for j in nearest.tolist()]
    for k in np.flatnonzero(ties).tolist():
        out[k] = network.get_closest_lane_index(positions[k], headings[k])
    return out
