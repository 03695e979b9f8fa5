"""A safety layer for an agent's ego on ``tap_bench/womd-v0``: its acceleration capped by the
braking an IDM driver needs for the road user in the ego's own swept box.

Shielding (Alshiekh et al. 2018, "Safe Reinforcement Learning via Shielding") and the safety
layer of Dalal et al. 2018 ("Safe Exploration in Continuous Action Spaces") put a correction
between a learned policy and the plant: the policy decides, the layer lets through what is
safe. Here the policy keeps its meta-actions (lane, target speed); at every simulated step
(10 Hz) the longitudinal acceleration its controller asks for is capped by IDM's
interaction term (Treiber, Hennecke & Helbing 2000) for the nearest road user in the ego's
swept box (:func:`~tap_bench.sim.womd_observation.swept_leader`: where the ego's box goes
over the next 3 s from its heading, speed and steering, not where the route is):

    cap = a * (1 - (s* / s)^2),  s* = s0 + max(0, v T + v dv / (2 sqrt(a b))),

with s the gap [m], v the ego's speed and dv the closing speed [m/s]; IDM's free-road term
is left to the policy. The cap never asks for more braking than ``emergency_braking``. With
no road user in the swept box the policy's acceleration goes through.

With ``predicted`` (off by default: the fifth ``ppo-womd`` trained without it) the layer
also caps for the road users whose own predicted motion meets the ego's way
(:func:`~tap_bench.sim.womd_observation.predicted_conflict`: the ego's box along its swept
poses at the speed the policy's acceleration gives, each crossing or oncoming road user's
box at its velocity and heading, compared at matched times within ``tolerance`` s over the
same 3 s): the same IDM term for a standing obstacle at the edge of that road user's zone
(a car turning across the ego's lane, or the ego turning across oncoming traffic). The
smaller of the two caps applies. With ``lanes`` too, road users are predicted along the
map's lanes under them and every branch of their successors, at their speed or up to
``other_acceleration`` faster (:func:`lane_conflict`), instead of at their velocity and
heading: a car whose lane turns across the ego's way is braked for before it turns. With
``hold`` too (off by default), a road user so found stays braked for until it has passed or
left the ego's way, stands clear of it, or is too near for the ego to stop before its ground
(:meth:`SafetyLayer.held_conflict`), not only while the predicted times match.

It is part of an agent's action space, chosen by the agent's own action config
(``{"type": "DiscreteMetaAction", ..., "safety_layer": true}``, or a mapping of
:class:`SafetyLayer`'s fields); an agent may drive with options it was not trained with (the
shipped ``ppo-womd`` seeds trained with the swept-box cap and drive with ``hold`` too). The
env's default action has none, and no other policy's ego gets one. :attr:`SafetyLayer.capped` and
:attr:`SafetyLayer.braked` count the simulated steps in which it changed the policy's
acceleration (and made it brake where the policy did not).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_observation import (
    CROSS_MIN_ANGLE,
    MIN_CROSS_SPEED,
    NO_LEADER,
    PREDICT_TOLERANCE,
    SWEPT_HORIZON,
    SWEPT_MARGIN,
    SWEPT_STEP,
    Leader,
    boxes_overlap,
    pose_times,
    swept_poses,
)

__all__ = ["HOLD_MISSES", "LANE_ACCELERATION", "LANE_ANGLE", "LANE_BRANCHES", "LANE_OFF",
           "LANE_SAMPLE", "SafetyLayer", "lane_conflict", "lane_meetings", "lane_paths",
           "safety_layer"]

LANE_ACCELERATION = 1.0  # [m/s^2] a road user's predicted speed may grow this fast
LANE_SAMPLE = 1.0  # [m] a road user's predicted path is sampled this often
LANE_OFF = 1.0  # [m] beyond half its lane's width from the centre a road user is off it
LANE_ANGLE = math.radians(45.0)  # [rad] heading this far off its lane's: not following it
LANE_BRANCHES = 8  # at most this many branches of successor lanes per road user
LANE_DEPTH = 6  # ... each at most this many lanes on from the one under it
LANE_BLEND = 5.0  # [m] a road user off its lane's centre joins it over this distance
HOLD_MISSES = 5  # simulated steps a held road user's lanes miss the ego's way: released


@dataclasses.dataclass
class SafetyLayer:
    """IDM's interaction term as a cap on the ego's acceleration (see the module docstring).

    Attributes:
        max_acceleration: IDM's a [m/s^2].
        comfortable_braking: IDM's b [m/s^2] (positive).
        emergency_braking: the most braking the cap asks for [m/s^2] (positive).
        time_gap: IDM's T [s].
        min_gap: IDM's s0, bumper to bumper [m].
        predicted: also cap for the road users whose predicted motion meets the ego's way.
        tolerance: with ``predicted``, how much earlier or later [s] a road user may reach
            the place the ego is at and still count.
        lanes: with ``predicted``, road users are predicted along the map's lanes under
            them and every branch of their successors (:func:`lane_conflict`), not at
            their velocity and heading.
        other_acceleration: with ``lanes``, how fast [m/s^2] a road user's speed may grow
            (0: at its speed).
        hold: with ``lanes``, a road user once braked for stays a conflict until it has
            passed or left the ego's way (:meth:`held_conflict`), not only while the
            predicted times match.
        hold_point: with ``hold``, a held road user is braked for where the ego would have
            stopped for it when it was found (or nearer, where the ground of its lanes now
            meets the ego's way nearer and the ego can still stop before it), not where
            the nearest of all its lanes' ground meets the ego's way.
        steps: simulated steps the layer judged (an episode's, since :meth:`reset`).
        capped: steps in which it lowered the policy's acceleration.
        braked: steps in which it made the ego brake (the cap < 0) where the policy asked
            for no braking (an acceleration >= 0).
    """

    max_acceleration: float = 3.0
    comfortable_braking: float = 3.0
    emergency_braking: float = 8.0
    time_gap: float = 1.0
    min_gap: float = 2.0
    predicted: bool = False
    tolerance: float = PREDICT_TOLERANCE
    lanes: bool = False
    other_acceleration: float = LANE_ACCELERATION
    hold: bool = False
    hold_point: bool = False
    steps: int = dataclasses.field(default=0, compare=False)
    capped: int = dataclasses.field(default=0, compare=False)
    braked: int = dataclasses.field(default=0, compare=False)
    foreseen: int = dataclasses.field(default=0, compare=False)

    def __post_init__(self) -> None:
        for flag in ("predicted", "lanes", "hold", "hold_point"):
            if not isinstance(getattr(self, flag), bool):
                raise ParameterError(f"safety_layer.{flag}", getattr(self, flag),
                                     "true or false")
        value = self.other_acceleration
        if (isinstance(value, bool) or not isinstance(value, int | float)
                or not math.isfinite(value) or value < 0):
            raise ParameterError("safety_layer.other_acceleration", value, "a number >= 0")
        for field in ("max_acceleration", "comfortable_braking", "emergency_braking",
                      "time_gap", "min_gap", "tolerance"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, int | float)
                    or not math.isfinite(value) or value <= 0):
                raise ParameterError(f"safety_layer.{field}", value, "a number > 0")
        if self.hold and not (self.predicted and self.lanes):
            raise ParameterError("safety_layer.hold", self.hold,
                                 "false, or true with predicted and lanes true")
        if self.hold_point and not self.hold:
            raise ParameterError("safety_layer.hold_point", self.hold_point,
                                 "false, or true with hold true")
        self._last = None  # the simulated step last judged (a decision acts twice in it)
        # id() of the road users held: (simulated steps since their lanes last met the
        # ego's way, where the ego would stop for them then (x, y) [m])
        self._held: dict[int, tuple[int, np.ndarray]] = {}
        self._passing: set[int] = set()  # id() of those the ego can no longer stop for

    def reset(self) -> None:
        """Zero the counts (a new episode)."""
        self.steps = self.capped = self.braked = self.foreseen = 0
        self._last = None
        self._held, self._passing = {}, set()

    def cap(self, speed: float, gap: float, closing: float) -> float:
        """The most acceleration [m/s^2] allowed at ``speed`` [m/s] with a road user
        ``gap`` m ahead closing at ``closing`` m/s (inf: no road user, gap inf)."""
        if not math.isfinite(gap):
            return math.inf
        a, b = self.max_acceleration, self.comfortable_braking
        v = max(speed, 0.0)
        wanted = self.min_gap + max(0.0, v * self.time_gap + v * closing / (2 * math.sqrt(a * b)))
        return max(a * (1.0 - (wanted / max(gap, 0.1)) ** 2), -self.emergency_braking)

    def apply(self, ego: Any, others: list[Any], step: int | None = None) -> None:
        """Cap ``ego.action["acceleration"]`` (set by its controller this step) for the
        nearest of ``others`` in its swept box (and, with :attr:`predicted`, for the nearest
        predicted conflict); count the step once (``step``: the road's clock, a decision's
        two acts in one step count once)."""
        from tap_bench.sim.womd_observation import predicted_conflict, swept_leader

        lead = swept_leader(ego, others)
        limit = self.cap(float(ego.speed), lead.gap, lead.closing)
        wanted = float(ego.action["acceleration"])
        foreseen = False
        if self.hold:
            road = getattr(ego, "road", None)
            conflict = self.held_conflict(ego, others, getattr(road, "network", None), wanted,
                                          step is None or step != self._last)
        elif self.predicted and self.lanes:
            road = getattr(ego, "road", None)
            conflict = lane_conflict(ego, others, getattr(road, "network", None), wanted,
                                     self.tolerance, max_acceleration=self.max_acceleration,
                                     other_acceleration=self.other_acceleration)
        elif self.predicted:
            conflict = predicted_conflict(ego, others, wanted, self.tolerance,
                                          max_acceleration=self.max_acceleration)
        if self.predicted:
            ahead = self.cap(float(ego.speed), conflict.gap, conflict.closing)
            foreseen = ahead < min(limit, wanted)
            limit = min(limit, ahead)
        new = step is None or step != self._last
        self._last = step
        if new:
            self.steps += 1
        if limit < wanted:
            ego.action["acceleration"] = limit
            if new:
                self.capped += 1
                self.braked += bool(limit < 0 <= wanted)
                self.foreseen += foreseen

    def held_conflict(self, ego: Any, others: list[Any], network: Any,
                      acceleration: float, new: bool = True) -> Leader:
        """The nearest conflict to brake for with :attr:`hold` (gap [m], closing [m/s];
        ``new``: a new simulated step, not a decision's second act in the same one).

        A road user whose lanes meet the ego's way at a matched time (:func:`lane_conflict`)
        is held: from then on it is braked for (IDM's term for a standing obstacle where
        the ego's way first meets the ground its box covers from where it is now on along
        its branches, :func:`lane_meetings`' ``way``), whether or not the times still
        match, until it is released: it is gone (not in ``others``), its branches have not
        met the ego's way for :data:`HOLD_MISSES` simulated steps (it has passed the
        crossing, or taken a branch away from it; meanwhile the ego stops where it would
        have stopped for it, projected on its heading), it heads within
        :data:`~tap_bench.sim.womd_observation.CROSS_MIN_ANGLE` of the ego's way (the swept
        box's), or it stands (slower than :data:`~tap_bench.sim.womd_observation.
        MIN_CROSS_SPEED`) with its box at least :attr:`min_gap` clear of the ego's way. A
        road user, held or newly found, that the ego can no longer stop for (its ground
        within the ego's stopping distance at :attr:`emergency_braking`, or already meeting
        the ego's box) is not braked for while it stays in the ego's way: braking would stop
        the ego in the crossing. With :attr:`hold_point` a held road user is braked for
        where the ego would have stopped for it when it was found, unless its ground now
        meets the ego's way nearer and the ego can still stop before that."""
        index = {id(other): i for i, other in enumerate(others)}
        watched = [index[key] for key in [*self._held, *self._passing] if key in index]
        timed, way = lane_meetings(ego, others, network, acceleration, self.tolerance,
                                   max_acceleration=self.max_acceleration,
                                   other_acceleration=self.other_acceleration,
                                   watched=watched)
        v = max(float(ego.speed), 0.0)
        stop = v * v / (2 * self.emergency_braking)  # [m] the ego's shortest stop
        p = np.asarray(ego.position, float)[:2]
        u = np.array([math.cos(float(ego.heading)), math.sin(float(ego.heading))])
        held: dict[int, tuple[int, np.ndarray]] = {}
        passing: set[int] = set()
        gap = math.inf
        for i, other in enumerate(others):
            key = id(other)
            if key in self._passing:
                if math.isfinite(timed[i]) or math.isfinite(way[i]):
                    passing.add(key)
                continue
            misses = 0
            if key in self._held and not _released(ego, other, self.min_gap):
                entry = float(way[i])
                misses, point = self._held[key]
                kept = float((point - p) @ u)  # [m] to where it would have stopped
                if not math.isfinite(entry):
                    misses += new
                    entry = kept if misses < HOLD_MISSES else math.inf
                else:
                    misses = 0
                    if not self.hold_point:
                        point = p + entry * u
                    elif entry > kept or entry - SWEPT_STEP < stop:
                        entry = kept
            else:
                entry = float(timed[i])
                point = p + entry * u if math.isfinite(entry) else p
            if not math.isfinite(entry):
                continue
            if entry <= 0.0 or entry - SWEPT_STEP < stop:
                passing.add(key)
                continue
            held[key] = (misses, point)
            gap = min(gap, entry - SWEPT_STEP)
        self._held, self._passing = held, passing
        return Leader(gap, v) if math.isfinite(gap) else NO_LEADER


def _released(ego: Any, other: Any, clear: float) -> bool:
    """Whether a held road user ``other`` goes the ego's way (heading within
    :data:`~tap_bench.sim.womd_observation.CROSS_MIN_ANGLE` of the ego's) or stands
    (slower than :data:`~tap_bench.sim.womd_observation.MIN_CROSS_SPEED`) with its box,
    ``clear`` m larger on each side, off the ego's swept box (``SWEPT_MARGIN`` wider)."""
    off = abs((float(other.heading) - float(ego.heading) + math.pi) % (2 * math.pi) - math.pi)
    if off < CROSS_MIN_ANGLE:
        return True
    if float(np.hypot(*np.asarray(other.velocity, float)[:2])) >= MIN_CROSS_SPEED:
        return False
    _, xy, heading = swept_poses(ego)
    where = np.asarray(other.position, float)[:2][None, None]
    return not boxes_overlap(xy, heading, float(ego.LENGTH) / 2,
                             float(ego.WIDTH) / 2 + SWEPT_MARGIN, where,
                             np.array([float(other.heading)]),
                             np.array([float(other.LENGTH) / 2 + clear]),
                             np.array([float(other.WIDTH) / 2 + clear])).any()


def lane_paths(network: Any, position: np.ndarray, heading: float, length: float
               ) -> list[np.ndarray]:
    """Where a road user at ``position`` (x, y [m]) heading ``heading`` [rad] goes along the
    map: one polyline (m, 2) [m] per branch, from its position along the lane under it and
    on through every branch of that lane's successors (:data:`LANE_BRANCHES` at most,
    :data:`LANE_DEPTH` lanes on), each at least ``length`` m long (continued straight past a
    dead end); it joins the centre line :data:`LANE_BLEND` m on. A road user on no lane
    (none in ``network``, farther than half the lane's width + :data:`LANE_OFF` from its
    centre, or heading more than :data:`LANE_ANGLE` off it) goes straight on along its
    heading.

    ``network`` answers ``get_closest_lane_index(position, heading)``, ``get_lane(index)``
    (lanes with ``arrays`` (px, py, tx, ty, s), ``width``, ``length``,
    ``local_coordinates``, ``heading_at``) and ``successors(index)``
    (:class:`~tap_bench.sim.womd_road.WomdNetwork`); None: straight on."""
    p = np.asarray(position, dtype=float)[:2]
    ahead = np.array([math.cos(heading), math.sin(heading)])
    straight = [np.array([p, p + max(length, 1.0) * ahead])]
    if network is None or not hasattr(network, "successors"):
        return straight
    index = network.get_closest_lane_index(p, heading)
    if index is None:
        return straight
    lane = network.get_lane(index)
    lon, lat = lane.local_coordinates(p)
    off = abs((lane.heading_at(lon) - heading + math.pi) % (2 * math.pi) - math.pi)
    if abs(lat) > lane.width / 2 + LANE_OFF or off > LANE_ANGLE or lon > lane.length + LANE_OFF:
        return straight
    paths: list[np.ndarray] = []
    # lane, from [m along it], pieces, length, depth; from its position the path joins the
    # lane's centre LANE_BLEND m on
    stack = [(index, lon + LANE_BLEND, [p[None]], LANE_BLEND, 0)]
    while stack:
        index, start, pieces, done, depth = stack.pop()
        lane = network.get_lane(index)
        px, py, _, _, s = lane.arrays
        beyond = s > start + 1e-6
        pieces = [*pieces, np.column_stack([px[beyond], py[beyond]])]
        done += max(float(lane.length) - start, 0.0)
        exits = network.successors(index) if done < length and depth < LANE_DEPTH else []
        room = LANE_BRANCHES - len(paths) - len(stack)
        if exits and room > 0:
            for nxt in exits[:room]:
                stack.append((nxt, 0.0, pieces, done, depth + 1))
            continue
        line = np.concatenate(pieces)
        step = np.hypot(*np.diff(line, axis=0).T)
        line = line[np.r_[True, step > 1e-6]]  # a lane's end and the next's start once
        if len(line) < 2:
            line = straight[0]
        run = float(np.hypot(*np.diff(line, axis=0).T).sum())
        if run < length:  # a dead end: straight on along its last segment
            d = line[-1] - line[-2]
            line = np.vstack([line, line[-1] + d / np.hypot(*d) * (length - run)])
        paths.append(line)
    return paths


_CACHE_SIZE = 20_000  # road users' predicted samples kept per network


def _samples(network: Any, position: np.ndarray, heading: float, speed: float,
             length: float, width: float, tolerance: float, acceleration: float, span: float
             ) -> tuple[Any, ...]:
    """A road user's boxes along its :func:`lane_paths` (see :func:`lane_conflict`): (pos
    (J, 2) [m], heading (J,) [rad], half length, half width (J,) [m], earliest and latest
    time there (J,) [s], arc length from its position (J,) [m], the number of samples of
    each branch). Kept on the network by the
    road user's state: a logged road user is at the same place in every episode of its
    scene."""
    key = (float(position[0]), float(position[1]), heading, speed, length, width, tolerance,
           acceleration, span)
    cache = None
    if network is not None:
        cache = network.__dict__.setdefault("_lane_samples", {})
        found = cache.get(key)
        if found is not None:
            return found
    o = np.asarray(position, float)
    a = acceleration
    far = speed * span + 0.5 * a * span**2
    d = np.arange(-speed * tolerance, far + 1e-9, LANE_SAMPLE)  # (j,) arc lengths [m]
    if a > 0:
        early = (np.sqrt(np.maximum(speed**2 + 2 * a * d, 0.0)) - speed) / a
        early = np.where(d < 0, d / speed, early)
    else:
        early = d / speed
    lo, hi = early - tolerance, d / speed + tolerance
    back_of = d < 0  # behind its position: straight back along its heading
    pos, head = [], []
    lines = lane_paths(network, o, heading, far)
    for line in lines:
        seg = np.diff(line, axis=0)
        run = np.concatenate([[0.0], np.cumsum(np.hypot(*seg.T))])
        k = np.clip(np.searchsorted(run, d, side="right") - 1, 0, len(seg) - 1)
        u = seg[k] / np.hypot(*seg[k].T)[:, None]
        u[back_of] = (math.cos(heading), math.sin(heading))
        pos.append(np.where(back_of[:, None], o + d[:, None] * u,
                            line[k] + (d - run[k])[:, None] * u))
        head.append(np.arctan2(u[:, 1], u[:, 0]))
    n = len(lines) * len(d)
    found = (np.concatenate(pos), np.concatenate(head),
             np.full(n, length / 2 + LANE_SAMPLE / 2), np.full(n, width / 2),
             np.tile(lo, len(lines)), np.tile(hi, len(lines)), np.tile(d, len(lines)),
             [len(d)] * len(lines))
    if cache is not None:
        if len(cache) >= _CACHE_SIZE:
            cache.clear()
        cache[key] = found
    return found


def lane_conflict(ego: Any, others: list[Any], network: Any, acceleration: float = 0.0,
                  tolerance: float = PREDICT_TOLERANCE, horizon: float = SWEPT_HORIZON,
                  max_acceleration: float = 3.0,
                  other_acceleration: float = LANE_ACCELERATION,
                  margin: float = SWEPT_MARGIN) -> Leader:
    """The nearest place on the ego's way where a road user predicted along the map's lanes
    meets it at a matched time (the seventh ``ppo-womd``'s safety layer).

    The ego's box goes along its swept poses (:func:`~tap_bench.sim.womd_observation.
    swept_poses`) at the speed its ``acceleration`` gives (:func:`~tap_bench.sim.
    womd_observation.pose_times`). Each road user moving at :data:`~tap_bench.sim.
    womd_observation.MIN_CROSS_SPEED` or more whose heading is at least
    :data:`~tap_bench.sim.womd_observation.CROSS_MIN_ANGLE` off the ego's (those going the
    ego's way are the swept box's) goes along each of its :func:`lane_paths`: its box is
    placed every :data:`LANE_SAMPLE` m along the branch (heading along it, half a sample
    longer at each end), from ``tolerance`` s of its speed behind it to as far as it can go
    in ``horizon`` + ``tolerance`` s. Its centre is at arc length ``d`` between the time at
    its speed ``v`` with ``other_acceleration`` a (``(sqrt(v^2 + 2 a d) - v) / a``) less
    ``tolerance`` and ``d / v`` plus ``tolerance``. A branch conflicts when one of its boxes
    overlaps the ego's box (``margin`` m wider on each side) at a pose the ego reaches
    within ``horizon`` at a time within that interval. The ego must then stay out of the
    whole branch's ground (its zone): the gap is the distance its centre goes to the first
    pose whose box meets that zone (less one :data:`~tap_bench.sim.womd_observation.
    SWEPT_STEP`), the zone standing still (closing = the ego's speed). A branch whose zone
    already meets the ego's box where it is now is left out (braking cannot clear it).

    Args:
        ego: the ego vehicle (as :func:`~tap_bench.sim.womd_observation.predicted_conflict`'s).
        others: the road users (``position``, ``heading``, ``velocity``, ``LENGTH``,
            ``WIDTH``).
        network: the map's lanes (see :func:`lane_paths`); None: straight on.
        acceleration: [m/s^2] the ego's asked-for acceleration.
        tolerance: [s] the time margin on each side of a matched time.
        horizon: [s] how far ahead in time the ego is advanced.
        max_acceleration: [m/s^2] the most acceleration the ego's prediction takes.
        other_acceleration: [m/s^2] the most a road user's speed grows (>= 0).
        margin: [m] added to the ego's half width.

    Returns:
        The zone's gap and closing speed; ``NO_LEADER`` with no conflict.
    """
    timed, _ = lane_meetings(ego, others, network, acceleration, tolerance, horizon,
                             max_acceleration, other_acceleration, margin)
    if not np.isfinite(timed).any():
        return NO_LEADER
    return Leader(max(float(timed.min()) - SWEPT_STEP, 0.0), max(float(ego.speed), 0.0))


def lane_meetings(ego: Any, others: list[Any], network: Any, acceleration: float = 0.0,
                  tolerance: float = PREDICT_TOLERANCE, horizon: float = SWEPT_HORIZON,
                  max_acceleration: float = 3.0,
                  other_acceleration: float = LANE_ACCELERATION,
                  margin: float = SWEPT_MARGIN, watched: Any = ()
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Where each road user's lanes meet the ego's way (:func:`lane_conflict`'s test, per
    road user).

    Returns (timed, way), each (len(others),) [m along the ego's way, from its centre]:
    ``timed`` the ego's distance to the first of its poses whose box meets the ground of a
    branch that meets it at a matched time (:func:`lane_conflict`: road users that cross or
    come the other way, at :data:`~tap_bench.sim.womd_observation.MIN_CROSS_SPEED` or more;
    inf where none; a branch whose ground already meets the ego's box is left out); ``way``,
    for the road users of ``watched`` (indexes into ``others``; others inf), the same
    distance to the ground its box covers from where it is now on along any of its branches,
    at any time (0: that ground meets the ego's box where it is now; inf: none of it meets
    the ego's way within :data:`~tap_bench.sim.womd_observation.SWEPT_HORIZON` s of the
    ego's speed, or :data:`~tap_bench.sim.womd_observation.SWEPT_MIN_DISTANCE` m). A watched
    road user slower than ``MIN_CROSS_SPEED`` is placed along its branches as far as one at
    that speed goes. The other arguments are :func:`lane_conflict`'s."""
    n = len(others)
    timed, way = np.full(n, np.inf), np.full(n, np.inf)
    if not n:
        return timed, way
    s, xy, heading = swept_poses(ego)
    p = np.asarray(ego.position, float)
    h = float(ego.heading)
    el, ew = float(ego.LENGTH) / 2, float(ego.WIDTH) / 2 + margin
    a = float(other_acceleration)
    span = horizon + tolerance
    vel = np.array([np.asarray(v.velocity, float) for v in others]).reshape(-1, 2)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    oh = np.array([float(v.heading) for v in others])
    length = np.array([float(v.LENGTH) for v in others])
    width = np.array([float(v.WIDTH) for v in others])
    at = np.array([np.asarray(v.position, float)[:2] for v in others]).reshape(-1, 2)
    off = np.abs((oh - h + np.pi) % (2 * np.pi) - np.pi)
    placed = np.maximum(speed, MIN_CROSS_SPEED)  # a watched road user standing: placed so
    far = placed * span + 0.5 * a * span**2  # [m] the farthest each can go
    near_ego = np.hypot(*(at - p).T) <= float(s[-1]) + far + length + width + 2 * (el + ew)
    fresh = (speed >= MIN_CROSS_SPEED) & (off >= CROSS_MIN_ANGLE) & near_ego
    watch = np.zeros(n, bool)
    watch[np.asarray(list(watched), int)] = True
    watch &= near_ego
    keep = np.flatnonzero(fresh | watch)
    if not len(keep):
        return timed, way
    found = [_samples(network, at[i], float(oh[i]), float(placed[i]), float(length[i]),
                      float(width[i]), tolerance, a, span) for i in keep.tolist()]
    groups = [n for one in found for n in one[-1]]
    owner = np.repeat(keep, [len(one[-1]) for one in found])  # (G,) each branch's road user
    pos, head, half_l, half_w, t_lo, t_hi, arc = (np.concatenate([one[j] for one in found])
                                                  for j in range(7))
    # broad phase: samples outside the ego's poses' bounds, then those whose centre comes
    # near no ego pose, cannot overlap
    radius = math.hypot(el, ew) + np.hypot(half_l, half_w) + SWEPT_STEP
    lo_xy, hi_xy = xy.min(axis=0), xy.max(axis=0)
    inside = np.flatnonzero(((pos >= lo_xy - radius[:, None])
                             & (pos <= hi_xy + radius[:, None])).all(axis=1))
    if not len(inside):
        return timed, way
    near = (((pos[inside][None] - xy[:, None]) ** 2).sum(axis=-1)
            <= radius[inside] ** 2).any(axis=0)
    if not near.any():
        return timed, way
    cols = inside[near]
    overlap = boxes_overlap(xy, heading, el, ew, pos[cols][None], head[cols], half_l[cols],
                             half_w[cols])  # (k, J')
    t_pose, reached = pose_times(ego, s, acceleration, horizon, max_acceleration)
    matched = (overlap & reached[:, None] & (t_pose[:, None] >= t_lo[cols])
               & (t_pose[:, None] <= t_hi[cols])).any(axis=0)  # (J',)
    first = np.where(overlap, s[:, None], np.inf).min(axis=0)  # (J',) the ego meets it [m]
    group = np.repeat(np.arange(len(groups)), groups)[cols]
    g = len(groups)
    meets = np.zeros(g, bool)
    np.logical_or.at(meets, group, matched)
    entry = np.full(g, np.inf)
    np.minimum.at(entry, group, first)
    entry = np.where(meets & (entry > 0.0) & fresh[owner], entry, np.inf)
    np.minimum.at(timed, owner, entry)
    ahead = np.full(g, np.inf)  # from where it is now on, at any time
    np.minimum.at(ahead, group, np.where(arc[cols] >= 0.0, first, np.inf))
    np.minimum.at(way, owner, np.where(watch[owner], ahead, np.inf))
    return timed, way


def safety_layer(setting: Any) -> SafetyLayer | None:
    """The layer an action config's ``safety_layer`` asks for: None for false or missing,
    the defaults for true, a mapping of :class:`SafetyLayer`'s fields for others.

    Raises:
        ParameterError: neither a flag nor a mapping of known fields (names them).
    """
    if setting is None or setting is False:
        return None
    if setting is True:
        return SafetyLayer()
    fields = [f.name for f in dataclasses.fields(SafetyLayer)
              if f.name not in ("steps", "capped", "braked", "foreseen")]
    if not isinstance(setting, Mapping) or any(key not in fields for key in setting):
        raise ParameterError("action.safety_layer", setting,
                             f"true, false or a mapping of {', '.join(fields)}")
    return SafetyLayer(**dict(setting))
