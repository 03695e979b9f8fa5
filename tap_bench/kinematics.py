"""Kinematics of SPEC section 2: plausible speed, heading and yaw rate, and the one-second
distributions.

All functions work on a validated trajectory table (:func:`validate_and_index`) as flat
arrays over its rows, one pass for all tracks at once. Derivatives are taken within each
valid segment only, so values never leak across a gap or from one track into another:

- a = dv/dt and w = d(heading)/dt by central differences inside a segment and one-sided
  differences at its two ends (numpy.gradient's rule, with the actual time stamps),
- a segment of a single step has a = w = 0.

Real tracks carry glitches (SPEC section 2). Before differentiating, each is repaired and
counted (:class:`Plausibility` holds the parameters; docs/tap.md gives the figures they
were chosen on):

- **speed spikes**: a run of 1 to 3 steps whose speed jumps away from both neighbours by
  more than ``a_max`` allows and back again (both neighbours agreeing with each other) is
  replaced by the straight line between the neighbours (longest runs first); a first or
  last step that jumps away from two agreeing neighbours takes its neighbour's value;
- **heading flips and jumps**: the heading is unwrapped step by step; a step change of
  more than pi/2 is taken as a flip of the box by pi and folded back; a step change whose
  yaw rate exceeds ``v / r_min + w_noise`` (v: the larger repaired speed of the two steps)
  is bounded to it;
- **untrusted headings**: a heading is only trusted where the vehicle moves. Each segment
  is cut into one-second blocks (10 steps from its start, the last one shorter); a block
  moves when its mean position changes by ``v_heading`` per second or more between the
  blocks before and after it. Where it does not, and on every step of a segment whose
  block means never get ``min_travel`` away from the first one, the yaw rate is 0 (no
  turn, no merge);
- **reversing**: a moving block whose motion points more than 120 degrees away from the
  heading at its middle step is reversing. Reversing steps are flagged and counted; their
  yaw rate is kept (SPEC 4.6: the lateral label describes the turn of the path, and the
  direction of travel, heading + pi, turns as the nose does), while the threshold
  distributions leave them out (``trusted`` is forward motion only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.errors import ParameterError
from tap_bench.trajectories import (
    DT,
    DT_TOLERANCE,
    HZ,
    CheckedTable,
    TrackIndex,
    validate_and_index,
)

__all__ = ["STEPS_PER_SECOND", "Kinematics", "Plausibility", "compute_kinematics",
           "one_second_samples", "window_means"]

STEPS_PER_SECOND = round(HZ)
"""Steps in one second at 10 Hz: the shortest label run and the averaging window."""
_REVERSE_COS = -0.5
"""Motion more than 120 degrees away from the heading (cos below -0.5) is reversing."""


@dataclass(frozen=True)
class Plausibility:
    """What a vehicle can do: the bounds that tell a glitch from motion (SPEC section 2).

    Attributes:
        r_min: the tightest turning radius [m]; a yaw rate above v / r_min cannot be driven.
        w_noise: noise floor added to that bound [rad/s]; on the real WOMD samples 99 % of
            the heading changes of vehicles moving at 0.1 to 2 m/s stay below 0.5 to
            0.7 rad/s (docs/tap.md).
        a_max: the largest believable change of speed [m/s^2] (about 1 g): a spike needs
            a jump of more than a_max * 0.1 s on both sides.
        v_heading: the slowest motion [m/s], measured from positions, at which a heading
            is trusted.
        min_travel: a segment that never gets this far [m] from where it starts (1 s
            averaged positions) carries no turn and no merge.
        max_spike_steps: the longest speed spike repaired [steps].
    """

    r_min: float = 5.0
    w_noise: float = 0.5
    a_max: float = 10.0
    v_heading: float = 0.5
    min_travel: float = 1.0
    max_spike_steps: int = 3

    def __post_init__(self) -> None:
        for name in ("r_min", "w_noise", "a_max"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ParameterError(f"Plausibility.{name}", value, "a finite number > 0")
        for name in ("v_heading", "min_travel"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise ParameterError(f"Plausibility.{name}", value, "a finite number >= 0")
        if not (isinstance(self.max_spike_steps, int) and self.max_spike_steps >= 0):
            raise ParameterError("Plausibility.max_spike_steps", self.max_spike_steps,
                                 "an int >= 0")


@dataclass(frozen=True)
class Kinematics:
    """Per-row kinematic signals of a validated table (NaN, or False, on invalid rows).

    Attributes:
        t: (n_rows,) time [s].
        v: (n_rows,) speed [m/s], speed spikes repaired.
        a: (n_rows,) acceleration [m/s^2], from the repaired speed.
        w: (n_rows,) yaw rate [rad/s], positive counter-clockwise (a left turn), from the
            repaired heading; 0 where the heading is not trusted (reversing steps keep it:
            the path turns as the nose does).
        heading: (n_rows,) repaired heading [rad], unwrapped within each segment.
        x, y: (n_rows,) position [m].
        speed_glitch: (n_rows,) bool, the speed of this row was a spike and was replaced.
        heading_glitch: (n_rows,) bool, the heading change into this row was a flip or
            faster than the vehicle can turn, and was folded or bounded.
        trusted: (n_rows,) bool, the heading is trusted (the vehicle moves, forwards, in a
            segment that travels far enough).
        reversing: (n_rows,) bool, the vehicle moves against its heading.
        travel: (n_segments,) the farthest the segment gets from its start [m] (positions
            averaged over 1 s).
        index: where tracks and valid segments lie.
    """

    t: np.ndarray
    v: np.ndarray
    a: np.ndarray
    w: np.ndarray
    index: TrackIndex
    heading: np.ndarray | None = None
    x: np.ndarray | None = None
    y: np.ndarray | None = None
    speed_glitch: np.ndarray | None = None
    heading_glitch: np.ndarray | None = None
    trusted: np.ndarray | None = None
    reversing: np.ndarray | None = None
    travel: np.ndarray | None = None


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


def _despike(v: np.ndarray, dv: np.ndarray, t: np.ndarray, seg: np.ndarray,
             in_seg: np.ndarray, jump: float, max_steps: int
             ) -> tuple[np.ndarray, np.ndarray | None]:
    """Speed with its spikes replaced, and the (n,) bool mask of replaced rows.

    Args:
        v: (n,) speed [m/s]; dv: (n-1,) its step changes; t: (n,) time [s]; seg: (n,) the
            segment of each row (-1 invalid); in_seg: (n-1,) bool, step k -> k+1 inside a
            segment.
        jump: the largest believable change over one step [m/s].
        max_steps: the longest spike repaired.

    Returns:
        the repaired speed (``v`` itself, not a copy, when nothing was repaired) and the
        mask of repaired rows (None when nothing was). Only rows entered by a larger jump
        can start a spike, so the checks run on those few rows.
    """
    n = len(v)
    if n < 3:
        return v, None
    with np.errstate(invalid="ignore"):
        big = np.abs(dv) > jump  # NaN (invalid rows) compares False
    big &= in_seg
    entry = np.flatnonzero(big) + 1  # rows entered by a big jump from their segment
    if len(entry) == 0:
        return v, None
    v = v.copy()
    replaced = np.zeros(n, dtype=bool)
    # Longest first: in 1, 11, 10, 3, 12, 12, 1 the spikes are (11, 10) and (12, 12), not 3.
    for length in range(max_steps, 0, -1):
        start = entry[entry + length < n]
        start = start[seg[start + length] == seg[start]]
        if len(start) == 0:
            continue
        inner = v[start[:, None] + np.arange(length)]
        before, after = v[start - 1], v[start + length]
        with np.errstate(invalid="ignore"):
            up = inner.min(axis=1) - np.maximum(before, after) > jump
            down = np.minimum(before, after) - inner.max(axis=1) > jump
            spike = (up | down) & (np.abs(after - before) <= jump * (length + 1))
        for k in start[spike].tolist():
            if replaced[k - 1:k + length + 1].any():  # touches a spike already repaired
                continue
            rows = np.arange(k, k + length)
            t0, t1 = t[k - 1], t[k + length]
            v[rows] = v[k - 1] + (v[k + length] - v[k - 1]) * (t[rows] - t0) / (t1 - t0)
            replaced[rows] = True
    # A first (last) step that jumps away from two neighbours that agree with each other.
    ends = np.unique(np.concatenate([entry - 1, entry]))
    ends = ends[(ends >= 0) & (ends < n)]
    first = ends[(seg[ends] >= 0) & ((ends == 0) | (seg[np.maximum(ends - 1, 0)] != seg[ends]))
                 & (ends + 2 < n)]
    first = first[(seg[np.minimum(first + 2, n - 1)] == seg[first])]
    last = ends[(seg[ends] >= 0) & ((ends == n - 1) | (seg[np.minimum(ends + 1, n - 1)]
                                                       != seg[ends])) & (ends >= 2)]
    last = last[seg[last - 2] == seg[last]]
    with np.errstate(invalid="ignore"):
        first = first[(np.abs(v[first] - v[first + 1]) > jump)
                      & (np.abs(v[first + 1] - v[first + 2]) <= jump) & ~replaced[first + 1]]
        last = last[(np.abs(v[last] - v[last - 1]) > jump)
                    & (np.abs(v[last - 1] - v[last - 2]) <= jump) & ~replaced[last - 1]]
    v[first], v[last] = v[first + 1], v[last - 1]
    replaced[first] = replaced[last] = True
    return (v, replaced) if replaced.any() else (v, None)


_SUM_ONE_BY_ONE = 64  # tables of at most this many segments: one np.cumsum each


def _segment_cumsum(dh: np.ndarray, index: TrackIndex, n: int) -> np.ndarray:
    """(n,) the repaired heading changes summed from each valid segment's start: 0 on its
    first row, then ``dh[start] + ... + dh[row - 1]`` added one after the other, as
    ``np.cumsum`` of the segment alone adds them; 0 outside the segments.

    Summed within each segment, a track's headings have the bits they have in a table of
    its own, whatever rows come before it (one running sum over the whole table rounded
    each track by the sum of the tracks before it). In a large table the segments are
    summed as the rows of 2-D arrays: one per length that many segments have, and one per
    power of two of the other lengths, zeros padding each row after its segment.
    ``np.cumsum`` along a row adds in order, so the padding changes no sum before it.

    Args:
        dh: (n - 1,) float64, each step's repaired heading change [rad].
        index: the table's segments (row ranges).
        n: number of rows of the table.
    """
    cum = np.zeros(n)
    steps = index.segment_length - 1  # changes summed in each segment
    start = index.segment_start
    if len(start) <= _SUM_ONE_BY_ONE:
        for s, k in zip(start.tolist(), steps.tolist(), strict=True):
            np.cumsum(dh[s:s + k], out=cum[s + 1:s + 1 + k])
        return cum
    # Segments of one length in one 2-D array (tracks of a file share a few lengths); the
    # lengths that few segments have, padded with zeros to a power of two.
    lengths, count = np.unique(steps, return_counts=True)
    common = np.isin(steps, lengths[count >= _SUM_ONE_BY_ONE // 4])
    bucket = np.where(common, steps, -np.frexp(steps.astype(np.float64))[1])
    order = np.argsort(bucket, kind="stable")
    cuts = np.flatnonzero(np.diff(bucket[order])) + 1
    for which in np.split(order, cuts):
        k = int(steps[which].max())
        if k == 0:
            continue
        rows = start[which, None] + np.arange(k)  # (segments, k)
        if bool(common[which[0]]):
            cum[rows + 1] = np.cumsum(dh[rows], axis=1)
        else:  # beyond a segment: zeros, and rows it does not own, not written
            inside = rows < (start[which] + steps[which])[:, None]
            sums = np.cumsum(np.where(inside, dh[np.minimum(rows, n - 2)], 0.0), axis=1)
            cum[rows[inside] + 1] = sums[inside]
    return cum


def _anchor(heading: np.ndarray, cum: np.ndarray, index: TrackIndex, glitchy: np.ndarray
            ) -> np.ndarray:
    """(n_segments,) the constant that turns the summed repaired changes ``cum`` into
    headings: the raw heading at the segment's start, except in segments with a heading
    glitch (``glitchy``, (n_segments,) bool). There ``heading - cum`` is the constant on
    most rows but off by pi (or more) on the flipped ones: the direction (mod pi) is the
    axial mean of the offsets, and of its two senses the one most rows agree with.
    """
    first = index.segment_start
    out = heading[first] - cum[first]
    for s in np.flatnonzero(glitchy).tolist():
        offset = heading[first[s]:index.segment_stop[s]] - cum[first[s]:index.segment_stop[s]]
        c2 = 0.5 * np.arctan2(np.sin(2 * offset).sum(), np.cos(2 * offset).sum())
        out[s] = c2 if np.sign(np.cos(offset - c2)).sum() >= 0 else c2 + np.pi
    return out


def _blocks(index: TrackIndex) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-second blocks of every valid segment: (starts, lengths, segment of each block).

    Blocks of 10 steps from each segment's start; the last one of a segment takes what is
    left (1 to 10 steps).
    """
    lengths = index.segment_length
    n_blocks = -(-lengths // STEPS_PER_SECOND)
    seg = np.repeat(np.arange(index.n_segments), n_blocks)
    first_block = np.cumsum(n_blocks) - n_blocks
    within = np.arange(n_blocks.sum()) - np.repeat(first_block, n_blocks)
    starts = index.segment_start[seg] + within * STEPS_PER_SECOND
    stops = np.minimum(starts + STEPS_PER_SECOND, index.segment_stop[seg])
    return starts, stops - starts, seg


def _block_ends(checked: CheckedTable, starts: np.ndarray) -> np.ndarray:
    """(nb,) the end of each block's sum: the next block's start, or the end of the
    block's scenario when that comes first (the last block: the table's end)."""
    index = checked.index
    n = len(index.segment)
    ends = np.append(starts[1:], n)
    sids = checked.per_track_arrays(["scenario_id"])["scenario_id"]
    if len(sids) < 2:
        return ends
    sids = np.asarray(sids, dtype=object)
    new_scenario = np.flatnonzero(sids[1:] != sids[:-1]) + 1  # first track of each
    scenario_end = np.append(index.track_start[new_scenario], n)  # (scenarios,) rows
    cap = scenario_end[np.searchsorted(scenario_end, starts, side="right")]
    return np.minimum(ends, cap)


def _block_sums(values: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """(nb,) the sum of ``values[starts[i]:ends[i]]``, each range summed as ``reduceat``
    sums it."""
    if not len(starts):
        return np.zeros(0)
    bounds = np.empty(2 * len(starts), dtype=np.int64)
    bounds[0::2], bounds[1::2] = starts, ends
    if bounds[-1] == len(values):  # the table's end: reduceat's last range ends there
        bounds = bounds[:-1]
    return np.add.reduceat(values, bounds)[0::2]


def compute_kinematics(checked: CheckedTable, plausibility: Plausibility | None = None
                       ) -> Kinematics:
    """Plausible speed, heading, acceleration and yaw rate of every valid row.

    Args:
        checked: the result of :func:`validate_and_index` (rows grouped by track).
        plausibility: the bounds that tell glitches from motion (defaults of
            :class:`Plausibility`).
    """
    p = plausibility or Plausibility()
    index = checked.index
    seg = index.segment
    n = len(seg)
    t = np.asarray(checked["t"], dtype=np.float64)
    raw_heading = np.asarray(checked["heading"], dtype=np.float64)
    x = np.asarray(checked["x"], dtype=np.float64)
    y = np.asarray(checked["y"], dtype=np.float64)
    valid = seg >= 0
    in_seg = valid[1:] & (seg[1:] == seg[:-1])  # (n-1,) step k -> k+1 inside a segment

    v = np.asarray(checked["speed"], dtype=np.float64)
    dv = np.diff(v)
    v, speed_glitch = _despike(v, dv, t, seg, in_seg, p.a_max / HZ, p.max_spike_steps)
    if speed_glitch is None:
        speed_glitch = np.zeros(n, dtype=bool)
    else:
        dv = np.diff(v)

    # Heading: wrap each step's change, fold flips by pi, bound what the speed allows. The
    # bound is at least w_noise * 0.09 s, so only larger changes need a closer look.
    all_valid = bool(valid.all())
    dh = np.diff(raw_heading)
    dh[~in_seg] = 0.0
    size = np.abs(dh)
    wrap = np.flatnonzero(size > np.pi)
    dh[wrap] -= 2.0 * np.pi * np.round(dh[wrap] / (2.0 * np.pi))
    size[wrap] = np.abs(dh[wrap])
    heading_glitch = np.zeros(n, dtype=bool)
    k = np.flatnonzero(size > p.w_noise * DT * (1.0 - DT_TOLERANCE))
    if len(k):
        bound = (np.fmax(v[k], v[k + 1]) / p.r_min + p.w_noise) * (t[k + 1] - t[k])
        k, bound = k[np.abs(dh[k]) > bound], bound[np.abs(dh[k]) > bound]
        step = dh[k]
        step = np.where(np.abs(step) > 0.5 * np.pi, step - np.pi * np.sign(step), step)
        dh[k] = np.clip(step, -bound, bound)
        heading_glitch[k + 1] = True
    cum = _segment_cumsum(dh, index, n)
    glitchy = np.zeros(index.n_segments, dtype=bool)
    glitchy[seg[k + 1]] = True
    anchor = np.repeat(_anchor(raw_heading, cum, index, glitchy), index.segment_length)
    if all_valid:
        heading = cum + anchor
    else:  # the valid rows are the segments, in order
        heading = np.full(n, np.nan)
        heading[valid] = cum[valid] + anchor

    # Motion, from positions averaged over one-second blocks: each block moves by the
    # change between the blocks before and after it (its own neighbour at a segment end).
    starts, lengths, block_seg = _blocks(index)
    nb = len(starts)
    if all_valid:
        mx = np.add.reduceat(x, starts) / lengths if nb else np.zeros(0)
        my = np.add.reduceat(y, starts) / lengths if nb else np.zeros(0)
    else:  # each block's sum ends at the next block or at its scenario's end, whichever
        # comes first: a table of several scenarios sums each block over the rows it does
        # alone (the zeros of invalid rows after it, in its own scenario only)
        ends = _block_ends(checked, starts)
        mx = _block_sums(np.where(valid, x, 0.0), starts, ends) / lengths
        my = _block_sums(np.where(valid, y, 0.0), starts, ends) / lengths
    mt = 0.5 * (t[starts] + t[starts + lengths - 1])
    prev = np.arange(nb) - 1
    nxt = np.arange(nb) + 1
    if nb:
        prev[0] = 0
        nxt[-1] = nb - 1
    prev = np.where(block_seg[prev] == block_seg, prev, np.arange(nb))
    nxt = np.where(block_seg[nxt] == block_seg, nxt, np.arange(nb))
    ux, uy, span = mx[nxt] - mx[prev], my[nxt] - my[prev], mt[nxt] - mt[prev]
    dist = np.hypot(ux, uy)
    centre = heading[starts + lengths // 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        motion = np.where(span > 0, dist / span, 0.0)
        along = np.where(dist > 0, (ux * np.cos(centre) + uy * np.sin(centre)) / dist, 1.0)
    moving = motion >= p.v_heading
    first_block = (np.flatnonzero(np.r_[True, block_seg[1:] != block_seg[:-1]]) if nb else
        np.zeros(0, dtype=np.int64))
    home = np.repeat(first_block, np.diff(np.r_[first_block, nb]))
    travel = (np.maximum.reduceat(np.hypot(mx - mx[home], my - my[home]), first_block)
              if nb else np.zeros(0))
    far = travel[block_seg] >= p.min_travel  # a still vehicle neither turns nor reverses
    block_reversing = moving & far & (along < _REVERSE_COS)
    block_trusted = moving & far & ~block_reversing

    if all_valid:
        trusted = np.repeat(block_trusted, lengths)
    else:
        trusted = np.zeros(n, dtype=bool)
        trusted[valid] = np.repeat(block_trusted, lengths)
    reversing = np.zeros(n, dtype=bool)
    if block_reversing.any():
        reversing[valid] = np.repeat(block_reversing, lengths)

    a = _derivative(dv, t, index)
    w = _derivative(dh, t, index)
    w *= trusted | reversing  # 0 where the heading is not trusted (a reversing path turns)
    if not all_valid:
        w[~valid] = np.nan
        v = np.where(valid, v, np.nan)
    return Kinematics(t=t, v=v, a=a, w=w, index=index, heading=heading, x=x, y=y,
                      speed_glitch=speed_glitch, heading_glitch=heading_glitch,
                      trusted=trusted, reversing=reversing, travel=travel)


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


V_STOP = 0.1
"""The fixed Stopped threshold [m/s] (SPEC section 3)."""


def one_second_samples(table: pd.DataFrame | Kinematics, *, source: str = "trajectory table",
                       v_stop: float = V_STOP) -> dict[str, np.ndarray]:
    """The distributions D_w, D_a, D_v of SPEC section 3.

    One-second averages over non-overlapping 10-step windows of every valid segment,
    starting at the segment's first step; a trailing window shorter than 1 s is left out.
    Windows whose mean speed is <= ``v_stop`` are left out of D_a and D_w (stage 2 never
    applies Theta_a or Theta_w to stopped steps), and windows with a step whose heading is
    not trusted (:class:`Plausibility`: the vehicle does not move, reverses, or its segment
    travels less than 1 m) are left out of D_w: their yaw rate is not a measurement.

    Args:
        table: a trajectory table, or its :class:`Kinematics`.
        source: a name for the table in error messages (its file path).
        v_stop: the Stopped threshold [m/s].

    Returns:
        ``{"w": |mean yaw rate| [rad/s], "a": mean acceleration [m/s^2], "v": mean speed
        [m/s]}``, float64 arrays; ``v`` has one entry per window, ``a`` and ``w`` one per
        window they keep.
    """
    kin = table if isinstance(table, Kinematics) else compute_kinematics(
        validate_and_index(table, source=source))
    idx = kin.index
    n_windows = idx.segment_length // STEPS_PER_SECOND
    starts = np.repeat(idx.segment_start, n_windows)
    offsets = np.arange(n_windows.sum()) - np.repeat(np.cumsum(n_windows) - n_windows, n_windows)
    starts = starts + offsets * STEPS_PER_SECOND
    v = window_means(kin.v, starts, STEPS_PER_SECOND)
    moving = v > v_stop
    trusted = moving
    if kin.trusted is not None:
        trusted = moving & (window_means(kin.trusted.astype(np.float64), starts,
                                         STEPS_PER_SECOND) == 1.0)
    return {
        "w": np.abs(window_means(kin.w, starts[trusted], STEPS_PER_SECOND)),
        "a": window_means(kin.a, starts[moving], STEPS_PER_SECOND),
        "v": v,
    }
