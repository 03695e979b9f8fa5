"""The per-step features the realism score compares (SPEC section 9), as pure numpy functions.

Every function takes one simulation (or the log) of a scene as arrays over agents and steps:
``x, y, heading`` (n, T) [m, rad] in WOMD's axes, ``valid`` (n, T) bool, ``length, width``
(n,) [m]; it returns (n, T) arrays, NaN (or False) where the feature is undefined. The
definitions follow the Waymo Open Sim Agents Challenge 2025 (WOSAC: Montali et al., "The
Waymo Open Sim Agents Challenge", NeurIPS 2023, and the 2025 metrics configuration); they are
written here from those definitions:

- kinematic: linear speed [m/s] and acceleration [m/s^2], angular speed [rad/s] and
  acceleration [rad/s^2], by central differences of the positions and headings (a step is
  valid when the steps it differences are);
- distance to the nearest object [m]: signed distance between the agents' boxes (negative
  when they overlap: minus the penetration depth), the minimum over the other valid agents;
- collision: that distance below zero;
- time to collision [s]: to the agent followed (ahead of the front bumper, overlapping the
  agent's trail sideways, heading within 75 deg, within 10 deg when the overlap is under
  0.5 m) at constant speeds, capped at 5 s (also when nobody is followed or the gap opens);
- distance to the road edge [m]: the signed distance of the box's most off-road corner to
  the nearest road edge (WOMD draws edges with the road on their left: negative on the
  road), :func:`signed_edge_distance`; off-road: above zero;
- traffic-light violation: the centre crosses the stop point of a lane whose signal is red,
  moving along that lane.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np

__all__ = ["EDGE_CELL", "EDGE_SEARCH", "MAX_TTC", "TTC_HEADING", "TTC_SMALL_OVERLAP",
           "TTC_SMALL_OVERLAP_HEADING", "EdgeIndex", "box_corners", "box_signed_distance",
           "kinematic_features", "nearest_object_distance", "overlapping_pairs",
           "red_light_violations", "road_edge_distance", "signed_edge_distance",
           "time_to_collision"]

MAX_TTC = 5.0  # [s] time to collision when nobody is followed, the gap opens, or above it
TTC_HEADING = np.radians(75.0)  # [rad] widest heading difference to a followed agent
TTC_SMALL_OVERLAP = 0.5  # [m] below this sideways overlap ...
TTC_SMALL_OVERLAP_HEADING = np.radians(10.0)  # [rad] ... the heading must be this close
NEAREST_RANGE = 40.0  # [m] distances beyond this are not computed exactly (histogram top)
EDGE_SEARCH = 60.0  # [m] road edges farther than this from a point are not searched
EDGE_CELL = 5.0  # [m] side of the grid cells the edge search buckets segments in
SIGNAL_LATERAL = 0.5  # [m] beyond half the lane's width, a centre is not on the lane
SIGNAL_REACH = 10.0  # [m] a crossing of a stop point starts and ends this close to it


def _central(values: np.ndarray) -> np.ndarray:
    """(f[k+1] - f[k-1]) / 2 along the last axis, NaN at both ends."""
    out = np.full(values.shape, np.nan)
    out[..., 1:-1] = (values[..., 2:] - values[..., :-2]) / 2.0
    return out


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _central_valid(valid: np.ndarray) -> np.ndarray:
    out = np.zeros(valid.shape, bool)
    out[..., 1:-1] = valid[..., 2:] & valid[..., :-2]
    return out


def kinematic_features(x: np.ndarray, y: np.ndarray, heading: np.ndarray, valid: np.ndarray,
                       dt: float) -> dict[str, np.ndarray]:
    """Linear and angular speeds and accelerations by central differences.

    Args:
        x, y, heading: (..., T) [m, rad].
        valid: (..., T) bool.
        dt: seconds per step.

    Returns:
        ``linear_speed`` [m/s], ``linear_acceleration`` [m/s^2], ``angular_speed`` [rad/s],
        ``angular_acceleration`` [rad/s^2], each (..., T), NaN where a differenced step is
        invalid. A heading difference over two steps is wrapped at twice its one-step value
        (so turns up to pi/2 per step are read the short way round).
    """
    x = np.where(valid, x, np.nan)
    y = np.where(valid, y, np.nan)
    h = np.where(valid, heading, np.nan)
    speed = np.hypot(_central(x), _central(y)) / dt
    accel = _central(speed) / dt
    dh = _wrap(_central(h) * 2.0) / 2.0
    d2h = _wrap(_central(dh) * 2.0) / 2.0
    v1 = _central_valid(valid)
    v2 = _central_valid(v1)
    return {"linear_speed": np.where(v1, speed, np.nan),
            "linear_acceleration": np.where(v2, accel, np.nan),
            "angular_speed": np.where(v1, dh / dt, np.nan),
            "angular_acceleration": np.where(v2, d2h / dt ** 2, np.nan)}


def box_corners(x: np.ndarray, y: np.ndarray, heading: np.ndarray, length: np.ndarray,
                width: np.ndarray) -> np.ndarray:
    """Corners of oriented boxes, counter-clockwise from front-left... as (..., 4, 2) [m]."""
    c, s = np.cos(heading), np.sin(heading)
    hl, hw = np.asarray(length) / 2.0, np.asarray(width) / 2.0
    lx, ly = c * hl, s * hl  # half the length along the heading
    wx, wy = -s * hw, c * hw  # half the width to the left
    xs = np.stack([x + lx + wx, x - lx + wx, x - lx - wx, x + lx - wx], axis=-1)
    ys = np.stack([y + ly + wy, y - ly + wy, y - ly - wy, y + ly - wy], axis=-1)
    return np.stack([xs, ys], axis=-1)


def _point_segment(px, py, ax, ay, bx, by):
    """Distance from points to segments (broadcast) [m]."""
    dx, dy = bx - ax, by - ay
    n2 = dx * dx + dy * dy
    u = np.clip(((px - ax) * dx + (py - ay) * dy) / np.where(n2 > 0, n2, 1.0), 0.0, 1.0)
    return np.hypot(px - ax - u * dx, py - ay - u * dy)


def box_signed_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Signed distance between pairs of convex quadrilaterals (boxes) [m].

    Args:
        a, b: (P, 4, 2) corners (:func:`box_corners`).

    Returns:
        (P,): the gap between the boxes where they are apart; where they overlap, minus the
        penetration depth (the least overlap of their projections on the four edge
        normals: how far one box must move to clear the other).
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    # separating-axis test on the four edge directions (two per box)
    axes = np.concatenate([a[:, 1:3] - a[:, 0:2], b[:, 1:3] - b[:, 0:2]], axis=1)  # (P,4,2)
    norm = np.hypot(axes[..., 0], axes[..., 1])
    axes = axes / np.where(norm > 0, norm, 1.0)[..., None]
    pa = np.einsum("pkd,pjd->pkj", axes, a)  # (P, 4 axes, 4 corners)
    pb = np.einsum("pkd,pjd->pkj", axes, b)
    overlap = np.minimum(pa.max(-1), pb.max(-1)) - np.maximum(pa.min(-1), pb.min(-1))
    depth = overlap.min(-1)
    # the gap: least corner-to-edge distance, both ways
    a2 = np.roll(a, -1, axis=1)
    b2 = np.roll(b, -1, axis=1)
    d1 = _point_segment(a[:, :, None, 0], a[:, :, None, 1], b[:, None, :, 0], b[:, None, :, 1],
                        b2[:, None, :, 0], b2[:, None, :, 1])
    d2 = _point_segment(b[:, :, None, 0], b[:, :, None, 1], a[:, None, :, 0], a[:, None, :, 1],
                        a2[:, None, :, 0], a2[:, None, :, 1])
    gap = np.minimum(d1.min(axis=(1, 2)), d2.min(axis=(1, 2)))
    return np.where(depth > 0, -depth, gap)


PAIR_BLOCK = 400_000  # agent pairs x steps held at once by the pairwise features


def _chunk(pairs: int, t: int) -> int:
    """Steps per block so that a block's (steps, pairs) arrays hold at most PAIR_BLOCK."""
    return max(1, min(t, PAIR_BLOCK // max(pairs, 1)))


def nearest_object_distance(x: np.ndarray, y: np.ndarray, heading: np.ndarray,
                            valid: np.ndarray, length: np.ndarray, width: np.ndarray,
                            *, selves: np.ndarray | None = None,
                            limit: float = NEAREST_RANGE) -> np.ndarray:
    """Signed distance of each agent's box to the nearest other valid box [m].

    Args:
        selves: the rows to measure (default all); the others count as objects only.
        limit: exact up to this [m]; pairs that cannot come nearer (centre distance minus
            half of both diagonals) are not measured, and an agent with none nearer gets
            the lower bound of its nearest pair (at least ``limit``).

    Returns:
        (n, T): NaN where the agent is invalid or not in ``selves``; inf with no other valid
        agent.
    """
    n, t = x.shape
    selves = np.arange(n) if selves is None else np.asarray(selves, np.int64)
    out = np.full((n, t), np.nan)
    if n == 0 or len(selves) == 0:
        return out
    step = _chunk(len(selves) * n, t)
    for k0 in range(0, t, step):
        w = slice(k0, min(k0 + step, t))
        out[selves, w] = _nearest(x[:, w], y[:, w], heading[:, w], valid[:, w], length, width,
                                  selves, limit)
    return out


def _nearest(x, y, heading, valid, length, width, selves, limit) -> np.ndarray:
    """:func:`nearest_object_distance` of ``selves`` over a block of steps, (m, t)."""
    t = x.shape[1]
    m = len(selves)
    half_diag = np.hypot(length, width) / 2.0
    px = np.where(valid, x, np.nan).T  # (t, n)
    py = np.where(valid, y, np.nan).T
    centre = np.hypot(px[:, selves, None] - px[:, None, :], py[:, selves, None] - py[:, None, :])
    pair_ok = valid.T[:, selves, None] & valid.T[:, None, :]
    pair_ok[:, np.arange(m), selves] = False
    centre = np.where(pair_ok, centre, np.inf)  # (t, m, n)
    bound = centre - half_diag[None, selves, None] - half_diag[None, None, :]
    value = np.maximum(bound.min(axis=2), limit)  # (t, m) where nothing is nearer
    # candidates: pairs that may be nearer than the limit and than the nearest centre
    reach = np.minimum(limit, centre.min(axis=2))
    kk, ii, jj = np.nonzero(bound < reach[:, :, None])
    if len(kk):
        si = selves[ii]
        corners_i = box_corners(x[si, kk], y[si, kk], heading[si, kk], length[si], width[si])
        corners_j = box_corners(x[jj, kk], y[jj, kk], heading[jj, kk], length[jj], width[jj])
        d = box_signed_distance(corners_i, corners_j)
        exact = np.full((t, m), np.inf)
        np.minimum.at(exact, (kk, ii), d)
        value = np.minimum(value, exact)
    value = np.where(np.isfinite(centre.min(axis=2)), value, np.inf)
    return np.where(valid[selves], value.T, np.nan)


def overlapping_pairs(x: np.ndarray, y: np.ndarray, heading: np.ndarray, valid: np.ndarray,
                      length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Pairs of valid boxes that overlap, (m, 3) rows (step, i, j) with i < j."""
    n, t = x.shape
    found = []
    half_diag = np.hypot(length, width) / 2.0
    step = _chunk(n * n, t)
    for k0 in range(0, t, step):
        w = slice(k0, min(k0 + step, t))
        px = np.where(valid[:, w], x[:, w], np.nan).T
        py = np.where(valid[:, w], y[:, w], np.nan).T
        with np.errstate(invalid="ignore"):
            centre = np.hypot(px[:, :, None] - px[:, None, :], py[:, :, None] - py[:, None, :])
            near = centre < half_diag[None, :, None] + half_diag[None, None, :]
        near &= np.triu(np.ones((n, n), bool), 1)[None]
        kk, ii, jj = np.nonzero(near)
        if not len(kk):
            continue
        kk = kk + k0
        d = box_signed_distance(
            box_corners(x[ii, kk], y[ii, kk], heading[ii, kk], length[ii], width[ii]),
            box_corners(x[jj, kk], y[jj, kk], heading[jj, kk], length[jj], width[jj]))
        hit = d < 0
        found.append(np.stack([kk[hit], ii[hit], jj[hit]], axis=1))
    return np.concatenate(found) if found else np.zeros((0, 3), np.int64)


def time_to_collision(x: np.ndarray, y: np.ndarray, heading: np.ndarray, valid: np.ndarray,
                      length: np.ndarray, width: np.ndarray, speed: np.ndarray,
                      *, selves: np.ndarray | None = None) -> np.ndarray:
    """Time to collision with the agent followed [s], at most :data:`MAX_TTC`.

    Args:
        speed: (n, T) [m/s] each agent's linear speed (NaN: 0).
        selves: the rows to measure (default all).

    The agent followed: the nearest other valid agent whose box is ahead of the front bumper
    (the longitudinal gap from the bumper to its nearest corner positive) and overlaps the
    agent's straight trail sideways, heading within :data:`TTC_HEADING` (within
    :data:`TTC_SMALL_OVERLAP_HEADING` when the overlap is under :data:`TTC_SMALL_OVERLAP`).
    TTC = gap / (own speed - its speed) when closing, else :data:`MAX_TTC`.

    Returns:
        (n, T): NaN where the agent is invalid or not in ``selves``.
    """
    n, t = x.shape
    selves = np.arange(n) if selves is None else np.asarray(selves, np.int64)
    out = np.full((n, t), np.nan)
    if len(selves) == 0:
        return out
    step = _chunk(len(selves) * n, t)
    for k0 in range(0, t, step):
        w = slice(k0, min(k0 + step, t))
        out[selves, w] = _ttc(x[:, w], y[:, w], heading[:, w], valid[:, w], length, width,
                              speed[:, w], selves)
    return out


def _ttc(x, y, heading, valid, length, width, speed, selves) -> np.ndarray:
    """:func:`time_to_collision` of ``selves`` over a block of steps, (m, t)."""
    m = len(selves)
    v = np.nan_to_num(speed).T  # (t, n)
    px, py, h = x.T, y.T, heading.T
    dx = px[:, None, :] - px[:, selves, None]  # [k, self, other]: other - self
    dy = py[:, None, :] - py[:, selves, None]
    c, s = np.cos(h[:, selves])[:, :, None], np.sin(h[:, selves])[:, :, None]
    lon = c * dx + s * dy
    lat = -s * dx + c * dy
    dh = np.abs(_wrap(h[:, None, :] - h[:, selves, None]))
    cos_d, sin_d = np.abs(np.cos(dh)), np.abs(np.sin(dh))
    ln, wd = length[None, None, :], width[None, None, :]
    other_lon = ln / 2 * cos_d + wd / 2 * sin_d
    other_lat = ln / 2 * sin_d + wd / 2 * cos_d
    gap = lon - length[None, selves, None] / 2 - other_lon
    side = np.abs(lat) - width[None, selves, None] / 2 - other_lat  # < 0: overlaps the trail
    with np.errstate(invalid="ignore"):
        follow = (gap > 0) & (side < 0) & (dh <= TTC_HEADING) \
            & ((side < -TTC_SMALL_OVERLAP) | (dh <= TTC_SMALL_OVERLAP_HEADING))
    follow &= valid.T[:, None, :]
    follow[:, np.arange(m), selves] = False
    masked = np.where(follow, gap, np.inf)
    j = masked.argmin(axis=2)  # (t, m)
    nearest = np.take_along_axis(masked, j[..., None], axis=2)[..., 0]
    closing = v[:, selves] - np.take_along_axis(v, j, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(np.isfinite(nearest) & (closing > 0), nearest / closing, MAX_TTC)
    return np.where(valid[selves], np.minimum(ttc, MAX_TTC).T, np.nan)


def _edge_segments(edges: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """Segments (a, b) of the edges and, per segment, the unit left normals of the segments
    before and after it on the same polyline (its own where none)."""
    a_parts, b_parts, prev_parts, next_parts = [], [], [], []
    for line in edges:
        line = np.asarray(line, float)[:, :2]
        if len(line) < 2:
            continue
        keep = np.r_[True, np.hypot(*np.diff(line, axis=0).T) > 1e-9]
        line = line[keep]
        if len(line) < 2:
            continue
        d = np.diff(line, axis=0)
        normal = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
        a_parts.append(line[:-1])
        b_parts.append(line[1:])
        prev_parts.append(np.vstack([normal[:1], normal[:-1]]))
        next_parts.append(np.vstack([normal[1:], normal[-1:]]))
    if not a_parts:
        z = np.zeros((0, 2))
        return z, z, z, z
    return (np.concatenate(a_parts), np.concatenate(b_parts), np.concatenate(prev_parts),
            np.concatenate(next_parts))


class EdgeIndex:
    """Road edges ready for signed-distance queries (segments bucketed in a grid of
    :data:`EDGE_CELL` cells); build once per scene.

    Args:
        edges: road-edge polylines (k_i, 2) [m], the road on their left.
    """

    def __init__(self, edges: Sequence[np.ndarray]) -> None:
        self.a, self.b, self.n_prev, self.n_next = _edge_segments(edges)
        self.empty = len(self.a) == 0
        if self.empty:
            return
        lo_xy = np.minimum(self.a, self.b)
        hi_xy = np.maximum(self.a, self.b)
        self.lo = lo_xy.min(axis=0) - EDGE_CELL
        lo_cell = np.floor((lo_xy - self.lo) / EDGE_CELL).astype(np.int64)
        hi_cell = np.floor((hi_xy - self.lo) / EDGE_CELL).astype(np.int64)
        self.shape = (int(hi_cell[:, 0].max()) + 2, int(hi_cell[:, 1].max()) + 2)
        span = hi_cell - lo_cell + 1
        count = span[:, 0] * span[:, 1]
        owner = np.repeat(np.arange(len(self.a)), count)
        local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        cx = lo_cell[owner, 0] + local // span[owner, 1]
        cy = lo_cell[owner, 1] + local % span[owner, 1]
        cell = cx * self.shape[1] + cy
        order = np.argsort(cell, kind="stable")
        self.owner = owner[order].astype(np.int64)
        self.start = np.searchsorted(cell[order], np.arange(self.shape[0] * self.shape[1] + 1)
                                     ).astype(np.int64)

    def signed_distance(self, points: np.ndarray, search: float = EDGE_SEARCH) -> np.ndarray:
        """Signed distance of (m, 2) points [m] (:func:`signed_edge_distance`)."""
        points = np.asarray(points, float).reshape(-1, 2)
        out = np.full(len(points), np.nan)
        ok = np.isfinite(points).all(axis=1)
        if self.empty or not ok.any():
            return out
        p = np.ascontiguousarray(points[ok])
        j, dist = _grid_nearest(p, self.a, self.b, self.owner, self.start, self.lo,
                                self.shape[0], self.shape[1], float(search))
        found = j >= 0
        j, p, dist = j[found], p[found], dist[found]
        d = self.b[j] - self.a[j]
        n2 = (d ** 2).sum(axis=1)
        u_raw = ((p - self.a[j]) * d).sum(axis=1) / n2
        foot = self.a[j] + np.clip(u_raw, 0.0, 1.0)[:, None] * d
        own = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.sqrt(n2)[:, None]
        normal = np.where((u_raw <= 0)[:, None], own + self.n_prev[j],
                          np.where((u_raw >= 1)[:, None], own + self.n_next[j], own))
        left = ((p - foot) * normal).sum(axis=1)
        values = np.full(len(found), np.nan)
        values[found] = np.where(left > 0, -dist, dist)
        out[ok] = values
        return out


def signed_edge_distance(points: np.ndarray, edges: Sequence[np.ndarray],
                         *, search: float = EDGE_SEARCH) -> np.ndarray:
    """Signed distance of points to the nearest road edge [m]: negative on the road side.

    WOMD draws road edges with the road on their left (SPEC section 8), so a point on the
    left of its nearest edge segment is on the road. Where the nearest point is a vertex
    joining two segments, the side is read against the sum of both segments' left normals
    (the vertex's pseudo-normal), which makes the sign right outside convex and concave
    corners alike; at a line's open end, against the end segment's own normal.

    Args:
        points: (m, 2) [m].
        edges: road-edge polylines (k_i, 2).
        search: edges farther than this from a point are not searched.

    Returns:
        (m,) [m]; NaN with no edge within ``search``.
    """
    return EdgeIndex(edges).signed_distance(points, search)


@numba.njit(cache=True, nogil=True)
def _grid_nearest(points, a, b, owner, start, lo, nx, ny, search):  # pragma: no cover
    m = points.shape[0]
    best_j = np.full(m, -1, np.int64)
    best_d = np.full(m, np.inf)
    rings = int(search / EDGE_CELL) + 1
    for i in range(m):
        px, py = points[i, 0], points[i, 1]
        cx = int(np.floor((px - lo[0]) / EDGE_CELL))
        cy = int(np.floor((py - lo[1]) / EDGE_CELL))
        bd, bj = np.inf, -1
        for r in range(rings + 1):
            if bd <= (r - 1) * EDGE_CELL:
                break
            for gx in range(cx - r, cx + r + 1):
                if gx < 0 or gx >= nx:
                    continue
                for gy in range(cy - r, cy + r + 1):
                    if gy < 0 or gy >= ny:
                        continue
                    if max(abs(gx - cx), abs(gy - cy)) != r:
                        continue
                    c = gx * ny + gy
                    for q in range(start[c], start[c + 1]):
                        k = owner[q]
                        dx, dy = b[k, 0] - a[k, 0], b[k, 1] - a[k, 1]
                        n2 = dx * dx + dy * dy
                        u = ((px - a[k, 0]) * dx + (py - a[k, 1]) * dy) / n2
                        u = min(max(u, 0.0), 1.0)
                        d = math.hypot(px - a[k, 0] - u * dx, py - a[k, 1] - u * dy)
                        if d < bd:
                            bd, bj = d, k
        if bd <= search:
            best_j[i], best_d[i] = bj, bd
    return best_j, best_d


def road_edge_distance(x: np.ndarray, y: np.ndarray, heading: np.ndarray, valid: np.ndarray,
                       length: np.ndarray, width: np.ndarray,
                       edges: Sequence[np.ndarray] | EdgeIndex) -> np.ndarray:
    """Signed distance to the road edge of each box's most off-road corner [m], (n, T);
    NaN where the agent is invalid or the scene has no road edge near it.

    Args:
        edges: the road-edge polylines, or their :class:`EdgeIndex`."""
    n, t = x.shape
    out = np.full((n, t), np.nan)
    index = edges if isinstance(edges, EdgeIndex) else EdgeIndex(edges)
    if index.empty or not valid.any():
        return out
    corners = box_corners(x, y, heading, length[:, None], width[:, None])  # (n, T, 4, 2)
    ii, kk = np.nonzero(valid)
    d = index.signed_distance(corners[ii, kk].reshape(-1, 2)).reshape(-1, 4)
    out[ii, kk] = d.max(axis=1)
    return out


def red_light_violations(x: np.ndarray, y: np.ndarray, heading: np.ndarray,
                         valid: np.ndarray, lanes: Sequence[np.ndarray],
                         lane_widths: Sequence[float], stop_points: np.ndarray,
                         red: np.ndarray) -> np.ndarray:
    """Steps at which an agent runs a red light, (n, T) bool.

    Args:
        lanes: the controlled lanes' centre lines (k of (m_i, 2)), in driving order.
        lane_widths: (k,) [m].
        stop_points: (k, 2) [m] where traffic on each lane stops.
        red: (T, k) bool: the lane's signal is red at the step.

    A violation at step k: the agent's centre passes the stop point along the lane between
    steps k-1 and k (its arc length from before to at or beyond the stop point's) while
    within half the lane's width + :data:`SIGNAL_LATERAL` of the lane's line through the stop
    point (its direction there) and :data:`SIGNAL_REACH` of the point at both steps, heading
    along the lane (within 90 deg), with the signal red at step k.
    """
    n, t = x.shape
    out = np.zeros((n, t), bool)
    if not len(lanes) or t < 2:
        return out
    for j, line in enumerate(lanes):
        if not red[:, j].any():
            continue
        line = np.asarray(line, float)[:, :2]
        if len(line) < 2:
            continue
        stop = np.asarray(stop_points[j], float)
        _, _, lane_h = _project(line, stop[None])
        # the lane's direction at the stop point: a crossing is a move through it
        c, s_ = math.cos(lane_h[0]), math.sin(lane_h[0])
        dx, dy = x - stop[0], y - stop[1]
        along = c * dx + s_ * dy
        across = -s_ * dx + c * dy
        with np.errstate(invalid="ignore"):
            on = (np.abs(across) <= lane_widths[j] / 2 + SIGNAL_LATERAL) & valid \
                & (np.abs(along) <= SIGNAL_REACH) & (np.cos(heading - lane_h[0]) > 0)
            cross = (along[:, :-1] < 0) & (along[:, 1:] >= 0) & on[:, :-1] & on[:, 1:]
        out[:, 1:] |= cross & red[1:, j][None, :]
    return out


def _project(line: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, ...]:
    """(arc length, signed lateral offset (left positive), lane heading) of points projected
    on a polyline; NaN for NaN points."""
    a, b = line[:-1], line[1:]
    d = b - a
    n2 = np.maximum((d ** 2).sum(axis=1), 1e-12)
    cum = np.r_[0.0, np.cumsum(np.sqrt(n2))]
    out_s = np.full(len(points), np.nan)
    out_lat = np.full(len(points), np.nan)
    out_h = np.full(len(points), np.nan)
    ok = np.isfinite(points).all(axis=1)
    p = points[ok]
    if not len(p):
        return out_s, out_lat, out_h
    ap = p[:, None, :] - a[None]
    u = np.clip((ap * d[None]).sum(-1) / n2[None], 0.0, 1.0)
    foot = a[None] + u[..., None] * d[None]
    dist = np.hypot(p[:, None, 0] - foot[..., 0], p[:, None, 1] - foot[..., 1])
    j = dist.argmin(axis=1)
    rows = np.arange(len(p))
    # beyond the ends, the arc length extends along the end segments
    u_raw = (ap[rows, j] * d[j]).sum(-1) / n2[j]
    u_j = np.where((j == 0) & (u_raw < 0), u_raw,
                   np.where((j == len(d) - 1) & (u_raw > 1), u_raw, u[rows, j]))
    out_s[ok] = cum[j] + u_j * np.sqrt(n2[j])
    cross = d[j, 0] * ap[rows, j, 1] - d[j, 1] * ap[rows, j, 0]
    out_lat[ok] = cross / np.sqrt(n2[j])
    out_h[ok] = np.arctan2(d[j, 1], d[j, 0])
    return out_s, out_lat, out_h
