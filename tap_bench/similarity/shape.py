"""Normalised trajectory shapes and the ADE and DTW distances between them.

For shape comparisons each trajectory (one valid segment of a track) is normalised (SPEC
section 2, TAP paper section 6.1): translated to start at the origin and rotated so that its
initial heading is 0 (it leaves the origin along +x).

- **ADE** (average displacement error): the mean over time steps of the distance between
  corresponding points, ``(1/n) sum_t ||a_t - b_t||`` [m]. It is defined for trajectories
  of equal length only: :func:`ade` refuses unequal lengths, and the nearest-neighbour search
  compares a trajectory with those of its own length, or with everything truncated to a
  common prefix (see :func:`tap_bench.similarity.ade_nearest`).
- **DTW** (dynamic time warping, full window): the least summed point distance over
  monotone warping paths from (0, 0) to (n-1, m-1) [m]; lengths may differ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.errors import LabelTableError, ParameterError, TapBenchError
from tap_bench.similarity import kernels
from tap_bench.trajectories import IDENTIFYING_COLUMNS, validate_and_index

__all__ = ["Shapes", "ade", "dtw", "normalised_shapes"]


@dataclass(frozen=True)
class Shapes:
    """Normalised trajectories laid end to end.

    Attributes:
        points: (total, 2) float64 normalised positions [m].
        offsets: (n + 1,) int64, trajectory i is ``points[offsets[i]:offsets[i + 1]]``.
        speed: (total,) float64 speed at each point [m/s].
        t: (total,) float64 time since the trajectory's first step [s].
        keys: n rows: scenario_id, track_id, segment, t_start [s] and the identifying
            columns the table had (source, env, policy, seed, object_type, is_ego).
    """

    points: np.ndarray
    offsets: np.ndarray
    speed: np.ndarray
    t: np.ndarray
    keys: pd.DataFrame

    def __len__(self) -> int:
        return len(self.offsets) - 1

    @property
    def lengths(self) -> np.ndarray:
        """(n,) int64 points per trajectory."""
        return np.diff(self.offsets)

    def __getitem__(self, i: int) -> np.ndarray:
        """(n_i, 2) the points of trajectory ``i``."""
        return self.points[self.offsets[i]:self.offsets[i + 1]]

    def speed_of(self, i: int) -> np.ndarray:
        return self.speed[self.offsets[i]:self.offsets[i + 1]]

    def time_of(self, i: int) -> np.ndarray:
        return self.t[self.offsets[i]:self.offsets[i + 1]]


def normalised_shapes(trajectories: pd.DataFrame, labels: pd.DataFrame | None = None, *,
                      min_steps: int = 2, source: str = "trajectory table") -> Shapes:
    """Normalise every trajectory of a table (or those a label table names).

    Args:
        trajectories: a trajectory table (SPEC section 1), validated on entry.
        labels: a label table with one row per trajectory (one level); the shapes then follow
            its rows, matched on (scenario_id, track_id, segment). Without it, every valid
            segment of at least ``min_steps`` steps, in track order.
        min_steps: the shortest segment kept when ``labels`` is not given (>= 2).
        source: a name for the trajectory table in error messages.

    Raises:
        LabelTableError: a label row names a trajectory the table does not have, or starts at
            another time (labels made from another file), or the label table repeats a
            trajectory (several levels: select one).
    """
    if min_steps < 2:
        raise ParameterError("min_steps", min_steps, "",
            message=f"min_steps must be >= 2 (a shape needs two points), got {min_steps}")
    checked = validate_and_index(trajectories, source=source)
    index = checked.index
    track_first = np.searchsorted(index.segment_track, np.arange(index.n_tracks))
    ordinal = np.arange(index.n_segments) - track_first[index.segment_track]
    tracks = checked.per_track(["scenario_id", "track_id", *IDENTIFYING_COLUMNS])
    t_all = np.asarray(checked["t"], dtype=np.float64)

    if labels is None:
        seg = np.flatnonzero(index.segment_length >= min_steps)
    else:
        seg = _segments_of_labels(labels, tracks, index, ordinal, t_all, source)
    starts, stops = index.segment_start[seg], index.segment_stop[seg]
    lengths = stops - starts
    offsets = np.zeros(len(seg) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    rows = np.repeat(starts, lengths) + (np.arange(offsets[-1]) - np.repeat(offsets[:-1], lengths))

    x = np.asarray(checked["x"], dtype=np.float64)
    y = np.asarray(checked["y"], dtype=np.float64)
    heading = np.asarray(checked["heading"], dtype=np.float64)
    x0 = np.repeat(x[starts], lengths)
    y0 = np.repeat(y[starts], lengths)
    h0 = np.repeat(heading[starts], lengths)
    dx, dy = x[rows] - x0, y[rows] - y0
    cos, sin = np.cos(h0), np.sin(h0)
    points = np.empty((len(rows), 2), dtype=np.float64)
    points[:, 0] = cos * dx + sin * dy
    points[:, 1] = -sin * dx + cos * dy
    keys = tracks.take(index.segment_track[seg]).reset_index(drop=True)
    keys.insert(2, "segment", ordinal[seg])
    keys.insert(3, "t_start", t_all[starts])
    return Shapes(points=points, offsets=offsets,
                  speed=np.asarray(checked["speed"], dtype=np.float64)[rows],
                  t=t_all[rows] - np.repeat(t_all[starts], lengths), keys=keys)


def _segments_of_labels(labels: pd.DataFrame, tracks: pd.DataFrame, index, ordinal: np.ndarray,
                        t_all: np.ndarray, source: str) -> np.ndarray:
    """Segment index of each label row (in label order)."""
    for col in ("scenario_id", "track_id"):
        if col not in labels.columns:
            raise LabelTableError(f"label table: missing column {col!r}; make it with "
                                  "'tap-bench label'.")
    seg_key = pd.DataFrame({
        "scenario_id": tracks["scenario_id"].astype(str).to_numpy()[index.segment_track],
        "track_id": tracks["track_id"].astype(str).to_numpy()[index.segment_track],
        "segment": ordinal, "_seg": np.arange(index.n_segments)})
    lab = pd.DataFrame({
        "scenario_id": labels["scenario_id"].astype(str).to_numpy(),
        "track_id": labels["track_id"].astype(str).to_numpy(),
        "segment": (labels["segment"].to_numpy(dtype=np.int64) if "segment" in labels.columns
                    else np.zeros(len(labels), dtype=np.int64)),
        "_row": np.arange(len(labels))})
    dup = lab.duplicated(["scenario_id", "track_id", "segment"]).to_numpy()
    if dup.any():
        pos = int(np.flatnonzero(dup)[0])
        raise LabelTableError(
            f"label table: row {pos} repeats trajectory {lab['scenario_id'].iloc[pos]}:"
            f"{lab['track_id'].iloc[pos]} segment {lab['segment'].iloc[pos]}; give one row per "
            "trajectory (select a single level).")
    merged = lab.merge(seg_key, on=["scenario_id", "track_id", "segment"], how="left")
    merged = merged.sort_values("_row", kind="stable")
    seg = merged["_seg"].to_numpy()
    missing = np.isnan(seg.astype(np.float64))
    if missing.any():
        pos = int(np.flatnonzero(missing)[0])
        raise LabelTableError(
            f"label table: row {pos} ({lab['scenario_id'].iloc[pos]}:{lab['track_id'].iloc[pos]}"
            f" segment {lab['segment'].iloc[pos]}) has no valid segment in {source}. Were the "
            "labels made from this trajectory file? Relabel it with 'tap-bench label'.")
    seg = seg.astype(np.int64)
    if "t_start" in labels.columns:
        t_lab = labels["t_start"].to_numpy(dtype=np.float64)
        off = np.abs(t_all[index.segment_start[seg]] - t_lab) > 1e-6
        if off.any():
            pos = int(np.flatnonzero(off)[0])
            raise LabelTableError(
                f"label table: row {pos} ({lab['scenario_id'].iloc[pos]}:"
                f"{lab['track_id'].iloc[pos]}) starts at t_start={t_lab[pos]!r} s but that "
                f"segment of {source} starts at {t_all[index.segment_start[seg[pos]]]!r} s: "
                "the labels were made from another file. Relabel it with 'tap-bench label'.")
    return seg


def _as_points(a: np.ndarray, name: str) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2 or len(a) < 1:
        raise TapBenchError(f"{name} must be an (n, 2) array of points with n >= 1, got shape "
                            f"{a.shape}")
    return a


def ade(a: np.ndarray, b: np.ndarray) -> float:
    """Average displacement error of two (n, 2) trajectories of equal length [m].

    Raises:
        TapBenchError: the lengths differ (compare a common prefix: ``ade(a[:k], b[:k])``).
    """
    a, b = _as_points(a, "a"), _as_points(b, "b")
    if len(a) != len(b):
        raise TapBenchError(f"ADE needs trajectories of equal length, got {len(a)} and {len(b)} "
                            f"points; compare a common prefix (a[:{min(len(a), len(b))}]) or use "
                            "DTW.")
    return float(kernels.ade_sum(a, b)) / len(a)


def dtw(a: np.ndarray, b: np.ndarray) -> float:
    """Dynamic time warping distance of (n, 2) and (m, 2) trajectories [m], full window."""
    return float(kernels.dtw_full(_as_points(a, "a"), _as_points(b, "b")))
