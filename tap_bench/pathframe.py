"""The ego's path as a reference line (SPEC section 7): ``s`` and ``d`` of every other agent.

For one ego path (a valid segment of one track: its positions at consecutive 0.1 s steps)
the reference line is the polyline of those positions, extended straight along the ego's
heading at both ends. Every other agent at every step of the path gets

- ``s`` [m]: its position along the reference line, relative to the ego's own position at
  that step; positive ahead;
- ``d`` [m]: its signed distance across the line, positive to the left;
- ``heading_rel`` [rad]: its heading minus the line's direction at its foot point, wrapped
  to (-pi, pi] (0: the same direction, pi: oncoming);
- ``v_along`` [m/s]: its velocity along the line (speed * cos(heading_rel)).

No map is needed: the line is where the ego actually drives, so a leader ahead on a curve or
in a roundabout lies at ``d`` near 0 and a vehicle on the inner lane of a roundabout at
``d`` of about a lane width. The frame is fixed in space for the whole path: ``d`` of an
agent changes only when that agent moves across the ego's path.

Pruning (never all pairs at every step): agents are put in a grid of cells of the reach
(the largest distance asked for); each ego step looks at its own and the eight neighbouring
cells of its scene and time step only, keeps agents within the reach, and projects each of
them onto the part of the line within ``behind`` .. ``ahead`` of the ego's arc position,
decimated to vertices about :data:`PATH_SPACING` apart. All of it is flat numpy over every
path at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "CORRIDOR_HALF_WIDTH",
    "EXTENSION",
    "PATH_SPACING",
    "PathFrame",
    "Paths",
    "SAME_DIRECTION",
    "path_frame",
    "scene_keys",
]

CORRIDOR_HALF_WIDTH = 1.8
"""[m] the ego's corridor is |d| <= this: half a lane (SPEC 7). Measured on the real WOMD
samples and highway-env, vehicles in the ego's lane sit within 1 m of its path and those in
the next lane 3 m or more away (docs/interactions.md)."""
SAME_DIRECTION = np.pi / 3
"""[rad] an agent whose heading is within this of the path's direction drives along it
(a leader can be followed); crossing and oncoming agents are not leaders."""
PATH_SPACING = 2.0
"""[m] vertices of the reference line are kept about this far apart. The line then departs
from the recorded path by at most the sagitta c^2 / (8 R): 0.05 m on a 10 m radius turn."""
EXTENSION = 1000.0
"""[m] length of the straight extensions at both ends of the line (beyond any reach)."""

_TWO_PI = 2.0 * np.pi


def scene_keys(scenario_codes: np.ndarray, step: np.ndarray) -> np.ndarray:
    """(n,) int64 key shared by the rows of one scenario at one time step.

    Args:
        scenario_codes: (n,) int scenario index of each row.
        step: (n,) int time step of each row (round(t * 10)).
    """
    step = np.asarray(step, np.int64)
    if not len(step):
        return step
    lo = int(step.min())
    span = int(step.max()) - lo + 1
    return np.asarray(scenario_codes, np.int64) * span + (step - lo)


@dataclass(frozen=True)
class Paths:
    """The rows of a scene and the ego paths to build frames for.

    Attributes:
        key: (n,) int64 scene-and-step key of each row (:func:`scene_keys`).
        track: (n,) int64 track of each row (an agent is never its own other).
        x, y: (n,) position [m].
        heading: (n,) [rad], counter-clockwise from +x.
        speed: (n,) [m/s].
        start, stop: (P,) int64 row range of each path: the ego's rows at consecutive steps,
            in time order (one valid segment of one track).
    """

    key: np.ndarray
    track: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    start: np.ndarray
    stop: np.ndarray

    @property
    def n_paths(self) -> int:
        return len(self.start)

    def ego_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """((m,) row of every ego step laid end to end, (m,) its path)."""
        length = self.stop - self.start
        m = int(length.sum())
        path = np.repeat(np.arange(self.n_paths), length)
        offset = np.arange(m) - np.repeat(np.cumsum(length) - length, length)
        return np.repeat(self.start, length) + offset, path


@dataclass(frozen=True)
class PathFrame:
    """Other agents in the frames of the ego paths, one entry per (ego step, other agent).

    Entries are ordered by ego step (paths laid end to end, as :meth:`Paths.ego_rows`).
    Arrays are (p,) over entries, except ``arc`` and the per-step ones, (m,) over ego steps.

    Attributes:
        step: index of the ego step (into :meth:`Paths.ego_rows`).
        other: row of the other agent.
        s: [m] along the line, relative to the ego; positive ahead.
        d: [m] across the line; positive to the left.
        heading_rel: [rad] the other's heading minus the line's direction at its foot point.
        v_along: [m/s] the other's velocity along the line.
        ego_row: (m,) row of each ego step.
        ego_path: (m,) path of each ego step.
        arc: (m,) [m] arc length of each ego step along its path from the path's start.
    """

    step: np.ndarray
    other: np.ndarray
    s: np.ndarray
    d: np.ndarray
    heading_rel: np.ndarray
    v_along: np.ndarray
    ego_row: np.ndarray
    ego_path: np.ndarray
    arc: np.ndarray

    def __len__(self) -> int:
        return len(self.step)


def _wrap(angle: np.ndarray) -> np.ndarray:
    return np.pi - np.mod(np.pi - angle, _TWO_PI)


def _ragged(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(group of each element, position within its group) for groups of ``counts``."""
    total = int(counts.sum())
    group = np.repeat(np.arange(len(counts)), counts)
    within = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return group, within


def _reference_lines(paths: Paths, ego_row: np.ndarray, ego_path: np.ndarray, spacing: float):
    """The decimated, extended polylines of every path, laid end to end.

    Returns (vx, vy, vs, first, count, arc): vertex coordinates and arc lengths (q,), the
    first vertex and vertex count of each path (P,), and the arc length of each ego step (m,).
    """
    x, y, h = paths.x[ego_row], paths.y[ego_row], paths.heading[ego_row]
    length = paths.stop - paths.start
    first_step = np.cumsum(length) - length
    step_len = np.hypot(np.diff(x), np.diff(y))
    new_path = np.zeros(len(ego_row), bool)
    new_path[first_step] = True
    step_len = np.where(new_path[1:], 0.0, step_len)
    arc = np.concatenate([[0.0], np.cumsum(step_len)]) if len(ego_row) else np.zeros(0)
    arc = arc - np.repeat(arc[first_step], length)
    # keep a vertex when its arc length enters a new spacing bin, and every path's ends
    bins = np.floor(arc / spacing)
    keep = np.ones(len(ego_row), bool)
    keep[1:] = bins[1:] != bins[:-1]
    keep |= new_path
    last_step = first_step + length - 1
    keep[last_step] = True
    # a path whose ego never moves keeps one vertex (the extensions give it a direction)
    keep[last_step] &= (arc[last_step] > 0) | (length == 1)
    kept = np.flatnonzero(keep)
    kept_path = ego_path[kept]
    n_kept = np.bincount(kept_path, minlength=paths.n_paths)
    count = n_kept + 2
    first = np.cumsum(count) - count
    q = int(count.sum())
    vx, vy, vs = np.empty(q), np.empty(q), np.empty(q)
    _, within = _ragged(n_kept)
    dest = first[kept_path] + 1 + within
    vx[dest], vy[dest], vs[dest] = x[kept], y[kept], arc[kept]
    hb, he = h[first_step], h[last_step]
    back, front = first, first + count - 1
    vx[back] = x[first_step] - EXTENSION * np.cos(hb)
    vy[back] = y[first_step] - EXTENSION * np.sin(hb)
    vs[back] = -EXTENSION
    vx[front] = x[last_step] + EXTENSION * np.cos(he)
    vy[front] = y[last_step] + EXTENSION * np.sin(he)
    vs[front] = arc[last_step] + EXTENSION
    return vx, vy, vs, first, count, arc


def _neighbours(paths: Paths, ego_row: np.ndarray, others: np.ndarray, reach: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """(ego step, other row) pairs of the same scene and step within ``reach`` of each other,
    found through a grid of cells of side ``reach`` (3 x 3 cells per ego step)."""
    cell = max(float(reach), 1.0)
    ox, oy = paths.x[others], paths.y[others]
    ex, ey = paths.x[ego_row], paths.y[ego_row]
    x0 = min(ox.min(), ex.min())
    y0 = min(oy.min(), ey.min())
    cx = np.floor((ox - x0) / cell).astype(np.int64) + 1
    cy = np.floor((oy - y0) / cell).astype(np.int64) + 1
    ny = int(max(cy.max(), np.floor((ey.max() - y0) / cell) + 1)) + 2
    nx = int(max(cx.max(), np.floor((ex.max() - x0) / cell) + 1)) + 2
    o_key = (paths.key[others] * nx + cx) * ny + cy
    order = np.argsort(o_key, kind="stable")
    o_sorted = o_key[order]
    ecx = np.floor((ex - x0) / cell).astype(np.int64) + 1
    ecy = np.floor((ey - y0) / cell).astype(np.int64) + 1
    e_key = paths.key[ego_row]
    steps, rows = [], []
    for dx in (-1, 0, 1):  # the 3 cells of one grid row are adjacent in the sorted keys
        k_lo = (e_key * nx + ecx + dx) * ny + ecy - 1
        lo = np.searchsorted(o_sorted, k_lo, "left")
        hi = np.searchsorted(o_sorted, k_lo + 2, "right")
        group, within = _ragged(hi - lo)
        steps.append(group)
        rows.append(others[order[lo[group] + within]])
    step = np.concatenate(steps)
    other = np.concatenate(rows)
    near = (paths.track[other] != paths.track[ego_row[step]]) & (
        np.hypot(paths.x[other] - ex[step], paths.y[other] - ey[step]) <= reach)
    step, other = step[near], other[near]
    order = np.lexsort((other, step))
    return step[order], other[order]


def path_frame(paths: Paths, others: np.ndarray | None = None, *, ahead: float = 100.0,
               behind: float = 30.0, lateral: float = 10.0, spacing: float = PATH_SPACING
               ) -> PathFrame:
    """Every other agent near each ego step, in the frame of the ego's path.

    Args:
        paths: the rows and the ego paths (:class:`Paths`).
        others: (n,) bool, rows that may be others (valid rows of the object types wanted);
            default every row.
        ahead: [m] largest ``s`` kept.
        behind: [m] largest ``-s`` kept.
        lateral: [m] largest ``|d|`` kept.
        spacing: [m] vertex spacing of the reference line.

    Returns:
        :class:`PathFrame` of the kept (ego step, other) pairs.
    """
    for name, value in (("ahead", ahead), ("behind", behind), ("lateral", lateral),
                        ("spacing", spacing)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"path_frame: {name} must be a finite distance > 0 m, got "
                             f"{value!r}.")
    ego_row, ego_path = paths.ego_rows()
    vx, vy, vs, first, count, arc = _reference_lines(paths, ego_row, ego_path, spacing)
    empty = np.zeros(0)
    others_rows = np.flatnonzero(np.ones(len(paths.key), bool) if others is None else others)
    if not len(ego_row) or not len(others_rows):
        ints = np.zeros(0, np.int64)
        return PathFrame(ints, ints, empty, empty, empty, empty, ego_row, ego_path, arc)
    reach = float(np.hypot(max(ahead, behind), lateral))
    step, other = _neighbours(paths, ego_row, others_rows, reach)

    # the part of each line within [arc - behind, arc + ahead] of the ego step: its segments
    path = ego_path[step]
    # one sorted array of every line's vertex arc lengths, each path offset past the last
    span = 10.0 * EXTENSION + arc.max(initial=0.0)
    global_s = vs + np.repeat(np.arange(len(first)), count) * span
    at = arc[step] + path * span
    lo = np.searchsorted(global_s, at - behind, "right") - 1
    hi = np.searchsorted(global_s, at + ahead, "left")
    lo = np.clip(lo, first[path], first[path] + count[path] - 2)
    hi = np.clip(hi, lo + 1, first[path] + count[path] - 1)
    n_seg = hi - lo
    pair, within = _ragged(n_seg)
    a = lo[pair] + within  # segment a -> a + 1
    ax, ay = vx[a], vy[a]
    ux, uy = vx[a + 1] - ax, vy[a + 1] - ay
    len2 = np.maximum(ux * ux + uy * uy, 1e-12)
    px, py = paths.x[other][pair] - ax, paths.y[other][pair] - ay
    tt = np.clip((px * ux + py * uy) / len2, 0.0, 1.0)
    ex_, ey_ = px - tt * ux, py - tt * uy
    dist2 = ex_ * ex_ + ey_ * ey_
    starts = np.cumsum(n_seg) - n_seg
    best = np.minimum.reduceat(dist2, starts)
    is_best = dist2 <= best[pair]
    # the first (nearest along the line) of equally near segments
    pos = np.full(len(step), len(pair))
    np.minimum.at(pos, pair[is_best], np.flatnonzero(is_best))
    seg, t_best = a[pos], tt[pos]
    ux_b, uy_b = ux[pos], uy[pos]
    norm = np.sqrt(len2[pos])
    s_abs = vs[seg] + t_best * (vs[seg + 1] - vs[seg])
    s = s_abs - arc[step]
    d = (ux_b * py[pos] - uy_b * px[pos]) / norm
    direction = np.arctan2(uy_b, ux_b)
    heading_rel = _wrap(paths.heading[other] - direction)
    keep = (s <= ahead) & (s >= -behind) & (np.abs(d) <= lateral)
    v_along = paths.speed[other] * np.cos(heading_rel)
    return PathFrame(step=step[keep], other=other[keep], s=s[keep], d=d[keep],
                     heading_rel=heading_rel[keep], v_along=v_along[keep], ego_row=ego_row,
                     ego_path=ego_path, arc=arc)
