"""What an RL agent on ``tap_bench/womd-v0`` observes: the traffic and its route.

``{"type": "KinematicsRoute"}`` (the env's default observation) is highway-env's
``Kinematics`` observation (the ego and the nearest road users, relative, normalised;
same parameters, computed as :mod:`tap_bench.sim.observation` does) followed by the
ego's route, the lanes the logged ego drove (SPEC section 8), seen from the ego. It is one
flat float32 vector (an SB3 ``MlpPolicy`` reads it as it is):

- ``[0, V*F)``: the Kinematics array (V = ``vehicles_count`` rows of F = ``len(features)``
  columns), row by row, as highway-env computes it;
- then :data:`ROUTE_FEATURES` + 2 x ``route_points`` route values, each in [-1, 1]:

  ``route_x_k, route_y_k`` (k = 1 .. ``route_points``): the point of the route
  ``k * route_spacing`` metres ahead of the ego along the route, in the ego's frame (x
  forward, y to the driver's left), divided by the horizon ``route_points * route_spacing``
  [m] and clipped; the route continues straight on past its last lane.
  ``offset``: the ego's signed distance from its route lane's centre line (positive: the
  lane centre is to the driver's left), divided by :data:`OFFSET_SCALE` [m], clipped.
  ``sin_heading, cos_heading``: the route lane's heading at the ego relative to the ego's
  heading (positive sine: the lane turns to the left).
  ``change_distance``: the distance along the route to its next lane change (the logged
  driver changed lanes there), divided by the horizon and clipped (1: none within it).
  ``change_side``: +1 the next lane change goes left, -1 right, 0 none within the horizon.
  ``on_route``: 1 when the ego's lane is one of the route's, else 0.

- with ``leader`` (the env's default), then :data:`LEADER_FEATURES`, each in [-1, 1]:

  ``speed``: the ego's speed divided by :data:`SPEED_SCALE` [m/s].
  ``lead_gap``: the gap [m] (bumper to bumper, along the path) to the nearest road user in
  the ego's path ahead, divided by the horizon and clipped (1: none within it). The path is
  the polyline from the ego through the route's points; a road user is in it when its
  centre is within half the ego's width plus half its own of the polyline (so a car
  crossing the route ahead counts once it is in the way, a car in the next lane does not);
  with ``leader_corners`` (off by default) also when a corner of its box is within half the
  ego's width of the polyline (a car parked half in the lane, a car at an angle: the gap is
  then to that corner); with ``leader_swept`` (off by default) also the nearest road user
  in the ego's own swept box (:func:`swept_leader`: where the ego's box goes over the next
  :data:`SWEPT_HORIZON` seconds from its heading, speed and steering, whatever the route
  says), the nearer of the two: a car standing beside the route where the ego, off the
  route's centre after a turn, is heading, a car cutting in.
  ``lead_closing``: how fast the gap shrinks [m/s] (the ego's speed minus the leader's
  velocity along the path), divided by :data:`CLOSING_SCALE`, clipped; 0 with no leader.
  ``lead_inverse_ttc``: the inverse time to collision, closing speed / gap [1/s] (0 when
  the gap opens or there is no leader), divided by :data:`INVERSE_TTC_SCALE` and clipped
  (1: a collision within 0.5 s).

  Why: the Kinematics rows give the others' positions and velocities in the map's axes
  (not the ego's), normalised by +-200 m and +-80 m/s, so a car 10 m ahead closing at
  5 m/s moves its row by 0.05 and 0.06: the first agent trained on real scenes kept its
  speed into the car ahead (8 of its 10 at-fault collisions, docs/agents.md). These say it
  in the ego's own terms, at the scale that matters for following.

- with ``crossing`` (off by default), then :data:`CROSSING_COUNT` x :data:`CROSSING_FEATURES`,
  each in [0, 1], for the road users whose way crosses the ego's path ahead, nearest
  crossing point first:

  ``cross_distance``: the distance along the path from the ego to the point where the road
  user's way crosses it, divided by the horizon (1: no such road user).
  ``cross_ego_time``: the time the ego needs to get its front there at its current speed
  [s], divided by :data:`CROSS_HORIZON` and clipped (1: not within it, or no road user).
  ``cross_other_time``: the time the road user needs to get there at its current velocity
  [s], divided by :data:`CROSS_HORIZON` (1: no road user).

  A road user's way is the straight line it covers at its current velocity in
  :data:`CROSS_HORIZON` seconds; it crosses the path where that line meets the path at an
  angle of at least :data:`CROSS_MIN_ANGLE` (a car following the ego or driving beside it
  along its lane does not cross it). Why: the leader is seen only once it is in the path,
  and a car crossing the route is in it only a moment before the collision; the second and
  third agents trained on real scenes drove into such a car on a held-out scene as lane
  keeping does (docs/agents.md). The two times say who gets there first.

The route lane the ego is on is tracked along the route (never backwards), so a route that
comes back to a lane is followed in order. Lane changes take place where the map names the
lanes as neighbours, at the first point of that stretch ahead of the ego (the route's points
then follow the new lane), as the IDM controller does.
"""

from __future__ import annotations

import functools
import inspect
import math
from typing import Any, NamedTuple

import numba
import numpy as np
from gymnasium import spaces

from tap_bench.errors import did_you_mean
from tap_bench.sim.observation import FastKinematicObservation

__all__ = ["CLOSING_SCALE", "CROSSING_COUNT", "CROSSING_FEATURES", "CROSS_HORIZON",
           "CROSS_MIN_ANGLE", "Crossing", "INVERSE_TTC_SCALE", "LEADER_FEATURES", "Leader",
           "MIN_CROSS_SPEED", "NO_LEADER", "OBSERVATION_TYPE", "OFFSET_SCALE",
           "PREDICT_TOLERANCE", "ROUTE_FEATURES", "RouteObservation", "SPEED_SCALE",
           "SWEPT_HORIZON", "SWEPT_MARGIN", "SWEPT_STEP", "boxes_overlap", "pose_times",
           "predicted_conflict", "route_feature_names", "swept_leader", "swept_poses"]

OBSERVATION_TYPE = "KinematicsRoute"
"""The ``observation`` config's ``type`` of :class:`RouteObservation`."""

ROUTE_FEATURES = ("offset", "sin_heading", "cos_heading", "change_distance", "change_side",
                  "on_route")
"""The route values after the route points (see the module docstring)."""

OFFSET_SCALE = 5.0  # [m] the lateral offset is divided by this (clipped to [-1, 1])

LEADER_FEATURES = ("speed", "lead_gap", "lead_closing", "lead_inverse_ttc")
"""The values after the route's with ``leader`` (see the module docstring)."""

SPEED_SCALE = 30.0  # [m/s] the ego's speed is divided by this
CLOSING_SCALE = 10.0  # [m/s] the closing speed to the leader is divided by this
INVERSE_TTC_SCALE = 2.0  # [1/s] the inverse time to collision is divided by this

CROSSING_FEATURES = ("cross_distance", "cross_ego_time", "cross_other_time")
"""The values of one crossing road user with ``crossing`` (see the module docstring)."""
CROSSING_COUNT = 2  # crossing road users observed (nearest crossing point first)
CROSS_HORIZON = 5.0  # [s] a road user's way: where its velocity takes it in this time
CROSS_MIN_ANGLE = math.radians(15.0)  # [rad] a way meeting the path at less does not cross
MIN_CROSS_SPEED = 0.5  # [m/s] a road user slower than this crosses nobody's path

SWEPT_HORIZON = 3.0  # [s] the ego's swept box: where it goes in this time at its speed
SWEPT_MIN_DISTANCE = 10.0  # [m] ... and at least this far (a slow or standing ego)
SWEPT_STEP = 0.5  # [m] the swept box is the ego's box placed every this many metres
SWEPT_MARGIN = 0.25  # [m] the swept box is this much wider than the ego on each side
SWEPT_MAX_TURN = math.pi / 2  # [rad] the ego's turn is followed this far, then straight on
PREDICT_TOLERANCE = 1.0  # [s] a predicted meeting counts this much earlier or later
PREDICT_STEP = 0.1  # [s] the ego's predicted motion is stepped by this


class Leader(NamedTuple):
    """The nearest road user in the ego's path ahead (:meth:`RouteObservation.leader`).

    Attributes:
        gap: bumper-to-bumper distance along the path [m] (inf: none within the horizon).
        closing: how fast the gap shrinks [m/s] (0 with no leader; negative: it opens).
    """

    gap: float
    closing: float

    @property
    def inverse_ttc(self) -> float:
        """Closing speed / gap [1/s], 0 when the gap opens or there is no leader (a gap of
        10 cm or less counts as 10 cm)."""
        if not math.isfinite(self.gap) or self.closing <= 0:
            return 0.0
        return self.closing / max(self.gap, 0.1)


NO_LEADER = Leader(math.inf, 0.0)


class Crossing(NamedTuple):
    """A road user whose way crosses the ego's path ahead (:meth:`RouteObservation.
    crossings`).

    Attributes:
        distance: along the path from the ego to the crossing point [m].
        ego_time: the ego's time to get its front there at its current speed [s] (inf when
            it stands still).
        other_time: the road user's time to get there at its current velocity [s].
    """

    distance: float
    ego_time: float
    other_time: float


def route_feature_names(route_points: int, leader: bool = False,
                        crossing: bool = False) -> list[str]:
    """Names of the route part of the vector (and the leader's, with ``leader``, and the
    crossing road users', with ``crossing``), in order."""
    points = [f"route_{axis}_{k}" for k in range(1, route_points + 1) for axis in "xy"]
    crossers = [f"{name}_{k}" for k in range(1, CROSSING_COUNT + 1)
                for name in CROSSING_FEATURES] if crossing else []
    return [*points, *ROUTE_FEATURES, *(LEADER_FEATURES if leader else ()), *crossers]


_ROUTE_OPTIONS = ("route_points", "route_spacing", "leader", "crossing", "leader_corners",
                  "leader_swept")


@functools.cache
def _kinematics_options() -> frozenset[str]:
    """The named parameters of highway-env's Kinematics observation (its ``__init__``), read
    once per process (the signatures do not change)."""
    names: set[str] = set()
    for cls in FastKinematicObservation.__mro__:
        init = cls.__dict__.get("__init__")
        if init is not None:
            names |= {p.name for p in inspect.signature(init).parameters.values()
                      if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    return frozenset(names - {"self", "env"})


class RouteObservation(FastKinematicObservation):
    """highway-env's Kinematics observation (flattened) followed by the ego's route (see the
    module docstring for the layout).

    Args:
        env: the ``tap_bench/womd-v0`` highway-env environment (``env.route``: the route's
            lane indexes).
        route_points: route points observed ahead (>= 1).
        route_spacing: metres between them along the route (> 0).
        leader: append :data:`LEADER_FEATURES` (the road user in the ego's path ahead).
        leader_corners: a road user is also in the path when a corner of its box is within
            half the ego's width of it (a car parked half in the lane, a car turning in).
        crossing: append :data:`CROSSING_COUNT` x :data:`CROSSING_FEATURES` (the road users
            whose way crosses the ego's path ahead).
        leader_swept: the leader is the nearer of the route path's and the ego's own swept
            box's (:func:`swept_leader`).
        **kwargs: highway-env's Kinematics parameters (``vehicles_count``, ``features``...).
    """

    def __init__(self, env: Any, route_points: int = 5, route_spacing: float = 10.0,
                 leader: bool = False, crossing: bool = False, leader_corners: bool = False,
                 leader_swept: bool = False, **kwargs: Any) -> None:
        kwargs.pop("type", None)
        known = _kinematics_options()
        for key in kwargs:
            if key not in known:  # highway-env's Kinematics ignores an unknown key silently
                raise did_you_mean("KinematicsRoute observation option", key,
                                   known | set(_ROUTE_OPTIONS))
        super().__init__(env, **kwargs)
        if (isinstance(route_points, bool) or not isinstance(route_points, int)
                or route_points < 1):
            raise ValueError(f"KinematicsRoute observation: route_points {route_points!r} "
                             "must be an integer >= 1 (points observed along the route).")
        if (not isinstance(route_spacing, int | float) or isinstance(route_spacing, bool)
                or not math.isfinite(route_spacing) or route_spacing <= 0):
            raise ValueError(f"KinematicsRoute observation: route_spacing {route_spacing!r} "
                             "must be a number of metres > 0.")
        if not isinstance(leader, bool):
            raise ValueError(f"KinematicsRoute observation: leader {leader!r} must be true or "
                             "false (observe the road user in the ego's path ahead).")
        if not isinstance(crossing, bool):
            raise ValueError(f"KinematicsRoute observation: crossing {crossing!r} must be true "
                             "or false (observe the road users whose way crosses the ego's "
                             "path ahead).")
        self.leader_features = leader
        if not isinstance(leader_corners, bool):
            raise ValueError(f"KinematicsRoute observation: leader_corners {leader_corners!r} "
                             "must be true or false (a road user whose box reaches into the "
                             "path is in it).")
        if not isinstance(leader_swept, bool):
            raise ValueError(f"KinematicsRoute observation: leader_swept {leader_swept!r} must "
                             "be true or false (a road user in the ego's own swept box is a "
                             "leader).")
        self.crossing_features = crossing
        self.leader_corners = leader_corners
        self.leader_swept = leader_swept
        self.lead = NO_LEADER  # the leader at the last observation (the env's reward reads it)
        self.route_points = route_points
        self.route_spacing = float(route_spacing)
        self.horizon = route_points * self.route_spacing
        self._at = 0  # the route lane the ego was last on (the route is followed in order)

    @property
    def kinematics_size(self) -> int:
        """Values of the Kinematics part (V * F)."""
        return self.vehicles_count * len(self.features)

    @property
    def route_size(self) -> int:
        """Values of the route part (with the leader's)."""
        return (2 * self.route_points + len(ROUTE_FEATURES)
            + (len(LEADER_FEATURES) if self.leader_features else 0)
            + (CROSSING_COUNT * len(CROSSING_FEATURES) if self.crossing_features else 0))

    def space(self) -> spaces.Box:
        """One float32 vector: the Kinematics part is bounded as highway-env bounds it
        (unbounded), the route part in [-1, 1]."""
        low = np.r_[np.full(self.kinematics_size, -np.inf), -np.ones(self.route_size)]
        return spaces.Box(low=low.astype(np.float32), high=-low.astype(np.float32),
                          dtype=np.float32)

    def observe(self) -> np.ndarray:
        """The vector (see the module docstring)."""
        kinematics = np.asarray(super().observe(), dtype=np.float32).ravel()
        self.lead = NO_LEADER
        if not self.env.road or not getattr(self.env, "route", None):
            return np.concatenate([kinematics, np.zeros(self.route_size, np.float32)])
        return np.concatenate([kinematics, self.route_vector()])

    # the route seen from the ego
    def route_vector(self) -> np.ndarray:
        """The route part (float32, ``route_size`` values in [-1, 1])."""
        ego = self.observer_vehicle
        network = self.env.road.network
        route = list(self.env.route)
        p, k, s, lat, points, change = self._ahead(network, route)
        lane = network.get_lane(route[k])
        h = float(ego.heading)
        c, si = math.cos(h), math.sin(h)
        rel = points - p
        fwd = rel @ np.array([c, si])
        left = -(rel @ np.array([-si, c]))  # the sim frame's y points to the driver's right
        xy = np.column_stack([fwd, left]).ravel() / self.horizon
        dh = -(lane.heading_at(s) - h)  # WOMD axes: counter-clockwise = to the left
        if change is None:
            change_distance, change_side = 1.0, 0.0
        else:
            change_distance, change_side = change[0] / self.horizon, change[1]
        values = np.concatenate([xy, (lat / OFFSET_SCALE, math.sin(dh), math.cos(dh),
                                      change_distance, change_side,
                                      float(ego.lane_index in route))])
        path = np.concatenate([p[None], points])
        self.lead = self.leader(path)
        if self.leader_swept:
            swept = swept_leader(ego, self._road_users())
            if swept.gap < self.lead.gap:
                self.lead = swept
        if self.leader_features:
            lead = self.lead
            gap = lead.gap / self.horizon if math.isfinite(lead.gap) else 1.0
            values = np.concatenate([values, (float(ego.speed) / SPEED_SCALE, gap,
                                              lead.closing / CLOSING_SCALE,
                                              lead.inverse_ttc / INVERSE_TTC_SCALE)])
        if self.crossing_features:
            values = np.concatenate([values, self.crossing_vector(path)])
        return np.clip(values, -1.0, 1.0).astype(np.float32)

    def _ahead(self, network: Any, route: list) -> tuple[np.ndarray, int, float, float,
                                                         np.ndarray, Any]:
        """(the ego's position (2,) [m], its route position, longitudinal and offset on that
        lane (:meth:`_locate`), the route's points ahead and its next lane change
        (:meth:`_walk`))."""
        ego = self.observer_vehicle
        p = np.asarray(ego.position, float)
        k, s, lat = self._locate(network, route, p, ego.lane_index)
        points, change = self._walk(network, route, k, s)
        return p, k, s, lat, points, change

    def update_lead(self) -> Leader:
        """Set and return :attr:`lead`, the leader in the route's path ahead, as
        :meth:`route_vector` sets it, without the rest of the vector (the env's reward
        reads it)."""
        p, _, _, _, points, _ = self._ahead(self.env.road.network, list(self.env.route))
        self.lead = self.leader(np.concatenate([p[None], points]))
        return self.lead

    def crossing_vector(self, path: np.ndarray) -> np.ndarray:
        """The crossing part (:data:`CROSSING_COUNT` x :data:`CROSSING_FEATURES`, in [0, 1];
        see the module docstring) along ``path`` ((m, 2) [m, sim frame], from the ego)."""
        out = np.ones((CROSSING_COUNT, len(CROSSING_FEATURES)))
        for row, cross in zip(out, self.crossings(path)[:CROSSING_COUNT], strict=False):
            row[:] = (cross.distance / self.horizon, min(cross.ego_time / CROSS_HORIZON, 1.0),
                      cross.other_time / CROSS_HORIZON)
        return out.ravel()

    def _road_users(self) -> list[Any]:
        """The road's vehicles but the ego that can be hit now (collidable, not hidden)."""
        ego = self.observer_vehicle
        return [v for v in self.env.road.vehicles if v is not ego
                and getattr(v, "collidable", True) and not getattr(v, "hidden", False)]

    def crossings(self, path: np.ndarray) -> list[Crossing]:
        """The road users whose way crosses ``path`` (see the module docstring), nearest
        crossing point first.

        Args:
            path: (m, 2) the polyline ahead, from the ego's position on [m, sim frame].
        """
        ego, others = self.observer_vehicle, self._road_users()
        if not others or len(path) < 2:
            return []
        pos = np.array([v.position for v in others], dtype=float)  # (n, 2)
        ray = np.array([v.velocity for v in others], dtype=float) * CROSS_HORIZON
        reach = np.hypot(*ray.T)  # [m] how far each gets within the horizon
        keep = ((reach >= MIN_CROSS_SPEED * CROSS_HORIZON)
            & (np.hypot(*(pos - path[0]).T) <= self.horizon + reach))
        if not keep.any():
            return []
        pos, ray, reach = pos[keep], ray[keep], reach[keep]
        a, seg = path[:-1], np.diff(path, axis=0)  # (m-1, 2)
        length = np.hypot(*seg.T)
        ok = length > 1e-6
        a, seg, length = a[ok], seg[ok], length[ok]
        if not len(seg):
            return []
        cum = np.concatenate([(0.0,), np.cumsum(length)[:-1]])
        # a + u * seg = pos + t * ray, u and t in [0, 1]: 2-d cross products
        denom = seg[None, :, 0] * ray[:, None, 1] - seg[None, :, 1] * ray[:, None, 0]
        w = pos[:, None, :] - a[None, :, :]  # (n, m-1, 2)
        steep = np.abs(denom) >= math.sin(CROSS_MIN_ANGLE) * length[None] * reach[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (w[..., 0] * ray[:, None, 1] - w[..., 1] * ray[:, None, 0]) / denom
            t = (w[..., 0] * seg[None, :, 1] - w[..., 1] * seg[None, :, 0]) / denom
        hit = steep & (u >= 0) & (u <= 1) & (t >= 0) & (t <= 1)
        along = np.where(hit, cum[None] + u * length[None], np.inf)  # (n, m-1)
        j = along.argmin(axis=1)
        rows = np.flatnonzero(np.isfinite(along[np.arange(len(j)), j]))
        speed = max(float(ego.speed), 0.0)
        found = []
        for r in rows:
            s = float(along[r, j[r]])
            ahead = max(s - ego.LENGTH / 2, 0.0)
            ego_time = ahead / speed if speed > 1e-3 else (0.0 if ahead == 0 else math.inf)
            found.append(Crossing(s, ego_time, float(t[r, j[r]]) * CROSS_HORIZON))
        return sorted(found)

    def _road_user_states(self) -> tuple[list[Any], np.ndarray, np.ndarray]:
        """(the road users of :meth:`_road_users`, their positions (n, 2) [m, sim frame], the
        road's vehicle rows they are), from the road's states laid out at once where the
        road lays them out (:class:`~tap_bench.sim.womd_road.WomdRoad`)."""
        road = self.env.road
        snapshot = getattr(road, "_snapshot", None)
        if snapshot is None:
            others = self._road_users()
            positions = np.array([v.position for v in others], dtype=float).reshape(-1, 2)
            return others, positions, np.arange(len(others))
        layout, now = snapshot()
        users = now["collidable"].copy()
        ego = self.observer_vehicle
        vehicles = layout.vehicles
        for i in layout.others:  # the simulated ones may wait hidden
            if getattr(vehicles[i], "hidden", False):
                users[i] = False
        # the env puts the ego first (a policy's takes its place)
        for i in [0] if vehicles and vehicles[0] is ego else range(len(vehicles)):
            if vehicles[i] is ego:
                users[i] = False
        rows = np.flatnonzero(users)
        return [vehicles[i] for i in rows.tolist()], now["position"][rows], rows

    def leader(self, path: np.ndarray) -> Leader:
        """The nearest road user in the ego's path ahead (see the module docstring).

        Args:
            path: (m, 2) the polyline ahead, from the ego's position on [m, sim frame].
        """
        ego = self.observer_vehicle
        others, pos, rows = self._road_user_states()
        if not others or len(path) < 2:
            return NO_LEADER
        layout = getattr(self.env.road, "_vehicle_layout", None)
        if layout is not None and len(rows) and layout.vehicles[rows[0]] is others[0]:
            widths, lengths = layout.width[rows], layout.length[rows]
        else:
            widths = np.array([v.WIDTH for v in others], dtype=float)
            lengths = np.array([v.LENGTH for v in others], dtype=float)
        headings = (np.array([v.heading for v in others], dtype=float)
                    if self.leader_corners else np.zeros(len(others)))
        k, gap, dx, dy = _path_leader(
            np.ascontiguousarray(path, dtype=float), np.ascontiguousarray(pos, dtype=float),
            widths, lengths, headings, float(ego.WIDTH), float(ego.LENGTH),
            float(self.horizon), self.leader_corners)
        if k < 0:
            return NO_LEADER
        lead_speed = float(np.dot(others[k].velocity, np.array([dx, dy])))
        return Leader(float(gap), float(ego.speed) - lead_speed)

    def _locate(self, network: Any, route: list, p: np.ndarray, lane_index: Any
                ) -> tuple[int, float, float]:
        """(route position, longitudinal [m] on that lane, offset to its centre [m, + left])
        of the ego: its own lane when that is on the route at or after the last position,
        else the route lane whose centre is nearest (beyond a lane's ends counts as far)."""
        start = min(self._at, len(route) - 1)
        if lane_index in route[start:]:
            k = route.index(lane_index, start)
            s, d = network.get_lane(route[k]).local_coordinates(p)
        else:
            best = None
            for j in range(start, len(route)):
                lane = network.get_lane(route[j])
                sj, dj = lane.local_coordinates(p)
                outside = max(0.0, -sj, sj - lane.length)
                cost = math.hypot(dj, outside)
                if best is None or cost < best[0]:
                    best = (cost, j, sj, dj)
            _, k, s, d = best
        self._at = k
        return k, float(s), -float(d)

    def _walk(self, network: Any, route: list, k: int, s: float
              ) -> tuple[np.ndarray, tuple[float, float] | None]:
        """The route's points every ``route_spacing`` m ahead of longitudinal ``s`` on route
        lane ``k``, and (distance [m], side +1 left / -1 right) of its next lane change within
        the horizon (None if none)."""
        targets = self.route_spacing * np.arange(1, self.route_points + 1)
        points = np.zeros((self.route_points, 2))
        travelled, j, change = 0.0, 0, None
        lane = network.get_lane(route[k])
        while j < self.route_points:
            nxt = route[k + 1] if k + 1 < len(route) else None
            side = _side(network, route[k], nxt) if nxt is not None else None
            if side is not None:  # a lane change: where the map allows it, from here on
                start = max(s, _neighbour_start(network, route[k], nxt))
                stop = start
            elif nxt is not None:  # along to the lane's end, then the next lane
                stop = max(lane.length, s)
            else:  # the route's last lane: straight on past its end
                stop = math.inf
            first = j
            while j < self.route_points and travelled + stop - s >= targets[j]:
                j += 1
            if j > first:  # the points on this lane, at once
                along = s + targets[first:j] - travelled
                points[first:j] = (lane.centre_points(along) if hasattr(lane, "centre_points")
                                   else [lane.position(a, 0.0) for a in along])
            if j == self.route_points:
                break
            travelled += stop - s
            if side is not None:
                if change is None:
                    change = (travelled, side)
                here = lane.position(stop, 0.0)
                lane = network.get_lane(nxt)
                s = float(lane.local_coordinates(here)[0])
            else:
                lane = network.get_lane(nxt)
                s = 0.0
            k += 1
        if change is not None and change[0] > self.horizon:
            change = None
        return points, change


def swept_poses(ego: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the ego's centre goes: (s, xy, heading) at every :data:`SWEPT_STEP` metres
    along its way over :data:`SWEPT_HORIZON` seconds at its speed (at least
    :data:`SWEPT_MIN_DISTANCE` m), s from 0 [m]; (k,), (k, 2) [m, sim frame], (k,) [rad].

    The way is an arc of the curvature its steering gives (highway-env's bicycle model:
    heading rate = speed sin(beta) / (length / 2), beta = arctan(tan(steering) / 2)), followed
    for :data:`SWEPT_MAX_TURN` of turn, then straight on; when the ego steers, the poses
    straight on along its heading follow (the same s again): the steering of a slow ego
    swings from lock to lock from one step to the next, and a car right ahead must not drop
    out of the box for a step."""
    speed = max(float(ego.speed), 0.0)
    distance = max(speed * SWEPT_HORIZON, SWEPT_MIN_DISTANCE)
    s = np.arange(0.0, distance + 1e-9, SWEPT_STEP)
    action = getattr(ego, "action", None) or {}
    steering = float(action.get("steering", 0.0))
    beta = math.atan(0.5 * math.tan(steering))
    kappa = math.sin(beta) / (float(ego.LENGTH) / 2)  # [1/m] heading change per metre
    h0 = float(ego.heading) + beta  # the velocity's direction
    turn = np.clip(kappa * s, -SWEPT_MAX_TURN, SWEPT_MAX_TURN)
    heading = h0 + turn
    if abs(kappa) < 1e-6:
        xy = s[:, None] * np.array([math.cos(h0), math.sin(h0)])
    else:
        arc = np.minimum(s, abs(SWEPT_MAX_TURN / kappa))  # the part driven while turning
        on_arc = np.column_stack([np.sin(h0 + kappa * arc) - math.sin(h0),
                                  math.cos(h0) - np.cos(h0 + kappa * arc)]) / kappa
        xy = on_arc + (s - arc)[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        h = float(ego.heading)
        xy = np.concatenate([xy, s[:, None] * np.array([math.cos(h), math.sin(h)])])
        s, heading = np.concatenate([s, s]), np.concatenate([heading, np.full(len(s), h)])
    return s, np.asarray(ego.position, float) + xy, heading


def swept_leader(ego: Any, others: list[Any], margin: float = SWEPT_MARGIN) -> Leader:
    """The nearest road user the ego's swept box meets: the ego's box (``margin`` m wider
    on each side) placed along :func:`swept_poses` is tested against each road user's box
    where it is now (separating axes); the first pose that overlaps gives the gap, the
    distance the ego's centre goes before it (less one :data:`SWEPT_STEP`: never more than
    the true gap). Road users whose centre is not ahead of the ego's (along its heading) are
    left out (those beside and behind). The closing speed is the ego's speed minus the
    other's velocity along the ego's heading at that pose.

    Args:
        ego: the ego vehicle (``position``, ``heading``, ``speed``, ``LENGTH``, ``WIDTH``,
            ``action["steering"]``; highway-env's sim frame).
        others: the road users (``position``, ``heading``, ``velocity``, ``LENGTH``,
            ``WIDTH``).
        margin: [m] added to the ego's half width.
    """
    if not others:
        return NO_LEADER
    s, xy, heading = swept_poses(ego)
    p = np.asarray(ego.position, float)
    pos = np.array([v.position for v in others], dtype=float)  # (n, 2)
    h = float(ego.heading)
    ahead = (pos - p) @ np.array([math.cos(h), math.sin(h)]) > 0
    ahead &= np.hypot(*(pos - p).T) <= s[-1] + 10.0 + float(ego.LENGTH)
    if not ahead.any():
        return NO_LEADER
    idx = np.flatnonzero(ahead)
    pos = pos[idx]
    oh = np.array([others[i].heading for i in idx], dtype=float)
    half_l = np.array([others[i].LENGTH for i in idx], dtype=float) / 2
    half_w = np.array([others[i].WIDTH for i in idx], dtype=float) / 2
    overlap = boxes_overlap(xy, heading, float(ego.LENGTH) / 2,
                             float(ego.WIDTH) / 2 + margin, pos[None], oh, half_l, half_w)
    hit = overlap.any(axis=0)
    if not hit.any():
        return NO_LEADER
    along = np.where(overlap, s[:, None], np.inf)  # (k, n)
    first = along.argmin(axis=0)  # (n,) each road user's first pose that overlaps
    k = int(np.argmin(along[first, np.arange(len(first))]))
    pose = int(first[k])
    gap = max(float(s[pose]) - SWEPT_STEP, 0.0)
    direction = np.array([math.cos(heading[pose]), math.sin(heading[pose])])
    lead_speed = float(np.dot(others[idx[k]].velocity, direction))
    return Leader(gap, max(float(ego.speed), 0.0) - lead_speed)


def predicted_conflict(ego: Any, others: list[Any], acceleration: float = 0.0,
                       tolerance: float = PREDICT_TOLERANCE, horizon: float = SWEPT_HORIZON,
                       max_acceleration: float = 3.0, margin: float = SWEPT_MARGIN) -> Leader:
    """The nearest place on the ego's way where a road user's own predicted motion meets it:
    both advanced over the same ``horizon`` and compared at matched times.

    The ego's box goes along :func:`swept_poses` at the speed its ``acceleration`` gives
    (clipped to [-8, ``max_acceleration``] m/s^2, never reversing, never faster than its
    ``target_speed`` when it has one, else its speed or what the acceleration gives): pose k
    is reached at time t_k (the first 0.1 s step at which the distance covered reaches
    it). Each road user moving at :data:`MIN_CROSS_SPEED` or more whose heading is at least
    :data:`CROSS_MIN_ANGLE` off the ego's (crossing or oncoming traffic: road users going
    the ego's way are the swept box's, :func:`swept_leader`) goes on at its velocity and
    heading; its box at t_k, stretched along its heading by its speed times ``tolerance``
    [s] at both ends (it may come that much earlier or later), is tested against the ego's
    box at pose k (``margin`` m wider on each side; separating axes). Where they overlap
    within ``horizon`` the ego must give way before the road user's *zone*, the ground its
    box covers from ``tolerance`` s before now to ``horizon`` + ``tolerance`` s: the gap is
    the distance the ego's centre goes to the first pose whose box meets the zone (less
    one :data:`SWEPT_STEP`), and the zone stands still (closing = the ego's speed). A road
    user whose zone already meets the ego's box where it is now is left out: braking
    cannot clear that one (a car behind, one in the ego's way already).

    Args:
        ego: the ego vehicle (as :func:`swept_leader`'s; ``target_speed`` if it has one).
        others: the road users (``position``, ``heading``, ``velocity``, ``LENGTH``,
            ``WIDTH``).
        acceleration: [m/s^2] the ego's asked-for acceleration (its controller's this step).
        tolerance: [s] the time margin on each side of a matched time.
        horizon: [s] how far ahead in time both are advanced.
        max_acceleration: [m/s^2] the most acceleration the ego's prediction takes.
        margin: [m] added to the ego's half width.

    Returns:
        The zone's gap and closing speed; :data:`NO_LEADER` with no conflict.
    """
    if not others:
        return NO_LEADER
    s, xy, heading = swept_poses(ego)
    p = np.asarray(ego.position, float)
    h = float(ego.heading)
    vel = np.array([np.asarray(v.velocity, float) for v in others]).reshape(-1, 2)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    oh = np.array([float(v.heading) for v in others])
    half_l = np.array([float(v.LENGTH) for v in others]) / 2
    half_w = np.array([float(v.WIDTH) for v in others]) / 2
    pos = np.array([np.asarray(v.position, float) for v in others]).reshape(-1, 2)
    off = np.abs((oh - h + np.pi) % (2 * np.pi) - np.pi)
    reach = (float(s[-1]) + speed * (horizon + tolerance) + half_l + half_w
             + float(ego.LENGTH) / 2 + float(ego.WIDTH) / 2 + margin)
    keep = ((speed >= MIN_CROSS_SPEED) & (off >= CROSS_MIN_ANGLE)
            & (np.hypot(*(pos - p).T) <= reach))
    if not keep.any():
        return NO_LEADER
    vel, speed, oh, half_l, half_w, pos = (a[keep] for a in (vel, speed, oh, half_l, half_w,
                                                              pos))
    v = max(float(ego.speed), 0.0)
    t_pose, reached = pose_times(ego, s, acceleration, horizon, max_acceleration)
    el, ew = float(ego.LENGTH) / 2, float(ego.WIDTH) / 2 + margin
    moved = pos[None] + t_pose[:, None, None] * vel[None]  # (k, n, 2)
    matched = boxes_overlap(xy, heading, el, ew, moved, oh, half_l + speed * tolerance,
                             half_w) & reached[:, None]
    meets = matched.any(axis=0)
    if not meets.any():
        return NO_LEADER
    centre = pos + 0.5 * horizon * vel  # the zone: from -tolerance to horizon + tolerance
    zone = boxes_overlap(xy, heading, el, ew, centre[None], oh,
                          half_l + speed * (0.5 * horizon + tolerance), half_w)
    along = np.where(zone, s[:, None], np.inf)  # (k, n)
    entry = along.min(axis=0)  # (n,) where the ego's way enters each zone [m]
    entry = np.where(meets & (entry > 0.0), entry, np.inf)
    if not np.isfinite(entry).any():
        return NO_LEADER
    return Leader(max(float(entry.min()) - SWEPT_STEP, 0.0), v)


def pose_times(ego: Any, s: np.ndarray, acceleration: float, horizon: float = SWEPT_HORIZON,
               max_acceleration: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """When the ego's centre reaches each of its swept poses ``s`` (k,) [m]: its speed
    changes by ``acceleration`` [m/s^2] (clipped to [-8, ``max_acceleration``], never
    reversing, never above its ``target_speed`` when it has one, else its speed), stepped by
    :data:`PREDICT_STEP` s; a pose is reached at the first step whose distance covered
    reaches it. Returns (t (k,) [s], reached within ``horizon`` (k,) bool; t 0 where not)."""
    v = max(float(ego.speed), 0.0)
    a = min(max(float(acceleration), -8.0), max_acceleration)
    top = float(getattr(ego, "target_speed", math.inf))
    top = max(v, top) if a > 0 else v
    t = np.arange(0.0, horizon + 1e-9, PREDICT_STEP)
    speeds = np.clip(v + a * t, 0.0, top)
    covered = np.concatenate([[0.0], np.cumsum(0.5 * (speeds[1:] + speeds[:-1])
                                                * PREDICT_STEP)])
    at = np.searchsorted(covered, s - 1e-9)  # the first step that reaches each pose
    reached = at < len(t)
    return np.where(reached, t[np.minimum(at, len(t) - 1)], 0.0), reached


def boxes_overlap(xy: np.ndarray, heading: np.ndarray, half_length: float, half_width: float,
                   pos: np.ndarray, oh: np.ndarray, half_l: np.ndarray, half_w: np.ndarray
                   ) -> np.ndarray:
    """(k, n) bool: whether the ego's box at pose k (centre ``xy`` (k, 2) [m], ``heading``
    (k,) [rad], half sizes [m]) overlaps road user n's box (centre ``pos`` (k or 1, n, 2)
    [m], heading ``oh`` (n,) [rad], half sizes ``half_l``, ``half_w`` (n,) [m]): separating
    axes, touching counts."""
    eu = np.column_stack([np.cos(heading), np.sin(heading)])[:, None, :]  # (k, 1, 2)
    ew = np.column_stack([-np.sin(heading), np.cos(heading)])[:, None, :]
    ou = np.column_stack([np.cos(oh), np.sin(oh)])[None]  # (1, n, 2)
    ow = np.column_stack([-np.sin(oh), np.cos(oh)])[None]
    d = pos - xy[:, None, :]  # (k, n, 2)
    el, ewid = half_length, half_width

    def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (a * b).sum(axis=-1)

    overlap = np.ones(d.shape[:2], bool)
    for axis in (eu, ew, ou, ow):
        reach = (el * np.abs(dot(eu, axis)) + ewid * np.abs(dot(ew, axis))
                 + half_l * np.abs(dot(ou, axis)) + half_w * np.abs(dot(ow, axis)))
        overlap &= np.abs(dot(d, axis)) <= reach
    return overlap


@numba.njit(cache=True, nogil=True)
def _foot(x, y, ax, ay, sx, sy, length, cum):  # pragma: no cover - compiled
    """(distance [m] from (x, y) to the polyline of segments ``a + u * s`` (lengths
    ``length``, starting ``cum`` along it), distance along it to the foot [m], the nearest
    segment (the first of the nearest))."""
    best, along, j = np.inf, 0.0, -1
    for m in range(ax.shape[0]):
        rx, ry = x - ax[m], y - ay[m]
        t = min(max((rx * sx[m] + ry * sy[m]) / length[m] ** 2, 0.0), 1.0)
        d = math.hypot(x - (ax[m] + t * sx[m]), y - (ay[m] + t * sy[m]))
        if d < best:
            best, along, j = d, cum[m] + t * length[m], m
    return best, along, j


@numba.njit(cache=True, nogil=True)
def _path_leader(path, pos, widths, lengths, headings, ego_width, ego_length, horizon,
                 corners):  # pragma: no cover - compiled
    """:meth:`RouteObservation.leader` over road users at ``pos`` (n, 2) with boxes
    ``lengths`` x ``widths`` [m] (and ``headings`` [rad] when their ``corners`` count) along
    ``path`` (m, 2) [m]: (the nearest in the path ahead, -1 if none; its gap [m]; the unit
    direction of the path's segment it is on)."""
    n_seg = path.shape[0] - 1
    ax, ay = np.empty(n_seg), np.empty(n_seg)
    sx, sy, length = np.empty(n_seg), np.empty(n_seg), np.empty(n_seg)
    m = 0
    for q in range(n_seg):  # the segments longer than 1e-6 m
        dx, dy = path[q + 1, 0] - path[q, 0], path[q + 1, 1] - path[q, 1]
        d = math.hypot(dx, dy)
        if d > 1e-6:
            ax[m], ay[m], sx[m], sy[m], length[m] = path[q, 0], path[q, 1], dx, dy, d
            m += 1
    if m == 0:
        return -1, np.inf, 0.0, 0.0
    ax, ay, sx, sy, length = ax[:m], ay[:m], sx[:m], sy[:m], length[:m]
    cum = np.zeros(m)
    for q in range(1, m):
        cum[q] = cum[q - 1] + length[q - 1]
    best, best_k, best_j = np.inf, -1, -1
    for i in range(pos.shape[0]):
        x, y = pos[i, 0], pos[i, 1]
        if not math.hypot(x - path[0, 0], y - path[0, 1]) <= horizon + 10.0:
            continue
        lateral, along, j = _foot(x, y, ax, ay, sx, sy, length, cum)
        gap = np.inf
        if lateral <= (ego_width + widths[i]) / 2 and along > 0 and along <= horizon:
            gap = along - (ego_length + lengths[i]) / 2
        if corners:  # a corner of its box within half the ego's width
            fx, fy = math.cos(headings[i]), math.sin(headings[i])
            for sl in (1, -1):
                for sw in (1, -1):
                    cx = x + sl * lengths[i] / 2 * fx + sw * widths[i] / 2 * -fy
                    cy = y + sl * lengths[i] / 2 * fy + sw * widths[i] / 2 * fx
                    c_lat, c_along, _ = _foot(cx, cy, ax, ay, sx, sy, length, cum)
                    if c_lat <= ego_width / 2 and c_along > 0 and c_along <= horizon:
                        gap = min(gap, max(c_along - ego_length / 2, 0.0))
        if gap < best:
            best, best_k, best_j = gap, i, j
    if best_k < 0:
        return -1, np.inf, 0.0, 0.0
    return best_k, best, sx[best_j] / length[best_j], sy[best_j] / length[best_j]


def _side(network: Any, a: Any, b: Any) -> float | None:
    """+1 when route lane ``b`` is a left neighbour of ``a``, -1 a right one, None when it is
    not a neighbour (an exit: the route goes on along the lane)."""
    if b in network.successors(a):
        return None
    lane = network.road_map.lanes[network.womd_id(a)]
    for n in lane.left:
        if network.index.get(n.lane) == b:
            return 1.0
    for n in lane.right:
        if network.index.get(n.lane) == b:
            return -1.0
    return None


def _neighbour_start(network: Any, a: Any, b: Any) -> float:
    """Longitudinal [m] on lane ``a`` where lane ``b`` starts being its neighbour."""
    lane = network.road_map.lanes[network.womd_id(a)]
    for n in (*lane.left, *lane.right):
        if network.index.get(n.lane) == b:
            centre = np.asarray(lane.centre, float)
            if len(centre) < 2:
                return 0.0
            s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(centre, axis=0).T))]
            return float(s[min(max(n.self_start, 0), len(s) - 1)])
    return 0.0
