"""Interaction labels (SPEC section 7): what an ego does around others, per step, naming them.

For every step of an ego segment, one relation and the other agent it concerns:

===================  ===========================================================================
relation             when (``s``, ``d``: the other agent in the ego's path frame,
                     :mod:`tap_bench.pathframe`; corridor ``|d| <= corridor``)
===================  ===========================================================================
``Free Driving``     nobody driving along the path in the corridor ahead within the range
                     (``range_m`` or ``range_s`` times the ego's speed, the larger)
``Following``        the nearest such agent ahead (the leader)
``Lead Braking``     while Following, the leader decelerates: its acceleration, averaged over
                     the 1 s window centred on the step, is at or below ``a_dec``
``Cut-in``           an agent enters the corridor ahead from outside (it was at least
                     ``approach`` beyond the corridor's edge in the ``approach_window`` before)
                     by its own sideways motion, and becomes the leader; lasts
                     ``event_duration``, from ``cut_in_lead`` before the entry
``Cut-out``          the leader leaves the corridor by its own sideways motion (and gets at
                     least ``approach`` beyond the edge within ``approach_window``); lasts
                     ``event_duration`` from the exit
``Overtaking``       the ego passes a moving agent outside its corridor (``corridor < |d| <=
                     band``): its ``s`` goes from positive to negative; lasts while it is
                     within ``pass_length`` of alongside, at least 1 s
``Being Overtaken``  the reverse: ``s`` goes from negative to positive
===================  ===========================================================================

"By its own sideways motion": the frame is the ego's own path, so an agent also enters or
leaves the corridor when the *ego* changes lanes towards or away from it. An entry (exit)
counts as the other's only when (a) the other agent's own maneuver-level lateral label is a
turn or a merge within 1 s of the crossing (it moves sideways; a lane change or a turn
into the road), and (b) the ego's maneuver-level label where the path meets the other
agent is not a merge towards (away from) that agent's side. A lane change TAP does not
label (one already under way when the record starts, or too gentle to show a yaw
pattern) is not attributed to anyone: no Cut-in or Cut-out is reported.

Where several relations hold at one step the first of Cut-in, Cut-out, Lead Braking,
Overtaking, Being Overtaken, Following, Free Driving wins. Runs (of one relation with one
other agent) shorter than 1 s then follow stage 2's joining rule: the shortest joins its
longer neighbour, taking its relation and agent (Lead Braking's 1 s averaging is stage 2's
low-pass). Only vehicles and cyclists are others (pedestrians are not followed).

Beyond the ends of the ego's record the path goes on along its lane (with a map) or along
an arc of its last curvature (:mod:`tap_bench.pathframe`): a leader stopped ahead on a curve
is still the leader. Where the road bends differently from that arc, ``d`` changes there
without anyone moving sideways, so cut-ins and cut-outs are only detected where the other
agent's foot point lies on the recorded path, or ahead of its end when the path ends on a
steady curve or along a lane of the map (its heading changes over its last two seconds
differ by at most 0.05 rad while it drove at least 20 m: a straight road or a curve of
constant radius; an episode that ends in a crash during a cut-in on a highway).

Guards (SPEC 7): Overtaking and Being Overtaken need the other agent to go from at least
``pass_distance`` (a vehicle length) ahead to that far behind (or back), not a mere sign
change of ``s`` (a car keeping pace beside the ego on a curve is neither); an ego slower
than ``min_ego_speed`` over a whole run gets no relation but Free Driving and Following (a
parked ego is not overtaken, nor does its leader brake for it); a Cut-in needs the agent to
drive along the ego's path (heading within ``same_direction``) for 1 s after it enters (a
car crossing an intersection in front of the ego is not a cut-in). The label table's
``interaction`` sequence names the other agent of each run: ``Following (12) > Following
(7)``.
The parameters and the data that justify them: docs/interactions.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.errors import TapBenchError
from tap_bench.kinematics import STEPS_PER_SECOND, Kinematics
from tap_bench.pathframe import (
    CORRIDOR_HALF_WIDTH,
    LEADER_RANGE_M,
    LEADER_RANGE_S,
    SAME_DIRECTION,
    LaneMap,
    Paths,
    leader_reach,
    nearest_leader,
    path_frame,
    scene_lanes,
)
from tap_bench.stages import Runs, find_runs, join_short_runs
from tap_bench.trajectories import HZ, CheckedTable

__all__ = [
    "BEING_OVERTAKEN",
    "CUT_IN",
    "CUT_OUT",
    "FOLLOWING",
    "FREE_DRIVING",
    "LEAD_BRAKING",
    "OVERTAKING",
    "RELATIONS",
    "InteractionConfig",
    "InteractionSteps",
    "interaction_steps",
]

RELATIONS = sdl.INTERACTION_NAMES
"""The interaction vocabulary; a per-step relation is an index into it."""
FREE_DRIVING, FOLLOWING, CUT_IN, CUT_OUT, OVERTAKING, BEING_OVERTAKEN, LEAD_BRAKING = range(7)
OTHER_TYPES = ("vehicle", "cyclist")
"""Object types that can be the other agent of a relation."""
END_STEADY_STEPS = 20  # [steps] a path ends on a steady curve when its heading changes over
END_STEADY_RAD = 0.05  # [rad] its last two seconds differ by at most this (0.05 rad: a
# straight road and a 1 km radius at 25 m/s tell apart, a curve of constant radius does not)
END_STEADY_DISTANCE = 20.0  # [m] ... while driving at least this far over them (not parked)


@dataclass(frozen=True)
class InteractionConfig:
    """Parameters of the interaction axis (docs/interactions.md justifies each on data).

    Attributes:
        corridor: [m] half width of the ego's corridor (SPEC 7: half a lane).
        range_m: [m] a leader counts up to this far ahead along the path ...
        range_s: [s] ... or up to this many seconds at the ego's speed, whichever is more.
        same_direction: [rad] largest heading difference to the path of a leader or passed
            agent (crossing and oncoming traffic are neither).
        band: [m] largest ``|d|`` of an agent the ego overtakes or is overtaken by (the
            next lane).
        approach: [m] how far beyond the corridor's edge a cutting-in agent came from, or a
            cutting-out agent goes to.
        approach_window: [s] within which it came from (goes to) there.
        event_duration: [s] how long a Cut-in or Cut-out lasts (the time in which the ego
            has to respond).
        cut_in_lead: [s] a Cut-in starts this long before the agent crosses the corridor's
            edge (it is already moving in; an episode that ends in a crash soon after the
            crossing still shows the Cut-in).
        pass_length: [m] an overtaken agent is alongside while ``|s| <=`` this.
        min_moving_speed: [m/s] slower agents are not overtaken (parked cars are passed).
        pass_distance: [m] an agent is overtaken (overtakes) only when it goes from at
            least this far ahead of the ego to this far behind (or back): one vehicle
            length (SPEC 7's guard), so a car keeping pace beside the ego, whose ``s``
            wavers about 0 on a curve, is neither.
        min_ego_speed: [m/s] an ego slower than this over a whole run gets no relation but
            Free Driving and Following (SPEC 7: a parked ego is not overtaken, nor does its
            parked leader brake).
        min_run: [s] the shortest run of one relation (stage 2).
    """

    corridor: float = CORRIDOR_HALF_WIDTH
    range_m: float = LEADER_RANGE_M
    range_s: float = LEADER_RANGE_S
    same_direction: float = SAME_DIRECTION
    band: float = 6.0
    approach: float = 1.0
    approach_window: float = 3.0
    event_duration: float = 2.0
    cut_in_lead: float = 1.0
    pass_length: float = 5.0
    min_moving_speed: float = 2.0
    pass_distance: float = 5.0
    min_ego_speed: float = 1.0
    min_run: float = 1.0

    def __post_init__(self) -> None:
        for name in ("corridor", "range_m", "range_s", "same_direction", "band",
                     "approach", "approach_window", "event_duration", "pass_length",
                     "min_run", "cut_in_lead", "pass_distance"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise TapBenchError(f"InteractionConfig.{name} must be a finite number > 0, "
                                    f"got {value!r}.")
        if self.band <= self.corridor:
            raise TapBenchError(f"InteractionConfig.band ({self.band} m) must be wider than "
                                f"the corridor ({self.corridor} m).")
        if self.cut_in_lead >= self.event_duration:
            raise TapBenchError(f"InteractionConfig.cut_in_lead ({self.cut_in_lead} s) must be "
                                f"shorter than event_duration ({self.event_duration} s).")
        for name in ("min_moving_speed", "min_ego_speed"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value >= 0):
                raise TapBenchError(f"InteractionConfig.{name} must be >= 0 m/s, got "
                                    f"{value!r}.")

    def steps(self, seconds: float) -> int:
        return max(1, round(seconds * STEPS_PER_SECOND))


@dataclass(frozen=True)
class InteractionSteps:
    """Per-step relations of the ego segments, laid end to end as given.

    Attributes:
        relation: (m,) int8 index into :data:`RELATIONS`.
        other_row: (m,) int64 row (of the checked table) of the other agent at that step,
            -1 for Free Driving.
        other_track: (m,) int64 track index of the other agent, -1 for Free Driving.
        leader_row: (m,) int64 row of the leader before the relations were assigned (-1).
        cut_in_step: (k,) int64 ego steps at which an agent cut in (its entry).
        cut_in_track: (k,) int64 the track that cut in.
        runs: the runs of (relation, other agent) per segment (codes: relation * (T + 1) +
            other track + 1, T the number of tracks).
    """

    relation: np.ndarray
    other_row: np.ndarray
    other_track: np.ndarray
    leader_row: np.ndarray
    cut_in_step: np.ndarray
    cut_in_track: np.ndarray
    runs: Runs


def _smoothed(values: np.ndarray, kin: Kinematics, rows: np.ndarray, width: int
              ) -> np.ndarray:
    """(k,) mean of ``values`` over the ``width``-step window centred on each of ``rows``
    (valid rows), shifted to lie inside its valid segment (the whole segment when shorter)."""
    idx = kin.index
    seg = idx.segment[rows]
    s0, s1 = idx.segment_start[seg], idx.segment_stop[seg]
    w = np.minimum(width, s1 - s0)
    lo = np.clip(rows - width // 2, s0, s1 - w)
    total = np.zeros(len(rows))
    for k in range(width):  # width is 10: ten gathers beat a cumulative sum of every row
        inside = k < w
        total[inside] += values[lo[inside] + k]
    return total / w


def _paint(relation, other, start, stop, code, row_of):
    """Set ``relation``/``other`` over the half-open step ranges [start, stop) to ``code`` and
    the given other rows (later ranges win)."""
    counts = np.maximum(stop - start, 0)
    if not counts.sum():
        return
    group = np.repeat(np.arange(len(start)), counts)
    pos = np.repeat(start, counts) + (np.arange(counts.sum())
                                      - np.repeat(np.cumsum(counts) - counts, counts))
    relation[pos] = code
    other[pos] = row_of[group]


def interaction_steps(checked: CheckedTable, kin: Kinematics, start: np.ndarray,
                      stop: np.ndarray, lateral: np.ndarray, a_dec: float,
                      config: InteractionConfig | None = None, *,
                      map_table: pd.DataFrame | LaneMap | None = None) -> InteractionSteps:
    """The relation of every step of the given ego segments.

    Args:
        checked: the validated trajectory table (rows grouped by track, in time order).
        kin: its kinematics.
        start, stop: (S,) row ranges of the ego segments (valid segments of tracks).
        lateral: (n,) maneuver-level lateral code of every row of ``checked``
            (:data:`tap_bench.sdl.LATERAL_NAMES`; -1 where the row carries no label): tells
            an ego's lane change from an other agent's.
        a_dec: [m/s^2] the deceleration threshold (TAP's Theta_a, negative).
        config: parameters.
        map_table: lane centre lines (:mod:`tap_bench.maps`; a scenario's map has its
            ``scenario_id`` or its ``env`` as ``map_id``): the ego's path goes on along its
            lane beyond the record; or a :class:`~tap_bench.pathframe.LaneMap` of them
            shared with other calls (:func:`~tap_bench.pathframe.scene_lanes`). None: along
            an arc of its last curvature.
    """
    config = config or InteractionConfig()
    idx = kin.index
    n = len(kin.t)
    step_no = np.rint(kin.t * HZ).astype(np.int64)
    # per-track columns are read at each track's first row only (strings are slow per row)
    # (taken from the input's rows, without putting the whole column in track order)
    per_track = checked.per_track_arrays(["scenario_id", "object_type", "env"])
    scen_of_track, _ = pd.factorize(per_track["scenario_id"], sort=False)
    scen = scen_of_track[idx.track]
    span = int(step_no.max() - step_no.min() + 1) if n else 1
    key = scen.astype(np.int64) * span + (step_no - (step_no.min() if n else 0))
    x = np.asarray(checked["x"], float)
    y = np.asarray(checked["y"], float)
    heading = np.asarray(checked["heading"], float)
    speed = np.asarray(checked["speed"], float)
    others = idx.segment >= 0
    if "object_type" in checked:
        # validated: each a str, lower case (a few tracks: no pandas round trip)
        kinds = per_track["object_type"].tolist()
        others &= np.fromiter((k in OTHER_TYPES for k in kinds), bool, len(kinds))[idx.track]
    lanes = None
    if map_table is not None:
        names = pd.Series(per_track["scenario_id"]).to_numpy()
        scenes = pd.unique(names)
        table = pd.DataFrame({"scenario_id": names})
        if "env" in checked:
            table["env"] = pd.Series(per_track["env"]).to_numpy()
        lanes = scene_lanes(table, scen_of_track, scenes, map_table)
    paths = Paths(scene=scen.astype(np.int64), key=key, track=idx.track, x=x, y=y,
                  heading=heading, speed=speed,
                  start=np.asarray(start, np.int64), stop=np.asarray(stop, np.int64))
    ego_row, ego_path = paths.ego_rows()
    m = len(ego_row)
    if len(lateral) != n:
        raise TapBenchError(f"interaction_steps: {len(lateral)} lateral codes for {n} rows.")
    if m == 0:  # no ego segment long enough to label: no relation to find
        none = np.zeros(0, np.int64)
        return InteractionSteps(relation=np.zeros(0, np.int8), other_row=none,
                                other_track=none, leader_row=none, cut_in_step=none,
                                cut_in_track=none, runs=Runs(none, none, none, none))
    ego_lateral = lateral[ego_row]
    v_e = speed[ego_row]
    reach = leader_reach(v_e, config.range_m, config.range_s)
    # what the relations need: the corridor and its edges far ahead (leaders, cut-ins and
    # cut-outs), the next lanes near the ego (overtaking)
    frame = path_frame(paths, others, ahead=reach, behind=1.0,
                       lateral=config.corridor + config.approach + 0.5,
                       near=3.0 * config.pass_length, lateral_near=config.band, lanes=lanes)
    q_step, q_other = frame.step, frame.other
    s, d, hrel = frame.s, frame.d, frame.heading_rel
    track = idx.track[q_other]
    along = np.abs(hrel) <= config.same_direction

    # the leader: the nearest agent driving along the path in the corridor, within range
    # (the same rule as the safety measures')
    leader_pair = nearest_leader(frame, reach, corridor=config.corridor,
                                 same_direction=config.same_direction)
    has_leader = leader_pair >= 0
    leader_row = np.full(m, -1, np.int64)  # indexed only where there is one: an ego
    leader_row[has_leader] = q_other[leader_pair[has_leader]]  # alone has no pairs at all

    # each (ego path, other track) as a time series: the pair one step before and after
    order = np.lexsort((q_step, track, ego_path[q_step]))
    pos_in = np.empty(len(order), np.int64)
    pos_in[order] = np.arange(len(order))

    def lagged(pairs: np.ndarray, lag: int) -> np.ndarray:
        """The pair ``lag`` steps later (negative: earlier) in the same series, or -1."""
        j = pos_in[pairs] + lag
        ok = (j >= 0) & (j < len(order))
        out = np.full(len(pairs), -1, np.int64)
        other = order[np.clip(j, 0, max(len(order) - 1, 0))]
        ok &= (track[other] == track[pairs]) & (q_step[other] - q_step[pairs] == lag)
        ok &= ego_path[q_step[other]] == ego_path[q_step[pairs]]
        out[ok] = other[ok]
        return out

    def lagged_all(pairs: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``lagged`` of every lag at once: (pairs, lags) arrays of the pair ``lag`` steps
        later and whether there is one (where there is not, the pair is arbitrary)."""
        j = pos_in[pairs][:, None] + lags[None, :]
        ok = (j >= 0) & (j < len(order))
        other = order[np.clip(j, 0, len(order) - 1)]
        ok &= (track[other] == track[pairs][:, None]) \
            & (q_step[other] - q_step[pairs][:, None] == lags[None, :])
        ok &= ego_path[q_step[other]] == ego_path[q_step[pairs]][:, None]
        return other, ok

    def reaches(pairs: np.ndarray, direction: int) -> np.ndarray:
        """Within the approach window before (-1) or after (+1): |d| >= corridor + approach."""
        lags = direction * np.arange(1, config.steps(config.approach_window) + 1)
        if not len(pairs) or not len(lags):
            return np.zeros(len(pairs), bool)
        other, ok = lagged_all(pairs, lags)
        return (ok & (np.abs(d[other]) >= config.corridor + config.approach)).any(axis=1)

    arc = frame.arc
    # arc length of every ego step, offset per path so one searchsorted serves all paths
    path_span = float(arc.max(initial=0.0)) + 2 * float(reach.max(initial=0.0)) + 10.0
    arc_global = arc + ego_path * path_span
    path_first = np.searchsorted(ego_path, np.arange(paths.n_paths))
    path_last = np.r_[path_first[1:], m] - 1
    merge_window = STEPS_PER_SECOND
    window = np.arange(-merge_window, merge_window + 1)  # the steps within 1 s

    def ego_merging(pairs: np.ndarray, side: np.ndarray) -> np.ndarray:
        """The ego merges towards ``side`` (+1 left, -1 right) where its path meets the
        other agent of each pair (within 1 s of that point)."""
        p = ego_path[q_step[pairs]]
        at = np.searchsorted(arc_global, arc[q_step[pairs]] + s[pairs] + p * path_span)
        at = np.clip(at, path_first[p], path_last[p])
        want = np.where(side > 0, sdl.LEFT_MERGE, sdl.RIGHT_MERGE)
        # every step of the window at once: (pairs, window) steps, kept on the path
        k = np.clip(at[:, None] + window[None, :], path_first[p][:, None],
                    path_last[p][:, None])
        return (ego_lateral[k] == want[:, None]).any(axis=1)

    # the extension beyond the record's end is trusted where the path ends on a steady
    # curve (the arc then is the road) or along a lane of the map
    h_last = heading[ego_row[path_last]]
    back = np.maximum(path_last - END_STEADY_STEPS, path_first)
    mid = np.maximum(path_last - END_STEADY_STEPS // 2, path_first)
    late = np.angle(np.exp(1j * (h_last - heading[ego_row[mid]])))
    early = np.angle(np.exp(1j * (heading[ego_row[mid]] - heading[ego_row[back]])))
    ends_steady = (np.abs(late - early) <= END_STEADY_RAD) \
        & (arc[path_last] - arc[back] >= END_STEADY_DISTANCE)
    if lanes is not None:
        ends_steady |= lanes.covers(paths.scene[paths.start]) & (
            arc[path_last] - arc[back] >= END_STEADY_DISTANCE)

    def on_record(pairs: np.ndarray) -> np.ndarray:
        """The other's foot point lies on the ego's recorded path, or on the extension ahead
        of a path that ends on a steady curve (elsewhere the road may bend away from the
        extension, and d changes without anyone moving sideways)."""
        st = q_step[pairs]
        at = arc[st] + s[pairs]
        path = ego_path[st]
        return (at >= 0) & ((at <= arc[path_last[path]]) | ends_steady[path])

    def other_moving_sideways(pairs: np.ndarray) -> np.ndarray:
        """The other agent's own lateral label is a turn or a merge within 1 s."""
        rows = q_other[pairs]
        seg = idx.segment[rows]
        lo, hi = idx.segment_start[seg], idx.segment_stop[seg] - 1
        code = lateral[np.clip(rows[:, None] + window[None, :], lo[:, None], hi[:, None])]
        return (code > sdl.STRAIGHT).any(axis=1)

    def drives_along(pairs: np.ndarray) -> np.ndarray:
        """After it enters, the agent drives along the ego's path for 1 s (heading within
        ``same_direction`` at every step the ego's path goes on; SPEC 7's guard): a car
        crossing an intersection in front of the ego is not a cut-in."""
        if not len(pairs):
            return along[pairs].copy()
        last = path_last[ego_path[q_step[pairs]]]
        lags = np.arange(1, STEPS_PER_SECOND + 1)
        other, ok = lagged_all(pairs, lags)
        goes_on = q_step[pairs][:, None] + lags[None, :] <= last[:, None]
        return along[pairs] & (~goes_on | (ok & along[other])).all(axis=1)

    # Cut-in: the new leader was outside the corridor one step before, and far out earlier
    new_lead = leader_pair[has_leader]
    prev = lagged(new_lead, -1)
    entering = new_lead[(prev >= 0)]
    prev = prev[prev >= 0]
    out_before = np.abs(d[prev]) > config.corridor
    entering, prev = entering[out_before], prev[out_before]
    ok = (on_record(entering) & reaches(entering, -1) & other_moving_sideways(entering)
          & ~ego_merging(entering, np.sign(d[prev])) & drives_along(entering))
    cut_in = entering[ok]

    # Cut-out: the leader of the step before is outside the corridor now, still ahead
    had = np.flatnonzero(has_leader[:-1]) if m > 1 else np.zeros(0, np.int64)
    had = had[ego_path[had + 1] == ego_path[had]]
    nxt = lagged(leader_pair[had], 1)
    ok = nxt >= 0
    leaving = nxt[ok]
    ok = (np.abs(d[leaving]) > config.corridor) & (s[leaving] > 0)
    leaving = leaving[ok]
    ok = (on_record(leaving) & reaches(leaving, +1) & other_moving_sideways(leaving)
          & ~ego_merging(leaving, -np.sign(d[leaving])))
    cut_out = leaving[ok]

    # Overtaking / Being Overtaken: s changes sign beside the corridor
    prev_all = lagged(np.arange(len(order)), -1)
    has_prev = prev_all >= 0
    q = np.flatnonzero(has_prev)
    p = prev_all[q]
    beside = ((np.abs(d[q]) > config.corridor) & (np.abs(d[q]) <= config.band)
              & (np.abs(d[p]) > config.corridor) & along[q]
              & (speed[q_other[q]] >= config.min_moving_speed))
    # SPEC 7's guard: from a vehicle length ahead to a length behind (or back) in the same
    # series, not a sign change of s (a car keeping pace beside the ego on a curve)
    series = np.r_[True, (track[order][1:] != track[order][:-1])
                   | (ego_path[q_step[order]][1:] != ego_path[q_step[order]][:-1])]
    series_start = np.maximum.accumulate(np.where(series, np.arange(len(order)), 0))
    series_stop = np.minimum.accumulate(
        np.where(np.r_[series[1:], True], np.arange(len(order)), len(order))[::-1])[::-1]

    def seen_before(cond: np.ndarray, at: np.ndarray) -> np.ndarray:
        """cond (in series order) holds at or before position ``at`` in its series."""
        last = np.maximum.accumulate(np.where(cond, np.arange(len(order)), -1))
        return last[at] >= series_start[at]

    def seen_after(cond: np.ndarray, at: np.ndarray) -> np.ndarray:
        nxt = np.minimum.accumulate(np.where(cond, np.arange(len(order)),
                                             len(order))[::-1])[::-1]
        return nxt[at] <= series_stop[at]

    s_sorted = s[order]
    far_ahead = s_sorted >= config.pass_distance
    far_behind = s_sorted <= -config.pass_distance
    passing = q[beside & (s[p] > 0) & (s[q] <= 0)]
    passing = passing[seen_before(far_ahead, pos_in[passing])
                      & seen_after(far_behind, pos_in[passing])]
    passed_by = q[beside & (s[p] < 0) & (s[q] >= 0)]
    passed_by = passed_by[seen_before(far_behind, pos_in[passed_by])
                          & seen_after(far_ahead, pos_in[passed_by])]

    relation = np.zeros(m, np.int8)
    other = np.full(m, -1, np.int64)
    relation[has_leader] = FOLLOWING
    other[has_leader] = leader_row[has_leader]
    last_step = path_last[ego_path]  # (m,) last step of each step's path

    def windows(pairs: np.ndarray, before: np.ndarray, after: np.ndarray):
        st = q_step[pairs]
        lo = np.maximum(st - before, path_first[ego_path[st]])
        hi = np.minimum(st + after, last_step[st] + 1)
        return lo, hi

    def pass_half(pairs: np.ndarray) -> np.ndarray:
        rel = np.abs(v_e[q_step[pairs]] - frame.v_along[pairs])
        h = np.rint(config.pass_length / np.maximum(rel, 0.1) * HZ).astype(np.int64)
        return np.clip(h, config.steps(config.min_run) // 2, 2 * STEPS_PER_SECOND)

    h = pass_half(passed_by)
    _paint(relation, other, *windows(passed_by, h, h + 1), BEING_OVERTAKEN, q_other[passed_by])
    h = pass_half(passing)
    _paint(relation, other, *windows(passing, h, h + 1), OVERTAKING, q_other[passing])
    # Lead Braking: the leader's acceleration over the centred 1 s window
    braking = has_leader.copy()
    braking[has_leader] = _smoothed(kin.a, kin, leader_row[has_leader],
                                    STEPS_PER_SECOND) <= a_dec
    relation[braking] = LEAD_BRAKING
    other[braking] = leader_row[braking]
    event = config.steps(config.event_duration)
    zero = np.zeros(len(cut_out), np.int64)
    _paint(relation, other, *windows(cut_out, zero, zero + event), CUT_OUT, q_other[cut_out])
    lead = np.full(len(cut_in), config.steps(config.cut_in_lead), np.int64)
    _paint(relation, other, *windows(cut_in, lead, event - lead), CUT_IN, q_other[cut_in])

    # runs of one (relation, other agent); stage 2's joining of runs shorter than 1 s
    other_track = np.where(other >= 0, idx.track[np.maximum(other, 0)], -1)
    n_tracks = idx.n_tracks + 1
    code = relation.astype(np.int64) * n_tracks + other_track + 1
    seg_first = np.ones(m, bool)
    seg_first[1:] = ego_path[1:] != ego_path[:-1]
    runs = join_short_runs(find_runs(code, ego_path, seg_first), config.steps(config.min_run))
    # SPEC 7's guard: an ego slower than min_ego_speed over a whole run (parked, waiting)
    # is neither overtaken nor cut in on; its leader's braking is not its concern
    top = np.maximum.reduceat(v_e, runs.start) if len(runs.start) else np.zeros(0)
    still = (top < config.min_ego_speed) & (runs.code // n_tracks > FOLLOWING)
    if still.any():
        base = np.where(has_leader, FOLLOWING, FREE_DRIVING).astype(np.int64)
        base_track = np.where(has_leader, idx.track[np.maximum(leader_row, 0)], -1)
        step_still = np.repeat(still, runs.length)
        code = np.repeat(runs.code, runs.length)
        code[step_still] = (base * n_tracks + base_track + 1)[step_still]
        runs = join_short_runs(find_runs(code, ego_path, seg_first),
                               config.steps(config.min_run))
    code = np.repeat(runs.code, runs.length)
    relation = (code // n_tracks).astype(np.int8)
    other_track = code % n_tracks - 1
    # the other's row at each step (its track's row at that step; -1 where not recorded)
    other_row = _row_at(other_track, key[ego_row], idx.track, key)
    return InteractionSteps(relation=relation, other_row=other_row, other_track=other_track,
                            leader_row=leader_row, cut_in_step=q_step[cut_in],
                            cut_in_track=track[cut_in], runs=runs)


def _row_at(track: np.ndarray, step_key: np.ndarray, row_track: np.ndarray,
            row_key: np.ndarray) -> np.ndarray:
    """(m,) the row of ``track`` at ``step_key`` (-1 when the track has none there)."""
    out = np.full(len(track), -1, np.int64)
    want = track >= 0
    if not want.any():
        return out
    span = int(row_key.max()) + 1
    combined = row_track.astype(np.int64) * span + row_key
    order = np.argsort(combined, kind="stable")
    target = track[want] * span + step_key[want]
    pos = np.clip(np.searchsorted(combined[order], target), 0, len(order) - 1)
    hit = combined[order][pos] == target
    rows = np.where(hit, order[pos], -1)
    out[want] = rows
    return out
