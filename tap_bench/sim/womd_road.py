"""The road of a recorded WOMD scene in highway-env: its network, its vehicles, its routes.

- :class:`WomdNetwork`: one :class:`~tap_bench.sim.womd_lanes.FastPolyLane` per WOMD lane,
  the exits and neighbours of the map (:class:`~tap_bench.womd.roadmap.RoadMap`) as the
  lane graph, and the compiled lane lookup;
- :class:`LogVehicle` (an agent replaying its log), :class:`WomdMDPVehicle` (the
  meta-action ego: lane changes to the map's neighbours), :class:`WomdIDMVehicle` (IDM/MOBIL
  along a route, stopping at red stop points);
- :class:`WomdRoad`: the step counter the replays read, the neighbour search (all positions
  projected on a lane at once, once per step), the ego's collisions, signals, off-road;
- :func:`logged_route`: the lanes a logged path follows.

Everything is in highway-env's mirrored frame (``y`` and headings negated, :func:`sim_frame`);
:mod:`tap_bench.sim.womd_env` records back in WOMD's axes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numba
import numpy as np
from highway_env import utils
from highway_env.road.lane import LineType
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle

from tap_bench.sim.road_edges import RoadEdges, left_road
from tap_bench.sim.traffic import near_pairs
from tap_bench.sim.womd_lanes import FastPolyLane, LaneIndex, lane_points
from tap_bench.sim.womd_scene import Scene

__all__ = ["HIDDEN", "OFF_ROAD_MARGIN", "ROUTE_CORRIDOR", "ROUTE_OFF_MAP", "STOP_LOOKAHEAD",
           "STOP_MARGIN", "WALKER_CLEARANCE", "WALKER_HORIZON", "WALKER_LOOKAHEAD", "LogVehicle",
           "WomdIDMVehicle", "WomdMDPVehicle", "WomdNetwork", "WomdRoad", "logged_route",
           "path_progress", "sim_frame"]

OFF_ROAD_MARGIN = 0.5  # [m] beyond half the lane's width, from every lane centre: off road
ROUTE_CORRIDOR = 4.0  # [m] progress counts while the ego is this close to the logged path
ROUTE_OFF_MAP = 3.0  # [m] a logged position farther than half a lane width + this is off
STOP_MARGIN = 1.0  # [m] IDM stops its front bumper this far before a red stop point
STOP_LOOKAHEAD = 60.0  # [m] stop points farther ahead along the route are ignored
HIDDEN = 1.0e6  # [m] where an agent waits while the log has no valid state for it
WALKER_LOOKAHEAD = 50.0  # [m] IDM yields to pedestrians and cyclists in its way this far ahead
WALKER_HORIZON = 1.5  # [s] ... where they are now or will be in this time
WALKER_CLEARANCE = 1.0  # [m] ... within half the vehicle's width + this of the lane centre
WALKER_RADIUS = 0.5  # [m] IDM stops its front bumper STOP_MARGIN before this around them
WALKER_STILL = 0.5  # [m/s] slower walkers count as standing in the way
WALKER_ALONG = math.cos(math.radians(30.0))  # a walker within 30 deg of the lane moves along


def sim_frame(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """WOMD (x, y) -> highway-env's mirrored frame."""
    return np.stack([np.asarray(x, float), -np.asarray(y, float)], axis=-1)


# ------------------------------------------------------------------ the road network


class WomdNetwork(RoadNetwork):
    """A highway-env road network of WOMD lanes.

    Lane index of WOMD lane ``k``: ``(str(k), f"{k}>", 0)``. The graph's nodes do not carry
    the topology; the WOMD exits and neighbours do, through :meth:`next_lane` and
    :meth:`side_lanes_at`, and :meth:`get_closest_lane_index` is compiled
    (:class:`~tap_bench.sim.womd_lanes.LaneIndex`).

    Attributes:
        road_map: the WOMD map.
        index: WOMD lane id -> lane index.
        left_out: WOMD lane ids not built (a single distinct point).
    """

    def __init__(self, road_map: Any) -> None:
        super().__init__()
        self.road_map = road_map
        self.index: dict[int, tuple[str, str, int]] = {}
        self.left_out: list[int] = []
        lanes = []
        for lane in road_map.lanes.values():
            points = lane_points(lane.centre)
            if points is None:
                self.left_out.append(lane.id)
                continue
            limit = lane.speed_limit if np.isfinite(lane.speed_limit) else 20.0
            # drawn (rgb_array) with a dashed line where the map names a neighbour
            lines = tuple(LineType.STRIPED if side else LineType.CONTINUOUS
                          for side in (lane.left, lane.right))
            built = FastPolyLane(sim_frame(points[:, 0], points[:, 1]).tolist(), lane.width,
                                 womd_id=lane.id, speed_limit=limit, line_types=lines)
            index = (str(lane.id), f"{lane.id}>", 0)
            self.add_lane(index[0], index[1], built)
            self.index[lane.id] = index
            lanes.append((index, built))
        self.lookup = LaneIndex(lanes)

    def get_closest_lane_index(self, position: np.ndarray, heading: float | None = None
                               ) -> tuple[str, str, int]:
        return self.lookup.closest(position, heading)

    def womd_id(self, lane_index: Any) -> int:
        """The WOMD id of a lane index."""
        return int(lane_index[0])

    def successors(self, lane_index: Any) -> list[tuple[str, str, int]]:
        """Lane indexes of the lane's exits (those built)."""
        lane = self.road_map.lanes[self.womd_id(lane_index)]
        return [self.index[i] for i in lane.exit if i in self.index]

    def side_lanes_at(self, lane_index: Any, position: np.ndarray, side: str | None = None
                      ) -> list[tuple[str, str, int]]:
        """The map's neighbours of a lane at ``position`` (within their index range):
        ``side`` ``"left"``, ``"right"`` or None for both."""
        lane = self.road_map.lanes[self.womd_id(lane_index)]
        built = self.get_lane(lane_index)
        lon, _ = built.local_coordinates(position)
        at = _point_index(lane.centre, lon)
        out = []
        for name in ("left", "right"):
            if side not in (None, name):
                continue
            for n in getattr(lane, name):
                if n.self_start <= at <= n.self_end and n.lane in self.index:
                    out.append(self.index[n.lane])
        return out

    def side_lanes(self, lane_index: Any) -> list[tuple[str, str, int]]:
        """The map's neighbours of a lane anywhere along it (MOBIL then checks that the lane
        is reachable from where the vehicle is)."""
        lane = self.road_map.lanes[self.womd_id(lane_index)]
        return [self.index[n.lane] for n in (*lane.left, *lane.right) if n.lane in self.index]

    def next_lane(self, current_index: Any, route: Any = None, position: np.ndarray = None,
                  np_random: Any = None) -> Any:
        """The lane after ``current_index``: the route's next lane when it is an exit of
        this one, else the exit that continues most straight; the lane itself at a dead
        end."""
        exits = self.successors(current_index)
        if not exits:
            return current_index
        if route:
            for k, index in enumerate(route):
                if index == current_index:
                    for later in route[k + 1:k + 4]:
                        if later in exits:
                            return later
                    break
            for index in route:
                if index in exits:
                    return index
        lane = self.get_lane(current_index)
        end_heading = lane.heading_at(lane.length)
        return min(exits, key=lambda i: abs(utils.wrap_to_pi(
            self.get_lane(i).heading_at(0.0) - end_heading)))


def _point_index(centre: np.ndarray, lon: float) -> int:
    """Index of the centre-line point at arc length ``lon`` [m] (clipped to the line)."""
    if len(centre) < 2:
        return 0
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(centre, axis=0).T))]
    return int(np.clip(np.searchsorted(s, lon), 0, len(centre) - 1))


# ------------------------------------------------------------------ vehicles


class LogVehicle(Vehicle):
    """An agent replaying its logged states (sim frame), hidden while the log has none.

    Attributes:
        row: the track's row in the scene.
    """

    def __init__(self, road: Road, row: int, states: np.ndarray, valid: np.ndarray,
                 length: float, width: float, clock: list[int]) -> None:
        self.states = states  # (T, 4) x, y, heading, speed in the sim frame
        self.valid_steps = valid
        self.clock = clock
        self.row = row
        self.LENGTH, self.WIDTH = float(length), float(width)
        x, y, h, v = self._state(clock[0])
        super().__init__(road, np.array([x, y]), h, v)
        self.diagonal = math.hypot(self.LENGTH, self.WIDTH)
        self.check_collisions = False
        self._place(clock[0])

    def _state(self, k: int) -> tuple[float, float, float, float]:
        if k < len(self.valid_steps) and self.valid_steps[k]:
            x, y, h, v = self.states[k]
            return x, y, h, v
        return HIDDEN + 10.0 * self.row, HIDDEN, 0.0, 0.0

    def _place(self, k: int) -> None:
        x, y, h, v = self._state(k)
        self.position = np.array([x, y])
        self.heading = h
        self.speed = v
        self.collidable = bool(k < len(self.valid_steps) and self.valid_steps[k])

    def act(self, action: Any = None) -> None:
        """Replaying: no decision."""

    def step(self, dt: float) -> None:
        """Move to the logged state of the road's current step."""
        self.impact = None
        self._place(self.clock[0])


class _RouteMixin:
    """Route following for WOMD vehicles: lane changes the route makes (the logged driver
    changed lanes there) and the map's neighbours only."""

    route: list

    def _route_change(self) -> Any:
        """The route's next lane when it is a neighbour of the current one (a logged lane
        change), else None."""
        if not self.route or self.lane_index not in self.route:
            return None
        k = self.route.index(self.lane_index)
        if k + 1 < len(self.route):
            nxt = self.route[k + 1]
            if nxt in self.road.network.side_lanes_at(self.lane_index, self.position):
                return nxt
        return None


class WomdMDPVehicle(_RouteMixin, MDPVehicle):
    """highway-env's meta-action vehicle on a WOMD map: ``LANE_LEFT``/``LANE_RIGHT`` go to
    the map's neighbour on that side where there is one (else nothing happens)."""

    def act(self, action: Any = None) -> None:
        if action in ("LANE_LEFT", "LANE_RIGHT"):
            side = "left" if action == "LANE_LEFT" else "right"
            for index in self.road.network.side_lanes_at(self.lane_index, self.position,
                                                         side):
                if self.road.network.get_lane(index).is_reachable_from(self.position):
                    self.target_lane_index = index
                    break
            action = None
        super().act(action)

    def step(self, dt: float) -> None:
        super().step(dt)
        self.speed = max(self.speed, 0.0)  # highway-env lets a braking vehicle reverse


class WomdIDMVehicle(_RouteMixin, IDMVehicle):
    """IDM/MOBIL on a WOMD map: follows its route (the route's lane changes included), MOBIL
    only towards the map's neighbours, stops at red (and yellow, when it can) stop points,
    never reverses."""

    def change_lane_policy(self) -> None:
        change = self._route_change()
        if change is not None and self.lane_index == self.target_lane_index:
            if self.road.network.get_lane(change).is_reachable_from(self.position):
                self.target_lane_index = change
                return
        network = self.road.network
        side_lanes = network.side_lanes
        network.side_lanes = lambda index: network.side_lanes_at(index, self.position)
        try:
            super().change_lane_policy()
        finally:
            network.side_lanes = side_lanes

    def mobil(self, lane_index: Any) -> bool:
        """highway-env's MOBIL without its planned-lane shortcut: that shortcut reads a route
        as lanes numbered across the road (``route[0][2]``), and every WOMD lane is number 0,
        so it accepted every safe change and a vehicle went back and forth between
        neighbours each second. The route's own lane changes are taken in
        :meth:`change_lane_policy`; MOBIL decides the others on its acceleration gain."""
        route, self.route = self.route, None
        try:
            return super().mobil(lane_index)
        finally:
            self.route = route

    def acceleration(self, ego_vehicle: ControlledVehicle, front_vehicle: Vehicle = None,
                     rear_vehicle: Vehicle = None) -> float:
        acc = super().acceleration(ego_vehicle, front_vehicle, rear_vehicle)
        if ego_vehicle is self:
            stop = getattr(self.road, "stop_distance", None)
            if stop is not None:
                d = stop(self)
                if d is not None:
                    acc = min(acc, self._stop_acceleration(d))
            walker = getattr(self.road, "walker_distance", None)
            if walker is not None:
                d = walker(self)
                if d is not None:
                    acc = min(acc, self._stop_acceleration(d - WALKER_RADIUS))
        return acc

    def _stop_acceleration(self, distance: float) -> float:
        """IDM's acceleration towards a standing obstacle placed so that the front bumper
        stops :data:`STOP_MARGIN` before a stop point ``distance`` [m] ahead (centre)."""
        v = max(self.speed, 0.0)
        gap = distance - self.LENGTH / 2 - STOP_MARGIN + self.DISTANCE_WANTED
        d_star = self.DISTANCE_WANTED + v * self.TIME_WANTED + v * v / (
            2 * math.sqrt(-self.COMFORT_ACC_MAX * self.COMFORT_ACC_MIN))
        free = 1 - (v / max(utils.not_zero(self.target_speed), 0.1)) ** self.DELTA
        return self.COMFORT_ACC_MAX * (free - (d_star / max(gap, 0.1)) ** 2)

    def step(self, dt: float) -> None:
        super().step(dt)
        self.speed = max(self.speed, 0.0)  # IDM can ask a stopped vehicle to reverse


# ------------------------------------------------------------------ the road


@numba.njit(cache=True, nogil=True)
def _lane_clearance(ax, ay, bx, by, half, owner, x, y):  # pragma: no cover - compiled
    """min over lanes of (distance to the lane's centre line - half its width) [m]."""
    best = np.inf
    for k in range(ax.shape[0]):
        dx, dy = bx[k] - ax[k], by[k] - ay[k]
        n2 = dx * dx + dy * dy
        u = 0.0 if n2 == 0 else ((x - ax[k]) * dx + (y - ay[k]) * dy) / n2
        u = min(max(u, 0.0), 1.0)
        d = math.hypot(x - ax[k] - u * dx, y - ay[k] - u * dy) - half[owner[k]]
        if d < best:
            best = d
    return best


def _intersecting(a: Vehicle, b: Vehicle) -> bool:
    """Whether two vehicles' boxes overlap now."""
    return bool(utils.are_polygons_intersecting(a.polygon(), b.polygon(), np.zeros(2),
                                                np.zeros(2))[0])


def _pair(a: Vehicle, b: Vehicle) -> tuple[int, int]:
    """The two vehicles' scene rows, in order (-1: no row)."""
    ra, rb = getattr(a, "row", -1), getattr(b, "row", -1)
    return (ra, rb) if ra <= rb else (rb, ra)


def _segments(lines: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """(ax, ay, bx, by, owner) of the segments of polylines (sim frame)."""
    parts = [(np.asarray(p)[:-1], np.asarray(p)[1:], np.full(len(p) - 1, i))
             for i, p in enumerate(lines) if len(p) >= 2]
    if not parts:
        z = np.zeros(0)
        return z, z, z, z, np.zeros(0, np.int64)
    a = np.concatenate([p[0] for p in parts])
    b = np.concatenate([p[1] for p in parts])
    owner = np.concatenate([p[2] for p in parts]).astype(np.int64)
    return (np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1]),
            np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1]), owner)


class WomdRoad(Road):
    """highway-env's road for a WOMD scene: the step counter the log replays read, the
    neighbour search projected once per step per lane (compiled), collisions checked for the
    vehicles that check them, signals and off-road geometry.

    Attributes:
        clock: [k], the record's step the road is at.
    """

    def __init__(self, network: WomdNetwork, scene: Scene, clock: list[int],
                 np_random: Any = None) -> None:
        super().__init__(network=network, vehicles=[], np_random=np_random,
                         record_history=False)
        self.scene = scene
        self.clock = clock
        road = scene.road
        lanes = [lane for lane in road.lanes.values() if lane.id in network.index]
        self._lane_segments = _segments([sim_frame(*lane.centre.T) for lane in lanes])
        self._half = np.array([lane.width / 2 for lane in lanes])
        self.road_edges = RoadEdges.from_polylines(road.road_edges)  # WOMD's axes
        self.off_road_start: dict[str, float] = {}
        self._projections: dict[Any, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._walker_rows = frozenset(np.flatnonzero(np.isin(scene.object_types,
                                                             ("pedestrian", "cyclist"))).tolist())
        self._walkers: tuple[np.ndarray, ...] | None = None
        self._positions: np.ndarray | None = None
        self._movers: list[Vehicle] = []
        signals = road.signals
        self._signal_lanes = [network.index.get(int(i)) for i in signals.lane]
        self._stop_s = []
        for k, index in enumerate(self._signal_lanes):
            if index is None:
                self._stop_s.append(np.nan)
                continue
            p = sim_frame(*signals.stop_point[k])
            self._stop_s.append(float(network.get_lane(index).local_coordinates(p)[0]))
        self._red = signals.red
        self._red_or_yellow = signals.red_or_yellow

    # the neighbour search, once per lane per step
    def act(self) -> None:
        self._projections.clear()
        self._movers = [v for v in self.vehicles if v.collidable]
        self._positions = (np.array([v.position for v in self._movers])
                           if self._movers else np.zeros((0, 2)))
        walkers = [v for v in self._movers if getattr(v, "row", -1) in self._walker_rows]
        if walkers:
            xy = np.array([v.position for v in walkers], float)
            heading = np.array([v.heading for v in walkers], float)
            speed = np.array([max(float(v.speed), 0.0) for v in walkers])
            ahead = xy + WALKER_HORIZON * speed[:, None] * np.c_[np.cos(heading),
                                                                 np.sin(heading)]
            self._walkers = (xy, ahead, heading, speed)
        else:
            self._walkers = None
        for vehicle in self.vehicles:
            vehicle.act()

    def neighbour_vehicles(self, vehicle: Any, lane_index: Any = None
                           ) -> tuple[Any | None, Any | None]:
        lane_index = lane_index or vehicle.lane_index
        if not lane_index or self._positions is None:
            return super().neighbour_vehicles(vehicle, lane_index)
        lane = self.network.get_lane(lane_index)
        table = self._projections.get(lane_index)
        if table is None:
            lon, lat = lane.project(self._positions[:, 0], self._positions[:, 1])
            on = (np.abs(lat) <= lane.width / 2 + 1.0) & (lon >= -lane.VEHICLE_LENGTH) \
                & (lon < lane.length + lane.VEHICLE_LENGTH)
            table = self._projections[lane_index] = (np.flatnonzero(on), lon, lat)
        members, lon, _ = table
        s = lane.local_coordinates(vehicle.position)[0]
        front = rear = None
        s_front = s_rear = None
        for i in members:
            v = self._movers[i]
            if v is vehicle:
                continue
            sv = lon[i]
            if s <= sv and (s_front is None or sv <= s_front):
                s_front, front = sv, v
            if sv < s and (s_rear is None or sv > s_rear):
                s_rear, rear = sv, v
        return front, rear

    def step(self, dt: float) -> None:
        """Move everyone one step, then check collisions: every pair in which a vehicle
        checks them (the ego; idm traffic), with highway-env's rule (``handle_collisions``:
        boxes that intersect are both ``crashed``, boxes that will within the step are
        pushed apart and crashed at the next; a crashed simulated vehicle brakes to a stop,
        a replayed one keeps to its log). Pairs of traffic (the ego not in them) that
        collide are added to :attr:`traffic_collisions` as (step at which they are crashed,
        row, row), once; pairs that already overlap in the log at the current time are not
        collisions of the simulation (the record's own boxes) and are not checked."""
        self.clock[0] += 1
        self._positions = None
        for vehicle in self.vehicles:
            vehicle.step(dt)
        vehicles = [v for v in self.vehicles if v.collidable]
        near = near_pairs(vehicles, [], dt)
        if near is None:  # an object without position or diagonal: every pair, as highway-env
            near = np.ones((len(vehicles), len(vehicles)), bool)
        ego = self.vehicles[0]  # the env puts the ego first (a policy's takes its place)
        for i, j in zip(*np.nonzero(np.triu(near | near.T, 1)), strict=True):
            a, b = vehicles[i], vehicles[j]
            if a is ego or b is ego:  # the env names the ego's partner
                other = b if a is ego else a
                row = getattr(other, "row", -1)
                if row in self.ego_exempt:  # the record's overlap, while it lasts
                    if _intersecting(ego, other):
                        continue
                    self.ego_exempt.discard(row)
                a.handle_collisions(b, dt)
                continue
            pair = _pair(a, b)
            if pair in self.exempt:
                continue
            # whether this pair collides: it intersects (both crashed now), or will within
            # dt (an impact, which crashes a simulated vehicle at its next step)
            crashed, impact = (a.crashed, b.crashed), (a.impact, b.impact)
            a.crashed = b.crashed = False
            a.impact = b.impact = None
            a.handle_collisions(b, dt)
            now = a.crashed and b.crashed
            soon = a.impact is not None or b.impact is not None
            a.crashed |= crashed[0]
            b.crashed |= crashed[1]
            if a.impact is None:  # highway-env's last impact of a step wins
                a.impact = impact[0]
            if b.impact is None:
                b.impact = impact[1]
            if (now or soon) and pair not in self._pairs:
                self._pairs.add(pair)
                self.traffic_collisions.append((self.clock[0] + (0 if now else 1), *pair))

    def start_collisions(self) -> None:
        """Begin an episode's collision record (the vehicles placed, the ego first): pairs
        of traffic that overlap already (log states at the current time) are exempt, and
        so are the agents whose boxes overlap the ego's there (:attr:`ego_exempt`, rows),
        until they come apart: the record's overlaps, not collisions (SPEC section 8)."""
        self.traffic_collisions: list[tuple[int, int, int]] = []
        self._pairs: set[tuple[int, int]] = set()
        self.exempt: set[tuple[int, int]] = set()
        ego = self.vehicles[0]
        self.ego_exempt: set[int] = {
            v.row for v in self.vehicles[1:] if v.collidable and hasattr(v, "row")
            and np.hypot(*(v.position - ego.position)) <= (v.diagonal + ego.diagonal) / 2
            and _intersecting(ego, v)}
        vehicles = [v for v in self.vehicles[1:] if v.collidable]
        near = near_pairs(vehicles, [], 0.0)
        if near is None:
            return
        for i, j in zip(*np.nonzero(np.triu(near | near.T, 1)), strict=True):
            a, b = vehicles[i], vehicles[j]
            if utils.are_polygons_intersecting(a.polygon(), b.polygon(), np.zeros(2),
                                               np.zeros(2))[0]:
                self.exempt.add(_pair(a, b))

    # signals
    def _lanes_ahead(self, vehicle: Vehicle, lookahead: float) -> list[tuple[Any, float]]:
        """(lane index, where the lane starts [m] along the vehicle's way from its centre) of
        its lane and the next ones (its route's, else the straightest) up to ``lookahead``
        [m] (at most three more)."""
        network = self.network
        lane_index = vehicle.lane_index
        s = network.get_lane(lane_index).local_coordinates(vehicle.position)[0]
        ahead = [(lane_index, -s)]
        route = getattr(vehicle, "route", None)
        offset = network.get_lane(lane_index).length - s
        current = lane_index
        for _ in range(3):
            if offset > lookahead:
                break
            nxt = network.next_lane(current, route=route, position=vehicle.position)
            if nxt == current:
                break
            ahead.append((nxt, offset))
            offset += network.get_lane(nxt).length
            current = nxt
        return ahead

    def walker_distance(self, vehicle: Vehicle) -> float | None:
        """Distance [m] along the vehicle's lanes to the nearest pedestrian or cyclist in its
        way ahead (within :data:`WALKER_LOOKAHEAD`): one whose position now or in
        :data:`WALKER_HORIZON` s (at its logged velocity) is within half the vehicle's width
        + :data:`WALKER_CLEARANCE` of the lane's centre line, crossing it or standing (one
        moving along the lane is a leader IDM follows already); None if none."""
        walkers = self._walkers
        if walkers is None or not len(walkers[0]):
            return None
        key = (self.clock[0], vehicle.lane_index)  # MOBIL asks again within a step
        cached = vehicle.__dict__.get("_walker_distance")
        if cached is not None and cached[0] == key:
            return cached[1]
        best = self._walker_distance(vehicle, walkers)
        vehicle.__dict__["_walker_distance"] = (key, best)
        return best

    def _walker_distance(self, vehicle: Vehicle, walkers: tuple[np.ndarray, ...]
                         ) -> float | None:
        positions, predicted, heading, speed = walkers
        reach = WALKER_LOOKAHEAD + vehicle.LENGTH + WALKER_HORIZON * float(speed.max())
        delta = positions - vehicle.position
        if not (delta[:, 0] ** 2 + delta[:, 1] ** 2 <= reach * reach).any():
            return None  # nobody within reach of its way (the usual case): no lane walk
        half = vehicle.WIDTH / 2 + WALKER_CLEARANCE
        best = None
        for index, base in self._lanes_ahead(vehicle, WALKER_LOOKAHEAD):
            lane = self.network.get_lane(index)
            for points in (positions, predicted):
                lon, lat = lane.project(points[:, 0], points[:, 1])
                d = base + lon
                near = (np.abs(lat) <= half) & (lon >= 0) & (lon <= lane.length) \
                    & (d > 0) & (d <= WALKER_LOOKAHEAD)
                for i in np.flatnonzero(near):
                    along = abs(math.cos(heading[i] - lane.heading_at(lon[i])))
                    if speed[i] >= WALKER_STILL and along > WALKER_ALONG:
                        continue
                    best = d[i] if best is None else min(best, float(d[i]))
        return best

    def stop_distance(self, vehicle: Vehicle) -> float | None:
        """Distance [m] along the vehicle's lanes to the nearest stop point ahead whose signal
        is red, or yellow and far enough to stop at (comfortable braking); None if none."""
        k = min(self.clock[0], len(self._red) - 1)
        if not len(self._signal_lanes) or k < 0:
            return None
        active = np.flatnonzero(self._red_or_yellow[k])
        # the yellow lines this vehicle decided to stop at (while they stay yellow or red)
        held = vehicle.__dict__.setdefault("yellow_stops", set())
        held.intersection_update(active.tolist())
        if not len(active):
            return None
        ahead = self._lanes_ahead(vehicle, STOP_LOOKAHEAD)
        best = None
        for j in active:
            index = self._signal_lanes[j]
            for lane, base in ahead:
                if lane != index or not np.isfinite(self._stop_s[j]):
                    continue
                d = base + self._stop_s[j]
                if d < -0.5 or d > STOP_LOOKAHEAD:
                    continue
                if not self._red[k, j] and j not in held:
                    # yellow: stop only when the bumper can stop STOP_MARGIN before the line
                    # braking comfortably; once it stops it keeps stopping (no late dash)
                    room = d - vehicle.LENGTH / 2 - STOP_MARGIN
                    brake = vehicle.speed ** 2 / max(2 * room, 1e-3)
                    if room <= 0 or brake > -getattr(vehicle, "COMFORT_ACC_MIN", -5.0):
                        continue
                    held.add(int(j))
                best = d if best is None else min(best, d)
        return best

    def crossed_red(self, before: np.ndarray, after: np.ndarray) -> bool:
        """Whether a move (sim frame) crossed a stop point whose signal is red at the road's
        step: from before to beyond it along its lane, within the lane's width."""
        k = min(self.clock[0], len(self._red) - 1)
        if k < 0 or not len(self._signal_lanes):
            return False
        for j in np.flatnonzero(self._red[k]):
            index = self._signal_lanes[j]
            if index is None or not np.isfinite(self._stop_s[j]):
                continue
            lane = self.network.get_lane(index)
            s0, d0 = lane.local_coordinates(before)
            s1, d1 = lane.local_coordinates(after)
            stop = self._stop_s[j]
            if s0 < stop <= s1 and max(abs(d0), abs(d1)) <= lane.width / 2 + OFF_ROAD_MARGIN:
                return True
        return False

    def off_road_distance(self, vehicle: Vehicle) -> tuple[float, str]:
        """(signed distance [m], rule) of a vehicle's box to the drivable area, positive off
        the road (SPEC section 8): against the road edges (:mod:`tap_bench.sim.road_edges`,
        rule ``"road edge"``) where one is within
        :data:`~tap_bench.sim.road_edges.EDGE_REACH` of it, else the centre's distance beyond
        half the nearest lane's width + :data:`OFF_ROAD_MARGIN` (rule ``"lane centre"``)."""
        x, y = float(vehicle.position[0]), float(vehicle.position[1])
        d = self.road_edges.box_distance(x, -y, -float(vehicle.heading),
                                         float(vehicle.LENGTH), float(vehicle.WIDTH))
        if np.isfinite(d):
            return d, "road edge"
        ax, ay, bx, by, owner = self._lane_segments
        if not len(ax):
            return float("nan"), "none"
        return float(_lane_clearance(ax, ay, bx, by, self._half, owner, x, y)
                     - OFF_ROAD_MARGIN), "lane centre"

    def start_off_road(self, vehicle: Vehicle) -> None:
        """Record where the ego starts, by each rule (the episode's start is the human's: a
        policy is judged on leaving the road, never on starting off it)."""
        x, y = float(vehicle.position[0]), float(vehicle.position[1])
        ax, ay, bx, by, owner = self._lane_segments
        lane = (float(_lane_clearance(ax, ay, bx, by, self._half, owner, x, y))
                - OFF_ROAD_MARGIN) if len(ax) else float("nan")
        edge = self.road_edges.box_distance(x, -y, -float(vehicle.heading),
                                            float(vehicle.LENGTH), float(vehicle.WIDTH))
        self.off_road_start = {"road edge": edge, "lane centre": lane}

    def off_road(self, vehicle: Vehicle) -> tuple[bool, float, str]:
        """(left the road, signed distance [m], rule) of a vehicle at this step
        (:meth:`off_road_distance`, :func:`~tap_bench.sim.road_edges.left_road` against the
        start :meth:`start_off_road` recorded by the same rule)."""
        if not vehicle.collidable:  # a replayed ego at a step its log does not have
            return False, float("nan"), "none"
        d, rule = self.off_road_distance(vehicle)
        return left_road(d, self.off_road_start.get(rule, float("nan"))), d, rule


# ------------------------------------------------------------------ routes


def logged_route(network: WomdNetwork, xy: np.ndarray, heading: np.ndarray
                 ) -> tuple[list[tuple[str, str, int]], float]:
    """The lanes a logged path follows (sim frame): the nearest lane by distance and heading
    at each position, consecutive repeats and one-step flickers removed, gaps between lanes
    that are neither exits nor neighbours bridged through the graph (up to three lanes).

    Returns:
        the route (lane indexes, in order) and the share of positions farther than half
        their lane's width + :data:`ROUTE_OFF_MAP` from it (the path leaves the map there).
    """
    seq, off = [], 0
    for p, h in zip(xy, heading, strict=True):
        index = network.get_closest_lane_index(p, h)
        lane = network.get_lane(index)
        _, lat = lane.local_coordinates(p)
        if abs(lat) > lane.width / 2 + ROUTE_OFF_MAP:
            off += 1
        if not seq or seq[-1] != index:
            seq.append(index)
    cleaned: list = []
    for index in seq:  # A B A -> A
        if len(cleaned) >= 2 and cleaned[-2] == index:
            cleaned.pop()
            continue
        cleaned.append(index)
    route = cleaned[:1]
    for b in cleaned[1:]:
        a = route[-1]
        if b in network.successors(a) or b in network.side_lanes(a):
            route.append(b)
            continue
        route.extend(_bridge(network, a, b))
        route.append(b)
    return route, off / max(len(xy), 1)


def _bridge(network: WomdNetwork, a: Any, b: Any, depth: int = 3) -> list:
    """Lanes between a and b through the exits (breadth first, up to ``depth``); [] if
    none."""
    frontier = [[a]]
    for _ in range(depth):
        nxt = []
        for path in frontier:
            for s in network.successors(path[-1]):
                if s == b:
                    return path[1:]
                if s not in path:
                    nxt.append([*path, s])
        frontier = nxt
    return []


def path_progress(path: np.ndarray, cum: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """(s, distance) [m] of point p projected on a polyline path (n >= 2) with arc lengths
    ``cum``."""
    a, b = path[:-1], path[1:]
    ab = b - a
    n2 = np.maximum((ab ** 2).sum(axis=1), 1e-12)
    u = np.clip(((p - a) * ab).sum(axis=1) / n2, 0, 1)
    q = a + u[:, None] * ab
    d = np.hypot(*(p - q).T)
    k = int(np.argmin(d))
    return float(cum[k] + u[k] * math.sqrt(n2[k])), float(d[k])


# ------------------------------------------------------------------ scenes and the env
