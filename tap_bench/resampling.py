"""Resampling a trajectory table taken at another rate (2 Hz, 25 Hz ...) to TAP's 10 Hz.

The rule, per track: the new time grid starts at the track's first time and steps by 0.1 s up
to its last time. x, y, speed (or vx, vy) and the unwrapped heading are linearly interpolated
between the two neighbouring samples; a new step is valid only if both neighbours are valid
(or it falls exactly on a valid sample). Per-track columns (``object_type``, ``source``,
``env``, ``policy``, ``seed``, ``is_ego``) are carried over; other per-step columns are
dropped. Upsampling cannot invent detail: yaw rate and acceleration become piecewise
constant between original samples.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench.errors import TrajectoryTableError
from tap_bench.trajectories import DT, IDENTIFYING_COLUMNS, REQUIRED_COLUMNS

__all__ = ["resample_to_10hz"]

_INTERPOLATED = ("x", "y", "speed", "vx", "vy")


def resample_to_10hz(table: pd.DataFrame, *, source: str = "trajectory table",
                     align: bool = False) -> pd.DataFrame:
    """Resample every track of ``table`` to 10 Hz by linear interpolation (rule above).

    Args:
        table: a trajectory table at any rate; rows of a track in increasing ``t``.
        source: a name for the table in error messages.
        align: put every track on one grid, the multiples of 0.1 s (from the first at or
            after its first time): the agents of a scene then share their steps, as the
            interaction axis needs. False: t0 + 0.1 k from each track's own first time.

    Returns:
        A trajectory table at exactly 10 Hz with a ``valid`` column.
    """
    missing = [c for c in REQUIRED_COLUMNS if c not in table.columns
               and not (c == "speed" and {"vx", "vy"} <= set(table.columns))]
    if missing:
        raise TrajectoryTableError(f"{source}: missing column(s) {missing} needed to resample",
                                   column=missing[0])
    if len(table) == 0:
        raise TrajectoryTableError(f"{source}: the table is empty")
    frame = table.reset_index(drop=True)
    sid = frame["scenario_id"].astype(str)
    tid = frame["track_id"].astype(str)
    key = pd.MultiIndex.from_arrays([sid, tid]).factorize(sort=True)[0]
    order = np.argsort(key, kind="stable")
    key = key[order]
    t = frame["t"].to_numpy(dtype=np.float64)[order]
    new = np.ones(len(t), dtype=bool)
    new[1:] = key[1:] != key[:-1]
    bad = ~new[1:] & (np.diff(t) <= 0)
    if bad.any():
        row = int(order[np.flatnonzero(bad)[0] + 1])
        raise TrajectoryTableError(
            f"{source}: t is not increasing within a track at row {row}; sort each track by "
            "t and drop duplicate times before resampling.", column="t", row=row)
    if not np.all(np.isfinite(t)):
        raise TrajectoryTableError(f"{source}: t has NaN or infinite values", column="t")

    starts = np.flatnonzero(new)
    stops = np.append(starts[1:], len(t))
    t_first, t1 = t[starts], t[stops - 1]
    t0 = np.ceil(t_first / DT - 1e-6) * DT if align else t_first
    n_new = np.maximum(np.floor((t1 - t0) / DT + 1e-6).astype(np.int64) + 1, 0)
    track_of_new = np.repeat(np.arange(len(starts)), n_new)
    k = np.arange(n_new.sum()) - np.repeat(np.cumsum(n_new) - n_new, n_new)
    t_new = t0[track_of_new] + k * DT
    # One monotonic axis for all tracks: shift each track by a multiple of a large span.
    span = float(np.max(t1 - t0)) + 10.0
    track_of_old = np.cumsum(new) - 1
    axis_old = (t - t_first[track_of_old]) + track_of_old * span
    axis_new = (t_new - t_first[track_of_new]) + track_of_new * span

    valid = (frame["valid"].to_numpy(dtype=bool)[order] if "valid" in frame
             else np.ones(len(t), dtype=bool))
    out = {"scenario_id": sid.to_numpy()[order][starts][track_of_new],
           "track_id": tid.to_numpy()[order][starts][track_of_new], "t": t_new}
    for col in _INTERPOLATED:
        if col in frame:
            values = frame[col].to_numpy(dtype=np.float64)[order]
            valid &= np.isfinite(values)
    for col in _INTERPOLATED:
        if col in frame:
            values = frame[col].to_numpy(dtype=np.float64)[order]
            out[col] = np.interp(axis_new, axis_old, np.where(valid, values, 0.0))
    heading = frame["heading"].to_numpy(dtype=np.float64)[order]
    valid &= np.isfinite(heading)
    step = np.diff(np.where(valid, heading, 0.0))
    step = (step + np.pi) % (2 * np.pi) - np.pi
    unwrapped = np.concatenate([[0.0], np.cumsum(step)])
    base = np.where(valid, heading, 0.0)[starts] - unwrapped[starts]
    unwrapped = unwrapped + base[track_of_old]
    out["heading"] = np.angle(np.exp(1j * np.interp(axis_new, axis_old, unwrapped)))
    out["valid"] = np.interp(axis_new, axis_old, valid.astype(np.float64)) > 1.0 - 1e-9
    result = pd.DataFrame(out)
    for col in IDENTIFYING_COLUMNS:
        if col in frame:
            result[col] = frame[col].to_numpy()[order][starts][track_of_new]
    for col in ("x", "y", "heading", "speed", "vx", "vy"):
        if col in result:
            result.loc[~result["valid"], col] = np.nan
    return result
