"""The ego's path as a reference line (SPEC section 7): ``s`` and ``d`` of every other agent.

For one ego path (a valid segment of one track: its positions at consecutive 0.1 s steps)
the reference line is the polyline of those positions, extended beyond both ends of the
record (SPEC 7):

- along the ego's lane, where a map is given (:class:`LaneMap`: the lane centre lines of a
  map table, :mod:`tap_bench.maps`): the lane nearest the record's end that runs the ego's
  way (within :data:`LANE_MATCH_DISTANCE` and :data:`LANE_MATCH_HEADING`), then the lanes
  that start where it ends (at a branch, the one that stays nearest the arc below);
- else along a circular arc with the ego's mean curvature over its last (first) second:
  the heading change over that second divided by the distance driven in it (over the last
  :data:`CURVATURE_STRETCH` metres driven when it drove less in that second: an ego that
  stops in a curve; 0 when the whole path drove less than :data:`MIN_CURVATURE_TRAVEL`; at
  most ``1 / R_MIN``). Where the curvature over that stretch fell below
  :data:`FADE_RATIO` of the one over the stretch before it (the exit of a turn) it falls
  on at the same rate to 0 and the line goes straight on. The arc turns at most
  :data:`MAX_EXTENSION_TURN` and goes straight on from there.

A leader stopped 25 m ahead on a 30 m curve at the end of a record is then still on the
line (``d`` near 0) at ``s`` = its distance along the curve, as on a straight road. Every
other agent at every step of the path gets

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

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from tap_bench.trajectories import HZ

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "CORRIDOR_HALF_WIDTH",
    "CURVATURE_STRETCH",
    "EXTENSION",
    "LANE_MATCH_DISTANCE",
    "LANE_MATCH_HEADING",
    "LEADER_RANGE_M",
    "LEADER_RANGE_S",
    "LaneMap",
    "MAX_EXTENSION_TURN",
    "MIN_CURVATURE_TRAVEL",
    "PATH_SPACING",
    "PathFrame",
    "Paths",
    "SAME_DIRECTION",
    "leader_reach",
    "nearest_leader",
    "path_frame",
    "scene_keys",
    "scene_lanes",
]

CORRIDOR_HALF_WIDTH = 1.8
"""[m] the ego's corridor is |d| <= this: half a lane (SPEC 7), between the vehicles of the
ego's lane and those of the next (their measured offsets: docs/interactions.md)."""
SAME_DIRECTION = math.pi / 3
"""[rad] an agent whose heading is within this of the path's direction drives along it
(a leader can be followed); crossing and oncoming agents are not leaders."""
LEADER_RANGE_M = 60.0
"""[m] a leader counts up to this far ahead along the path (SPEC 7: "60 m or 4 s") ..."""
LEADER_RANGE_S = 4.0
"""[s] ... or up to this many seconds at the ego's speed, whichever is farther
(:func:`leader_reach`). On data (docs/interactions.md): 87 % of WOMD's and 99.8 % of
highway-env's leaders lie within 4 s; beyond it drivers are in the free-flow regime of the
car-following literature (time headways above 3-4 s)."""
PATH_SPACING = 2.0
"""[m] vertices of the reference line are kept about this far apart. The line then departs
from the recorded path by at most the sagitta c^2 / (8 R): 0.05 m on a 10 m radius turn."""
EXTENSION = 1000.0
"""[m] length of the extensions at both ends of the line (beyond any reach)."""
FADE_RATIO = 0.75
"""A curvature over the last stretch below this share of the one over the stretch before is
a turn's exit, and the extension's curvature falls on to 0 at that rate; above it, the
extension is a circular arc (heading noise makes a steady curve's measured curvature waver
by a few per cent)."""
STRAIGHT_SPACING = 10.0
"""[m] vertex spacing of a straight extension (curved ones are denser: a chord stays within
5 cm of its arc)."""
MAX_EXTENSION_TURN = math.pi / 2
"""[rad] the arc beyond an end of the record turns at most this far, then goes straight:
a curve or an intersection turn seldom continues farther beyond where the record ends, and
a longer arc would wind back onto the ego's own path (a 30 m radius closes its circle in
188 m, inside the 100 m look-ahead and its margin)."""
MIN_CURVATURE_TRAVEL = 2.0
"""[m] the mean curvature at an end is taken only when the ego drove at least this far over
it; a parked ego extends straight (its heading change is noise)."""
CURVATURE_STRETCH = 5.0
"""[m] the mean curvature at an end is taken over the last (first) second, or, when the ego
drove less than this in it (it slowed to a stop), over the last (first) this many metres it
drove: an ego that stops in a curve extends along the curve it drove into the stop."""
R_MIN = 5.0
"""[m] the tightest radius an extension arc takes (SPEC 2's R_min)."""
LANE_MATCH_DISTANCE = 2.0
"""[m] a lane continues the path when its centre line passes within this of the record's
end (half a lane and the ego's offset in it)."""
LANE_MATCH_HEADING = math.pi / 6
"""[rad] ... and runs within this of the ego's heading there."""
LANE_JOIN_DISTANCE = 1.5
"""[m] a lane that starts within this of another's end continues it (the map table has no
topology; WOMD's and highway-env's connected lanes meet end to start)."""

CHAIN_MEMO = 2048
"""Most path ends a :class:`LaneMap` keeps the lane chains of (then it starts afresh): a
batch of 30 episodes has a few hundred; a chain of 200 m of WOMD lanes is some 20 kB."""
_TWO_PI = 2.0 * math.pi


def scene_keys(scenario_codes: np.ndarray, step: np.ndarray) -> np.ndarray:
    """(n,) int64 key shared by the rows of one scenario at one time step.

    Args:
        scenario_codes: (n,) int scenario index of each row.
        step: (n,) int time step of each row (round(t * 10)).
    """
    import numpy as np

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
        import numpy as np

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


@dataclass(frozen=True)
class LaneMap:
    """Lane centre lines per scene: where a path's record ends, its line goes on along them.

    One lane map can serve several calls on one batch of episodes (the interaction axis and
    the measures, :func:`scene_lanes`): built once per map table (:meth:`of_maps`), it keeps
    each lane's segments and every path end's lane match and chain of lanes, so a second
    call extending the same path end reads them rather than searching the lanes again (the
    points are the same, bit for bit).

    Attributes:
        scene: (L,) code of each lane's map (the ``scene`` of :class:`Paths` when
            ``scene_map`` is None).
        start, stop: (L,) point range of each lane in ``x``, ``y`` (at least 2 points, in
            driving order).
        x, y: (q,) points [m].
        scene_map: (S,) the map code of each scene code of the paths (-1: no map); None: a
            scene's code is its map's.
        map_ids: the ``map_id`` of each map code (:meth:`of_maps`; empty otherwise).
    """

    scene: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    x: np.ndarray
    y: np.ndarray
    scene_map: np.ndarray | None = None
    map_ids: tuple[str, ...] = ()
    _memo: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def of_maps(cls, map_table) -> LaneMap:
        """The lanes of every map of a map table (:mod:`tap_bench.maps`; its ``kind ==
        "lane"`` polylines), each under the code of its ``map_id`` (:attr:`map_ids`): one
        lane map a batch's calls share (:func:`scene_lanes` gives each its scenes)."""
        import numpy as np

        lanes = map_table[map_table["kind"] == "lane"]
        mid = lanes["map_id"].astype(str).to_numpy()
        ids = tuple(dict.fromkeys(mid.tolist()))
        code = {m: k for k, m in enumerate(ids)}
        feature = lanes["feature_id"].to_numpy(np.int64)
        new = (np.r_[True, (feature[1:] != feature[:-1]) | (mid[1:] != mid[:-1])]
            if len(feature) else np.zeros(0, bool))
        starts = np.flatnonzero(new)
        stops = np.r_[starts[1:], len(feature)].astype(np.int64)
        size = stops - starts
        keep = size >= 2
        starts, stops, size = starts[keep], stops[keep], size[keep]
        lx, ly = lanes["x"].to_numpy(float), lanes["y"].to_numpy(float)
        take = (np.concatenate([np.arange(a, b) for a, b in zip(starts.tolist(),
                                                               stops.tolist(), strict=True)])
            if len(starts) else np.zeros(0, np.int64))
        stop = np.cumsum(size).astype(np.int64)
        return cls(np.array([code[m] for m in mid[starts]], np.int64), stop - size, stop,
                   lx[take], ly[take], None, ids)

    @classmethod
    def from_table(cls, map_table, scene_maps) -> LaneMap:
        """The lanes of a map table (:mod:`tap_bench.maps`) for each scene.

        Args:
            map_table: a map table; its ``kind == "lane"`` polylines are used.
            scene_maps: (S,) the ``map_id`` of each scene code (a WOMD ``scenario_id``, or
                the env of a highway-env rollout); None where a scene has no map.
        """
        return cls.of_maps(map_table).for_scenes(scene_maps)

    def for_scenes(self, scene_maps) -> LaneMap:
        """This lane map for paths whose scene codes have the maps ``scene_maps`` (S,) (a
        ``map_id`` of :attr:`map_ids`, or None: no map), sharing its lanes and what it has
        matched and chained."""
        import numpy as np

        code = {m: k for k, m in enumerate(self.map_ids)}
        scene_map = np.array([code.get(str(m), -1) if m is not None else -1
                              for m in scene_maps], np.int64)
        return LaneMap(self.scene, self.start, self.stop, self.x, self.y, scene_map,
                       self.map_ids, self._memo)

    def _map(self, scene: int) -> int:
        if self.scene_map is None:
            return int(scene)
        return int(self.scene_map[scene]) if 0 <= scene < len(self.scene_map) else -1

    def covers(self, scenes: np.ndarray) -> np.ndarray:
        """(k,) bool: each scene code has lanes."""
        import numpy as np

        scenes = np.asarray(scenes, np.int64)
        if self.scene_map is not None:
            inside = (scenes >= 0) & (scenes < len(self.scene_map))
            scenes = np.where(inside, self.scene_map[np.where(inside, scenes, 0)], -1)
        return np.isin(scenes, self.scene)

    def _polyline(self, lane: int) -> tuple[np.ndarray, np.ndarray]:
        return self.x[self.start[lane]:self.stop[lane]], self.y[self.start[lane]:self.stop[lane]]

    def _segments(self, m: int) -> dict:
        """The segments of map ``m``'s lanes, lane after lane, each computed from its lane
        alone (as a lane-by-lane search would): start point, direction vector, squared
        length, heading, arc length at its start and its lane."""
        import numpy as np

        key = ("segments", m)
        if key not in self._memo:
            parts: dict[str, list] = {k: [] for k in ("ax", "ay", "ux", "uy", "len2", "h",
                                                      "arc", "root", "lane")}
            for lane in np.flatnonzero(self.scene == m).tolist():
                lx, ly = self._polyline(lane)
                ux, uy = np.diff(lx), np.diff(ly)
                len2 = np.maximum(ux * ux + uy * uy, 1e-12)
                root = np.sqrt(len2)
                for name, value in (("ax", lx[:-1]), ("ay", ly[:-1]), ("ux", ux), ("uy", uy),
                                    ("len2", len2), ("h", np.arctan2(uy, ux)),
                                    ("arc", np.r_[0.0, np.cumsum(root)][:-1]),
                                    ("root", root), ("lane", np.full(len(ux), lane))):
                    parts[name].append(value)
            seg = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in parts.items()}
            seg["lane"] = seg["lane"].astype(np.int64)
            seg["first"] = (np.flatnonzero(np.r_[True, seg["lane"][1:] != seg["lane"][:-1]])
                if len(seg["lane"]) else np.zeros(0, np.int64))
            self._memo[key] = seg
        return self._memo[key]

    def _match(self, scene: int, x0: float, y0: float, h0: float):
        """(lane, arc length of the foot point along it) of the lane nearest (x0, y0) that
        runs the ego's way, or None. Of lanes equally near, the last (in map order)."""
        import numpy as np

        m = self._map(scene)
        seg = self._segments(m) if m >= 0 else None
        if seg is None or not len(seg["lane"]):
            return None
        ax, ay, ux, uy, len2 = seg["ax"], seg["ay"], seg["ux"], seg["uy"], seg["len2"]
        t = np.clip(((x0 - ax) * ux + (y0 - ay) * uy) / len2, 0.0, 1.0)
        dist = np.where(np.abs(_wrap(seg["h"] - h0)) <= LANE_MATCH_HEADING,
                        np.hypot(ax + t * ux - x0, ay + t * uy - y0), np.inf)
        nearest = np.minimum.reduceat(dist, seg["first"])  # per lane, over its segments
        best = float(nearest.min())
        if not best <= LANE_MATCH_DISTANCE:
            return None
        k = int(np.flatnonzero(nearest == best)[-1])  # the last of equally near lanes
        lo = seg["first"][k]
        hi = seg["first"][k + 1] if k + 1 < len(seg["first"]) else len(dist)
        j = lo + int(np.argmax(dist[lo:hi] == best))  # its first nearest segment
        return int(seg["lane"][j]), float(seg["arc"][j] + t[j] * seg["root"][j])

    def _chain(self, scene: int, x0: float, y0: float, h0: float, kappa: float,
               forward: bool, need: float):
        """The lane chain from the foot point of (x0, y0) as (x, y, arc length) of its
        points: the fewest lanes from its start that reach ``need`` metres (or all there
        are), or None without a lane. Kept per path end, so a longer ``need`` later only
        adds lanes."""
        import numpy as np

        key = ("chain", self._map(scene), x0, y0, h0, kappa, forward)
        state = self._memo.get(key)
        if state is None:
            if len(self._memo) > CHAIN_MEMO:
                segments = {k: v for k, v in self._memo.items() if k[0] == "segments"}
                self._memo.clear()
                self._memo.update(segments)
            found = self._match(scene, x0, y0, h0)
            if found is None:
                self._memo[key] = state = {"none": True}
            else:
                lane, at = found
                lx, ly = self._polyline(lane)
                seg = np.r_[0.0, np.cumsum(np.hypot(np.diff(lx), np.diff(ly)))]
                if forward:
                    keep = seg > at
                    px = np.r_[np.interp(at, seg, lx), lx[keep]]
                    py = np.r_[np.interp(at, seg, ly), ly[keep]]
                else:
                    keep = seg < at
                    px = np.r_[np.interp(at, seg, lx), lx[keep][::-1]]
                    py = np.r_[np.interp(at, seg, ly), ly[keep][::-1]]
                state = {"none": False, "x": [px], "y": [py], "used": {lane},
                         "done": [float(np.hypot(np.diff(px), np.diff(py)).sum())],
                         "ended": False}
                self._memo[key] = state
        if state["none"]:
            return None
        while state["done"][-1] < need and not state["ended"]:
            chain_x, chain_y = state["x"], state["y"]
            ex, ey = chain_x[-1][-1], chain_y[-1][-1]
            if len(chain_x[-1]) < 2:
                state["ended"] = True
                break
            end_h = np.arctan2(chain_y[-1][-1] - chain_y[-1][-2],
                               chain_x[-1][-1] - chain_x[-1][-2])
            nxt = self._successor(scene, ex, ey, end_h, forward, state["used"], x0, y0, h0,
                                  kappa, state["done"][-1])
            if nxt is None:
                state["ended"] = True
                break
            state["used"].add(nxt)
            lx, ly = self._polyline(nxt)
            if not forward:
                lx, ly = lx[::-1], ly[::-1]
            chain_x.append(lx[1:])
            chain_y.append(ly[1:])
            state["done"].append(state["done"][-1]
                                 + float(np.hypot(np.diff(lx), np.diff(ly)).sum()))
        reached = np.flatnonzero(np.asarray(state["done"]) >= need)
        n = int(reached[0]) + 1 if len(reached) else len(state["done"])
        lines = state.setdefault("lines", {})
        if n not in lines:  # the first n pieces as one polyline: points and arc lengths
            cx, cy = np.concatenate(state["x"][:n]), np.concatenate(state["y"][:n])
            cs = np.r_[0.0, np.cumsum(np.hypot(np.diff(cx), np.diff(cy)))]
            keep = np.r_[True, np.diff(cs) > 1e-9]
            lines[n] = cx[keep], cy[keep], cs[keep]
        return lines[n]

    def follow(self, scene: int, x0: float, y0: float, h0: float, kappa: float,
               u: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Points at distances ``u`` (e,) (all >= 0: ahead along the lane; all <= 0:
        behind) from the foot point of (x0, y0) on the ego's lane, chaining the lanes that
        start where one ends (at a branch the one nearest the arc of curvature ``kappa``);
        straight on past the last lane. None where no lane runs the ego's way there."""
        import numpy as np

        forward = bool(np.all(u >= 0))
        dist = np.abs(u)
        need = float(np.sort(dist)[-2]) if len(dist) > 1 else float(dist.max(initial=0.0))
        chain = self._chain(scene, float(x0), float(y0), float(h0), float(kappa), forward,
                            need)
        if chain is None:
            return None
        cx, cy, cs = chain
        if len(cs) < 2:
            return None
        out_x = np.interp(dist, cs, cx)
        out_y = np.interp(dist, cs, cy)
        beyond = dist > cs[-1]  # straight on past the last lane, along its last direction
        if beyond.any():
            dx, dy = cx[-1] - cx[-2], cy[-1] - cy[-2]
            norm = max(np.hypot(dx, dy), 1e-12)
            extra = dist[beyond] - cs[-1]
            out_x[beyond] = cx[-1] + extra * dx / norm
            out_y[beyond] = cy[-1] + extra * dy / norm
        return out_x, out_y

    def _successor(self, scene, ex, ey, end_h, forward, used, x0, y0, h0, kappa, done):
        """The lane that starts (forward) or ends (backward) within LANE_JOIN_DISTANCE of
        (ex, ey) running on in the direction ``end_h``; at a branch the one whose point
        10 m on lies nearest the ego's arc."""
        import numpy as np

        best, best_err = None, np.inf
        for lane in np.flatnonzero(self.scene == self._map(scene)).tolist():
            if lane in used:
                continue
            lx, ly = self._polyline(lane)
            if not forward:
                lx, ly = lx[::-1], ly[::-1]
            if np.hypot(lx[0] - ex, ly[0] - ey) > LANE_JOIN_DISTANCE:
                continue
            h = np.arctan2(ly[1] - ly[0], lx[1] - lx[0])  # the chain's direction of travel
            if abs(_wrap(h - end_h)) > np.pi / 4:
                continue
            s = np.r_[0.0, np.cumsum(np.hypot(np.diff(lx), np.diff(ly)))]
            probe = min(10.0, s[-1])
            px, py = np.interp(probe, s, lx), np.interp(probe, s, ly)
            ax, ay = _extension_points(np.array([x0]), np.array([y0]),
                                       np.array([h0 if forward else h0 + np.pi]),
                                       np.array([kappa if forward else -kappa]),
                                       np.array([np.inf]), np.array([[done + probe]]))
            err = float(np.hypot(px - ax[0, 0], py - ay[0, 0]))
            if err < best_err:
                best, best_err = lane, err
        return best


def _wrap(angle: np.ndarray) -> np.ndarray:
    import numpy as np

    return np.pi - np.mod(np.pi - angle, _TWO_PI)


def _ragged(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(group of each element, position within its group) for groups of ``counts``."""
    import numpy as np

    total = int(counts.sum())
    group = np.repeat(np.arange(len(counts)), counts)
    within = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return group, within


# Every sum, search and interpolation below stays within one path: no path's numbers depend
# on the others laid beside it (no running sum across paths, no offsets that scale with the
# batch), so an episode labelled and measured alone or in a batch of any size gives the
# same floats, bit for bit (tests/bench/test_rerun.py).
_PADDED_CELLS = 1 << 24  # at most this many cells in the padded (paths, steps) cumsum


def _path_cumsum(values: np.ndarray, length: np.ndarray) -> np.ndarray:
    """The running sum of ``values`` restarting at each path (paths laid end to end with
    ``length`` elements each), each path's sum in its own order as ``np.cumsum`` of its
    values alone gives it."""
    import numpy as np

    out = np.empty(len(values))
    if not len(values):
        return out
    widest = int(length.max())
    if len(length) * widest <= _PADDED_CELLS:
        path, within = _ragged(length)
        padded = np.zeros((len(length), widest))
        padded[path, within] = values
        np.cumsum(padded, axis=1, out=padded)  # row by row: each path on its own
        out[:] = padded[path, within]
        return out
    start = 0
    for n in length.tolist():
        out[start:start + n] = np.cumsum(values[start:start + n])
        start += n
    return out


def _search_within(values: np.ndarray, count: np.ndarray, path: np.ndarray,
                   query: np.ndarray, side: str) -> np.ndarray:
    """``np.searchsorted`` of each ``query`` among the values of its ``path`` (paths laid end
    to end, ``count`` values each, sorted within each path), as an index into ``values``:
    exact comparisons of the values themselves, with no per-path offset added."""
    import numpy as np

    n = len(values)
    data_path = np.repeat(np.arange(len(count)), count)
    is_query = np.zeros(n + len(query), np.int8)
    is_query[n:] = 1
    ties = is_query if side == "right" else 1 - is_query  # right: values equal come first
    # (np.concatenate: np.r_'s parsing costs more than the work on an episode's arrays)
    order = np.lexsort((ties, np.concatenate((values, query)),
                        np.concatenate((data_path, path))))
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    q_rank = rank[n:]
    return q_rank - np.searchsorted(np.sort(q_rank), q_rank)  # values before each query


def _interp_within(x: np.ndarray, path: np.ndarray, xp: np.ndarray, fp: np.ndarray,
                   first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``np.interp(x, xp_path, fp_path)`` of each ``x`` on its ``path``'s polyline (paths laid
    end to end, ``count`` vertices each from ``first``), with numpy's formula and end
    rules, computed from that path's numbers only."""
    import numpy as np

    lo, hi = first[path], first[path] + count[path] - 1
    j = np.clip(_search_within(xp, count, path, x, "right") - 1, lo, np.maximum(hi - 1, lo))
    k = np.minimum(j + 1, hi)
    x0, x1, f0, f1 = xp[j], xp[k], fp[j], fp[k]
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = (f1 - f0) / (x1 - x0)
        out = slope * (x - x0) + f0
        again = np.isnan(out)
        out[again] = (slope * (x - x1) + f1)[again]
    same = np.isnan(out) & (f0 == f1)
    out[same] = f0[same]
    out = np.where(x < xp[lo], fp[lo], out)
    return np.where(x >= xp[hi], fp[hi], out)


_NODES = 64  # integration nodes of an extension's curved stretch (a few cm at most)


def _extension_points(x0: np.ndarray, y0: np.ndarray, h0: np.ndarray, kappa: np.ndarray,
                      fade: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points at distances ``u`` (P, e), >= 0, ahead of (x0, y0) (P,) heading ``h0`` (P,)
    [rad], along a curve that starts with curvature ``kappa`` (P,) [1/m] and falls linearly
    to 0 over ``fade`` (P,) metres (inf: a circular arc); it turns at most
    :data:`MAX_EXTENSION_TURN` and goes straight on from there. Returns (P, e) x and y."""
    return _extension_at(x0, y0, _extension_nodes(h0, kappa, fade, u), u)


def _extension_nodes(h0: np.ndarray, kappa: np.ndarray, fade: np.ndarray, u: np.ndarray
                     ) -> tuple:
    """The curve of :func:`_extension_points` at its integration nodes, for distances up
    to the largest of ``u`` on each row: (that largest (P,), the curved stretch's length
    (P,), node offsets x and y (P, N), cos and sin of the final heading (P, 1)). Two sets of
    distances with the same largest share them."""
    import numpy as np

    k = np.asarray(kappa, float)
    fade = np.asarray(fade, float)
    ak = np.abs(k)
    longest = np.max(u, axis=1, initial=0.0)
    # the length of the curved stretch: where the curvature reaches 0, or the turn its cap
    with np.errstate(divide="ignore", invalid="ignore"):
        cap = np.where(ak > 1e-9, MAX_EXTENSION_TURN / ak, 0.0)  # constant curvature
        full_turn = ak * fade / 2  # the whole turn of a fading curve
        root = fade * (1 - np.sqrt(np.clip(1 - 2 * MAX_EXTENSION_TURN / (ak * fade), 0, 1)))
    curved = np.where(np.isinf(fade), cap, np.where(full_turn > MAX_EXTENSION_TURN, root, fade))
    curved = np.where(ak > 1e-9, curved, 0.0)
    curved = np.minimum(curved, longest)  # no farther than asked
    g = curved[:, None] * np.linspace(0.0, 1.0, _NODES)[None, :]  # (P, N) nodes
    f = np.where(fade > 0, fade, np.inf)[:, None]  # a fade of 0 has no curved stretch
    with np.errstate(invalid="ignore"):
        turn = k[:, None] * np.where(np.isinf(f), g, g - g * g / (2 * f))
    head = h0[:, None] + turn
    dg = np.diff(g, axis=1)
    mid = 0.5 * (head[:, 1:] + head[:, :-1])  # the midpoint rule on each node interval
    nx = np.concatenate([np.zeros((len(k), 1)), np.cumsum(dg * np.cos(mid), axis=1)], axis=1)
    ny = np.concatenate([np.zeros((len(k), 1)), np.cumsum(dg * np.sin(mid), axis=1)], axis=1)
    return longest, curved, nx, ny, np.cos(head[:, -1:]), np.sin(head[:, -1:])


def _extension_at(x0: np.ndarray, y0: np.ndarray, nodes: tuple, u: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_extension_points` from the curve's nodes (:func:`_extension_nodes`)."""
    import numpy as np

    _, curved, nx, ny, cos_end, sin_end = nodes
    # on the curved stretch: between its (uniform) nodes; beyond it: straight on
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = np.where(curved[:, None] > 0, u / curved[:, None] * (_NODES - 1), 0.0)
    pos = np.clip(pos, 0.0, _NODES - 1)
    i = np.minimum(np.floor(pos).astype(np.int64), _NODES - 2)
    frac = pos - i
    rows = np.arange(len(curved))[:, None]
    out_x = nx[rows, i] + frac * (nx[rows, i + 1] - nx[rows, i])
    out_y = ny[rows, i] + frac * (ny[rows, i + 1] - ny[rows, i])
    rest = np.maximum(u - curved[:, None], 0.0)
    out_x = out_x + rest * cos_end
    out_y = out_y + rest * sin_end
    return x0[:, None] + out_x, y0[:, None] + out_y


def _fading(k_end: np.ndarray, k_before: np.ndarray, ds: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """(curvature at the end [1/m], metres over which it falls to 0) of each path end, from
    the mean curvature over the last stretch ``k_end`` and over the stretch before it
    ``k_before``, ``ds`` apart: a curvature that fell below :data:`FADE_RATIO` of the one
    before (the same sign) falls on at that rate (the exit of a turn, which goes straight
    on), else it holds (a steady curve whose measured curvature wavers, or a turn still
    tightening: inf)."""
    import numpy as np

    a_end, a_before = np.abs(k_end), np.abs(k_before)
    falling = ((np.sign(k_end) == np.sign(k_before)) & (a_end < FADE_RATIO * a_before)
        & (ds > 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.where(falling, (a_before - a_end) / np.where(ds > 0, ds, 1.0), 0.0)
        # the mean is the curvature half a stretch back: at the end it has fallen further
        at_end = np.where(falling, np.maximum(a_end - rate * ds / 2, 0.0), a_end)
        fade = np.where(falling & (at_end > 0), at_end / np.where(rate > 0, rate, 1.0),
                        np.inf)
    return np.sign(k_end) * at_end, fade


def _extension_spacing(kappa: np.ndarray, spacing: float) -> np.ndarray:
    """(P,) [m] vertex spacing of the extensions: a chord departs from an arc of curvature
    kappa by c^2 |kappa| / 8, kept under 5 cm, between ``spacing`` and
    :data:`STRAIGHT_SPACING` (a straight extension needs few vertices, and each costs a
    projection)."""
    import numpy as np

    with np.errstate(divide="ignore"):
        chord = np.sqrt(8 * 0.05 / np.abs(kappa))
    return np.clip(chord, spacing, STRAIGHT_SPACING)


def _end_curvature(h: np.ndarray, arc: np.ndarray, end: np.ndarray, other: np.ndarray
                   ) -> np.ndarray:
    """(P,) [1/m] mean curvature between the steps ``other`` and ``end`` (one second apart,
    or less on a short path): heading change over distance driven; 0 where the ego drove
    less than :data:`MIN_CURVATURE_TRAVEL` or the heading jumped (a flip is not a turn)."""
    import numpy as np

    dh = _wrap(h[end] - h[other])
    ds = np.abs(arc[end] - arc[other])
    ok = (ds >= MIN_CURVATURE_TRAVEL) & (np.abs(dh) <= np.pi / 2)
    kappa = np.where(ok, dh / np.where(ok, ds, 1.0), 0.0)
    # the end is later (front) or earlier (back): dh / ds is the curvature either way
    return np.clip(kappa, -1.0 / R_MIN, 1.0 / R_MIN)


def _line_base(paths: Paths, ego_row: np.ndarray, ego_path: np.ndarray, spacing: float
               ) -> tuple:
    """What :func:`_reference_lines` computes before the reach matters: the ego steps'
    positions, headings and arc lengths, the vertices kept, the curvature of each end, and
    room for the extensions' nodes (two frames of the same paths share it)."""
    import numpy as np

    x, y, h = paths.x[ego_row], paths.y[ego_row], paths.heading[ego_row]
    length = paths.stop - paths.start
    first_step = np.cumsum(length) - length
    step_len = np.hypot(np.diff(x), np.diff(y))
    new_path = np.zeros(len(ego_row), bool)
    new_path[first_step] = True
    step_len = np.where(new_path[1:], 0.0, step_len)
    arc = _path_cumsum(np.r_[0.0, step_len] if len(ego_row) else np.zeros(0), length)
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
    hb, he = h[first_step], h[last_step]
    # the last (first) second of the record, or of its motion: back (on) until the ego drove
    # CURVATURE_STRETCH (a path that ends standing still curves as it drove into the stop)
    second = round(HZ)
    every = np.arange(paths.n_paths)
    reach_f = np.maximum(arc[last_step] - arc[np.maximum(last_step - second, first_step)],
                         CURVATURE_STRETCH)
    at_f = _search_within(arc, length, every, arc[last_step] - reach_f, "right") - 1
    reach_b = np.maximum(arc[np.minimum(first_step + second, last_step)] - arc[first_step],
                         CURVATURE_STRETCH)
    at_b = _search_within(arc, length, every, arc[first_step] + reach_b, "left")
    at_f = np.clip(at_f, first_step, last_step)
    at_b = np.clip(at_b, first_step, last_step)
    # the same stretch once more, farther from the end: is the curvature falling (a turn's
    # exit)? then it falls on at that rate (to 0: straight on), else it holds (a curve)
    ds_f = arc[last_step] - arc[at_f]
    ds_b = arc[at_b] - arc[first_step]
    at_f0 = np.clip(_search_within(arc, length, every, arc[at_f] - ds_f, "right") - 1,
                    first_step, last_step)
    at_b0 = np.clip(_search_within(arc, length, every, arc[at_b] + ds_b, "left"),
                    first_step, last_step)
    k_front, fade_f = _fading(_end_curvature(h, arc, last_step, at_f),
                              _end_curvature(h, arc, at_f, at_f0), ds_f)
    k_back, fade_b = _fading(_end_curvature(h, arc, at_b, first_step),
                             _end_curvature(h, arc, at_b0, at_b), ds_b)
    return (x, y, first_step, last_step, arc, kept, kept_path, n_kept, hb, he, k_front,
            fade_f, k_back, fade_b, {})  # the last: the extensions' nodes, once known


def _reference_lines(paths: Paths, ego_row: np.ndarray, ego_path: np.ndarray, spacing: float,
                     reach: float, lanes: LaneMap | None = None, base: tuple | None = None):
    """The decimated, extended polylines of every path, laid end to end.

    Each line: the back extension (a far vertex at -EXTENSION, then vertices every
    ``spacing`` to :data:`STRAIGHT_SPACING` metres (:func:`_extension_spacing`) from
    ``reach`` or more to the start), the recorded positions about ``spacing`` apart, and
    the front extension likewise. Extensions follow the ego's lane
    where ``lanes`` has one, else an arc of the ego's mean curvature over the last (first)
    second (module docstring).

    Returns (vx, vy, vs, first, count, arc): vertex coordinates and arc lengths (q,), the
    first vertex and vertex count of each path (P,), and the arc length of each ego step (m,).
    ``base``: :func:`_line_base` of the same paths, spacing (computed when None).
    """
    import numpy as np

    (x, y, first_step, last_step, arc, kept, kept_path, n_kept, hb, he, k_front, fade_f,
     k_back, fade_b, _) = (_line_base(paths, ego_row, ego_path, spacing) if base is None
        else base)
    # distances of the extension vertices from each end, (P, e) far to near: the far vertex
    # at EXTENSION, then every few metres (closer on tighter arcs, or along lanes) to reach
    mapped = (lanes.covers(paths.scene[paths.start]) if lanes is not None
              else np.zeros(paths.n_paths, bool))
    step_f = np.where(mapped, spacing, _extension_spacing(k_front, spacing))
    step_b = np.where(mapped, spacing, _extension_spacing(k_back, spacing))
    n_ext = int(np.ceil(reach / spacing)) if paths.n_paths else 0
    k = np.arange(n_ext, 0, -1)[None, :]
    far = np.full((paths.n_paths, 1), EXTENSION)
    ext_f = np.hstack([far, np.minimum(step_f[:, None] * k, EXTENSION / 2)])
    ext_b = np.hstack([far, np.minimum(step_b[:, None] * k, EXTENSION / 2)])
    n_e = n_ext + 1
    count = n_kept + 2 * n_e
    first = np.cumsum(count) - count
    q = int(count.sum())
    vx, vy, vs = np.empty(q), np.empty(q), np.empty(q)
    _, within = _ragged(n_kept)
    dest = first[kept_path] + n_e + within
    vx[dest], vy[dest], vs[dest] = x[kept], y[kept], arc[kept]
    # the back extension: forwards from the first position, facing backwards, where the
    # path's curvature has the other sign
    # the curve's nodes once for the frames of the same paths (their farthest distance is
    # the same: EXTENSION), then the points at this reach's distances
    nodes = base[-1] if base is not None else {}
    for end, h_end, k_end, fade, ext in (("back", hb + np.pi, -k_back, fade_b, ext_b),
                                          ("front", he, k_front, fade_f, ext_f)):
        known = nodes.get(end)
        if known is None or not np.array_equal(known[0], np.max(ext, axis=1, initial=0.0)):
            nodes[end] = _extension_nodes(h_end, k_end, fade, ext)
    bx, by = _extension_at(x[first_step], y[first_step], nodes["back"], ext_b)
    fx, fy = _extension_at(x[last_step], y[last_step], nodes["front"], ext_f)
    if lanes is not None and paths.n_paths:
        for p in range(paths.n_paths):
            scene = int(paths.scene[paths.start[p]])
            f, b = last_step[p], first_step[p]
            along = lanes.follow(scene, x[f], y[f], he[p], k_front[p], ext_f[p])
            if along is not None:
                fx[p], fy[p] = along
            along = lanes.follow(scene, x[b], y[b], hb[p], k_back[p], -ext_b[p])
            if along is not None:
                bx[p], by[p] = along
    back = first[:, None] + np.arange(n_e)[None, :]  # (P, e), far to near
    vx[back], vy[back] = bx, by
    vs[back] = -ext_b
    front = (first + count - 1)[:, None] - np.arange(n_e)[None, :]  # far to near
    vx[front], vy[front] = fx, fy
    vs[front] = arc[last_step, None] + ext_f
    return vx, vy, vs, first, count, arc


def _line_cells(vx, vy, vs, first, count, lo_arc, hi_arc, scene, cell):
    """The grid cells near each line: (cell key, path, arc_lo, arc_hi) per (path, cell),
    sorted by cell key. A cell is near a line when one of the line's samples (every half
    cell) lies in it or in one of its 8 neighbours; arc_lo .. arc_hi is the arc range of
    those samples. A point within ``lateral`` of the line (``cell = 4/3 lateral + spacing``)
    has its foot point F within a quarter cell of a sample S, so it is within ``lateral +
    cell / 4 < cell`` of S on each axis: its cell is one of S's 9, and F's arc is within a
    quarter cell of the range."""
    import numpy as np

    n_paths = len(first)
    half = cell / 2
    n_samp = np.ceil((hi_arc - lo_arc) / half).astype(np.int64) + 1
    path, k = _ragged(n_samp)
    arc = lo_arc[path] + k * half
    sx = _interp_within(arc, path, vs, vx, first, count)
    sy = _interp_within(arc, path, vs, vy, first, count)
    cx = np.floor(sx / cell).astype(np.int64)
    cy = np.floor(sy / cell).astype(np.int64)
    dx = np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])
    dy = np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])
    keys = _cell_key(scene[path][:, None], cx[:, None] + dx, cy[:, None] + dy).ravel()
    path9 = np.repeat(path, 9)
    arc9 = np.repeat(arc, 9)
    # (cell, path) pairs in order, stable; arc ranges reduced over each. One int64 key of
    # both while it cannot overflow (keys * n_paths: a table of many scenes and paths, as
    # interactions='all' of 25,900 tracks, went past 2^63 and the pairs out of order),
    # else sorted by the two (the same order)
    if not len(keys) or (int(keys.min()) >= 0 and
                         int(keys.max()) < np.iinfo(np.int64).max // max(n_paths, 1) - 1):
        both = keys * n_paths + path9
        order = np.argsort(both, kind="stable")
        both = both[order]
        new = np.r_[True, both[1:] != both[:-1]]
    else:
        order = np.lexsort((path9, keys))
        k, p = keys[order], path9[order]
        new = np.r_[True, (k[1:] != k[:-1]) | (p[1:] != p[:-1])]
    arc9 = arc9[order]
    start = np.flatnonzero(new)
    return (keys[order][start], path9[order][start], np.minimum.reduceat(arc9, start),
            np.maximum.reduceat(arc9, start))


def _cell_key(scene, cx, cy):
    # cells of 1e6 per axis per scene: coordinates up to 1e7 m (SPEC 2) over cells >= 10 m
    return (scene * 2_000_003 + cx + 1_000_001) * 2_000_003 + cy + 1_000_001


def path_frame(paths: Paths, others: np.ndarray | None = None, *,
               ahead: float | np.ndarray = 100.0, behind: float = 30.0, lateral: float = 10.0,
               near: float = 0.0, lateral_near: float = 0.0, spacing: float = PATH_SPACING,
               lanes: LaneMap | None = None) -> PathFrame:
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
        lanes: lane centre lines that continue the line beyond the record's ends (None:
            arcs of the ego's last and first curvature).

    Returns:
        :class:`PathFrame` of the kept (ego step, other) pairs, ordered by ego step.
    """
    import numpy as np

    if near > 0 and lateral_near > lateral:
        _check_distances(behind, lateral, spacing)
        ego_row, ego_path = paths.ego_rows()
        base = _line_base(paths, ego_row, ego_path, spacing)  # the same for both frames
        main = _path_frame(paths, others, ahead, behind, lateral, spacing, lanes, base)
        _check_distances(near, lateral_near, spacing)
        side = _path_frame(paths, others, near, near, lateral_near, spacing, lanes, base)
        fields = ("step", "other", "s", "d", "heading_rel", "v_along")
        both = {f: np.concatenate((getattr(main, f), getattr(side, f))) for f in fields}
        order = np.lexsort((both["other"], both["step"]))
        both = {f: v[order] for f, v in both.items()}
        new = np.ones(len(order), bool)
        new[1:] = (both["step"][1:] != both["step"][:-1]) | (both["other"][1:]
                                                             != both["other"][:-1])
        return PathFrame(**{f: v[new] for f, v in both.items()}, ego_row=main.ego_row,
                         ego_path=main.ego_path, arc=main.arc)
    _check_distances(behind, lateral, spacing)
    return _path_frame(paths, others, ahead, behind, lateral, spacing, lanes)


def _check_distances(behind: float, lateral: float, spacing: float) -> None:
    import numpy as np

    for name, value in (("behind", behind), ("lateral", lateral), ("spacing", spacing)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"path_frame: {name} must be a finite distance > 0 m, got "
                             f"{value!r}.")


def _path_frame(paths: Paths, others: np.ndarray | None, ahead: float | np.ndarray,
                behind: float, lateral: float, spacing: float, lanes: LaneMap | None,
                base: tuple | None = None) -> PathFrame:
    """:func:`path_frame` of one zone (``near`` 0); ``base``: :func:`_line_base` of the
    paths when known."""
    import numpy as np

    ego_row, ego_path = paths.ego_rows()
    ahead = np.broadcast_to(np.asarray(ahead, float), (len(ego_row),))
    if len(ahead) and not (np.isfinite(ahead).all() and (ahead > 0).all()):
        raise ValueError("path_frame: ahead must be a finite distance > 0 m.")
    far = float(max(ahead.max(initial=0.0), behind))
    cell = 4.0 / 3.0 * lateral + spacing  # see _line_cells: every point within lateral
    vx, vy, vs, first, count, arc = _reference_lines(paths, ego_row, ego_path, spacing,
                                                     far + 2 * cell, lanes, base)
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
    last = first + count - 1
    # the foot point lies within half a sample spacing of the range (see _line_cells)
    lo = _search_within(vs, count, path, w_lo - cell / 2, "right") - 1
    hi = _search_within(vs, count, path, w_hi + cell / 2, "left")
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


def leader_reach(speed: np.ndarray | float, range_m: float = LEADER_RANGE_M,
                 range_s: float = LEADER_RANGE_S) -> np.ndarray:
    """[m] How far ahead along its path an ego at ``speed`` has a leader: ``range_m``, or
    ``range_s`` seconds at its speed where that is farther (SPEC 7: "60 m or 4 s").

    The one rule of the safety measures (:mod:`tap_bench.bench.measures`: headway, TTC) and
    the interaction axis (:mod:`tap_bench.interactions`: Following, Free Driving): the
    leader a measure is taken to is the agent the ego is Following.

    Args:
        speed: [m/s] the ego's speed, a number or (m,) one per ego step (a negative or NaN
            speed counts as 0).
        range_m: [m] the reach at low speed.
        range_s: [s] the reach in time at speed.

    Returns:
        (m,) float reach [m] (a 0-d array for a number).
    """
    import numpy as np

    v = np.nan_to_num(np.asarray(speed, float), nan=0.0)
    return np.maximum(range_m, range_s * np.maximum(v, 0.0))


def nearest_leader(frame: PathFrame, reach: np.ndarray, *,
                   corridor: float = CORRIDOR_HALF_WIDTH,
                   same_direction: float = SAME_DIRECTION) -> np.ndarray:
    """The leader of every ego step: the nearest agent ahead on the path (``0 < s <=
    reach``), inside the corridor (``|d| <= corridor``) and driving along it (``|heading_rel|
    <= same_direction``).

    Args:
        frame: the agents around the ego steps (:func:`path_frame`, with ``ahead`` at least
            ``reach`` and ``lateral`` at least ``corridor``).
        reach: (m,) [m] per ego step, how far ahead a leader counts (:func:`leader_reach`).
        corridor: [m] half width of the corridor.
        same_direction: [rad] largest heading difference to the path of a leader.

    Returns:
        (m,) int64 index into the frame's entries of each ego step's leader, -1 where there
        is none; of two agents equally near, the one of the lower row.
    """
    import numpy as np

    m = len(frame.ego_row)
    leader = np.full(m, -1, np.int64)
    reach = np.broadcast_to(np.asarray(reach, float), (m,))
    cand = np.flatnonzero((frame.s > 0) & (frame.s <= reach[frame.step])
                          & (np.abs(frame.d) <= corridor)
                          & (np.abs(frame.heading_rel) <= same_direction))
    if not len(cand):
        return leader
    step = frame.step[cand]
    nearest = np.full(m, np.inf)
    np.minimum.at(nearest, step, frame.s[cand])
    tie = cand[frame.s[cand] == nearest[step]]  # entries of a step are ordered by row
    first = np.full(m, len(frame.step), np.int64)
    np.minimum.at(first, frame.step[tie], tie)
    has = first < len(frame.step)
    leader[has] = first[has]
    return leader


def scene_lanes(table, scene_codes: np.ndarray, scenes, map_table) -> LaneMap:
    """The :class:`LaneMap` of a trajectory table's scenes: a scene's map is the map table's
    ``map_id`` equal to its ``scenario_id`` (WOMD), else to its ``env`` (highway-env, where
    every seed drives on the env's road).

    Args:
        table: the trajectory table (``scenario_id``, optional ``env``).
        scene_codes: (n,) scene code of each row of ``table``.
        scenes: the scenario id of each scene code.
        map_table: a map table (:mod:`tap_bench.maps`), or a :class:`LaneMap` made of one
            (:meth:`LaneMap.of_maps`) that several calls share: then its lanes are not
            built again, and what one call matched and chained the next one reads.
    """
    import numpy as np

    shared = map_table if isinstance(map_table, LaneMap) else None
    ids = (set(shared.map_ids) if shared is not None else
        set(map_table["map_id"].astype(str).unique()))
    maps: list[str | None] = [str(s) if str(s) in ids else None for s in scenes]
    if "env" in table.columns and any(m is None for m in maps):
        first = np.unique(np.asarray(scene_codes), return_index=True)[1]
        env = table["env"].take(first).astype(str).to_numpy()
        maps = [m if m is not None or env[k] not in ids else env[k]
                for k, m in enumerate(maps)]
    if shared is not None:
        return shared.for_scenes(maps)
    return LaneMap.from_table(map_table, maps)
