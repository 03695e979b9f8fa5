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

Pruning (never all pairs at every step): the grid cells each line passes near are hashed
with the arc range of the line there; an agent's row meets a path only if its cell is one
of those and the path has an ego step at that time, and is then projected onto the fine
segments (vertices about :data:`PATH_SPACING` apart) of that arc range only. All of it is
flat numpy over every path at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "COARSE_SPACING",
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
COARSE_SPACING = 10.0
"""[m] spacing of the vertices of the straight extensions near the path's ends."""
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
        scene: (n,) int64 scenario of each row (rows of different scenarios never meet).
        key: (n,) int64 scene-and-step key of each row (:func:`scene_keys`).
        track: (n,) int64 track of each row (an agent is never its own other).
        x, y: (n,) position [m].
        heading: (n,) [rad], counter-clockwise from +x.
        speed: (n,) [m/s].
        start, stop: (P,) int64 row range of each path: the ego's rows at consecutive steps,
            in time order (one valid segment of one track).
    """

    scene: np.ndarray
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


def _reference_lines(paths: Paths, ego_row: np.ndarray, ego_path: np.ndarray, spacing: float,
                     coarse: float, reach: float):
    """The decimated, extended polylines of every path, laid end to end.

    Each line: the straight back extension (a far vertex at -EXTENSION, then vertices every
    ``coarse`` metres from ``reach`` to the start), the recorded positions about ``spacing``
    apart, and the front extension likewise.

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
    arc = _path_arc(step_len, first_step, length)
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
    n_ext = int(np.ceil(reach / coarse))
    ext = np.r_[EXTENSION, coarse * np.arange(n_ext, 0, -1)]  # distances from the end
    count = n_kept + 2 * len(ext)
    first = np.cumsum(count) - count
    q = int(count.sum())
    vx, vy, vs = np.empty(q), np.empty(q), np.empty(q)
    _, within = _ragged(n_kept)
    dest = first[kept_path] + len(ext) + within
    vx[dest], vy[dest], vs[dest] = x[kept], y[kept], arc[kept]
    hb, he = h[first_step], h[last_step]
    back = first[:, None] + np.arange(len(ext))[None, :]  # (P, e), far to near
    vx[back] = x[first_step, None] - ext[None, :] * np.cos(hb)[:, None]
    vy[back] = y[first_step, None] - ext[None, :] * np.sin(hb)[:, None]
    vs[back] = -ext[None, :]
    front = (first + count - 1)[:, None] - np.arange(len(ext))[None, :]  # far to near
    vx[front] = x[last_step, None] + ext[None, :] * np.cos(he)[:, None]
    vy[front] = y[last_step, None] + ext[None, :] * np.sin(he)[:, None]
    vs[front] = arc[last_step, None] + ext[None, :]
    return vx, vy, vs, first, count, arc


def _path_arc(step_len: np.ndarray, first_step: np.ndarray, length: np.ndarray
              ) -> np.ndarray:
    """(m,) arc length [m] of each ego step along its own path: the running sum of
    ``step_len`` (m - 1,) (the length of the step into each next row) restarted at 0 at
    every path's first step. Each path is summed on its own, so a path's arc lengths are
    the same bits whichever paths come before it in the table (a batch of episodes or one)."""
    arc = np.zeros(int(length.sum()))
    for first, n in zip(first_step.tolist(), length.tolist(), strict=True):
        if n > 1:
            np.cumsum(step_len[first:first + n - 1], out=arc[first + 1:first + n])
    return arc


def _line_cells(vx, vy, vs, first, count, lo_arc, hi_arc, scene, cell):
    """The grid cells near each line: (cell key, path, arc_lo, arc_hi) per (path, cell),
    sorted by cell key. A cell is near a line when one of the line's samples (every half
    cell) lies in it or in one of its 8 neighbours; arc_lo .. arc_hi is the arc range of
    those samples. A point within ``lateral`` of the line (``cell = 4/3 lateral + spacing``)
    has its foot point F within a quarter cell of a sample S, so it is within ``lateral +
    cell / 4 < cell`` of S on each axis: its cell is one of S's 9, and F's arc is within a
    quarter cell of the range."""
    n_paths = len(first)
    half = cell / 2
    n_samp = np.ceil((hi_arc - lo_arc) / half).astype(np.int64) + 1
    path, k = _ragged(n_samp)
    arc = lo_arc[path] + k * half
    span = vs.max() - vs.min() + 1.0
    offset = np.repeat(np.arange(n_paths), count) * span
    g = vs + offset
    sx = np.interp(arc + path * span, g, vx)
    sy = np.interp(arc + path * span, g, vy)
    cx = np.floor(sx / cell).astype(np.int64)
    cy = np.floor(sy / cell).astype(np.int64)
    dx = np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])
    dy = np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])
    keys = _cell_key(scene[path][:, None], cx[:, None] + dx, cy[:, None] + dy).ravel()
    path9 = np.repeat(path, 9)
    arc9 = np.repeat(arc, 9)
    both = keys * n_paths + path9  # (cell, path) pairs; arc ranges reduced over each
    order = np.argsort(both, kind="stable")
    both, arc9 = both[order], arc9[order]
    start = np.flatnonzero(np.r_[True, both[1:] != both[:-1]])
    return (keys[order][start], path9[order][start], np.minimum.reduceat(arc9, start),
            np.maximum.reduceat(arc9, start))


def _cell_key(scene, cx, cy):
    # cells of 1e6 per axis per scene: coordinates up to 1e7 m (SPEC 2) over cells >= 10 m
    return (scene * 2_000_003 + cx + 1_000_001) * 2_000_003 + cy + 1_000_001


def path_frame(paths: Paths, others: np.ndarray | None = None, *,
               ahead: float | np.ndarray = 100.0, behind: float = 30.0, lateral: float = 10.0,
               near: float = 0.0, lateral_near: float = 0.0, spacing: float = PATH_SPACING
               ) -> PathFrame:
    """Every other agent near each ego step, in the frame of the ego's path.

    Kept: agents with ``-behind <= s <= ahead`` and ``|d| <= lateral``, and, when ``near``
    is given, agents with ``|s| <= near`` and ``|d| <= lateral_near`` (a wider zone beside
    the ego: the next lanes).

    Pruned, never all pairs at every step: the cells of a grid (side ``lateral`` +
    ``spacing``) that each line passes near are hashed with the arc range of the line
    there; an agent's row meets a path only when its cell is one of them and the path has an
    ego step at that row's time, and it is projected exactly onto the fine segments of that
    arc range within the ego step's window.

    Args:
        paths: the rows and the ego paths (:class:`Paths`).
        others: (n,) bool, rows that may be others (valid rows of the object types wanted);
            default every row.
        ahead: [m] largest ``s`` kept: a number, or (m,) one per ego step.
        behind: [m] largest ``-s`` kept.
        lateral: [m] largest ``|d|`` kept.
        near, lateral_near: [m] the zone beside the ego (0: none).
        spacing: [m] vertex spacing of the reference line.

    Returns:
        :class:`PathFrame` of the kept (ego step, other) pairs, ordered by ego step.
    """
    if near > 0 and lateral_near > lateral:
        main = path_frame(paths, others, ahead=ahead, behind=behind, lateral=lateral,
                          spacing=spacing)
        side = path_frame(paths, others, ahead=near, behind=near, lateral=lateral_near,
                          spacing=spacing)
        fields = ("step", "other", "s", "d", "heading_rel", "v_along")
        both = {f: np.r_[getattr(main, f), getattr(side, f)] for f in fields}
        order = np.lexsort((both["other"], both["step"]))
        both = {f: v[order] for f, v in both.items()}
        new = np.ones(len(order), bool)
        new[1:] = (both["step"][1:] != both["step"][:-1]) | (both["other"][1:]
                                                             != both["other"][:-1])
        return PathFrame(**{f: v[new] for f, v in both.items()}, ego_row=main.ego_row,
                         ego_path=main.ego_path, arc=main.arc)
    for name, value in (("behind", behind), ("lateral", lateral), ("spacing", spacing)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"path_frame: {name} must be a finite distance > 0 m, got "
                             f"{value!r}.")
    ego_row, ego_path = paths.ego_rows()
    ahead = np.broadcast_to(np.asarray(ahead, float), (len(ego_row),))
    if len(ahead) and not (np.isfinite(ahead).all() and (ahead > 0).all()):
        raise ValueError("path_frame: ahead must be a finite distance > 0 m.")
    far = float(max(ahead.max(initial=0.0), behind))
    cell = 4.0 / 3.0 * lateral + spacing  # see _line_cells: every point within lateral
    vx, vy, vs, first, count, arc = _reference_lines(paths, ego_row, ego_path, spacing,
                                                     COARSE_SPACING, far + 2 * cell)
    empty = np.zeros(0)
    ints = np.zeros(0, np.int64)
    others_rows = np.flatnonzero(np.ones(len(paths.key), bool) if others is None else others)
    if not len(ego_row) or not len(others_rows):
        return PathFrame(ints, ints, empty, empty, empty, empty, ego_row, ego_path, arc)
    length = paths.stop - paths.start
    step0 = np.cumsum(length) - length
    last_step = step0 + length - 1
    # the stretch of each line any ego step looks at
    a_lo = arc[step0] - behind - cell
    a_hi = arc[last_step] + np.maximum.reduceat(ahead, step0) + cell
    c_key, c_path, c_lo, c_hi = _line_cells(vx, vy, vs, first, count, a_lo, a_hi,
                                            paths.scene[paths.start], cell)
    # join the other agents' rows on those cells
    o_key = _cell_key(paths.scene[others_rows], np.floor(paths.x[others_rows] / cell)
                      .astype(np.int64), np.floor(paths.y[others_rows] / cell).astype(np.int64))
    lo = np.searchsorted(c_key, o_key, "left")
    hi = np.searchsorted(c_key, o_key, "right")
    which, within = _ragged(hi - lo)
    entry = lo[which] + within
    other = others_rows[which]
    path = c_path[entry]
    # the path's ego step at the other's time (rows of one scene and step share a key)
    k = paths.key[other] - paths.key[paths.start[path]]
    ok = (k >= 0) & (k < length[path])
    step = np.where(ok, step0[path] + k, 0)
    ok &= paths.key[ego_row[step]] == paths.key[other]
    ok &= paths.track[other] != paths.track[ego_row[step]]
    # the arc range of the line near the agent, within the ego step's window
    w_lo = np.maximum(c_lo[entry], arc[step] - behind - spacing)
    w_hi = np.minimum(c_hi[entry], arc[step] + ahead[step] + spacing)
    ok &= w_lo <= w_hi
    step, other, path, w_lo, w_hi = step[ok], other[ok], path[ok], w_lo[ok], w_hi[ok]
    px, py = paths.x[other], paths.y[other]

    # exact projection onto the fine segments of that range
    span = vs.max() - vs.min() + 1.0
    global_s = vs + np.repeat(np.arange(len(first)), count) * span
    last = first + count - 1
    # the foot point lies within half a sample spacing of the range (see _line_cells)
    lo = np.searchsorted(global_s, w_lo - cell / 2 + path * span, "right") - 1
    hi = np.searchsorted(global_s, w_hi + cell / 2 + path * span, "left")
    lo = np.clip(lo, first[path], last[path] - 1)
    hi = np.clip(hi, lo + 1, last[path])
    n_seg = hi - lo
    pair, within = _ragged(n_seg)
    a = lo[pair] + within  # segment a -> a + 1
    ax, ay = vx[a], vy[a]
    ux, uy = vx[a + 1] - ax, vy[a + 1] - ay
    len2 = np.maximum(ux * ux + uy * uy, 1e-12)
    qx, qy = px[pair] - ax, py[pair] - ay
    tt = np.clip((qx * ux + qy * uy) / len2, 0.0, 1.0)
    ex_, ey_ = qx - tt * ux, qy - tt * uy
    dist2 = ex_ * ex_ + ey_ * ey_
    starts = np.cumsum(n_seg) - n_seg
    if not len(starts):
        return PathFrame(ints, ints, empty, empty, empty, empty, ego_row, ego_path, arc)
    best = np.minimum.reduceat(dist2, starts)
    is_best = dist2 <= best[pair]
    pos = np.full(len(step), len(pair))  # the first (nearest along the line) of ties
    np.minimum.at(pos, pair[is_best], np.flatnonzero(is_best))
    seg, t_best = a[pos], tt[pos]
    s = vs[seg] + t_best * (vs[seg + 1] - vs[seg]) - arc[step]
    d = (ux[pos] * qy[pos] - uy[pos] * qx[pos]) / np.sqrt(len2[pos])
    keep = np.flatnonzero((s <= ahead[step]) & (s >= -behind) & (np.abs(d) <= lateral))
    keep = keep[np.lexsort((other[keep], step[keep]))]
    pos, other = pos[keep], other[keep]
    heading_rel = _wrap(paths.heading[other] - np.arctan2(uy[pos], ux[pos]))
    return PathFrame(step=step[keep], other=other, s=s[keep], d=d[keep],
                     heading_rel=heading_rel,
                     v_along=paths.speed[other] * np.cos(heading_rel), ego_row=ego_row,
                     ego_path=ego_path, arc=arc)
