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
from typing import Any

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
    rows = _Rows.of(checked, kin, map_table)
    paths = Paths(scene=rows.scene.astype(np.int64), key=rows.key, track=rows.index.track,
                  x=rows.x, y=rows.y, heading=rows.heading, speed=rows.speed,
                  start=np.asarray(start, np.int64), stop=np.asarray(stop, np.int64))
    ego_row, ego_path = paths.ego_rows()
    if len(lateral) != rows.n:
        raise TapBenchError(f"interaction_steps: {len(lateral)} lateral codes for {rows.n} rows.")
    if len(ego_row) == 0:  # no ego segment long enough to label: no relation to find
        none = np.zeros(0, np.int64)
        return InteractionSteps(relation=np.zeros(0, np.int8), other_row=none,
                                other_track=none, leader_row=none, cut_in_step=none,
                                cut_in_track=none, runs=Runs(none, none, none, none))
    scene = _EgoScene(rows, paths, ego_row, ego_path, lateral, config)
    cut_in = scene.cut_ins()
    cut_out = scene.cut_outs()
    passing, passed_by = scene.passes()
    relation, other = scene.relations(kin, a_dec, cut_in, cut_out, passing, passed_by)
    return scene.steps(relation, other, cut_in)


@dataclass(frozen=True)
class _Rows:
    """Per row of the trajectory table (n rows): its kinematics index, its scene (a code
    per ``scenario_id``), its key (scene and 10 Hz step), position [m], heading [rad],
    speed [m/s], whether it may be an ego's other agent, and the scenes' lanes (None
    without a map)."""

    index: Any
    n: int
    scene: np.ndarray
    key: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    others: np.ndarray
    lanes: LaneMap | None

    @classmethod
    def of(cls, checked: CheckedTable, kin: Kinematics,
           map_table: pd.DataFrame | LaneMap | None) -> _Rows:
        """The rows of ``checked`` (kinematics ``kin``), lanes from ``map_table``."""
        idx = kin.index
        n = len(kin.t)
        step_no = np.rint(kin.t * HZ).astype(np.int64)
        # per-track columns are read at each track's first row only (strings are slow per
        # row; taken from the input's rows, without putting the whole column in track order)
        per_track = checked.per_track_arrays(["scenario_id", "object_type", "env"])
        scen_of_track, _ = pd.factorize(per_track["scenario_id"], sort=False)
        scen = scen_of_track[idx.track]
        span = int(step_no.max() - step_no.min() + 1) if n else 1
        key = scen.astype(np.int64) * span + (step_no - (step_no.min() if n else 0))
        others = idx.segment >= 0
        if "object_type" in checked:
            # validated: each a str, lower case (a few tracks: no pandas round trip)
            kinds = per_track["object_type"].tolist()
            others &= np.fromiter((k in OTHER_TYPES for k in kinds), bool,
                                  len(kinds))[idx.track]
        lanes = None
        if map_table is not None:
            names = pd.Series(per_track["scenario_id"]).to_numpy()
            scenes = pd.unique(names)
            table = pd.DataFrame({"scenario_id": names})
            if "env" in checked:
                table["env"] = pd.Series(per_track["env"]).to_numpy()
            lanes = scene_lanes(table, scen_of_track, scenes, map_table)
        return cls(index=idx, n=n, scene=scen, key=key,
                   x=np.asarray(checked["x"], float), y=np.asarray(checked["y"], float),
                   heading=np.asarray(checked["heading"], float),
                   speed=np.asarray(checked["speed"], float), others=others, lanes=lanes)


class _PairSeries:
    """The path frame's (ego step, other agent) pairs as time series, one per (ego path,
    other track), in step order: the pair a few steps before or after, and whether a
    condition holds earlier or later in the same series."""

    def __init__(self, q_step: np.ndarray, track: np.ndarray, ego_path: np.ndarray) -> None:
        self.q_step, self.track, self.ego_path = q_step, track, ego_path
        order = np.lexsort((q_step, track, ego_path[q_step]))
        self.order = order
        self.pos_in = np.empty(len(order), np.int64)
        self.pos_in[order] = np.arange(len(order))
        series = np.r_[True, (track[order][1:] != track[order][:-1])
                       | (ego_path[q_step[order]][1:] != ego_path[q_step[order]][:-1])]
        self.series_start = np.maximum.accumulate(np.where(series, np.arange(len(order)), 0))
        self.series_stop = np.minimum.accumulate(
            np.where(np.r_[series[1:], True], np.arange(len(order)), len(order))[::-1])[::-1]

    def lagged(self, pairs: np.ndarray, lag: int) -> np.ndarray:
        """The pair ``lag`` steps later (negative: earlier) in the same series, or -1."""
        order, track, q_step, ego_path = self.order, self.track, self.q_step, self.ego_path
        j = self.pos_in[pairs] + lag
        ok = (j >= 0) & (j < len(order))
        out = np.full(len(pairs), -1, np.int64)
        other = order[np.clip(j, 0, max(len(order) - 1, 0))]
        ok &= (track[other] == track[pairs]) & (q_step[other] - q_step[pairs] == lag)
        ok &= ego_path[q_step[other]] == ego_path[q_step[pairs]]
        out[ok] = other[ok]
        return out

    def lagged_all(self, pairs: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``lagged`` of every lag at once: (pairs, lags) arrays of the pair ``lag`` steps
        later and whether there is one (where there is not, the pair is arbitrary)."""
        order, track, q_step, ego_path = self.order, self.track, self.q_step, self.ego_path
        j = self.pos_in[pairs][:, None] + lags[None, :]
        ok = (j >= 0) & (j < len(order))
        other = order[np.clip(j, 0, len(order) - 1)]
        ok &= ((track[other] == track[pairs][:, None])
            & (q_step[other] - q_step[pairs][:, None] == lags[None, :]))
        ok &= ego_path[q_step[other]] == ego_path[q_step[pairs]][:, None]
        return other, ok

    def seen_before(self, cond: np.ndarray, at: np.ndarray) -> np.ndarray:
        """cond (in series order) holds at or before position ``at`` in its series."""
        last = np.maximum.accumulate(np.where(cond, np.arange(len(self.order)), -1))
        return last[at] >= self.series_start[at]

    def seen_after(self, cond: np.ndarray, at: np.ndarray) -> np.ndarray:
        """cond (in series order) holds at or after position ``at`` in its series."""
        n = len(self.order)
        nxt = np.minimum.accumulate(np.where(cond, np.arange(n), n)[::-1])[::-1]
        return nxt[at] <= self.series_stop[at]


class _EgoScene:
    """The ego paths' m steps, the other agents around them (the path frame's pairs) and
    their leaders: the events (cut-ins, cut-outs, passes) found on them, then the relation
    of every step (SPEC 7's rules; the module docstring)."""

    def __init__(self, rows: _Rows, paths: Paths, ego_row: np.ndarray, ego_path: np.ndarray,
                 lateral: np.ndarray, config: InteractionConfig) -> None:
        self.rows, self.config, self.lateral = rows, config, lateral
        self.ego_row, self.ego_path, self.m = ego_row, ego_path, len(ego_row)
        self.ego_lateral = lateral[ego_row]
        self.v_e = rows.speed[ego_row]
        reach = leader_reach(self.v_e, config.range_m, config.range_s)
        # what the relations need: the corridor and its edges far ahead (leaders, cut-ins
        # and cut-outs), the next lanes near the ego (overtaking)
        frame = path_frame(paths, rows.others, ahead=reach, behind=1.0,
                           lateral=config.corridor + config.approach + 0.5,
                           near=3.0 * config.pass_length, lateral_near=config.band,
                           lanes=rows.lanes)
        self.frame = frame
        self.q_step, self.q_other = frame.step, frame.other
        self.s, self.d = frame.s, frame.d
        self.track = rows.index.track[self.q_other]
        self.along = np.abs(frame.heading_rel) <= config.same_direction
        # the leader: the nearest agent driving along the path in the corridor, within
        # range (the same rule as the safety measures')
        self.leader_pair = nearest_leader(frame, reach, corridor=config.corridor,
                                          same_direction=config.same_direction)
        self.has_leader = self.leader_pair >= 0
        # indexed only where there is one: an ego alone has no pairs at all
        self.leader_row = np.full(self.m, -1, np.int64)
        self.leader_row[self.has_leader] = self.q_other[self.leader_pair[self.has_leader]]
        self.pairs = _PairSeries(self.q_step, self.track, ego_path)
        self.arc = arc = frame.arc
        # arc length of every ego step, offset per path so one searchsorted serves all paths
        self.path_span = (float(arc.max(initial=0.0)) + 2 * float(reach.max(initial=0.0))
                          + 10.0)
        self.arc_global = arc + ego_path * self.path_span
        self.path_first = np.searchsorted(ego_path, np.arange(paths.n_paths))
        self.path_last = np.r_[self.path_first[1:], self.m] - 1
        self.window = np.arange(-STEPS_PER_SECOND, STEPS_PER_SECOND + 1)  # the steps within 1 s
        self.ends_steady = self._ends_steady(paths)

    def _ends_steady(self, paths: Paths) -> np.ndarray:
        """(paths,) whether the extension beyond the record's end is trusted: the path ends
        on a steady curve (the arc then is the road) or along a lane of the map."""
        heading, ego_row, arc = self.rows.heading, self.ego_row, self.arc
        path_first, path_last = self.path_first, self.path_last
        h_last = heading[ego_row[path_last]]
        back = np.maximum(path_last - END_STEADY_STEPS, path_first)
        mid = np.maximum(path_last - END_STEADY_STEPS // 2, path_first)
        late = np.angle(np.exp(1j * (h_last - heading[ego_row[mid]])))
        early = np.angle(np.exp(1j * (heading[ego_row[mid]] - heading[ego_row[back]])))
        ends_steady = ((np.abs(late - early) <= END_STEADY_RAD)
            & (arc[path_last] - arc[back] >= END_STEADY_DISTANCE))
        if self.rows.lanes is not None:
            ends_steady |= self.rows.lanes.covers(paths.scene[paths.start]) & (
                arc[path_last] - arc[back] >= END_STEADY_DISTANCE)
        return ends_steady

    # -- tests on pairs --------------------------------------------------------------------
    def reaches(self, pairs: np.ndarray, direction: int) -> np.ndarray:
        """Within the approach window before (-1) or after (+1): |d| >= corridor + approach."""
        config = self.config
        lags = direction * np.arange(1, config.steps(config.approach_window) + 1)
        if not len(pairs) or not len(lags):
            return np.zeros(len(pairs), bool)
        other, ok = self.pairs.lagged_all(pairs, lags)
        return (ok & (np.abs(self.d[other]) >= config.corridor + config.approach)).any(axis=1)

    def ego_merging(self, pairs: np.ndarray, side: np.ndarray) -> np.ndarray:
        """The ego merges towards ``side`` (+1 left, -1 right) where its path meets the
        other agent of each pair (within 1 s of that point)."""
        q_step, path_first, path_last = self.q_step, self.path_first, self.path_last
        p = self.ego_path[q_step[pairs]]
        at = np.searchsorted(self.arc_global,
                             self.arc[q_step[pairs]] + self.s[pairs] + p * self.path_span)
        at = np.clip(at, path_first[p], path_last[p])
        want = np.where(side > 0, sdl.LEFT_MERGE, sdl.RIGHT_MERGE)
        # every step of the window at once: (pairs, window) steps, kept on the path
        k = np.clip(at[:, None] + self.window[None, :], path_first[p][:, None],
                    path_last[p][:, None])
        return (self.ego_lateral[k] == want[:, None]).any(axis=1)

    def on_record(self, pairs: np.ndarray) -> np.ndarray:
        """The other's foot point lies on the ego's recorded path, or on the extension ahead
        of a path that ends on a steady curve (elsewhere the road may bend away from the
        extension, and d changes without anyone moving sideways)."""
        st = self.q_step[pairs]
        at = self.arc[st] + self.s[pairs]
        path = self.ego_path[st]
        return (at >= 0) & ((at <= self.arc[self.path_last[path]]) | self.ends_steady[path])

    def other_moving_sideways(self, pairs: np.ndarray) -> np.ndarray:
        """The other agent's own lateral label is a turn or a merge within 1 s."""
        idx = self.rows.index
        rows = self.q_other[pairs]
        seg = idx.segment[rows]
        lo, hi = idx.segment_start[seg], idx.segment_stop[seg] - 1
        code = self.lateral[np.clip(rows[:, None] + self.window[None, :], lo[:, None],
                                    hi[:, None])]
        return (code > sdl.STRAIGHT).any(axis=1)

    def drives_along(self, pairs: np.ndarray) -> np.ndarray:
        """After it enters, the agent drives along the ego's path for 1 s (heading within
        ``same_direction`` at every step the ego's path goes on; SPEC 7's guard): a car
        crossing an intersection in front of the ego is not a cut-in."""
        along = self.along
        if not len(pairs):
            return along[pairs].copy()
        last = self.path_last[self.ego_path[self.q_step[pairs]]]
        lags = np.arange(1, STEPS_PER_SECOND + 1)
        other, ok = self.pairs.lagged_all(pairs, lags)
        goes_on = self.q_step[pairs][:, None] + lags[None, :] <= last[:, None]
        return along[pairs] & (~goes_on | (ok & along[other])).all(axis=1)

    # -- events ----------------------------------------------------------------------------
    def cut_ins(self) -> np.ndarray:
        """The pairs where an agent cuts in: the new leader was outside the corridor one
        step before, and far out earlier."""
        d = self.d
        new_lead = self.leader_pair[self.has_leader]
        prev = self.pairs.lagged(new_lead, -1)
        entering = new_lead[(prev >= 0)]
        prev = prev[prev >= 0]
        out_before = np.abs(d[prev]) > self.config.corridor
        entering, prev = entering[out_before], prev[out_before]
        ok = (self.on_record(entering) & self.reaches(entering, -1)
              & self.other_moving_sideways(entering)
              & ~self.ego_merging(entering, np.sign(d[prev])) & self.drives_along(entering))
        return entering[ok]

    def cut_outs(self) -> np.ndarray:
        """The pairs where the leader of the step before is outside the corridor now,
        still ahead."""
        m, d, s, ego_path = self.m, self.d, self.s, self.ego_path
        had = np.flatnonzero(self.has_leader[:-1]) if m > 1 else np.zeros(0, np.int64)
        had = had[ego_path[had + 1] == ego_path[had]]
        nxt = self.pairs.lagged(self.leader_pair[had], 1)
        ok = nxt >= 0
        leaving = nxt[ok]
        ok = (np.abs(d[leaving]) > self.config.corridor) & (s[leaving] > 0)
        leaving = leaving[ok]
        ok = (self.on_record(leaving) & self.reaches(leaving, +1)
              & self.other_moving_sideways(leaving)
              & ~self.ego_merging(leaving, -np.sign(d[leaving])))
        return leaving[ok]

    def passes(self) -> tuple[np.ndarray, np.ndarray]:
        """The pairs where the ego overtakes the other, and where the other overtakes the
        ego: s changes sign beside the corridor, from a vehicle length ahead to a length
        behind (or back) in the same series (SPEC 7's guard: not a sign change of s, as of
        a car keeping pace beside the ego on a curve)."""
        config, d, s, pairs = self.config, self.d, self.s, self.pairs
        prev_all = pairs.lagged(np.arange(len(pairs.order)), -1)
        has_prev = prev_all >= 0
        q = np.flatnonzero(has_prev)
        p = prev_all[q]
        beside = ((np.abs(d[q]) > config.corridor) & (np.abs(d[q]) <= config.band)
                  & (np.abs(d[p]) > config.corridor) & self.along[q]
                  & (self.rows.speed[self.q_other[q]] >= config.min_moving_speed))
        s_sorted = s[pairs.order]
        far_ahead = s_sorted >= config.pass_distance
        far_behind = s_sorted <= -config.pass_distance
        passing = q[beside & (s[p] > 0) & (s[q] <= 0)]
        passing = passing[pairs.seen_before(far_ahead, pairs.pos_in[passing])
                          & pairs.seen_after(far_behind, pairs.pos_in[passing])]
        passed_by = q[beside & (s[p] < 0) & (s[q] >= 0)]
        passed_by = passed_by[pairs.seen_before(far_behind, pairs.pos_in[passed_by])
                              & pairs.seen_after(far_ahead, pairs.pos_in[passed_by])]
        return passing, passed_by

    # -- the relation of every step --------------------------------------------------------
    def windows(self, pairs: np.ndarray, before: np.ndarray,
                after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The ego steps ``before`` to ``after`` around each pair's step, within its path."""
        st = self.q_step[pairs]
        lo = np.maximum(st - before, self.path_first[self.ego_path[st]])
        hi = np.minimum(st + after, self.path_last[self.ego_path][st] + 1)
        return lo, hi

    def pass_half(self, pairs: np.ndarray) -> np.ndarray:
        """Half a pass's steps: a pass length at the speed difference, within bounds."""
        config = self.config
        rel = np.abs(self.v_e[self.q_step[pairs]] - self.frame.v_along[pairs])
        h = np.rint(config.pass_length / np.maximum(rel, 0.1) * HZ).astype(np.int64)
        return np.clip(h, config.steps(config.min_run) // 2, 2 * STEPS_PER_SECOND)

    def relations(self, kin: Kinematics, a_dec: float, cut_in: np.ndarray,
                  cut_out: np.ndarray, passing: np.ndarray,
                  passed_by: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(m,) relation code and other agent's row of every ego step: following its
        leader, then the events painted over it in order of precedence (being overtaken,
        overtaking, lead braking, cut-out, cut-in)."""
        config, q_other, has_leader = self.config, self.q_other, self.has_leader
        leader_row = self.leader_row
        relation = np.zeros(self.m, np.int8)
        other = np.full(self.m, -1, np.int64)
        relation[has_leader] = FOLLOWING
        other[has_leader] = leader_row[has_leader]
        h = self.pass_half(passed_by)
        _paint(relation, other, *self.windows(passed_by, h, h + 1), BEING_OVERTAKEN,
               q_other[passed_by])
        h = self.pass_half(passing)
        _paint(relation, other, *self.windows(passing, h, h + 1), OVERTAKING,
               q_other[passing])
        # Lead Braking: the leader's acceleration over the centred 1 s window
        braking = has_leader.copy()
        braking[has_leader] = _smoothed(kin.a, kin, leader_row[has_leader],
                                        STEPS_PER_SECOND) <= a_dec
        relation[braking] = LEAD_BRAKING
        other[braking] = leader_row[braking]
        event = config.steps(config.event_duration)
        zero = np.zeros(len(cut_out), np.int64)
        _paint(relation, other, *self.windows(cut_out, zero, zero + event), CUT_OUT,
               q_other[cut_out])
        lead = np.full(len(cut_in), config.steps(config.cut_in_lead), np.int64)
        _paint(relation, other, *self.windows(cut_in, lead, event - lead), CUT_IN,
               q_other[cut_in])
        return relation, other

    def steps(self, relation: np.ndarray, other: np.ndarray,
              cut_in: np.ndarray) -> InteractionSteps:
        """The relations as runs of one (relation, other agent), stage 2's joining of runs
        shorter than 1 s and SPEC 7's guard for a still ego applied."""
        config, idx, ego_path = self.config, self.rows.index, self.ego_path
        has_leader = self.has_leader
        other_track = np.where(other >= 0, idx.track[np.maximum(other, 0)], -1)
        n_tracks = idx.n_tracks + 1
        code = relation.astype(np.int64) * n_tracks + other_track + 1
        seg_first = np.ones(self.m, bool)
        seg_first[1:] = ego_path[1:] != ego_path[:-1]
        runs = join_short_runs(find_runs(code, ego_path, seg_first),
                               config.steps(config.min_run))
        # SPEC 7's guard: an ego slower than min_ego_speed over a whole run (parked,
        # waiting) is neither overtaken nor cut in on; its leader's braking is not its concern
        top = np.maximum.reduceat(self.v_e, runs.start) if len(runs.start) else np.zeros(0)
        still = (top < config.min_ego_speed) & (runs.code // n_tracks > FOLLOWING)
        if still.any():
            base = np.where(has_leader, FOLLOWING, FREE_DRIVING).astype(np.int64)
            base_track = np.where(has_leader, idx.track[np.maximum(self.leader_row, 0)], -1)
            step_still = np.repeat(still, runs.length)
            code = np.repeat(runs.code, runs.length)
            code[step_still] = (base * n_tracks + base_track + 1)[step_still]
            runs = join_short_runs(find_runs(code, ego_path, seg_first),
                                   config.steps(config.min_run))
        code = np.repeat(runs.code, runs.length)
        relation = (code // n_tracks).astype(np.int8)
        other_track = code % n_tracks - 1
        # the other's row at each step (its track's row at that step; -1 where not recorded)
        other_row = _row_at(other_track, self.rows.key[self.ego_row], idx.track,
                            self.rows.key)
        return InteractionSteps(relation=relation, other_row=other_row,
                                other_track=other_track, leader_row=self.leader_row,
                                cut_in_step=self.q_step[cut_in],
                                cut_in_track=self.track[cut_in], runs=runs)


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
