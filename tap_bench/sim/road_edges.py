"""Off-road as the signed distance of a vehicle's box to the road edges (SPEC section 8).

WOMD draws its road edges (``ROAD_EDGE_BOUNDARY``, ``ROAD_EDGE_MEDIAN``) as polylines with
the drivable road on their **left** (checked on data: ``benchmarks/womd_edge_side.py``).
:class:`RoadEdges` holds a scene's edges as segments and answers, for any points, the
signed distance to the drivable area: **positive off the road**, negative on it (minus the
distance to the nearest edge).

- **The nearest segment decides.** A point's distance is to its nearest edge segment; its
  side is the side of that segment's line. Where the nearest point is a vertex shared by
  two segments (both equally near), the segment whose line the point is farther from
  decides (the textbook tie-break for polylines: right at convex and at reflex corners).
- **Open ends and gaps are road.** An edge end that meets no other edge (within
  :data:`JOIN_DISTANCE`) is open: a point whose nearest edge point is an open end, beyond
  it, is on the road (a driveway, a gap in the kerb, the end of the mapped edges). A
  closed polyline (a median island) has no open end.
- **Only near edges decide.** A point with no edge within :data:`EDGE_REACH` gets NaN:
  the caller falls back to another rule (the lanes, :mod:`tap_bench.sim.womd_road`).

**The box, not the centre.** A vehicle is off the road when any corner of its box is
(:func:`box_corners`, :meth:`RoadEdges.box_distance` = the largest corner distance): a
wheel over the kerb is off the road whatever the centre does, and a long vehicle turning
sweeps its corners where its centre never goes. The centre with half the width would miss
the front and rear overhangs in a turn and a box at an angle to the kerb.

**Leaving the road, not starting off it.** The off-road measure and the off-road
termination of ``tap_bench/womd-v0`` ask whether the ego *left* the road
(:func:`left_road`): off by more than :data:`OFF_ROAD_TOLERANCE` where it started on the
road, or by :data:`LEAVE_MARGIN` more than where it started when the human's start was off
it already (a car parked over the kerb). A policy is never ended for a start the human
made. The tolerance is the map's: WOMD edges are drawn kerb lines, and the parked human's
box crosses them by 0.14 m in one of our 16 real scenes.

Coordinates are WOMD's (y to the left, heading counter-clockwise) [m]: in highway-env's
mirrored frame the left of an edge is its right, so callers convert first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["EDGE_REACH", "JOIN_DISTANCE", "LEAVE_MARGIN", "OFF_ROAD_TOLERANCE", "RoadEdges",
           "box_corners", "left_road"]

EDGE_REACH = 15.0  # [m] an edge farther than this from the box's centre does not decide
JOIN_DISTANCE = 1.0  # [m] an edge end this close to another edge (or its own start) is joined
OFF_ROAD_TOLERANCE = 0.3  # [m] a box corner this far beyond an edge is still on the road
LEAVE_MARGIN = 1.0  # [m] started off the road: off only when this much farther out


def left_road(distance: float, start: float) -> bool:
    """Whether a vehicle whose box is ``distance`` [m] off the road (signed, positive off)
    left it, having started ``start`` [m] off it (NaN: not known, taken as on the road)."""
    if not distance > OFF_ROAD_TOLERANCE:  # NaN too
        return False
    if not start > OFF_ROAD_TOLERANCE:
        return True
    return distance > start + LEAVE_MARGIN


def box_corners(x: np.ndarray | float, y: np.ndarray | float, heading: np.ndarray | float,
                length: np.ndarray | float, width: np.ndarray | float) -> np.ndarray:
    """The four corners of oriented boxes, counter-clockwise from front left.

    Args:
        x, y, heading, length, width: centres [m], headings [rad], sizes [m]; any shapes
            that broadcast together (shape ``S``).

    Returns:
        (*S, 4, 2) corners [m].
    """
    x, y, heading, length, width = np.broadcast_arrays(
        *(np.asarray(v, float) for v in (x, y, heading, length, width)))
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    lon = np.array([0.5, -0.5, -0.5, 0.5]) * length[..., None]
    lat = np.array([0.5, 0.5, -0.5, -0.5]) * width[..., None]
    return np.stack([x[..., None] + lon * c - lat * s,
                     y[..., None] + lon * s + lat * c], axis=-1)


@dataclass(frozen=True)
class RoadEdges:
    """A scene's road edges as segments (see the module docstring).

    Attributes:
        a, b: (m, 2) segment starts and ends [m], along each edge's direction.
        open_start: (m,) the segment starts an edge whose start is open.
        open_end: (m,) the segment ends an edge whose end is open.
    """

    a: np.ndarray
    b: np.ndarray
    open_start: np.ndarray
    open_end: np.ndarray

    @classmethod
    def from_polylines(cls, lines: Sequence[np.ndarray]) -> RoadEdges:
        """Segments of edge polylines ((n_i, 2) each [m], WOMD's axes); repeated points
        dropped, polylines of one distinct point left out."""
        polys = []
        for line in lines:
            p = np.asarray(line, float)[:, :2]
            p = p[np.isfinite(p).all(axis=1)]
            if len(p) >= 2:
                keep = np.r_[True, np.hypot(*np.diff(p, axis=0).T) > 1e-6]
                p = p[keep]
            if len(p) >= 2:
                polys.append(p)
        if not polys:
            z = np.zeros((0, 2))
            return cls(z, z, np.zeros(0, bool), np.zeros(0, bool))
        a = np.concatenate([p[:-1] for p in polys])
        b = np.concatenate([p[1:] for p in polys])
        owner = np.concatenate([np.full(len(p) - 1, i) for i, p in enumerate(polys)])
        first = np.r_[0, np.cumsum([len(p) - 1 for p in polys])[:-1]]
        last = np.cumsum([len(p) - 1 for p in polys]) - 1
        open_start = np.zeros(len(a), bool)
        open_end = np.zeros(len(a), bool)
        for i, p in enumerate(polys):
            closed = np.hypot(*(p[0] - p[-1])) <= JOIN_DISTANCE
            for end, flags, seg in ((p[0], open_start, first[i]), (p[-1], open_end, last[i])):
                if closed:
                    continue
                others = owner != i
                if others.any():
                    d, _, _ = _segment_distance(end[None], a[others], b[others])
                    if d.min() <= JOIN_DISTANCE:
                        continue
                flags[seg] = True
        return cls(a, b, open_start, open_end)

    def __len__(self) -> int:
        return len(self.a)

    def signed_distance(self, points: np.ndarray, reach: float = EDGE_REACH) -> np.ndarray:
        """Signed distance [m] of points to the drivable area: positive off the road
        (right of the nearest edge), negative on it; NaN where no edge is within ``reach``.

        Args:
            points: (n, 2) [m].
            reach: edges farther than this [m] do not decide.

        Returns:
            (n,) [m].
        """
        points = np.asarray(points, float).reshape(-1, 2)
        out = np.full(len(points), np.nan)
        if not len(self.a) or not len(points):
            return out
        d, u, cross = _segment_distance(points, self.a, self.b)
        near = d.min(axis=1)
        tie = d <= near[:, None] + 1e-9
        # among the nearest segments, the one whose line the point is farthest from
        pick = np.argmax(np.where(tie, np.abs(cross), -1.0), axis=1)
        rows = np.arange(len(points))
        u_p, side = u[rows, pick], cross[rows, pick]
        beyond_open = (self.open_start[pick] & (u_p < 0)) | (self.open_end[pick] & (u_p > 1))
        off = (side < 0) & ~beyond_open
        out = np.where(off, near, -near)
        out[near > reach] = np.nan
        return out

    def box_distance(self, x: float, y: float, heading: float, length: float, width: float,
                     reach: float = EDGE_REACH) -> float:
        """Signed distance [m] of a box to the drivable area: the largest over its four
        corners (positive: a corner is off the road); NaN when no edge is within ``reach``
        of the box's centre."""
        if not len(self.a):
            return float("nan")
        d, _, _ = _segment_distance(np.array([[x, y]], float), self.a, self.b)
        near = float(d.min())
        if near > reach:
            return float("nan")
        # a corner's nearest segment is within the centre's nearest + the diagonal
        subset = np.flatnonzero(d[0] <= near + np.hypot(length, width) + 1e-9)
        edges = RoadEdges(self.a[subset], self.b[subset], self.open_start[subset],
                          self.open_end[subset])
        corners = box_corners(x, y, heading, length, width)
        return float(np.max(edges.signed_distance(corners, reach=np.inf)))


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(distance, position along, signed distance to the line) of (n, 2) points to (m, 2)
    segments a -> b: (n, m) each; position along is 0 at a and 1 at b (not clipped); the
    line distance is positive left of a -> b [m]."""
    ab = b - a
    n2 = np.maximum((ab ** 2).sum(axis=1), 1e-12)
    px = points[:, 0:1] - a[None, :, 0]
    py = points[:, 1:2] - a[None, :, 1]
    u = (px * ab[None, :, 0] + py * ab[None, :, 1]) / n2
    t = np.clip(u, 0.0, 1.0)
    d = np.hypot(px - t * ab[None, :, 0], py - t * ab[None, :, 1])
    cross = (ab[None, :, 0] * py - ab[None, :, 1] * px) / np.sqrt(n2)
    return d, u, cross
