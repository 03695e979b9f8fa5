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
  Stopped if the window's mean speed is at most v_stop, else the trace rule on its mean a.
- Joining: while a segment has a run shorter than 1 s, its shortest such run (the earliest
  on ties) takes the label of its longer neighbour (the earlier one on ties).
- Merges: turn runs are paired greedily from the start: a turn and the next turn of the
  opposite direction that starts at most ``merge_gap`` after the first ends become one
  merge when the heading comes back and the vehicle moved sideways (:func:`_merge_ok`);
  a turn that was paired is not paired again; two lane changes in a row share their
  middle turn, which is split where the heading is back (:func:`_merges`, :func:`_chain`);
  a pair that moved the other way than its first turn, measured across both its end
  headings and in the path its headings drive, is a merge of the side it moved.
- Action classes inside a turn run use |w| <= w_grad Gradual (|w| under w_str included),
  <= w_med Medium, else Aggressive; inside a moving run v <= v_slow Slow, <= v_med Medium,
  else Fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tap_bench import sdl
from tap_bench.errors import ParameterError, TapBenchError
from tap_bench.kinematics import STEPS_PER_SECOND, window_means
from tap_bench.thresholds import Thresholds

__all__ = ["StageConfig", "StepLabels", "run_stages"]


@dataclass(frozen=True)
class StageConfig:
    """Parameters of the stages.

    Attributes:
        min_run: the shortest label run [s] (SPEC: 1 s); also the low-pass window.
        merge_gap: the longest stretch between the end of a merge's first turn and the
            start of its second [s] (4 s).
        merge_heading: the largest net heading change over a merge [rad] (0.2): the
            vehicle ends up parallel to where it started.
        merge_offset: the smallest sideways move of a merge [m] (1.5), across the heading
            at its start, towards the first turn's side.
        merge_excursion: the largest heading change from the start at any step of a merge
            [rad] (pi/6, the bound of Waymo's straight trajectory types, inside which a
            lateral move is STRAIGHT_LEFT or STRAIGHT_RIGHT); an S-curve that turns
            farther is two turns.
    """

    min_run: float = 1.0
    merge_gap: float = 4.0
    merge_heading: float = 0.2
    merge_offset: float = 1.5
    merge_excursion: float = float(np.pi / 6)

    def __post_init__(self) -> None:
        if not self.min_run > 0:
            raise TapBenchError(f"StageConfig.min_run must be > 0 s, got {self.min_run!r}")
        for name, unit in (("merge_gap", "s"), ("merge_heading", "rad"), ("merge_offset", "m"),
                           ("merge_excursion", "rad")):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise ParameterError(f"StageConfig.{name}", value, f"a finite number >= 0 "
                                     f"[{unit}]")

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


def _agree_with_average(codes: np.ndarray, signal: np.ndarray, layout: _Layout, classify,
                        th: Thresholds, checked: tuple[int, int], fallback: int
                        ) -> np.ndarray:
    """SPEC 4.5: a run labelled one of ``checked`` whose mean ``signal`` (its net change
    over its duration: the mean yaw rate is the heading change over the run, the mean
    acceleration the speed change) does not itself classify as that label becomes
    ``fallback`` (Straight; Maintain Speed): a run that crossed the threshold only on
    noise."""
    runs = find_runs(codes, layout.seg, layout.seg_first)
    check = np.isin(runs.code, checked)
    if not check.any():
        return codes
    mean = np.add.reduceat(signal, runs.start) / runs.length
    wrong = check & (classify(mean, th) != runs.code)
    if not wrong.any():
        return codes
    runs.code[wrong] = fallback
    return runs.expand(len(codes))


@dataclass(frozen=True)
class _Layout:
    seg: np.ndarray  # (m,) segment of each step
    seg_first: np.ndarray  # (m,) bool, first step of a segment
    seg_start: np.ndarray  # (S,) first step of each segment
    seg_stop: np.ndarray  # (S,) one past its last step


def _trace_lateral(w: np.ndarray, th: Thresholds) -> np.ndarray:
    """(n,) int8 codes: Left above w_str, else Right below -w_str, else Straight."""
    out = np.full(np.shape(w), sdl.STRAIGHT, np.int8)
    out[w < -th.w_str] = sdl.RIGHT
    out[w > th.w_str] = sdl.LEFT  # (Left first where both hold)
    return out


def _trace_longitudinal(a: np.ndarray, th: Thresholds) -> np.ndarray:
    """(n,) int8 codes: Accelerate above a_acc, else Decelerate at a_dec or below, else
    Maintain."""
    out = np.full(np.shape(a), sdl.MAINTAIN, np.int8)
    out[a <= th.a_dec] = sdl.DECELERATE
    out[a > th.a_acc] = sdl.ACCELERATE  # (Accelerate first where both hold)
    return out


@dataclass(frozen=True)
class _Path:
    """Heading (unwrapped within each segment) [rad] and position [m] of the steps.

    ``heading``, ``x``, ``y`` are (n,) arrays over rows; ``rows`` (m,) maps each step to
    its row (the steps of a segment are consecutive rows).
    """

    heading: np.ndarray
    x: np.ndarray
    y: np.ndarray
    rows: np.ndarray


def _merge_ok(path: _Path, a: np.ndarray, b: np.ndarray, side: np.ndarray,
              config: StageConfig) -> np.ndarray:
    """(k,) bool: the steps [a, b) of one segment form a merge towards ``side`` (+1 left).

    The heading comes back (net change <= merge_heading), never strays farther than
    merge_excursion from the start, and the vehicle moves sideways by merge_offset or more
    towards ``side``, across the heading at ``a``.
    """
    if len(a) == 0:
        return np.zeros(0, dtype=bool)
    h = path.heading
    first, last = path.rows[a], path.rows[b - 1]
    h0 = h[first]
    net = h[last] - h0
    offset = (-(path.x[last] - path.x[first]) * np.sin(h0)
              + (path.y[last] - path.y[first]) * np.cos(h0))
    bounds = np.empty(2 * len(a), dtype=np.int64)
    bounds[0::2], bounds[1::2] = first, last + 1
    padded = np.append(h, h[-1])  # last + 1 may be one past the last row
    high = np.maximum.reduceat(padded, bounds)[0::2]
    low = np.minimum.reduceat(padded, bounds)[0::2]
    excursion = np.maximum(high - h0, h0 - low)
    return ((np.abs(net) <= config.merge_heading) & (side * offset >= config.merge_offset)
            & (excursion <= config.merge_excursion))


def _drove_sideways(path: _Path, a: np.ndarray, b: np.ndarray, side: np.ndarray,
                    config: StageConfig) -> np.ndarray:
    """(k,) bool: over the steps [a, b) of one segment the vehicle moved merge_offset or
    more towards ``side`` (+1 left) across the heading where they *end*, and its heading
    drove it there: the sideways move its headings and step lengths make (the sum of
    sin(heading - heading at a) times each step's length) is merge_offset or more towards
    ``side`` too. What :func:`_merge_ok` measures across the start heading alone may be
    the error of a start taken mid-swing; positions that the headings do not drive (a
    mirrored y axis) move nowhere."""
    out = np.zeros(len(a), dtype=bool)
    h, x, y = path.heading, path.x, path.y
    for k, (first, last, towards) in enumerate(zip(path.rows[a].tolist(),
                                                   path.rows[b - 1].tolist(),
                                                   np.asarray(side).tolist(), strict=True)):
        dx, dy = x[last] - x[first], y[last] - y[first]
        h1 = float(h[last])
        at_end = -dx * np.sin(h1) + dy * np.cos(h1)
        rows = np.arange(first, last + 1)
        step = np.hypot(np.diff(x[rows]), np.diff(y[rows]))
        driven = float(np.sum(np.sin(h[rows[:-1]] - h[first]) * step))
        out[k] = min(towards * at_end, towards * driven) >= config.merge_offset
    return out


def _wiggle_ok(path: _Path, a: np.ndarray, b: np.ndarray, side: np.ndarray,
               config: StageConfig, *, at_end: bool = False,
               along: np.ndarray | None = None) -> np.ndarray:
    """(k,) bool: the steps [a, b) of one segment, turns that start towards ``side`` and
    alternate, are a wiggle: the heading comes back (net change <= merge_heading, never
    farther than merge_excursion from the start) while the vehicle never gets as far
    sideways as a merge moves it (under merge_offset from where it started, across its
    heading there, at every step): an aborted lane change or a swerve, not turns (SPEC 4.3).
    Two lane changes in a row (out and back) get a lane width away and stay merges.

    ``at_end``: the sideways move is measured where [a, b) ends, as a merge's is (SPEC
    4.3): a pair of opposite turns that :func:`_merge_ok` refused, or a lone turn with the
    sub-threshold steering around it, whose heading comes back and which ends less than
    merge_offset sideways from where it started moved less than a merge, and is a wiggle
    however far out it went on the way: an aborted lane change 1.7 m out and on its way
    back when the turns end (its straightening under w_str). A lane change out and back is
    four turns (or three, the middle two joined), which :func:`_chain` splits into two
    merges; its three turns as a whole are checked at every step (``at_end`` False).

    ``along``: (k,) the step whose heading is the direction the wiggle is measured from
    (its heading comes back to it, strays from it at most merge_excursion, and the sideways
    move is taken across it); default ``a``. A turn right after a merge starts where the
    merge ends, mid-swing when the lane change overshot the lane's centre: its correction
    is measured from the heading where the merge started, the lane's direction.
    """
    del side
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    if not len(a):
        return np.zeros(0, dtype=bool)
    length = b - a
    # every candidate's steps at once: the rows of [a, b) for each, one after the other
    step = np.repeat(a - (np.cumsum(length) - length), length) + np.arange(length.sum())
    rows = path.rows[step]
    first = path.rows[a]
    h = path.heading
    h0 = h[first if along is None else path.rows[np.asarray(along, dtype=np.int64)]]
    # sin and cos of each start heading one by one, as a scalar (their bits must not
    # depend on how many candidates there are)
    sin0 = np.array([np.sin(v) for v in h0])
    cos0 = np.array([np.cos(v) for v in h0])
    across = (-(path.x[rows] - np.repeat(path.x[first], length)) * np.repeat(sin0, length)
              + (path.y[rows] - np.repeat(path.y[first], length)) * np.repeat(cos0, length))
    turned = np.abs(h[rows] - np.repeat(h0, length))
    bounds = np.cumsum(length) - length
    sideways = (np.abs(across[bounds + length - 1]) if at_end
                else np.maximum.reduceat(np.abs(across), bounds))
    return ((np.abs(h[path.rows[b - 1]] - h0) <= config.merge_heading)
            & (np.maximum.reduceat(turned, bounds) <= config.merge_excursion)
            & (sideways < config.merge_offset))


def _back_at(path: _Path, pos: int, start: int, stop: int, side: int) -> int:
    """The first step of [start, stop) where the heading is back at its value at ``pos``
    (having turned towards ``side``, +1 left), or -1."""
    h = path.heading
    back = side * (h[path.rows[start:stop]] - h[path.rows[pos]]) <= 0
    hit = np.flatnonzero(back)
    return start + int(hit[0]) if len(hit) else -1


def _chain(path: _Path, start: np.ndarray, stop: np.ndarray, side: np.ndarray, first: int,
           last: int, config: StageConfig, min_steps: int, code: np.ndarray,
           cut_off: np.ndarray) -> None:
    """Merges along turns ``first`` .. ``last`` of one segment, each consecutive pair a
    candidate (opposite sides, close enough): lane changes in a row. Writes merge codes into
    ``code`` (m,).

    Greedy from the start. The current turn (from ``pos``, which may lie inside a turn run
    after a split) and the next one: if the heading is back at its value at ``pos`` inside
    the next turn and the part up to there is a merge whose rest pairs with the whole turn
    after it (however little of the next turn is left), or, with 1 s or more of it left,
    with the turn after it split the same way, the next turn is split there: its rest
    starts the next lane change. Otherwise the pair is a merge if it passes whole; else,
    if the part up to where the heading is back is a wiggle and the rest pairs with the turn
    after it as a merge, the wiggle ends there; else the pair is a wiggle when it is one and
    the heading was not back before the next turn began (that turn then starts a move of
    its own); else the current turn stays a turn. A pair whose second turn is one the data
    cut off (``cut_off``, (k,) bool) is never a wiggle.
    """

    def ok(a: int, b: int, towards: int) -> bool:
        return bool(_merge_ok(path, np.array([a]), np.array([b]), np.array([towards]),
                              config)[0])

    def merge_code(towards: int) -> int:
        return sdl.LEFT_MERGE if towards > 0 else sdl.RIGHT_MERGE

    def wiggle(a: int, b: int, towards: int, at_end: bool = False) -> bool:
        return bool(_wiggle_ok(path, np.array([a]), np.array([b]), np.array([towards]),
                               config, at_end=at_end)[0])

    i, pos = first, int(start[first])
    while i < last:
        nxt_start, nxt_stop = int(start[i + 1]), int(stop[i + 1])
        # the next turn with the turn back the data cut off after it, as one: what the pair
        # is checked over, as the whole run was before the cut-off part was told apart
        tail = i + 2 <= last and bool(cut_off[i + 2])
        nxt_end = int(stop[i + 2]) if tail else nxt_stop
        # an aborted lane change: out, back, and straightening (three turns) or out and
        # back (two), never a merge's distance sideways: Straight
        if i + 2 <= last and wiggle(pos, int(stop[i + 2]), int(side[i])):
            code[pos:int(stop[i + 2])] = sdl.STRAIGHT
            i += 3
            if i <= last:
                pos = int(start[i])
            continue
        cut = _back_at(path, pos, nxt_start, nxt_stop, int(side[i]))
        if i + 1 < last and cut > nxt_start and ok(pos, cut, int(side[i])):
            # the rest of the next turn and the whole turn after it are the second lane
            # change (however little of the next turn is left: the lateral move back
            # starts where the heading is back), or 1 s or more of it is left and pairs
            # with the turn after it split the same way
            # (a rest under 1 s only when the pair after it is the whole turn after: what
            # the next step checks unless a turn back the data cut off follows it)
            long_rest = nxt_stop - cut >= min_steps
            cut2 = _back_at(path, cut, int(start[i + 2]), int(stop[i + 2]), int(side[i + 1]))
            if (ok(cut, int(stop[i + 2]), int(side[i + 1]))
                    and (long_rest or not (i + 3 <= last and cut_off[i + 3]))) or (
                    long_rest and not cut_off[i + 2] and cut2 > start[i + 2]
                    and ok(cut, cut2, int(side[i + 1]))):
                code[pos:cut] = merge_code(int(side[i]))
                i, pos = i + 1, cut
                continue
        if ok(pos, nxt_end, int(side[i])):
            code[pos:nxt_end] = merge_code(int(side[i]))
            i += 3 if tail else 2
        elif (i + 1 < last and cut > nxt_start and wiggle(pos, cut, int(side[i]), at_end=True)
              and ok(cut, int(stop[i + 2]), int(side[i + 1]))):
            # the heading is back early in the next turn, which goes on into a lateral
            # move with the turn after it: a wiggle up to there, then that move
            code[pos:cut] = sdl.STRAIGHT
            i, pos = i + 1, cut
            continue
        elif (not cut_off[i + 1] and wiggle(pos, nxt_end, int(side[i]), at_end=True)
              and _back_at(path, pos, int(stop[i]), nxt_start, int(side[i])) < 0):
            # (not when the heading was back before the next turn began: that turn starts
            # a move of its own, which may pair with the turn after it)
            code[pos:nxt_end] = sdl.STRAIGHT
            i += 3 if tail else 2
        else:
            i += 1
        if i <= last:
            pos = int(start[i])


def _cut_off_returns(runs: Runs, trace: np.ndarray, turn: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The turn back that the end of the data cut short, of the turn runs ``turn`` (indices
    into ``runs``).

    A turn run that ends its segment and inside which the trace's last turn goes the other
    way (straight steps may follow it; at least one of its steps a central difference, not
    only the segment's last, one-sided step) had begun to turn back when the data ended: the
    straightening of a lane change cut off, shorter than a run can be, which the low-pass
    gave to the turn. Returns the indices (into ``turn``) of such runs and, for each, the
    first step of that last trace run: the turn back, a turn run of its own for the merge
    rule (SPEC 4.3: a lane change and its partial return on a straight road are merges).
    """
    none = np.zeros(0, dtype=np.int64)
    n_runs = len(runs.start)
    ends_segment = np.r_[runs.seg[1:] != runs.seg[:-1], True][turn]
    if not ends_segment.any():
        return none, none
    seg_first = np.zeros(len(trace), dtype=bool)
    seg_first[runs.start[np.r_[True, runs.seg[1:] != runs.seg[:-1]]]] = True
    step_seg = np.repeat(runs.seg, runs.length)
    traced = find_runs(trace.astype(np.int64), step_seg, seg_first)
    turning = np.flatnonzero(traced.code != sdl.STRAIGHT)
    if not len(turning):
        return none, none
    turning = turning[np.r_[traced.seg[turning][1:] != traced.seg[turning][:-1], True]]
    last_turning = np.full(int(runs.seg[n_runs - 1]) + 1, -1)
    last_turning[traced.seg[turning]] = turning  # each segment's last turning trace run
    which = np.flatnonzero(ends_segment)
    k = last_turning[runs.seg[turn[which]]]
    kk = np.maximum(k, 0)
    # the segment's last step reads a one-sided difference (kinematics), the noisiest
    # yaw rate of all: the turn back must show in a central difference too
    seg_stop = (runs.start + runs.length)[turn[which]]
    central = traced.length[kk] - (traced.start[kk] + traced.length[kk] == seg_stop)
    back = ((k >= 0) & (traced.code[kk] != runs.code[turn[which]])
            & (traced.start[kk] > runs.start[turn[which]]) & (central >= 1))
    return which[back], traced.start[k[back]]


_TURNED_BACK = 1e-6  # [rad] the least heading change back that counts (not rounding noise)


def _peaked_at_end(runs: Runs, path: _Path, trace: np.ndarray, turn: np.ndarray,
                   which: np.ndarray, back: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_cut_off_returns`' answer (``which``, ``back``) with the turn runs that end
    their segment after the heading stopped turning their way and began to turn back, too
    little for the trace to read a turn (under w_str): the trace no longer turns the run's
    way at the second and third last steps (central differences), and the heading at the
    last step is back from its value two steps before. Their turn back starts at the second
    last step. Returns both, ordered by ``which``."""
    ends = np.r_[runs.seg[1:] != runs.seg[:-1], True][turn]
    ends[which] = False
    cand = np.flatnonzero(ends & (runs.length[turn] >= 3))
    if not len(cand):
        return which, back
    last = runs.start[turn[cand]] + runs.length[turn[cand]] - 1
    code = runs.code[turn[cand]]
    towards = np.where(code == sdl.LEFT, 1, -1)
    h = path.heading
    turned_back = ((towards * (h[path.rows[last]] - h[path.rows[last - 2]]) < -_TURNED_BACK)
                   & (trace[last - 1] != code) & (trace[last - 2] != code))
    which = np.r_[which, cand[turned_back]]
    back = np.r_[back, last[turned_back] - 1]
    order = np.argsort(which, kind="stable")
    return which[order], back[order]


def _merges(runs: Runs, path: _Path, config: StageConfig, min_steps: int,
            trace: np.ndarray | None = None) -> Runs:
    """Stage 3: pairs of opposite turns that form a lateral move become merges.

    Turn runs are paired greedily from the start of each segment. A turn and the next one,
    going the other way and starting at most ``merge_gap`` after the first ends, form a
    merge (the straight steps between them included) when :func:`_merge_ok` holds. A lone
    such pair is checked for all segments at once. Where several follow each other (lane
    changes in a row: right, then back left reads Right, Left, Right, the middle turn being
    the end of the first and the start of the second), :func:`_chain` pairs them one by one
    and splits a middle turn where the heading is back.

    ``trace``: the (m,) trace-level lateral codes. A turn that the end of the data cut off
    while it turned back (:func:`_cut_off_returns`, :func:`_peaked_at_end`) is paired with
    that turn back as with a second turn run: a merge when :func:`_merge_ok` holds up to
    the segment's end. Such a pair is never a wiggle: the data ended before the move could
    show where it ends.

    A lone pair that is no merge towards its first turn's side is one towards its second
    turn's when :func:`_merge_ok` holds that way and :func:`_drove_sideways` confirms it:
    the turn that began the move was joined to the next by the low-pass, or cut off by the
    start of the data.
    """
    m = len(path.rows)
    turn = np.flatnonzero((runs.code == sdl.LEFT) | (runs.code == sdl.RIGHT))
    start = runs.start[turn]
    stop = start + runs.length[turn]
    side = np.where(runs.code[turn] == sdl.LEFT, 1, -1)
    seg = runs.seg[turn]
    cut_off = np.zeros(len(turn), dtype=bool)
    if trace is not None and len(turn):
        which, back = _cut_off_returns(runs, trace, turn)
        which, back = _peaked_at_end(runs, path, trace, turn, which, back)
        if len(which):
            # the turn back becomes a turn run of its own, right after the run it ended
            at = which + 1
            start = np.insert(start, at, back)
            stop = np.insert(stop, at, stop[which])
            stop[at - 1 + np.arange(len(at))] = back
            side = np.insert(side, at, -side[which])
            seg = np.insert(seg, at, seg[which])
            cut_off = np.insert(cut_off, at, True)
    if len(start) < 2:
        return runs
    cand = ((seg[1:] == seg[:-1]) & (side[1:] != side[:-1])
            & (start[1:] - stop[:-1] <= config.merge_gap_steps))
    if not cand.any():
        return runs
    before = np.r_[False, cand[:-1]]
    after = np.r_[cand[1:], False]
    lone = np.flatnonzero(cand & ~before & ~after)
    is_merge = _merge_ok(path, start[lone], stop[lone + 1], side[lone], config)
    # a pair whose first turn began the other way (the turn that started the move was cut
    # off by the start of the data, or the low-pass joined it to the turn after it) moved
    # towards its second turn's side: a merge of that side, when the move shows across
    # its start heading, its end heading and in the path its headings drive
    other = lone[~is_merge]
    reverse = other[_merge_ok(path, start[other], stop[other + 1], -side[other], config)]
    reverse = reverse[_drove_sideways(path, start[reverse], stop[reverse + 1],
                                      -side[reverse], config)]
    is_merge[np.isin(lone, reverse)] = True
    merged = lone[is_merge]
    rest = lone[~is_merge & ~cut_off[lone + 1]]
    wiggles = rest[_wiggle_ok(path, start[rest], stop[rest + 1], side[rest], config,
                              at_end=True)]

    code = runs.expand(m).astype(np.int64)
    reverse_ids = set(reverse.tolist())  # once, not per merge
    for i in merged.tolist():
        towards = -side[i] if i in reverse_ids else side[i]
        code[start[i]:stop[i + 1]] = sdl.LEFT_MERGE if towards > 0 else sdl.RIGHT_MERGE
    for i in wiggles.tolist():
        code[start[i]:stop[i + 1]] = sdl.STRAIGHT
    chain_first = np.flatnonzero(cand & ~before & after)
    for first in chain_first.tolist():
        last = first + 1
        while last < len(cand) and cand[last]:
            last += 1
        _chain(path, start, stop, side, first, last, config, min_steps, code, cut_off)
    seg_first = np.zeros(m, dtype=bool)
    seg_first[runs.start[np.r_[True, runs.seg[1:] != runs.seg[:-1]]]] = True
    return find_runs(code, np.repeat(runs.seg, runs.length), seg_first)


def _lone_wiggles(runs: Runs, path: _Path, config: StageConfig) -> Runs:
    """Stage 3, after the merges: a turn run that sub-threshold steering around it undoes
    is a wiggle (SPEC 4.3). Around the run, up to half ``merge_gap`` each side and no
    farther than the neighbouring merges, the heading is back where it was (within
    merge_heading) and the vehicle never gets merge_offset sideways: an aborted lane change
    whose outward and straightening parts the low-pass left under w_str (out 1 m and back
    at 25 m/s reads as one Right Turn of the return otherwise), or the correction after a
    lane change that overshot the lane's centre (a turn right after a merge is also
    measured from the heading where the merge started: the merge ends mid-swing; a turn
    whose window starts mid-swing is also measured from the heading where the window ends,
    when the turn came back: the net change over the window within merge_heading and under
    half the turn's own). The window stops at the merges and turns before and after the run
    (a straight run between or not). A turn next to another turn is left to the pair
    rules."""
    turn = np.flatnonzero((runs.code == sdl.LEFT) | (runs.code == sdl.RIGHT))
    if not len(turn):
        return runs
    n_runs = len(runs.start)
    stop = runs.start + runs.length
    seg_lo = runs.start[np.searchsorted(runs.seg, runs.seg, "left")]
    seg_hi = stop[np.searchsorted(runs.seg, runs.seg, "right") - 1]
    busy = runs.code != sdl.STRAIGHT
    is_turn = (runs.code == sdl.LEFT) | (runs.code == sdl.RIGHT)
    gap = config.merge_gap_steps // 2
    # the neighbours of each turn run in its segment
    prev_same = np.r_[False, runs.seg[1:] == runs.seg[:-1]][turn]
    next_same = np.r_[runs.seg[1:] == runs.seg[:-1], False][turn]
    prev, nxt = np.maximum(turn - 1, 0), np.minimum(turn + 1, n_runs - 1)
    lo = np.maximum(runs.start[turn] - gap, seg_lo[turn])
    hi = np.minimum(stop[turn] + gap, seg_hi[turn])
    lo = np.where(prev_same & busy[prev], np.maximum(lo, stop[prev]), lo)
    hi = np.where(next_same & busy[nxt], np.minimum(hi, runs.start[nxt]), hi)
    # nor past a merge or turn farther off (with a straight run between)
    idx = np.arange(n_runs)
    last_busy = np.maximum.accumulate(np.where(busy, idx, -1))
    next_busy = np.minimum.accumulate(np.where(busy, idx, n_runs)[::-1])[::-1]
    before = last_busy[prev]
    after = next_busy[nxt]
    far_prev = prev_same & (before >= 0) & (runs.seg[np.maximum(before, 0)] == runs.seg[turn])
    far_next = next_same & (after < n_runs) & (
        runs.seg[np.minimum(after, n_runs - 1)] == runs.seg[turn])
    lo = np.where(far_prev, np.maximum(lo, stop[np.maximum(before, 0)]), lo)
    hi = np.where(far_next, np.minimum(hi, runs.start[np.minimum(after, n_runs - 1)]), hi)
    # a turn right after a merge is also measured from the heading where the merge started
    is_merge = (runs.code == sdl.LEFT_MERGE) | (runs.code == sdl.RIGHT_MERGE)
    after_merge = prev_same & is_merge[prev]
    merge_start = runs.start[prev]
    # a turn against another: the pair rules decide
    alone = ~((prev_same & is_turn[prev]) | (next_same & is_turn[nxt]))
    turn, lo, hi = turn[alone], lo[alone], hi[alone]
    after_merge, merge_start = after_merge[alone], merge_start[alone]
    if not len(turn):
        return runs
    ok = _wiggle_ok(path, lo, hi, np.zeros(len(turn), dtype=np.int64), config, at_end=True)
    redo = np.flatnonzero(~ok & after_merge)
    ok[redo] = _wiggle_ok(path, lo[redo], hi[redo], np.zeros(len(redo), dtype=np.int64),
                          config, at_end=True, along=merge_start[redo])
    # and from the heading where the window ends, the direction the vehicle settled in,
    # when the turn came back: the heading where the window starts is that one's (within
    # merge_heading) and the net change over the window is under half the turn's own (a
    # bend keeps its heading change: net and turn are one). A window that starts
    # mid-swing (the lane change before the turn still under way) reads its offset across
    # a heading off the road's
    redo = np.flatnonzero(~ok)
    h = path.heading
    net = np.abs(h[path.rows[lo[redo]]] - h[path.rows[hi[redo] - 1]])
    own = np.abs(h[path.rows[stop[turn[redo]] - 1]] - h[path.rows[runs.start[turn[redo]]]])
    redo = redo[(net <= config.merge_heading) & (2 * net < own)]
    ok[redo] = _wiggle_ok(path, lo[redo], hi[redo], np.zeros(len(redo), dtype=np.int64),
                          config, at_end=True, along=hi[redo] - 1)
    wiggle = turn[ok]
    if not len(wiggle):
        return runs
    runs.code[wiggle] = sdl.STRAIGHT
    return coalesce(runs)


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


_ACTION_LATERAL_BASE = np.zeros(5, np.int64)
_ACTION_LATERAL_BASE[[sdl.STRAIGHT, sdl.LEFT, sdl.RIGHT, sdl.LEFT_MERGE, sdl.RIGHT_MERGE]] = [
    sdl.ACTION_STRAIGHT, 1, 4, sdl.ACTION_LEFT_MERGE, sdl.ACTION_RIGHT_MERGE]
"""Action-level lateral code of each maneuver code, before a turn's intensity."""
_ACTION_LONGITUDINAL_BASE = np.zeros(5, np.int64)
_ACTION_LONGITUDINAL_BASE[[sdl.MAINTAIN, sdl.ACCELERATE, sdl.DECELERATE, sdl.STOPPED,
                           sdl.REVERSING]] = [3 * sdl.MAINTAIN, 3 * sdl.ACCELERATE,
                                              3 * sdl.DECELERATE, sdl.ACTION_STOPPED,
                                              sdl.ACTION_REVERSING]
"""Action-level longitudinal code of each trend code, before the speed class."""


def run_stages(w: np.ndarray, a: np.ndarray, v: np.ndarray, seg_length: np.ndarray,
               thresholds: Thresholds, config: StageConfig = StageConfig(), *,
               heading: np.ndarray, x: np.ndarray, y: np.ndarray,
               rows: np.ndarray | None = None,
               reversing: np.ndarray | None = None) -> StepLabels:
    """Label every step of the given segments at all four levels.

    Args:
        w: (m,) yaw rate [rad/s] of the steps of all segments laid end to end.
        a: (m,) acceleration [m/s^2].
        v: (m,) speed [m/s].
        seg_length: (S,) steps in each segment, summing to m; each at least
            ``config.min_steps`` long.
        thresholds: Theta.
        config: stage parameters.
        heading: heading [rad], unwrapped within each segment (stage 3's net heading
            change and sideways move): (m,) per step, or (n,) per row with ``rows``.
        x, y: position [m], like ``heading``.
        rows: (m,) the row of ``heading``, ``x``, ``y`` of each step; the steps of one
            segment must be consecutive rows. Default: the arrays are per step.
        reversing: (m,) bool, the vehicle moves backwards at that step (SPEC 4.6: a run of
            1 s or more is labelled Reversing). Default: never.
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
    trace_lat = _trace_lateral(w, th)
    trace_long = _trace_longitudinal(a, th)

    # Stage 2: trend. Stopped steps are Straight, reversing runs of 1 s or more Reversing;
    # then the low-pass, and every turn (accelerate, decelerate) run must agree with its own
    # average (SPEC 4.5)
    stopped = v <= th.v_stop
    w_eff = np.where(stopped, 0.0, w)
    lat = np.where(stopped, sdl.STRAIGHT, trace_lat)
    lon = np.where(stopped, sdl.STOPPED, trace_long)
    if reversing is not None and np.any(reversing):
        back = find_runs(np.asarray(reversing, np.int64), seg, seg_first)
        long_back = np.repeat((back.code == 1) & (back.length >= min_steps), back.length)
        lon = np.where(long_back & ~stopped, sdl.REVERSING, lon)

    def classify_lat(starts):
        return _trace_lateral(window_means(w_eff, starts, min_steps), th)

    def classify_long(starts):
        mean_v = window_means(v, starts, min_steps)
        return np.where(mean_v <= th.v_stop, sdl.STOPPED,
                        _trace_longitudinal(window_means(a, starts, min_steps), th))

    passed_lat = _low_pass(lat, layout, classify_lat, min_steps)
    trend_lat = _agree_with_average(passed_lat, w_eff, layout, _trace_lateral, th,
                                    (sdl.LEFT, sdl.RIGHT), sdl.STRAIGHT)
    trend_long = _agree_with_average(_low_pass(lon, layout, classify_long, min_steps), a,
                                     layout, _trace_longitudinal, th,
                                     (sdl.ACCELERATE, sdl.DECELERATE), sdl.MAINTAIN)

    # Stage 3: maneuver.
    path = _Path(heading=np.asarray(heading, dtype=np.float64),
                 x=np.asarray(x, dtype=np.float64), y=np.asarray(y, dtype=np.float64),
                 rows=np.arange(m) if rows is None else np.asarray(rows, dtype=np.int64))
    # The merge rule reads the turn runs as the low-pass left them: a lane change whose
    # halves the low-pass cut off-centre (each half's mean under w_str: a run joined across
    # the heading's peak) is still a lateral move of merge_offset that ends parallel, and
    # stays a merge; the average rule (SPEC 4.5) then straightens the turns no merge or
    # wiggle claims (docs/tap.md: 94.3 % of completed lane changes were merges with the
    # average rule applied first, 98.4 % this way, as without it)
    paired = _merges(find_runs(passed_lat, seg, seg_first), path, config,
                     min_steps, trace_lat).expand(m)
    claimed = (paired == sdl.LEFT_MERGE) | (paired == sdl.RIGHT_MERGE) | (
        (paired == sdl.STRAIGHT) & (passed_lat != sdl.STRAIGHT))
    lat_runs = _lone_wiggles(find_runs(np.where(claimed, paired, trend_lat), seg, seg_first),
                             path, config)
    maneuver_lat = lat_runs.expand(m)

    # Stage 4: action.
    abs_w = np.abs(w_eff)
    w_class = (abs_w > th.w_grad).astype(np.int8) + (abs_w > th.w_med)
    is_turn = (lat_runs.code == sdl.LEFT) | (lat_runs.code == sdl.RIGHT)
    intensity = _refine(lat_runs, abs_w, w_class, is_turn, (th.w_grad, th.w_med), min_steps)
    # Straight and the merges their action codes, a turn 1 + 3 * side + its intensity (the
    # intensity is 0 off the turns: _refine gives the runs not refined 0)
    action_lat = _ACTION_LATERAL_BASE[maneuver_lat] + intensity
    long_runs = find_runs(trend_long, seg, seg_first)
    v_class = (v > th.v_slow).astype(np.int8) + (v > th.v_med)
    moving = (long_runs.code != sdl.STOPPED) & (long_runs.code != sdl.REVERSING)
    speed = _refine(long_runs, v, v_class, moving, (th.v_slow, th.v_med), min_steps)
    # Stopped and Reversing their action codes, the others 3 * code + speed class (0 on
    # the runs not refined: Stopped, Reversing)
    action_long = _ACTION_LONGITUDINAL_BASE[trend_long] + speed

    i8 = np.int8
    return StepLabels(
        trace_lateral=trace_lat, trace_longitudinal=trace_long,
        trend_lateral=trend_lat.astype(i8), trend_longitudinal=trend_long.astype(i8),
        maneuver_lateral=maneuver_lat.astype(i8), maneuver_longitudinal=trend_long.astype(i8),
        action_lateral=action_lat.astype(i8), action_longitudinal=action_long.astype(i8),
    )
