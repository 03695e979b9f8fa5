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
  replaced by the straight line between the neighbours (longest runs first); a first or last step that jumps
  away from two agreeing neighbours takes its neighbour's value;
- **heading flips and jumps**: the heading is unwrapped step by step; a step change of
  more than pi/2 is taken as a flip of the box by pi and folded back; a step change whose
  yaw rate exceeds ``v / r_min + w_noise`` (v: the larger repaired speed of the two steps)
  is bounded to it;
- **untrusted headings**: a heading is only trusted where the vehicle moves: its motion,
  measured from positions averaged over 1 s windows 1 s apart, is at least ``v_heading``;
  where it is not, and on every step of a segment that travels less than ``min_travel``
  in all, the yaw rate is 0 (no turn, no merge);
- **reversing**: a moving step whose motion points more than 120 degrees away from its
  heading is reversing; its yaw rate is 0 too, so reversing never reads as a turn the
  other way. Reversing steps are flagged and counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.errors import TapBenchError
from tap_bench.trajectories import HZ, CheckedTable, TrackIndex, validate_and_index

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
                raise TapBenchError(f"Plausibility.{name} must be a finite number > 0, got "
                                    f"{value!r}")
        for name in ("v_heading", "min_travel"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise TapBenchError(f"Plausibility.{name} must be a finite number >= 0, got "
                                    f"{value!r}")
        if not (isinstance(self.max_spike_steps, int) and self.max_spike_steps >= 0):
            raise TapBenchError("Plausibility.max_spike_steps must be an int >= 0, got "
                                f"{self.max_spike_steps!r}")


@dataclass(frozen=True)
class Kinematics:
    """Per-row kinematic signals of a validated table (NaN, or False, on invalid rows).

    Attributes:
        t: (n_rows,) time [s].
        v: (n_rows,) speed [m/s], speed spikes repaired.
        a: (n_rows,) acceleration [m/s^2], from the repaired speed.
        w: (n_rows,) yaw rate [rad/s], positive counter-clockwise (a left turn), from the
            repaired heading; 0 where the heading is not trusted.
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


def _shift(values: np.ndarray, k: int, fill) -> np.ndarray:
    """values[i + k] at i (``fill`` beyond the ends)."""
    out = np.full_like(values, fill)
    if k > 0:
        out[:-k] = values[k:]
    elif k < 0:
        out[-k:] = values[:k]
    else:
        out[:] = values
    return out


def _despike(v: np.ndarray, t: np.ndarray, seg: np.ndarray, jump: float, max_steps: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Speed with its spikes replaced, and the (n,) bool mask of replaced rows.

    ``jump`` is the largest believable change over one step [m/s]. ``seg`` is the segment
    of each row (-1 invalid).
    """
    v = v.copy()
    replaced = np.zeros(len(v), dtype=bool)
    n = len(v)
    if n < 3:
        return v, replaced
    # Longest first: in 1, 11, 10, 3, 12, 12, 1 the spikes are (11, 10) and (12, 12), not 3.
    for length in range(max_steps, 0, -1):
        before, after = _shift(v, -1, np.nan), _shift(v, length, np.nan)
        same = (seg >= 0) & (_shift(seg, -1, -2) == seg) & (_shift(seg, length, -2) == seg)
        inner = [_shift(v, k, np.nan) for k in range(length)]
        lo, hi = np.minimum.reduce(inner), np.maximum.reduce(inner)
        with np.errstate(invalid="ignore"):
            edge_hi, edge_lo = np.fmax(before, after), np.fmin(before, after)
            spike = same & (((lo - edge_hi > jump) | (edge_lo - hi > jump))
                            & (np.abs(after - before) <= jump * (length + 1)))
        for start in np.flatnonzero(spike):
            if replaced[start - 1:start + length + 1].any():  # overlaps a repaired spike
                continue
            t0, t1 = t[start - 1], t[start + length]
            rows = np.arange(start, start + length)
            v[rows] = v[start - 1] + (v[start + length] - v[start - 1]) * (t[rows] - t0) / (t1 - t0)
            replaced[rows] = True
    # A first (last) step that jumps away from two neighbours that agree with each other.
    nxt, nxt2 = _shift(v, 1, np.nan), _shift(v, 2, np.nan)
    prv, prv2 = _shift(v, -1, np.nan), _shift(v, -2, np.nan)
    seg_n2, seg_p2 = _shift(seg, 2, -2), _shift(seg, -2, -2)
    first = (seg >= 0) & (_shift(seg, -1, -2) != seg) & (seg_n2 == seg)
    last = (seg >= 0) & (_shift(seg, 1, -2) != seg) & (seg_p2 == seg)
    with np.errstate(invalid="ignore"):
        first &= (np.abs(v - nxt) > jump) & (np.abs(nxt - nxt2) <= jump)
        last &= (np.abs(v - prv) > jump) & (np.abs(prv - prv2) <= jump)
    v[first], v[last] = nxt[first], prv[last]
    replaced |= first | last
    return v, replaced


def _centred_means(values: np.ndarray, index: TrackIndex, width: int) -> np.ndarray:
    """Mean of ``values`` over the ``width``-step window centred on each row of a valid
    segment (shifted to lie inside it; the whole segment when shorter), NaN elsewhere."""
    n = len(values)
    seg = index.segment
    ok = seg >= 0
    csum = np.zeros(n + 1)
    np.cumsum(np.where(ok, values, 0.0), out=csum[1:])
    rows = np.arange(n)
    safe = np.where(ok, seg, 0)
    s0, s1 = index.segment_start[safe], index.segment_stop[safe]
    w = np.minimum(width, s1 - s0)
    lo = np.clip(rows - w // 2, s0, s1 - w)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (csum[lo + w] - csum[lo]) / w
    return np.where(ok, out, np.nan)


def _anchor(offset: np.ndarray, index: TrackIndex) -> np.ndarray:
    """(n_segments,) the constant that turns the summed repaired changes into headings.

    ``offset`` is raw heading minus summed changes per row: constant within a segment
    except where the raw heading was flipped by pi or jumped. The direction (mod pi) is the
    segment's axial mean of the offsets; of its two senses, the one most rows agree with.
    """
    if index.n_segments == 0:
        return np.zeros(0)
    starts = index.segment_start
    ok = index.segment >= 0
    two = np.where(ok, 2.0 * offset, 0.0)
    c2 = 0.5 * np.arctan2(np.add.reduceat(np.where(ok, np.sin(two), 0.0), starts),
                          np.add.reduceat(np.where(ok, np.cos(two), 0.0), starts))
    safe = np.where(ok, index.segment, 0)
    agree = np.where(ok, np.sign(np.cos(offset - c2[safe])), 0.0)
    return np.where(np.add.reduceat(agree, starts) >= 0, c2, c2 + np.pi)


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
    raw_v = np.asarray(checked["speed"], dtype=np.float64)
    raw_heading = np.asarray(checked["heading"], dtype=np.float64)
    x = np.array(checked["x"], dtype=np.float64)
    y = np.array(checked["y"], dtype=np.float64)
    valid = seg >= 0
    dt = np.diff(t)
    in_seg = valid[1:] & (seg[1:] == seg[:-1])  # (n-1,) step k -> k+1 inside a segment

    v, speed_glitch = _despike(raw_v, t, seg, p.a_max / HZ, p.max_spike_steps)

    # Heading: wrap each step's change, fold flips by pi, bound what the speed allows.
    dh = np.diff(raw_heading)
    dh = np.where(in_seg, (dh + np.pi) % (2.0 * np.pi) - np.pi, 0.0)
    flip = np.abs(dh) > 0.5 * np.pi
    dh = np.where(flip, dh - np.pi * np.sign(dh), dh)
    with np.errstate(invalid="ignore"):
        bound = (np.fmax(v[:-1], v[1:]) / p.r_min + p.w_noise) * dt
    over = np.abs(dh) > bound
    dh = np.clip(dh, -bound, bound) if n > 1 else dh
    heading_glitch = np.zeros(n, dtype=bool)
    heading_glitch[1:] = in_seg & (flip | over)
    cum = np.zeros(n)
    np.cumsum(dh, out=cum[1:])
    safe = np.where(valid, seg, 0)
    first = index.segment_start[safe]
    heading = np.where(valid, cum + _anchor(raw_heading - cum, index)[safe], np.nan)

    # Motion from positions averaged over 1 s, compared 1 s apart.
    mx = _centred_means(x, index, STEPS_PER_SECOND)
    my = _centred_means(y, index, STEPS_PER_SECOND)
    rows = np.arange(n)
    half = STEPS_PER_SECOND // 2
    ahead = np.minimum(rows + half, index.segment_stop[safe] - 1)
    behind = np.maximum(rows - half, first)
    ux, uy = mx[ahead] - mx[behind], my[ahead] - my[behind]
    span = t[ahead] - t[behind]
    dist = np.hypot(ux, uy)
    with np.errstate(invalid="ignore", divide="ignore"):
        motion = np.where(span > 0, dist / span, 0.0)
        along = np.where(dist > 0, (ux * np.cos(heading) + uy * np.sin(heading)) / dist, 1.0)
    moving = valid & (motion >= p.v_heading)
    reversing = moving & (along < _REVERSE_COS)
    far = np.hypot(mx - mx[first], my - my[first])
    travel = np.zeros(index.n_segments)
    if index.n_segments:
        travel = np.fmax.reduceat(np.where(valid, far, 0.0), index.segment_start)
    trusted = moving & ~reversing & (travel[safe] >= p.min_travel)

    a = _derivative(np.diff(v), t, index)
    w = np.where(trusted, _derivative(dh, t, index), 0.0)
    w[~valid] = np.nan
    v[~valid] = np.nan
    return Kinematics(t=t, v=v, a=a, w=w, index=index, heading=heading, x=x, y=y,
                      speed_glitch=speed_glitch & valid, heading_glitch=heading_glitch,
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
