"""The four TAP stages of SPEC section 4, vectorised over every segment at once.

The stages work on the steps of all labelled segments laid end to end (flat arrays) and on
*runs*: maximal stretches of one label inside one segment. Every operation is a numpy pass
over all steps or all runs; the only Python loops are over iterations of the low-pass
joining (each iteration handles every segment at once; their number is the largest count of
short runs left in one segment, a handful in practice).

Rules that SPEC leaves open, decided here and documented in docs/tap.md:

- Low-pass window: a short run of k steps is relabelled from the mean of its signal over the
  10-step window centred on it (k steps plus (10-k)//2 before and the rest after), shifted
  to lie inside the segment. Lateral signal: w with stopped steps set to 0; longitudinal:
  Stopped if the window's mean speed is below v_stop, else the trace rule on its mean a.
- Joining: while a segment has a run shorter than 1 s, its shortest such run (the earliest
  on ties) takes the label of its longer neighbour (the earlier one on ties).
- Merges: turn runs are paired greedily from the start: a turn and the next turn of the
  opposite direction that starts at most ``merge_gap`` after the first ends become one
  merge; a turn that was paired is not paired again.
- Action classes inside a turn run use |w| <= w_grad Gradual (|w| under w_str included),
  <= w_med Medium, else Aggressive; inside a moving run v <= v_slow Slow, <= v_med Medium,
  else Fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tap_bench import sdl
from tap_bench.errors import TapBenchError
from tap_bench.kinematics import STEPS_PER_SECOND, window_means
from tap_bench.thresholds import Thresholds

__all__ = ["StageConfig", "StepLabels", "run_stages"]


@dataclass(frozen=True)
class StageConfig:
    """Timing parameters of the stages.

    Attributes:
        min_run: the shortest label run [s] (SPEC: 1 s); also the low-pass window.
        merge_gap: the longest straight stretch between the two turns of a merge [s] (4 s).
    """

    min_run: float = 1.0
    merge_gap: float = 4.0

    def __post_init__(self) -> None:
        if not self.min_run > 0:
            raise TapBenchError(f"StageConfig.min_run must be > 0 s, got {self.min_run!r}")
        if not self.merge_gap >= 0:
            raise TapBenchError(f"StageConfig.merge_gap must be >= 0 s, got {self.merge_gap!r}")

    @property
    def min_steps(self) -> int:
        return max(1, round(self.min_run * STEPS_PER_SECOND))

    @property
    def merge_gap_steps(self) -> int:
        return round(self.merge_gap * STEPS_PER_SECOND)


@dataclass(frozen=True)
class StepLabels:
    """Per-step label codes of every level (see :func:`tap_bench.sdl.code_names`).

    Each attribute is an (m,) int8 array over the labelled steps laid end to end.
    """

    trace_lateral: np.ndarray
    trace_longitudinal: np.ndarray
    trend_lateral: np.ndarray
    trend_longitudinal: np.ndarray
    maneuver_lateral: np.ndarray
    maneuver_longitudinal: np.ndarray
    action_lateral: np.ndarray
    action_longitudinal: np.ndarray

    def codes(self, level: str, axis: str) -> np.ndarray:
        return getattr(self, f"{level}_{axis}")


@dataclass
class Runs:
    """Maximal runs of one code inside one segment, in order. All arrays are (R,) int64."""

    start: np.ndarray
    length: np.ndarray
    code: np.ndarray
    seg: np.ndarray

    def expand(self, n: int) -> np.ndarray:
        """Per-step codes, (n,) int8."""
        out = np.repeat(self.code, self.length).astype(np.int8)
        if len(out) != n:  # pragma: no cover - internal invariant
            raise AssertionError("runs do not tile the steps")
        return out


def find_runs(codes: np.ndarray, seg: np.ndarray, seg_first: np.ndarray) -> Runs:
    """Runs of ``codes`` (m,), breaking at segment starts (``seg_first``, (m,) bool)."""
    change = seg_first.copy()
    change[1:] |= codes[1:] != codes[:-1]
    start = np.flatnonzero(change)
    length = np.diff(np.append(start, len(codes)))
    return Runs(start=start, length=length, code=codes[start].astype(np.int64), seg=seg[start])


def coalesce(runs: Runs) -> Runs:
    """Join neighbouring runs of one segment that now carry the same code."""
    if len(runs.start) == 0:
        return runs
    keep = np.ones(len(runs.start), dtype=bool)
    keep[1:] = (runs.seg[1:] != runs.seg[:-1]) | (runs.code[1:] != runs.code[:-1])
    if keep.all():
        return runs
    first = np.flatnonzero(keep)
    return Runs(start=runs.start[first], length=np.add.reduceat(runs.length, first),
                code=runs.code[first], seg=runs.seg[first])


def join_short_runs(runs: Runs, min_steps: int) -> Runs:
    """Give each run shorter than ``min_steps`` the label of its longer neighbour.

    Per segment, the shortest short run (earliest on ties) goes first; it takes the label of
    its longer neighbour (the earlier one on ties). Repeats until no segment has a short run
    unless the segment is a single run.
    """
    while True:
        n = len(runs.start)
        short = runs.length < min_steps
        if n > 1:
            lone = np.ones(n, dtype=bool)  # a run that is its whole segment stays as it is
            same_prev = runs.seg[1:] == runs.seg[:-1]
            lone[1:] &= ~same_prev
            lone[:-1] &= ~same_prev
            short &= ~lone
        else:
            short[:] = False
        idx = np.flatnonzero(short)
        if len(idx) == 0:
            return runs
        order = np.lexsort((idx, runs.length[idx], runs.seg[idx]))
        idx = idx[order]
        first = np.ones(len(idx), dtype=bool)
        first[1:] = runs.seg[idx[1:]] != runs.seg[idx[:-1]]
        chosen = idx[first]
        left = chosen - 1
        right = chosen + 1
        has_left = (left >= 0) & (runs.seg[np.maximum(left, 0)] == runs.seg[chosen])
        has_right = (right < n) & (runs.seg[np.minimum(right, n - 1)] == runs.seg[chosen])
        left_len = np.where(has_left, runs.length[np.maximum(left, 0)], -1)
        right_len = np.where(has_right, runs.length[np.minimum(right, n - 1)], -1)
        take_left = left_len >= right_len
        runs.code[chosen] = np.where(take_left, runs.code[np.maximum(left, 0)],
                                     runs.code[np.minimum(right, n - 1)])
        runs = coalesce(runs)


def _low_pass(codes: np.ndarray, layout: _Layout, classify, min_steps: int) -> np.ndarray:
    runs = find_runs(codes, layout.seg, layout.seg_first)
    short = runs.length < min_steps
    if short.any():
        s, k, g = runs.start[short], runs.length[short], runs.seg[short]
        ws = s - (min_steps - k) // 2
        ws = np.clip(ws, layout.seg_start[g], layout.seg_stop[g] - min_steps)
        runs.code[short] = classify(ws)
        runs = coalesce(runs)
    return join_short_runs(runs, min_steps).expand(len(codes))


@dataclass(frozen=True)
class _Layout:
    seg: np.ndarray  # (m,) segment of each step
    seg_first: np.ndarray  # (m,) bool, first step of a segment
    seg_start: np.ndarray  # (S,) first step of each segment
    seg_stop: np.ndarray  # (S,) one past its last step


def _trace_lateral(w: np.ndarray, th: Thresholds) -> np.ndarray:
    return np.where(w > th.w_str, sdl.LEFT, np.where(w < -th.w_str, sdl.RIGHT, sdl.STRAIGHT))


def _trace_longitudinal(a: np.ndarray, th: Thresholds) -> np.ndarray:
    return np.where(a > th.a_acc, sdl.ACCELERATE,
                    np.where(a <= th.a_dec, sdl.DECELERATE, sdl.MAINTAIN))


def _merges(runs: Runs, gap_steps: int) -> Runs:
    turn = np.flatnonzero((runs.code == sdl.LEFT) | (runs.code == sdl.RIGHT))
    if len(turn) < 2:
        return runs
    i, j = turn[:-1], turn[1:]
    gap = runs.start[j] - (runs.start[i] + runs.length[i])
    cand = (runs.seg[i] == runs.seg[j]) & (runs.code[i] != runs.code[j]) & (gap <= gap_steps)
    # Greedy pairing: in a chain of overlapping candidate pairs take the 1st, 3rd, ...
    k = np.arange(len(cand))
    chain_start = cand & ~np.append(False, cand[:-1])
    pos = k - np.maximum.accumulate(np.where(chain_start, k, 0))
    take = cand & (pos % 2 == 0)
    i, j = i[take], j[take]
    merge = np.where(runs.code[i] == sdl.LEFT, sdl.LEFT_MERGE, sdl.RIGHT_MERGE)
    code = runs.code.copy()
    code[i] = merge
    code[j] = merge
    mid = j - i == 2
    code[i[mid] + 1] = merge[mid]
    return coalesce(Runs(runs.start, runs.length, code, runs.seg))


def _refine(runs: Runs, signal: np.ndarray, classes: np.ndarray, refine: np.ndarray,
            bounds: tuple[float, float], min_steps: int) -> np.ndarray:
    """Per-step class (0, 1, 2) inside the runs flagged by ``refine`` (R,) bool, else 0.

    A run keeps its per-step classes if every piece of one class is at least ``min_steps``
    long; otherwise the whole run takes the class of its mean ``signal``.
    """
    m = len(classes)
    run_start = np.zeros(m, dtype=bool)
    run_start[runs.start] = True
    piece_start = run_start.copy()
    piece_start[1:] |= classes[1:] != classes[:-1]
    starts = np.flatnonzero(piece_start)
    lengths = np.diff(np.append(starts, m))
    first_piece = np.searchsorted(starts, runs.start)
    shortest = np.minimum.reduceat(lengths, first_piece)
    mean = np.add.reduceat(signal, runs.start) / runs.length
    run_class = np.where(mean <= bounds[0], 0, np.where(mean <= bounds[1], 1, 2))
    # per run: -1 keeps the per-step classes, 0..2 is the class of the whole run, and runs
    # that are not refined get 0.
    choice = np.where(refine, np.where(shortest < min_steps, run_class, -1), 0)
    per_step = np.repeat(choice, runs.length)
    return np.where(per_step < 0, classes, per_step)


def run_stages(w: np.ndarray, a: np.ndarray, v: np.ndarray, seg_length: np.ndarray,
               thresholds: Thresholds, config: StageConfig = StageConfig()) -> StepLabels:
    """Label every step of the given segments at all four levels.

    Args:
        w: (m,) yaw rate [rad/s] of the steps of all segments laid end to end.
        a: (m,) acceleration [m/s^2].
        v: (m,) speed [m/s].
        seg_length: (S,) steps in each segment, summing to m; each at least
            ``config.min_steps`` long.
        thresholds: Theta.
        config: timing parameters.
    """
    m = len(w)
    min_steps = config.min_steps
    if len(seg_length) and seg_length.min() < min_steps:
        raise TapBenchError(f"run_stages needs segments of at least {min_steps} steps; got "
                            f"one of {seg_length.min()}")
    seg_stop = np.cumsum(seg_length)
    seg_start = seg_stop - seg_length
    seg = np.repeat(np.arange(len(seg_length)), seg_length)
    seg_first = np.zeros(m, dtype=bool)
    seg_first[seg_start] = True
    layout = _Layout(seg=seg, seg_first=seg_first, seg_start=seg_start, seg_stop=seg_stop)
    th = thresholds

    # Stage 1: trace.
    trace_lat = _trace_lateral(w, th).astype(np.int8)
    trace_long = _trace_longitudinal(a, th).astype(np.int8)

    # Stage 2: trend. Stopped steps are Straight; then the low-pass.
    stopped = v < th.v_stop
    w_eff = np.where(stopped, 0.0, w)
    lat = np.where(stopped, sdl.STRAIGHT, trace_lat)
    lon = np.where(stopped, sdl.STOPPED, trace_long)

    def classify_lat(starts):
        return _trace_lateral(window_means(w_eff, starts, min_steps), th)

    def classify_long(starts):
        mean_v = window_means(v, starts, min_steps)
        return np.where(mean_v < th.v_stop, sdl.STOPPED,
                        _trace_longitudinal(window_means(a, starts, min_steps), th))

    trend_lat = _low_pass(lat, layout, classify_lat, min_steps)
    trend_long = _low_pass(lon, layout, classify_long, min_steps)

    # Stage 3: maneuver.
    lat_runs = _merges(find_runs(trend_lat, seg, seg_first), config.merge_gap_steps)
    maneuver_lat = lat_runs.expand(m)

    # Stage 4: action.
    abs_w = np.abs(w_eff)
    w_class = (abs_w > th.w_grad).astype(np.int8) + (abs_w > th.w_med)
    is_turn = (lat_runs.code == sdl.LEFT) | (lat_runs.code == sdl.RIGHT)
    intensity = _refine(lat_runs, abs_w, w_class, is_turn, (th.w_grad, th.w_med), min_steps)
    side = np.where(maneuver_lat == sdl.RIGHT, 1, 0)
    action_lat = np.select(
        [maneuver_lat == sdl.STRAIGHT, maneuver_lat == sdl.LEFT_MERGE,
         maneuver_lat == sdl.RIGHT_MERGE],
        [sdl.ACTION_STRAIGHT, sdl.ACTION_LEFT_MERGE, sdl.ACTION_RIGHT_MERGE],
        1 + 3 * side + intensity,
    )
    long_runs = find_runs(trend_long, seg, seg_first)
    v_class = (v > th.v_slow).astype(np.int8) + (v > th.v_med)
    moving = long_runs.code != sdl.STOPPED
    speed = _refine(long_runs, v, v_class, moving, (th.v_slow, th.v_med), min_steps)
    action_long = np.where(trend_long == sdl.STOPPED, sdl.ACTION_STOPPED,
                           3 * trend_long + speed)

    i8 = np.int8
    return StepLabels(
        trace_lateral=trace_lat, trace_longitudinal=trace_long,
        trend_lateral=trend_lat.astype(i8), trend_longitudinal=trend_long.astype(i8),
        maneuver_lateral=maneuver_lat.astype(i8), maneuver_longitudinal=trend_long.astype(i8),
        action_lateral=action_lat.astype(i8), action_longitudinal=action_long.astype(i8),
    )
