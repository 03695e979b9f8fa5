"""WOMD lanes as highway-env lanes, and the lane lookup on them, the same answers sooner.

A WOMD lane centre line becomes a :class:`FastPolyLane`, a highway-env
``PolyLaneFixedWidth`` whose Frenet projection (``local_coordinates``) and ``heading_at``
run compiled: highway-env walks the lane's 1 m poses backwards in Python, one ``np.dot`` at
a time (about 2 us a pose: 100 us for a 50 m lane), and looks a pose up with ``np.argwhere``.
The compiled walk does the same arithmetic in the same order (``normal . (p - pose)`` and
``orthonormal . (p - pose)``, the first pose from the end whose projection is >= 0, pose 0
otherwise), so the coordinates equal highway-env's to the last bit or two.

:class:`LaneIndex` answers highway-env's ``RoadNetwork.get_closest_lane_index(position,
heading)`` over every lane of a scene in one compiled pass (highway-env computes
``distance_with_heading`` lane by lane in Python: with 100-400 WOMD lanes that was 80 % of a
simulated step); lanes whose estimate is within :data:`TOLERANCE` of the smallest are then
compared with the lanes' own ``distance_with_heading``, keeping highway-env's first minimum
in network order. :func:`project_positions` projects many positions on one lane at once
(the neighbour search of :class:`~tap_bench.sim.womd_env.WomdRoad`).

Tested against highway-env's own ``PolyLaneFixedWidth`` and ``get_closest_lane_index`` on
generated lanes (radii, directions, lengths) and on the lanes of the real scenarios.

Parts of this module re-state highway-env's code (MIT License, Copyright (c) 2018 Edouard
Leurent, (c) 2023 Farama Foundation): see THIRD_PARTY_NOTICES.md.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from typing import Any

import numba
import numpy as np
from highway_env.road.lane import PolyLaneFixedWidth

__all__ = ["MIN_LANE_LENGTH", "TOLERANCE", "FastPolyLane", "LaneIndex", "lane_points",
           "project_positions"]

MIN_LANE_LENGTH = 1.0
"""[m] highway-env samples a poly lane every metre and cannot build one shorter than this:
shorter WOMD lanes (short connectors) are extended along their direction to this length."""

TOLERANCE = 1e-6
"""[m] lanes whose estimated distance is this close to the smallest are re-compared."""


@numba.njit(cache=True, nogil=True)
def _frenet(px, py, nx, ny, s, x, y):  # pragma: no cover - compiled
    """highway-env's ``LinearSpline2D.cartesian_to_frenet`` of one point on one lane's poses
    (positions px, py; unit normals nx, ny; arc lengths s): (lon, lat)."""
    n = px.shape[0]
    last = n - 1
    proj = nx[last] * (x - px[last]) + ny[last] * (y - py[last])
    if proj >= 0:
        return s[last] + proj, -ny[last] * (x - px[last]) + nx[last] * (y - py[last])
    for idx in range(n - 2, 0, -1):
        proj = nx[idx] * (x - px[idx]) + ny[idx] * (y - py[idx])
        if proj >= 0:
            return s[idx] + proj, -ny[idx] * (x - px[idx]) + nx[idx] * (y - py[idx])
    proj = nx[0] * (x - px[0]) + ny[0] * (y - py[0])
    return proj, -ny[0] * (x - px[0]) + nx[0] * (y - py[0])


@numba.njit(cache=True, nogil=True)
def _pose_index(s, lon):  # pragma: no cover - compiled
    """highway-env's ``_get_idx_segment_for_lon``: the pose before the first sample > lon."""
    n = s.shape[0]
    for k in range(n):
        if lon < s[k]:
            return 0 if k == 0 else k - 1
    return n - 1


@numba.njit(cache=True, nogil=True)
def _frenet_many(px, py, nx, ny, s, xs, ys):  # pragma: no cover - compiled
    m = xs.shape[0]
    lon = np.empty(m)
    lat = np.empty(m)
    for i in range(m):
        lon[i], lat[i] = _frenet(px, py, nx, ny, s, xs[i], ys[i])
    return lon, lat


@numba.njit(cache=True, nogil=True)
def _distances(offsets, px, py, nx, ny, s, lengths, x, y, heading, use_heading
               ):  # pragma: no cover - compiled
    """highway-env's ``distance_with_heading`` of one point to every lane (lanes' poses
    concatenated; lane k's are offsets[k]:offsets[k + 1])."""
    n_lanes = offsets.shape[0] - 1
    out = np.empty(n_lanes)
    pi = math.pi
    for k in range(n_lanes):
        a, b = offsets[k], offsets[k + 1]
        lon, lat = _frenet(px[a:b], py[a:b], nx[a:b], ny[a:b], s[a:b], x, y)
        d = abs(lat) + max(lon - lengths[k], 0.0) + max(0.0 - lon, 0.0)
        if use_heading:
            idx = _pose_index(s[a:b], lon)
            lane_heading = math.atan2(ny[a + idx], nx[a + idx])
            d += abs(((heading - lane_heading + pi) % (2 * pi)) - pi)
        out[k] = d
    return out


def lane_points(centre: np.ndarray) -> np.ndarray | None:
    """A centre line (n, 2) [m] highway-env can build a lane on: repeated points dropped,
    extended along its last direction to :data:`MIN_LANE_LENGTH` when shorter; None for a
    line of a single distinct point (no direction)."""
    pts = np.asarray(centre, dtype=np.float64).reshape(-1, 2)
    if len(pts) < 2:
        return None
    step = np.hypot(*np.diff(pts, axis=0).T)
    pts = pts[np.r_[True, step > 1e-6]]
    if len(pts) < 2:
        return None
    length = float(np.hypot(*np.diff(pts, axis=0).T).sum())
    if length < MIN_LANE_LENGTH + 1e-9:
        d = pts[-1] - pts[-2]
        d = d / np.hypot(*d)
        pts = np.vstack([pts, pts[-1] + d * (MIN_LANE_LENGTH + 1e-6 - length)])
    return pts


def _pose_arrays(lane: PolyLaneFixedWidth) -> tuple[np.ndarray, ...]:
    """(px, py, nx, ny, s) of a highway-env poly lane's poses."""
    poses = lane.curve.poses
    px = np.array([p.position[0] for p in poses], dtype=np.float64)
    py = np.array([p.position[1] for p in poses], dtype=np.float64)
    nx = np.array([p.normal[0] for p in poses], dtype=np.float64)
    ny = np.array([p.normal[1] for p in poses], dtype=np.float64)
    return px, py, nx, ny, np.asarray(lane.curve.s_samples, dtype=np.float64)


class FastPolyLane(PolyLaneFixedWidth):
    """highway-env's ``PolyLaneFixedWidth`` with a compiled ``local_coordinates`` and a
    bisecting ``heading_at`` (same arithmetic; see the module docstring).

    Attributes:
        womd_id: the WOMD lane id.
        arrays: (px, py, nx, ny, s) of the lane's poses.
    """

    def __init__(self, lane_points: Sequence[Sequence[float]], width: float, *,
                 womd_id: int = -1, speed_limit: float = 20.0, **kwargs: Any) -> None:
        super().__init__(lane_points, width=width, speed_limit=speed_limit, **kwargs)
        self.womd_id = int(womd_id)
        self.arrays = _pose_arrays(self)
        self._s_list = self.arrays[4].tolist()
        self._headings = np.arctan2(self.arrays[3], self.arrays[2]).tolist()

    def local_coordinates(self, position: np.ndarray) -> tuple[float, float]:
        return _frenet(*self.arrays, float(position[0]), float(position[1]))

    def heading_at(self, longitudinal: float) -> float:
        k = bisect.bisect_right(self._s_list, longitudinal)
        if longitudinal != longitudinal:  # NaN: highway-env takes the last pose
            k = len(self._s_list)
        return self._headings[max(k - 1, 0)]

    def project(self, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) of many positions [m] at once."""
        return _frenet_many(*self.arrays, np.ascontiguousarray(xs, dtype=np.float64),
                            np.ascontiguousarray(ys, dtype=np.float64))


def project_positions(lane: FastPolyLane, positions: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(lon, lat) [m] of positions (n, 2) on ``lane``."""
    return lane.project(positions[:, 0], positions[:, 1])


class LaneIndex:
    """highway-env's ``get_closest_lane_index`` over the lanes of one network, compiled.

    Args:
        lanes: (lane index, lane) in the network's order; every lane a
            ``PolyLaneFixedWidth`` (a :class:`FastPolyLane` or highway-env's own).
    """

    def __init__(self, lanes: Sequence[tuple[Any, PolyLaneFixedWidth]]) -> None:
        self.indexes = [index for index, _ in lanes]
        self.lanes = [lane for _, lane in lanes]
        arrays = [lane.arrays if isinstance(lane, FastPolyLane) else _pose_arrays(lane)
                  for lane in self.lanes]
        sizes = np.array([len(a[0]) for a in arrays], dtype=np.int64)
        self.offsets = np.zeros(len(arrays) + 1, dtype=np.int64)
        np.cumsum(sizes, out=self.offsets[1:])
        self.px, self.py, self.nx, self.ny, self.s = (
            np.concatenate([a[i] for a in arrays]) if arrays else np.zeros(0)
            for i in range(5))
        self.lengths = np.array([lane.length for lane in self.lanes], dtype=np.float64)

    def distances(self, position: np.ndarray, heading: float | None = None) -> np.ndarray:
        """(n_lanes,) highway-env's ``distance_with_heading`` to every lane (estimates)."""
        return _distances(self.offsets, self.px, self.py, self.nx, self.ny, self.s,
                          self.lengths, float(position[0]), float(position[1]),
                          0.0 if heading is None else float(heading), heading is not None)

    def closest(self, position: np.ndarray, heading: float | None = None) -> Any:
        """The index of the closest lane, as highway-env's ``get_closest_lane_index``."""
        estimates = self.distances(position, heading)
        best = float(estimates.min())
        if not math.isfinite(best):
            return None
        candidates = np.flatnonzero(estimates <= best + TOLERANCE)
        if len(candidates) == 1:
            return self.indexes[int(candidates[0])]
        found = found_index = None
        for k in candidates:  # ties: the lanes' own arithmetic, first minimum in order
            d = PolyLaneFixedWidth.distance_with_heading(self.lanes[k], position, heading)
            if found is None or d < found:
                found, found_index = d, self.indexes[int(k)]
        return found_index
