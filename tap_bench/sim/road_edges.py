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
- **Indexed once per scene.** The segments are bucketed in a grid of :data:`EDGE_CELL` m
  cells; a query searches the rings of cells around each point out to its reach (compiled),
  so a step's query costs the segments near the point, not all of the scene's. The same
  index answers the ego's off-road measure (:mod:`tap_bench.sim.womd_road`) and the realism
  score's distance to the road edge (:mod:`tap_bench.realism.features`).

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

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba
import numpy as np

__all__ = ["EDGE_CELL", "EDGE_REACH", "JOIN_DISTANCE", "LEAVE_MARGIN", "OFF_ROAD_TOLERANCE",
           "RoadEdges", "box_corners", "left_road"]

EDGE_REACH = 15.0  # [m] an edge farther than this from the box's centre does not decide
JOIN_DISTANCE = 1.0  # [m] an edge end this close to another edge (or its own start) is joined
OFF_ROAD_TOLERANCE = 0.3  # [m] a box corner this far beyond an edge is still on the road
LEAVE_MARGIN = 1.0  # [m] started off the road: off only when this much farther out
EDGE_CELL = 5.0  # [m] side of the grid cells the nearest-segment search buckets segments in
TIE = 1e-9  # [m] segments this much nearer than the nearest are as near (a shared vertex)


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
    """A scene's road edges as segments, grid-indexed (see the module docstring).

    Attributes:
        a, b: (m, 2) segment starts and ends [m], along each edge's direction.
        open_start: (m,) the segment starts an edge whose start is open.
        open_end: (m,) the segment ends an edge whose end is open.
        owner: (m,) the polyline each segment belongs to.
    """

    a: np.ndarray
    b: np.ndarray
    open_start: np.ndarray
    open_end: np.ndarray
    owner: np.ndarray = field(default=None)  # type: ignore[assignment]
    _grid: tuple = field(default=(), repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.owner is None:
            object.__setattr__(self, "owner", np.arange(len(self.a), dtype=np.int64))
        object.__setattr__(self, "_grid", _build_grid(self.a, self.b))

    @classmethod
    def from_polylines(cls, lines: Sequence[np.ndarray]) -> RoadEdges:
        """Segments of edge polylines ((n_i, 2) each [m], WOMD's axes); repeated points
        dropped, polylines of one distinct point left out. All polylines cleaned at once
        (the same points as one by one: non-finite points dropped, then each point within
        1e-6 m of the one before it on its polyline)."""
        arrays = [np.asarray(line, float)[:, :2] for line in lines]
        n = len(arrays)
        pts = np.concatenate(arrays) if n else np.zeros((0, 2))
        line_of = np.repeat(np.arange(n, dtype=np.int64), [len(p) for p in arrays])
        a, b, owner, first, last, head, tail = _segments_of(
            np.ascontiguousarray(pts), line_of, n)
        if not len(a):
            z = np.zeros((0, 2))
            return cls(z, z, np.zeros(0, bool), np.zeros(0, bool), np.zeros(0, np.int64))
        open_start = np.zeros(len(a), bool)
        open_end = np.zeros(len(a), bool)
        edges = cls(a, b, open_start, open_end, owner)
        # an end is open when it meets no other polyline (nor its own start: closed)
        ends = np.concatenate([head, tail])
        own = np.r_[np.arange(len(head)), np.arange(len(head))].astype(np.int64)
        grid = edges._grid
        _, dist, _, _ = _grid_nearest(np.ascontiguousarray(ends), own, a, b, owner, *grid,
                                      JOIN_DISTANCE)
        closed = np.hypot(*(head - tail).T) <= JOIN_DISTANCE
        m = len(head)
        open_start[first[~closed & ~(dist[:m] <= JOIN_DISTANCE)]] = True
        open_end[last[~closed & ~(dist[m:] <= JOIN_DISTANCE)]] = True
        return edges

    def __len__(self) -> int:
        return len(self.a)

    def signed_distance(self, points: np.ndarray, reach: float = EDGE_REACH) -> np.ndarray:
        """Signed distance [m] of points to the drivable area: positive off the road
        (right of the nearest edge), negative on it; NaN where no edge is within ``reach``
        (or the point is not finite).

        Args:
            points: (n, 2) [m].
            reach: edges farther than this [m] do not decide.

        Returns:
            (n,) [m].
        """
        points = np.asarray(points, float).reshape(-1, 2)
        out = np.full(len(points), np.nan)
        ok = np.isfinite(points).all(axis=1)
        if not len(self.a) or not ok.any():
            return out
        out[ok] = self._signed(np.ascontiguousarray(points[ok]), float(reach))
        return out

    def _signed(self, points: np.ndarray, reach: float) -> np.ndarray:
        """:meth:`signed_distance` of finite points (n, 2) [m], contiguous, in one compiled
        pass."""
        return _signed_distances(points, self.a, self.b, self.owner, self.open_start,
                                 self.open_end, *self._grid, reach)

    def box_distance(self, x: float, y: float, heading: float, length: float, width: float,
                     reach: float = EDGE_REACH) -> float:
        """Signed distance [m] of a box to the drivable area: the largest over its four
        corners (positive: a corner is off the road); NaN when no edge is within ``reach``
        of the box's centre."""
        if not len(self.a) or not (math.isfinite(x) and math.isfinite(y)):
            return float("nan")
        far = float(reach + math.hypot(length, width))
        # numpy's cosine and sine, as box_corners takes them: the same corners to the bit
        c, s = float(np.cos(heading)), float(np.sin(heading))
        if math.isfinite(c) and math.isfinite(s) and math.isfinite(far):
            return float(_box_signed(float(x), float(y), c, s, float(length), float(width),
                                     float(reach), far, self.a, self.b, self.owner,
                                     self.open_start, self.open_end, *self._grid))
        if not math.isfinite(self._signed(np.array([[x, y]], float), float(reach))[0]):
            return float("nan")
        corners = box_corners(x, y, heading, length, width)
        return float(np.max(self.signed_distance(corners, far)))


@numba.njit(cache=True, nogil=True)
def _segments_of(pts, line_of, n):  # pragma: no cover - compiled
    """The segments of ``n`` polylines whose points ``pts`` (m, 2) [m] are concatenated
    (point i of polyline ``line_of[i]``), cleaned as :meth:`RoadEdges.from_polylines` says:
    non-finite points dropped, then each point within 1e-6 m of the (finite) point before
    it on its polyline, then the polylines of fewer than two points left.

    Returns:
        (a, b) (s, 2) segment starts and ends, owner (s,) its polyline's number among those
        kept, first and last (p,) each kept polyline's first and last segment, head and
        tail (p, 2) its first and last point.
    """
    m = pts.shape[0]
    keep = np.zeros(m, np.bool_)
    counts = np.zeros(n, np.int64)
    prev = -1  # the finite point before
    for i in range(m):
        x, y = pts[i, 0], pts[i, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        if (prev < 0 or line_of[i] != line_of[prev]
                or math.hypot(x - pts[prev, 0], y - pts[prev, 1]) > 1e-6):
            keep[i] = True
            counts[line_of[i]] += 1
        prev = i
    poly = np.full(n, -1, np.int64)
    n_poly = 0
    n_seg = 0
    for j in range(n):
        if counts[j] >= 2:
            poly[j] = n_poly
            n_poly += 1
            n_seg += counts[j] - 1
    a = np.empty((n_seg, 2))
    b = np.empty((n_seg, 2))
    owner = np.empty(n_seg, np.int64)
    first = np.empty(n_poly, np.int64)
    last = np.empty(n_poly, np.int64)
    head = np.empty((n_poly, 2))
    tail = np.empty((n_poly, 2))
    k = 0
    before = -1  # the kept point before, on a kept polyline
    for i in range(m):
        if not keep[i] or poly[line_of[i]] < 0:
            continue
        p = poly[line_of[i]]
        if before >= 0 and poly[line_of[before]] == p:
            a[k, 0], a[k, 1] = pts[before, 0], pts[before, 1]
            b[k, 0], b[k, 1] = pts[i, 0], pts[i, 1]
            owner[k] = p
            k += 1
        else:
            head[p, 0], head[p, 1] = pts[i, 0], pts[i, 1]
            first[p] = k
        tail[p, 0], tail[p, 1] = pts[i, 0], pts[i, 1]
        last[p] = k - 1
        before = i
    return a, b, owner, first, last, head, tail


def _build_grid(a: np.ndarray, b: np.ndarray) -> tuple:
    """(cell start offsets, segment ids by cell, grid origin, nx, ny) of segments a -> b
    bucketed in :data:`EDGE_CELL` m cells (a segment in every cell its bounding box
    touches; in a cell, by segment id)."""
    if not len(a):
        return (np.zeros(2, np.int64), np.zeros(0, np.int64), np.zeros(2), 1, 1)
    a, b = np.asarray(a, float), np.asarray(b, float)
    found = _cell_ranges(a, b) if a.ndim == 2 and a.shape[1] == 2 and a.shape == b.shape else None
    if found is not None and found[0]:  # finite segments: in one compiled pass
        _, lo, lo_cell, hi_cell = found
    else:
        lo_xy, hi_xy = np.minimum(a, b), np.maximum(a, b)
        lo = lo_xy.min(axis=0) - EDGE_CELL
        lo_cell = np.floor((lo_xy - lo) / EDGE_CELL).astype(np.int64)
        hi_cell = np.floor((hi_xy - lo) / EDGE_CELL).astype(np.int64)
    nx, ny = int(hi_cell[:, 0].max()) + 2, int(hi_cell[:, 1].max()) + 2
    start, segs = _cells_by_count(lo_cell, hi_cell, nx, ny)
    return (start, segs, lo.astype(float), nx, ny)


@numba.njit(cache=True, nogil=True)
def _cell_ranges(a, b):  # pragma: no cover - compiled
    """(finite, grid origin (2,), lowest and highest cell (m, 2) int of each segment's
    bounding box) of segments a -> b ((m, 2) each, m >= 1), as :func:`_build_grid`
    computes them with numpy; finite False (the rest not to be used) where a coordinate is
    not finite."""
    m = a.shape[0]
    lo = np.empty(2)
    lo_cell = np.empty((m, 2), np.int64)
    hi_cell = np.empty((m, 2), np.int64)
    for d in range(2):
        low = np.inf
        for k in range(m):
            if not (np.isfinite(a[k, d]) and np.isfinite(b[k, d])):
                return False, lo, lo_cell, hi_cell
            low = min(low, a[k, d], b[k, d])
        lo[d] = low - EDGE_CELL
        for k in range(m):
            lo_cell[k, d] = int(np.floor((min(a[k, d], b[k, d]) - lo[d]) / EDGE_CELL))
            hi_cell[k, d] = int(np.floor((max(a[k, d], b[k, d]) - lo[d]) / EDGE_CELL))
    return True, lo, lo_cell, hi_cell


@numba.njit(cache=True, nogil=True)
def _cells_by_count(lo_cell, hi_cell, nx, ny):  # pragma: no cover - compiled
    """The grid's buckets by a counting sort: segment k lies in the cells (cx, cy) of
    ``lo_cell[k] <= (cx, cy) <= hi_cell[k]`` ((m, 2) int each), cell number cx * ny + cy.
    Returns (start (nx * ny + 1,): where each cell's entries begin, segs: the segment ids,
    cell by cell, in id order within a cell)."""
    start = np.zeros(nx * ny + 1, np.int64)
    for k in range(lo_cell.shape[0]):
        for cx in range(lo_cell[k, 0], hi_cell[k, 0] + 1):
            for cy in range(lo_cell[k, 1], hi_cell[k, 1] + 1):
                start[cx * ny + cy + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    segs = np.empty(start[nx * ny], np.int64)
    for k in range(lo_cell.shape[0]):
        for cx in range(lo_cell[k, 0], hi_cell[k, 0] + 1):
            for cy in range(lo_cell[k, 1], hi_cell[k, 1] + 1):
                c = cx * ny + cy
                segs[fill[c]] = k
                fill[c] += 1
    return start, segs


@numba.njit(cache=True, nogil=True)
def _grid_nearest(points, skip_owner, a, b, owner, start, segs, lo, nx, ny, reach
                  ):  # pragma: no cover - compiled
    """Per point: (nearest segment or -1, its distance, position along it (not clipped),
    signed distance to its line, positive left) over the segments within ``reach``, not of
    polyline ``skip_owner[i]``; among segments as near (within :data:`TIE`, a shared
    vertex) the one whose line the point is farthest from."""
    m = points.shape[0]
    best_j = np.full(m, -1, np.int64)
    best_d = np.full(m, np.inf)
    best_u = np.zeros(m)
    best_c = np.zeros(m)
    rings = int(reach / EDGE_CELL) + 1 if np.isfinite(reach) else max(nx, ny)
    for i in range(m):
        px, py = points[i, 0], points[i, 1]
        cx = int(np.floor((px - lo[0]) / EDGE_CELL))
        cy = int(np.floor((py - lo[1]) / EDGE_CELL))
        bd, bj, bu, bc = np.inf, -1, 0.0, 0.0
        for r in range(rings + 1):
            if bd < (r - 1) * EDGE_CELL:
                break  # every unvisited cell is farther than the nearest found
            for gx in range(cx - r, cx + r + 1):
                if gx < 0 or gx >= nx:
                    continue
                for gy in range(cy - r, cy + r + 1):
                    if gy < 0 or gy >= ny or max(abs(gx - cx), abs(gy - cy)) != r:
                        continue
                    c = gx * ny + gy
                    for q in range(start[c], start[c + 1]):
                        k = segs[q]
                        if owner[k] == skip_owner[i]:
                            continue
                        # its bounding box farther than the nearest found (+ the tie and
                        # a margin far above rounding): it cannot be nearer, nor tie
                        ex = max(min(a[k, 0], b[k, 0]) - px, px - max(a[k, 0], b[k, 0]), 0.0)
                        ey = max(min(a[k, 1], b[k, 1]) - py, py - max(a[k, 1], b[k, 1]), 0.0)
                        if ex * ex + ey * ey > (bd + TIE + 1e-6) * (bd + TIE + 1e-6):
                            continue
                        dx, dy = b[k, 0] - a[k, 0], b[k, 1] - a[k, 1]
                        n2 = max(dx * dx + dy * dy, 1e-12)
                        u = ((px - a[k, 0]) * dx + (py - a[k, 1]) * dy) / n2
                        t = min(max(u, 0.0), 1.0)
                        d = math.hypot(px - a[k, 0] - t * dx, py - a[k, 1] - t * dy)
                        cr = (dx * (py - a[k, 1]) - dy * (px - a[k, 0])) / math.sqrt(n2)
                        if d < bd - TIE or (d <= bd + TIE and abs(cr) > abs(bc)):
                            bd, bj, bu, bc = min(d, bd), k, u, cr
        if bd <= reach:
            best_j[i], best_d[i], best_u[i], best_c[i] = bj, bd, bu, bc
    return best_j, best_d, best_u, best_c


@numba.njit(cache=True, nogil=True)
def _signed_distances(points, a, b, owner, open_start, open_end, start, segs, lo, nx, ny,
                      reach):  # pragma: no cover - compiled
    """Signed distance [m] of finite points to the drivable area (see
    :meth:`RoadEdges.signed_distance`); NaN where no edge is within ``reach``."""
    n = points.shape[0]
    pick, near, u_p, side = _grid_nearest(points, np.full(n, -1, np.int64), a, b, owner,
                                          start, segs, lo, nx, ny, reach)
    out = np.full(n, np.nan)
    for i in range(n):
        j = pick[i]
        if j < 0:
            continue
        beyond_open = (open_start[j] and u_p[i] < 0) or (open_end[j] and u_p[i] > 1)
        out[i] = near[i] if side[i] < 0 and not beyond_open else -near[i]
    return out


@numba.njit(cache=True, nogil=True)
def _box_signed(x, y, c, s, length, width, reach, far, a, b, owner, open_start, open_end,
                start, segs, lo, nx, ny):  # pragma: no cover - compiled
    """:meth:`RoadEdges.box_distance` of one box whose centre (x, y) [m], cosine and sine
    of its heading and size [m] are finite: NaN when no edge is within ``reach`` of the
    centre, else the largest signed distance of its corners (:func:`box_corners`) over
    the edges within ``far``."""
    centre = np.empty((1, 2))
    centre[0, 0], centre[0, 1] = x, y
    if not np.isfinite(_signed_distances(centre, a, b, owner, open_start, open_end, start,
                                         segs, lo, nx, ny, reach)[0]):
        return np.nan
    lon = (0.5 * length, -0.5 * length, -0.5 * length, 0.5 * length)
    lat = (0.5 * width, 0.5 * width, -0.5 * width, -0.5 * width)
    corners = np.empty((4, 2))
    for i in range(4):
        corners[i, 0] = x + lon[i] * c - lat[i] * s
        corners[i, 1] = y + lon[i] * s + lat[i] * c
    d = _signed_distances(corners, a, b, owner, open_start, open_end, start, segs, lo, nx,
                          ny, far)
    best = d[0]
    for i in range(1, 4):
        if np.isnan(d[i]) or np.isnan(best):
            return np.nan
        best = max(best, d[i])
    return best
