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
  the drivable area (WOMD draws edges with the road on their left: negative on the road;
  open ends and gaps are road), :class:`tap_bench.sim.road_edges.RoadEdges`, the same rule
  and index as the ego's off-road measure; off-road: above zero;
- traffic-light violation: the centre crosses the stop point of a lane whose signal is red,
  moving along that lane.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tap_bench.sim.road_edges import RoadEdges, box_corners

__all__ = ["EDGE_SEARCH", "MAX_TTC", "TTC_HEADING", "TTC_SMALL_OVERLAP",
           "TTC_SMALL_OVERLAP_HEADING", "box_signed_distance",
           "kinematic_features", "nearest_object_distance", "overlapping_pairs",
           "red_light_violations", "road_edge_distance", "time_to_collision"]

MAX_TTC = 5.0  # [s] time to collision when nobody is followed, the gap opens, or above it
TTC_HEADING = np.radians(75.0)  # [rad] widest heading difference to a followed agent
TTC_SMALL_OVERLAP = 0.5  # [m] below this sideways overlap ...
TTC_SMALL_OVERLAP_HEADING = np.radians(10.0)  # [rad] ... the heading must be this close
NEAREST_RANGE = 40.0  # [m] distances beyond this are not computed exactly (histogram top)
EDGE_SEARCH = 60.0  # [m] road edges farther than this from a point are not searched
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
        follow = ((gap > 0) & (side < 0) & (dh <= TTC_HEADING)
            & ((side < -TTC_SMALL_OVERLAP) | (dh <= TTC_SMALL_OVERLAP_HEADING)))
    follow &= valid.T[:, None, :]
    follow[:, np.arange(m), selves] = False
    masked = np.where(follow, gap, np.inf)
    j = masked.argmin(axis=2)  # (t, m)
    nearest = np.take_along_axis(masked, j[..., None], axis=2)[..., 0]
    closing = v[:, selves] - np.take_along_axis(v, j, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(np.isfinite(nearest) & (closing > 0), nearest / closing, MAX_TTC)
    return np.where(valid[selves], np.minimum(ttc, MAX_TTC).T, np.nan)


def road_edge_distance(x: np.ndarray, y: np.ndarray, heading: np.ndarray, valid: np.ndarray,
                       length: np.ndarray, width: np.ndarray,
                       edges: Sequence[np.ndarray] | RoadEdges) -> np.ndarray:
    """Signed distance to the road edge of each box's most off-road corner [m], (n, T);
    NaN where the agent is invalid or the scene has no road edge within
    :data:`EDGE_SEARCH` of it.

    Args:
        edges: the road-edge polylines, or their :class:`~tap_bench.sim.road_edges.RoadEdges`
            (the scene's, indexed once)."""
    n, t = x.shape
    out = np.full((n, t), np.nan)
    index = edges if isinstance(edges, RoadEdges) else RoadEdges.from_polylines(edges)
    if not len(index) or not valid.any():
        return out
    corners = box_corners(x, y, heading, length[:, None], width[:, None])  # (n, T, 4, 2)
    ii, kk = np.nonzero(valid)
    d = index.signed_distance(corners[ii, kk].reshape(-1, 2), EDGE_SEARCH).reshape(-1, 4)
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
            on = ((np.abs(across) <= lane_widths[j] / 2 + SIGNAL_LATERAL) & valid
                & (np.abs(along) <= SIGNAL_REACH) & (np.cos(heading - lane_h[0]) > 0))
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
