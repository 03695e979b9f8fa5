"""A collision of the ego with its cause: the agent it hit and whether it was at fault
(SPEC section 8).

- **Who.** The agent whose box overlaps the ego's most (:func:`overlap_area`: the
  intersection of two oriented boxes, clipped as convex polygons), not the nearest centre:
  a car rear-ending the ego 5 m from a parked car beside it is the car that hit it. Where
  no box overlaps (highway-env crashes a pair that *will* intersect within the step, and
  pushes them apart), the agent whose box is nearest the ego's (:func:`box_gap`).
- **Fault** (:func:`fault`), as nuPlan and NAVSIM score at-fault collisions. The ego is
  not at fault when

  1. a pedestrian or cyclist enters the ego while it is stopped (speed below
     :data:`STOPPED_SPEED`): ``"walker into stopped ego"``;
  2. it is stopped and is hit: ``"hit while stopped"``;
  3. the other's front hits the ego's rear half from behind: the contact point (the
     overlap's centroid, else the midpoint of the boxes' nearest points) is in the ego's
     rear half and the other's front half, the other's centre is behind the ego's, and it
     drives within :data:`REAR_END_ANGLE` of the ego's heading: ``"hit from behind"``;

  otherwise it is at fault (``"at fault"``). Boxes that already overlap at the current
  time (1.0 s) are the record's, not collisions
  (:meth:`tap_bench.sim.womd_road.WomdRoad.start_collisions`).

Every function works in any right- or left-handed frame (front, rear, behind and areas do
not change in a mirror): highway-env's mirrored frame as well as WOMD's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tap_bench.sim.road_edges import box_corners

__all__ = ["REAR_END_ANGLE", "STOPPED_SPEED", "Box", "Fault", "box_gap", "collision_partner",
           "fault", "overlap_area"]

STOPPED_SPEED = 0.5  # [m/s] slower is stopped: hit there, the ego is not at fault
REAR_END_ANGLE = math.radians(60.0)  # a rear-ender drives within this of the ego's heading
WALKERS = ("pedestrian", "cyclist")


@dataclass(frozen=True)
class Box:
    """A road user's box at one step: centre (x, y) [m], heading [rad], speed [m/s],
    length and width [m], object type (``vehicle``, ``pedestrian``, ``cyclist``, ...)."""

    x: float
    y: float
    heading: float
    speed: float
    length: float
    width: float
    kind: str = "vehicle"

    @property
    def corners(self) -> np.ndarray:
        """(4, 2) corners, counter-clockwise in a right-handed frame."""
        return box_corners(self.x, self.y, self.heading, self.length, self.width)

    def longitudinal(self, point: np.ndarray) -> float:
        """Position of a point along the box's heading from its centre [m]."""
        return float((point[0] - self.x) * math.cos(self.heading)
                     + (point[1] - self.y) * math.sin(self.heading))


@dataclass(frozen=True)
class Fault:
    """Whether the ego was at fault, and the rule that decided (``"at fault"``, ``"hit
    while stopped"``, ``"hit from behind"``, ``"walker into stopped ego"``)."""

    at_fault: bool
    reason: str


def _clip(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the part of convex polygon ``subject`` inside convex polygon
    ``clip`` (both (n, 2), the same orientation)."""
    orientation = np.sign(_signed_area(clip)) or 1.0
    out = subject
    for i in range(len(clip)):
        if not len(out):
            break
        a, b = clip[i], clip[(i + 1) % len(clip)]
        inside = orientation * ((b[0] - a[0]) * (out[:, 1] - a[1])
                                - (b[1] - a[1]) * (out[:, 0] - a[0])) >= 0
        points = []
        for j in range(len(out)):
            p, q = out[j], out[(j + 1) % len(out)]
            pin, qin = inside[j], inside[(j + 1) % len(out)]
            if pin:
                points.append(p)
            if pin != qin:  # the edge p -> q crosses the clip line a -> b
                d = q - p
                denom = (b[0] - a[0]) * d[1] - (b[1] - a[1]) * d[0]
                t = (((b[0] - a[0]) * (a[1] - p[1]) - (b[1] - a[1]) * (a[0] - p[0])) / denom
                    if denom else 0.0)
                points.append(p + t * d)
        out = np.array(points).reshape(-1, 2)
    return out


def _signed_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _centroid(poly: np.ndarray) -> np.ndarray:
    area = _signed_area(poly)
    if abs(area) < 1e-12:
        return poly.mean(axis=0)
    x, y = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    return np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (6.0 * area)


def overlap_area(a: Box, b: Box) -> float:
    """Area [m^2] of the intersection of two boxes (0 when they do not overlap)."""
    return abs(_signed_area(_clip(a.corners, b.corners)))


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0)
    return a + t * ab


def box_gap(a: Box, b: Box) -> tuple[float, np.ndarray]:
    """(distance [m], midpoint of the nearest points) between two boxes' outlines; the
    distance is 0 when they overlap."""
    ca, cb = a.corners, b.corners
    if overlap_area(a, b) > 0:
        return 0.0, _centroid(_clip(ca, cb))
    best, mid = math.inf, (a.x + b.x, a.y + b.y)
    for corners, other in ((ca, cb), (cb, ca)):
        for p in corners:
            for k in range(4):
                q = _point_segment(p, other[k], other[(k + 1) % 4])
                d = float(np.hypot(*(p - q)))
                if d < best:
                    best, mid = d, (p + q) / 2
    return best, np.asarray(mid, float)


def collision_partner(ego: Box, others: list[Box]) -> int | None:
    """Index of the agent the ego collided with: the largest overlap of boxes, else (none
    overlaps) the nearest box; None without others."""
    if not others:
        return None
    areas = np.array([overlap_area(ego, o) for o in others])
    if areas.max() > 0:
        return int(np.argmax(areas))
    return int(np.argmin([box_gap(ego, o)[0] for o in others]))


def fault(ego: Box, other: Box) -> Fault:
    """Whether the ego is at fault in its collision with ``other`` (the module docstring's
    rules, in that order)."""
    stopped = ego.speed < STOPPED_SPEED
    if stopped and other.kind in WALKERS:
        return Fault(False, "walker into stopped ego")
    if stopped:
        return Fault(False, "hit while stopped")
    _, contact = box_gap(ego, other)
    behind = ego.longitudinal(np.array([other.x, other.y])) < 0
    same_way = math.cos(other.heading - ego.heading) >= math.cos(REAR_END_ANGLE)
    if (behind and same_way and ego.longitudinal(contact) < 0
            and other.longitudinal(contact) > 0):
        return Fault(False, "hit from behind")
    return Fault(True, "at fault")
