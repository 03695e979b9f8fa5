"""Kinematics of SPEC section 2: acceleration, yaw rate and the one-second distributions.

All functions work on a validated trajectory table (:func:`validate_and_index`) as flat
arrays over its rows, one pass for all tracks at once. Derivatives are taken within each
valid segment only, so values never leak across a gap or from one track into another:

- heading is unwrapped first (each step's change is wrapped to (-pi, pi]),
- a = dv/dt and w = d(heading)/dt by central differences inside a segment and one-sided
  differences at its two ends (numpy.gradient's rule, with the actual time stamps),
- a segment of a single step has a = w = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.trajectories import HZ, TrackIndex, validate_and_index

__all__ = ["STEPS_PER_SECOND", "Kinematics", "compute_kinematics", "one_second_samples",
           "window_means"]

STEPS_PER_SECOND = round(HZ)
"""Steps in one second at 10 Hz: the shortest label run and the averaging window."""


@dataclass(frozen=True)
class Kinematics:
    """Per-row kinematic signals of a validated table (NaN on invalid rows).

    Attributes:
        t: (n_rows,) time [s].
        v: (n_rows,) speed [m/s].
        a: (n_rows,) acceleration [m/s^2].
        w: (n_rows,) yaw rate [rad/s], positive counter-clockwise (a left turn).
        index: where tracks and valid segments lie.
    """

    t: np.ndarray
    v: np.ndarray
    a: np.ndarray
    w: np.ndarray
    index: TrackIndex


def _derivative(step_diff: np.ndarray, t: np.ndarray, index: TrackIndex) -> np.ndarray:
    """d(value)/dt per row from the step differences ``step_diff[i] = value[i+1] - value[i]``.

    Central differences inside a valid segment, one-sided at its ends, 0 for a one-step
    segment, NaN on invalid rows. Each row uses at most two step differences of its own
    segment, so a track's values never depend on other rows of the table.
    """
    n = len(t)
    rows = np.arange(n)
    first = np.zeros(n, dtype=bool)
    last = np.zeros(n, dtype=bool)
    first[index.segment_start] = True
    last[index.segment_stop - 1] = True
    invalid = index.segment < 0
    lo = np.where(first | invalid, rows, rows - 1)
    hi = np.where(last | invalid, rows, rows + 1)
    d = np.append(np.nan_to_num(step_diff), 0.0)
    span = hi - lo
    num = np.where(span >= 1, d[lo], 0.0) + np.where(span == 2, d[np.minimum(lo + 1, n - 1)], 0.0)
    dt = t[hi] - t[lo]
    out = np.divide(num, dt, out=np.zeros(n), where=dt > 0)
    out[invalid] = np.nan
    return out


def compute_kinematics(clean: pd.DataFrame, index: TrackIndex) -> Kinematics:
    """Acceleration and yaw rate of every valid row of a validated table.

    Args:
        clean: the table returned by :func:`validate_and_index` (rows grouped by track).
        index: its :class:`TrackIndex`.
    """
    t = clean["t"].to_numpy(dtype=np.float64)
    v = clean["speed"].to_numpy(dtype=np.float64).copy()
    heading = clean["heading"].to_numpy(dtype=np.float64)
    dh = np.diff(heading)
    dh = (dh + np.pi) % (2.0 * np.pi) - np.pi  # the unwrapped heading's step change
    dv = np.diff(v)
    a = _derivative(dv, t, index)
    w = _derivative(dh, t, index)
    v[index.segment < 0] = np.nan
    return Kinematics(t=t, v=v, a=a, w=w, index=index)


def window_means(signal: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """Mean of ``signal[s:s+width]`` for each start ``s``; each window summed on its own.

    Args:
        signal: (n,) values.
        starts: (k,) int window starts; every window must lie inside ``signal``.
        width: window length [steps].

    Returns:
        (k,) means. A window's mean depends on its own values only, never on other rows.
    """
    if len(starts) == 0:
        return np.zeros(0)
    idx = starts[:, None] + np.arange(width)[None, :]
    return signal[idx].sum(axis=1) / width


def one_second_samples(table: pd.DataFrame | Kinematics) -> dict[str, np.ndarray]:
    """The distributions D_w, D_a, D_v of SPEC section 3.

    One-second averages over non-overlapping 10-step windows of every valid segment,
    starting at the segment's first step; a trailing window shorter than 1 s is left out.

    Args:
        table: a trajectory table, or its :class:`Kinematics`.

    Returns:
        ``{"w": |mean yaw rate| [rad/s], "a": mean acceleration [m/s^2], "v": mean speed
        [m/s]}``, each a float64 array of the same length (one entry per window).
    """
    kin = table if isinstance(table, Kinematics) else compute_kinematics(
        *validate_and_index(table))
    idx = kin.index
    n_windows = idx.segment_length // STEPS_PER_SECOND
    starts = np.repeat(idx.segment_start, n_windows)
    offsets = np.arange(n_windows.sum()) - np.repeat(np.cumsum(n_windows) - n_windows, n_windows)
    starts = starts + offsets * STEPS_PER_SECOND
    return {
        "w": np.abs(window_means(kin.w, starts, STEPS_PER_SECOND)),
        "a": window_means(kin.a, starts, STEPS_PER_SECOND),
        "v": window_means(kin.v, starts, STEPS_PER_SECOND),
    }
