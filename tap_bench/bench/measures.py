"""Safety and efficiency measures of the ego vehicle, one row per episode (scenario).

From a trajectory table (SPEC section 1) with ``is_ego`` marking the ego vehicle, for each
scenario:

==================  ======  ================================================================
column              unit    what
==================  ======  ================================================================
``crashed``         bool    the ego collided (any ego row with ``crashed`` true)
``mean_speed``      m/s     mean ego speed over its valid steps
``min_headway_s``   s       smallest time headway to the vehicle ahead: bumper gap / ego
                            speed, over steps with a leader and ego speed >= 1 m/s after the
                            first :data:`BURN_IN_S`; capped at :data:`HEADWAY_CAP_S`
``min_ttc_s``       s       smallest time to collision with the vehicle ahead: gap / closing
                            speed, over steps after the burn-in where the ego closes in; capped at
                            :data:`TTC_CAP_S` (no conflict at all gives the cap)
``rms_jerk``        m/s^3   root mean square of the ego's longitudinal jerk (d^2 v / dt^2)
``duration_s``      s       time the ego was recorded
==================  ======  ================================================================

The vehicle ahead (leader) at a step is the nearest other road user whose centre lies ahead
of the ego's centre along the ego's heading, less than :data:`LANE_HALF_WIDTH` to either
side and within :data:`LOOKAHEAD`; the gap is that distance less one :data:`VEHICLE_LENGTH`
(centre to centre, minus half a length of each). Surrounding vehicles are only known where
the table records them (highway-env rollouts record every vehicle; WOMD every tracked
agent): without them the headway and TTC are NaN. Everything is vectorised over the whole
table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd

from tap_bench.errors import TrajectoryTableError
from tap_bench.trajectories import HZ

__all__ = [
    "BURN_IN_S",
    "HEADWAY_CAP_S",
    "LANE_HALF_WIDTH",
    "LOOKAHEAD",
    "MEASURES",
    "MIN_SPEED_FOR_HEADWAY",
    "TTC_CAP_S",
    "VEHICLE_LENGTH",
    "Measure",
    "ego_measures",
    "ego_step_measures",
]

LANE_HALF_WIDTH = 2.0  # [m] half of highway-env's 4 m lane: a leader is within it laterally
VEHICLE_LENGTH = 5.0  # [m] highway-env's vehicle length; bumper gap = centre gap - length
LOOKAHEAD = 100.0  # [m] farthest leader considered, centre to centre
MIN_SPEED_FOR_HEADWAY = 1.0  # [m/s] below this a time headway is not meaningful
HEADWAY_CAP_S = 10.0  # [s] headways above this count as free driving
BURN_IN_S = 2.0  # [s] headway and TTC skip the first steps: the scenario sets those gaps
TTC_CAP_S = 10.0  # [s] times to collision above this (or none) count as no conflict


@dataclass(frozen=True)
class Measure:
    """A per-episode measure and which direction is better.

    Attributes:
        name: column of the measures table.
        unit: for axis labels.
        higher_is_better: True for speed, headway, TTC; False for crashes and jerk.
        description: one line for reports.
    """

    name: str
    unit: str
    higher_is_better: bool
    description: str


MEASURES: tuple[Measure, ...] = (
    Measure("crashed", "share", False, "collision rate of the ego"),
    Measure("mean_speed", "m/s", True, "mean ego speed"),
    Measure("min_headway_s", "s", True, "smallest time headway to the leader (capped 10 s)"),
    Measure("min_ttc_s", "s", True, "smallest time to collision with the leader (capped 10 s)"),
    Measure("rms_jerk", "m/s^3", False, "RMS longitudinal jerk of the ego"),
)
"""The measures scored in comparisons, in report order."""

_KEEP = ("env", "policy", "seed", "source")


class _EgoSteps(NamedTuple):
    """Every valid ego step of a table, sorted by scenario and time (m steps)."""

    table: pd.DataFrame
    sids: pd.Index  # scenario ids, by code
    sid_codes: np.ndarray  # (n,) scenario code of every row of the table
    is_ego: np.ndarray  # (n,) bool
    valid: np.ndarray  # (n,) bool
    rows: np.ndarray  # (m,) table rows of the ego steps
    key: np.ndarray  # (m,) scenario code * steps + step, increasing
    sid: np.ndarray  # (m,) scenario code of each ego step
    t: np.ndarray  # (m,) [s]
    speed: np.ndarray  # (m,) [m/s]
    gap: np.ndarray  # (m,) bumper gap to the leader [m], NaN without one
    headway: np.ndarray  # (m,) [s], NaN without a leader or below MIN_SPEED_FOR_HEADWAY
    ttc: np.ndarray  # (m,) [s], inf when not closing in, NaN without a leader
    burn_in: np.ndarray  # (m,) bool: within BURN_IN_S of the ego's first step


def _ego_steps(table: pd.DataFrame) -> _EgoSteps:
    for col in ("scenario_id", "track_id", "t", "x", "y", "heading", "speed", "is_ego"):
        if col not in table.columns:
            fix = (" Mark the ego (the policy's vehicle, WOMD's self-driving car) with a "
                   "boolean is_ego column." if col == "is_ego" else "")
            raise TrajectoryTableError(f"ego measures need column {col!r}; the table has "
                                       f"{', '.join(map(str, table.columns))}.{fix}",
                                       column=col)
    valid = np.ones(len(table), bool)
    if "valid" in table.columns:
        valid = table["valid"].fillna(False).to_numpy(bool, copy=True)
    for col in ("x", "y", "heading", "speed"):
        valid &= np.isfinite(table[col].to_numpy(float))
    t = table["t"].to_numpy(float)
    step = np.rint(t * HZ).astype(np.int64)
    sid_codes, sids = pd.factorize(table["scenario_id"], sort=False)
    is_ego = table["is_ego"].fillna(False).to_numpy(bool)
    ego_rows = np.flatnonzero(is_ego & valid)

    n_steps = int(step.max() - step.min() + 1) if len(step) else 1
    step0 = int(step.min()) if len(step) else 0
    key = sid_codes.astype(np.int64) * n_steps + (step - step0)

    ego_track = table["track_id"].take(ego_rows).to_numpy()  # not the whole string column
    ego_sid = sid_codes[ego_rows]
    _check_one_ego(ego_sid, ego_track, sids)

    order = np.argsort(key[ego_rows], kind="stable")
    ego_rows = ego_rows[order]
    ego_key = key[ego_rows]
    if len(ego_key) > 1 and np.any(ego_key[1:] == ego_key[:-1]):
        dup = ego_rows[1:][ego_key[1:] == ego_key[:-1]][0]
        raise TrajectoryTableError(
            f"row {dup}: the ego of scenario {table['scenario_id'].iloc[dup]!r} has two rows at "
            f"t = {t[dup]:g} s; each track has one row per 0.1 s step.", column="t", row=int(dup))

    x = table["x"].to_numpy(float)
    y = table["y"].to_numpy(float)
    heading = table["heading"].to_numpy(float)
    speed = table["speed"].to_numpy(float)

    gap, closing = _leader_gaps(key, valid & ~is_ego, ego_rows, ego_key, x, y, heading, speed)
    v_ego = speed[ego_rows]
    with np.errstate(divide="ignore", invalid="ignore"):
        headway = np.where(v_ego >= MIN_SPEED_FOR_HEADWAY, gap / v_ego, np.nan)
        ttc = np.where(closing > 0, gap / closing, np.inf)
    ttc = np.where(np.isnan(gap), np.nan, ttc)
    seg_sid = ego_sid[order]
    t_rel = t[ego_rows] - _group_first(t[ego_rows], seg_sid)
    return _EgoSteps(table, sids, sid_codes, is_ego, valid, ego_rows, ego_key, seg_sid,
                     t[ego_rows], v_ego, gap, headway, ttc, t_rel < BURN_IN_S - 1e-9)


def ego_step_measures(table: pd.DataFrame) -> pd.DataFrame:
    """The ego's safety measures at every valid step of every scenario (what
    :func:`ego_measures` reduces to one row per episode).

    Args:
        table: a trajectory table, as for :func:`ego_measures`.

    Returns:
        one row per valid ego step, sorted by scenario (in order of first appearance) and
        time: ``scenario_id``, ``t`` [s], ``speed`` [m/s], ``gap_m`` (bumper gap to the
        leader [m]), ``headway_s`` and ``ttc_s`` [s] (capped at :data:`HEADWAY_CAP_S` and
        :data:`TTC_CAP_S`; NaN without a leader, and the headway below
        :data:`MIN_SPEED_FOR_HEADWAY`), ``scored`` (False during the first
        :data:`BURN_IN_S`, which the episode minima leave out).
    """
    st = _ego_steps(table)
    return pd.DataFrame({
        "scenario_id": np.asarray(st.sids)[st.sid], "t": st.t, "speed": st.speed,
        "gap_m": st.gap, "headway_s": np.minimum(st.headway, HEADWAY_CAP_S),
        "ttc_s": np.minimum(st.ttc, TTC_CAP_S), "scored": ~st.burn_in})


def ego_measures(table: pd.DataFrame) -> pd.DataFrame:
    """Safety and efficiency measures of the ego of every scenario of a trajectory table.

    Args:
        table: trajectory table with ``scenario_id``, ``track_id``, ``t``, ``x``, ``y``,
            ``heading``, ``speed`` and ``is_ego``; optional ``valid``, ``crashed``, and the
            identifying ``env``, ``policy``, ``seed``, ``source``, which are carried over.
            Rows of one track must be at distinct 0.1 s steps.

    Returns:
        one row per scenario with an ego: ``scenario_id``, the identifying columns present,
        and the columns of the module docstring.

    Raises:
        TrajectoryTableError: ``is_ego`` is missing, or a scenario has two ego tracks.
    """
    st = _ego_steps(table)
    sids, sid_codes, is_ego, valid = st.sids, st.sid_codes, st.is_ego, st.valid
    ego_rows, ego_key, seg_sid, v_ego = st.rows, st.key, st.sid, st.speed
    # the initial gaps are the scenario's, not the policy's: skip the first BURN_IN_S of each
    headway = np.where(st.burn_in, np.nan, st.headway)
    ttc = np.where(st.burn_in, np.nan, st.ttc)

    # per scenario reductions over the ego's (sorted) rows
    starts = np.flatnonzero(np.r_[True, seg_sid[1:] != seg_sid[:-1]]) if len(seg_sid) else \
        np.zeros(0, np.int64)
    counts = np.diff(np.r_[starts, len(seg_sid)])
    scen = seg_sid[starts]
    has_others = np.bincount(sid_codes[~is_ego & valid], minlength=len(sids))[scen] > 0

    mean_speed = np.add.reduceat(v_ego, starts) / counts if len(starts) else np.zeros(0)
    min_headway = _reduce_min(headway, starts, HEADWAY_CAP_S)
    min_ttc = _reduce_min(ttc, starts, TTC_CAP_S)
    min_headway[~has_others] = np.nan
    min_ttc[~has_others] = np.nan
    rms_jerk = _rms_jerk(v_ego, ego_key, starts, counts)
    crashed = np.zeros(len(starts), bool)
    if "crashed" in table.columns:
        c = table["crashed"].fillna(False).to_numpy(bool)[ego_rows]
        crashed = np.logical_or.reduceat(c, starts) if len(starts) else crashed
    t_ego = st.t
    duration = (np.maximum.reduceat(t_ego, starts) - np.minimum.reduceat(t_ego, starts)
                + 1.0 / HZ) if len(starts) else np.zeros(0)

    first = ego_rows[starts]
    out = pd.DataFrame({"scenario_id": np.asarray(sids)[scen]})
    for col in _KEEP:
        if col in table.columns:
            out[col] = table[col].take(first).to_numpy()
    out["crashed"] = crashed
    out["mean_speed"] = mean_speed
    out["min_headway_s"] = min_headway
    out["min_ttc_s"] = min_ttc
    out["rms_jerk"] = rms_jerk
    out["duration_s"] = duration
    return out


def _check_one_ego(ego_sid: np.ndarray, ego_track: np.ndarray, sids) -> None:
    if not len(ego_sid):
        return
    pairs = pd.DataFrame({"s": ego_sid, "k": ego_track}).drop_duplicates()
    many = pairs["s"].duplicated(keep=False)
    if many.any():
        s = int(pairs.loc[many, "s"].iloc[0])
        tracks = sorted(map(str, pairs.loc[pairs["s"] == s, "k"]))
        raise TrajectoryTableError(
            f"scenario {sids[s]!r} has {len(tracks)} ego tracks ({', '.join(tracks[:5])}); "
            "is_ego must mark one track per scenario.", column="is_ego")


def _leader_gaps(key, other_mask, ego_rows, ego_key, x, y, heading, speed):
    """(m,) bumper gap to the leader and closing speed at each ego step (NaN: no leader)."""
    others = np.flatnonzero(other_mask)
    pos = np.searchsorted(ego_key, key[others])
    pos_ok = pos < len(ego_key)
    pos_ok[pos_ok] = ego_key[pos[pos_ok]] == key[others[pos_ok]]
    others, pos = others[pos_ok], pos[pos_ok]
    # the ego's frame per ego step (m values), gathered per other row
    h_e = heading[ego_rows]
    c, s = np.cos(h_e)[pos], np.sin(h_e)[pos]
    dx, dy = x[others] - x[ego_rows][pos], y[others] - y[ego_rows][pos]
    ahead = dx * c + dy * s
    lead = (ahead > 0) & (ahead < LOOKAHEAD)
    lead[lead] = np.abs(dy[lead] * c[lead] - dx[lead] * s[lead]) < LANE_HALF_WIDTH
    others, pos, ahead = others[lead], pos[lead], ahead[lead]
    gap = np.full(len(ego_key), np.nan)
    closing = np.full(len(ego_key), np.nan)
    if len(others):
        # nearest leader per ego step, in linear time (no sort of the candidate rows)
        nearest = np.full(len(ego_key), np.inf)
        np.minimum.at(nearest, pos, ahead)
        first = ahead == nearest[pos]
        p, o = pos[first], others[first]  # a tie keeps one of the equally near leaders
        gap[p] = np.maximum(nearest[p] - VEHICLE_LENGTH, 0.0)
        e = ego_rows[p]
        closing[p] = speed[e] - speed[o] * np.cos(heading[o] - heading[e])
    return gap, closing


def _group_first(values: np.ndarray, group: np.ndarray) -> np.ndarray:
    """(m,) the first value of each row's group (rows sorted by group)."""
    if not len(values):
        return values
    starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    return np.repeat(values[starts], np.diff(np.r_[starts, len(values)]))


def _reduce_min(values: np.ndarray, starts: np.ndarray, cap: float) -> np.ndarray:
    """Per-group minimum of ``values`` (NaN ignored), capped at ``cap``."""
    if not len(starts):
        return np.zeros(0)
    filled = np.where(np.isnan(values), np.inf, values)
    return np.minimum(np.minimum.reduceat(filled, starts), cap)


def _rms_jerk(v: np.ndarray, key: np.ndarray, starts: np.ndarray, counts: np.ndarray
              ) -> np.ndarray:
    """Per-group RMS of the second difference of speed over consecutive steps [m/s^3]."""
    if not len(starts):
        return np.zeros(0)
    group = np.repeat(np.arange(len(starts)), counts)
    d2 = (v[2:] - 2 * v[1:-1] + v[:-2]) * HZ * HZ
    # a second difference counts only if its three steps are consecutive, in one group
    ok = (group[2:] == group[:-2]) & (key[2:] - key[:-2] == 2)
    sq = np.bincount(group[2:][ok], weights=d2[ok] ** 2, minlength=len(starts))
    n = np.bincount(group[2:][ok], minlength=len(starts))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(sq / n)
