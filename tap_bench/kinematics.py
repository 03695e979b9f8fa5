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

from tap_bench.trajectories import HZ, CheckedTable, TrackIndex, validate_and_index

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
    num = np.zeros(n)
    den = np.ones(n)
    if n > 2:
        num[1:-1] = step_diff[:-1] + step_diff[1:]
        den[1:-1] = t[2:] - t[:-2]
    first = index.segment_start
    last = index.segment_stop - 1
    single = first == last
    f, lst = first[~single], last[~single]
    num[f] = step_diff[f]
    den[f] = t[f + 1] - t[f]
    num[lst] = step_diff[lst - 1]
    den[lst] = t[lst] - t[lst - 1]
    num[first[single]] = 0.0
    with np.errstate(invalid="ignore", divide="ignore"):  # invalid rows: set to NaN below
        out = num / den
    out[index.segment < 0] = np.nan
    return out


def compute_kinematics(checked: CheckedTable) -> Kinematics:
    """Acceleration and yaw rate of every valid row of a validated table.

    Args:
        checked: the result of :func:`validate_and_index` (rows grouped by track).
    """
    index = checked.index
    t = np.asarray(checked["t"], dtype=np.float64)
    v = np.array(checked["speed"], dtype=np.float64)
    heading = np.asarray(checked["heading"], dtype=np.float64)
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
    # reduceat over (start, start + width) pairs sums each window on its own, in order;
    # a window that ends at the last row is summed from its start to the end instead.
    n = len(signal)
    out = np.empty(len(starts))
    at_end = starts + width >= n
    inner = starts[~at_end]
    if len(inner):
        bounds = np.empty(2 * len(inner), dtype=np.int64)
        bounds[0::2] = inner
        bounds[1::2] = inner + width
        out[~at_end] = np.add.reduceat(signal, bounds)[0::2]
    if at_end.any():
        out[at_end] = np.add.reduceat(signal[n - width:], [0])[0]
    return out / width


def one_second_samples(table: pd.DataFrame | Kinematics, *, source: str = "trajectory table"
                       ) -> dict[str, np.ndarray]:
    """The distributions D_w, D_a, D_v of SPEC section 3.

    One-second averages over non-overlapping 10-step windows of every valid segment,
    starting at the segment's first step; a trailing window shorter than 1 s is left out.

    Args:
        table: a trajectory table, or its :class:`Kinematics`.
        source: a name for the table in error messages (its file path).

    Returns:
        ``{"w": |mean yaw rate| [rad/s], "a": mean acceleration [m/s^2], "v": mean speed
        [m/s]}``, each a float64 array of the same length (one entry per window).
    """
    kin = table if isinstance(table, Kinematics) else compute_kinematics(
        validate_and_index(table, source=source))
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
