"""``tap_bench/womd-v0``: drive a policy through recorded WOMD scenes (SPEC section 8).

One episode is one recorded scenario (the seed is its index in the files given, in file and
record order; ``reset(options={"scenario_id": ...})`` picks one by id). Its lanes become a
highway-env road network (:class:`WomdNetwork`: one :class:`~tap_bench.sim.womd_lanes.
FastPolyLane` per WOMD lane, 3.7 m wide unless the boundary lines say otherwise, connected by
WOMD's exit lanes, inferred where the data has none), so every highway-env policy and
observation works on it.

- **Time.** Before the current time (step 10, 1.0 s) everything replays the log; the env
  starts there, and the policy drives the ego to the end of the log at 10 Hz. The trajectory
  table holds the whole record (history and simulated future), so it lines up with the log
  step for step.
- **Ego and route.** The ego is the SDC unless a track id is given (``ego="123"``). Its route
  is the lanes its logged path follows (nearest lane by distance and heading, then along
  the graph: :func:`logged_route`); the controller follows it at every lane end, and lane
  changes go only to lanes the map names as neighbours at that point.
- **Traffic.** ``traffic="log"``: every other agent replays the log (non-reactive).
  ``traffic="idm"``: each vehicle valid at the current time that moves starts from its
  logged state and is driven by IDM/MOBIL (:class:`WomdIDMVehicle`) along its own logged
  route; parked vehicles, vehicles that appear later and vehicles whose path leaves the
  lanes replay. Pedestrians and cyclists always replay. IDM (traffic and an IDM ego) stops at
  a stop point whose signal is red, and at a yellow one when it can stop comfortably.
- **End.** At the log's end (truncated), on a collision of the ego or when the ego leaves
  the road (terminated). The human (policy ``log``) is never stopped early: its record is
  the reference, and its overlaps with other boxes are counted like anyone's.
- **Measured per step** on the ego's rows: ``off_road``, ``ran_red_light``,
  ``route_progress`` (share of the logged path covered so far), ``log_distance`` [m] (to the
  logged ego at the same step); :mod:`tap_bench.bench.measures` reduces them per episode.

Coordinates: highway-env's y axis points to the driver's right, so the scene is built
mirrored (y and headings negated) and recorded back in WOMD's axes, as
:mod:`tap_bench.sim.recorder` does; the driver's left stays the driver's left.

**What an RL agent observes.** The configured highway-env observation (``Kinematics`` by
default: the ego and the 15 nearest road users, relative, normalised) and the route through
the dynamics: with meta-actions the low-level controller follows the route's lanes (at a
lane end it takes the route's next lane), so ``IDLE``, ``FASTER`` and ``SLOWER`` drive along
the route and ``LANE_LEFT``/``LANE_RIGHT`` move to the map's neighbour on that side. The
route is not in the observation array.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numba
import numpy as np
import pandas as pd
from highway_env import utils
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_lanes import FastPolyLane, LaneIndex, lane_points
from tap_bench.sim.womd_scene import (
    CURRENT_STEP,
    TRAFFIC,
    Scene,
    SceneError,
    SceneRef,
    WomdScenes,
    load_scene,
)

__all__ = ["OFF_ROAD_MARGIN", "ROUTE_CORRIDOR", "TRAFFIC", "LogVehicle", "WomdEnv",
           "WomdIDMVehicle", "WomdNetwork", "WomdRoad", "WomdScenes", "logged_route",
           "make_womd_env"]

OFF_ROAD_MARGIN = 0.5  # [m] beyond half the lane's width, from every lane centre: off road
ROUTE_CORRIDOR = 4.0  # [m] progress counts while the ego is this close to the logged path
ROUTE_OFF_MAP = 3.0  # [m] a logged position farther than half a lane width + this is off
STOP_MARGIN = 1.0  # [m] IDM stops its front bumper this far before a red stop point
STOP_LOOKAHEAD = 60.0  # [m] stop points farther ahead along the route are ignored
PARKED_DISTANCE = 1.0  # [m] a vehicle that moves less over the record stays parked (replays)
HIDDEN = 1.0e6  # [m] where an agent waits while the log has no valid state for it
TARGET_SPEEDS = (0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0, 25.0, 30.0)
"""Target speeds of the meta-action ego [m/s] (highway-env's default 20-30 m/s is a
motorway's; these cover a city street too)."""


def _sim(x: np.ndarray, y: np.ndarray) -> np.ndarray:
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
            built = FastPolyLane(_sim(points[:, 0], points[:, 1]).tolist(), lane.width,
                                 womd_id=lane.id, speed_limit=limit)
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

    def acceleration(self, ego_vehicle: ControlledVehicle, front_vehicle: Vehicle = None,
                     rear_vehicle: Vehicle = None) -> float:
        acc = super().acceleration(ego_vehicle, front_vehicle, rear_vehicle)
        if ego_vehicle is self:
            stop = getattr(self.road, "stop_distance", None)
            if stop is not None:
                d = stop(self)
                if d is not None:
                    acc = min(acc, self._stop_acceleration(d))
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


@numba.njit(cache=True, nogil=True)
def _crosses(ax, ay, bx, by, px, py, qx, qy):  # pragma: no cover - compiled
    """Whether the move p -> q crosses any segment a -> b (proper intersection)."""
    for k in range(ax.shape[0]):
        d1 = (bx[k] - ax[k]) * (py - ay[k]) - (by[k] - ay[k]) * (px - ax[k])
        d2 = (bx[k] - ax[k]) * (qy - ay[k]) - (by[k] - ay[k]) * (qx - ax[k])
        d3 = (qx - px) * (ay[k] - py) - (qy - py) * (ax[k] - px)
        d4 = (qx - px) * (by[k] - py) - (qy - py) * (bx[k] - px)
        if d1 * d2 < 0 and d3 * d4 < 0:
            return True
    return False


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
        self._lane_segments = _segments([_sim(*lane.centre.T) for lane in lanes])
        self._half = np.array([lane.width / 2 for lane in lanes])
        self._edges = _segments([_sim(*e.T) for e in road.road_edges])
        self._projections: dict[Any, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._positions: np.ndarray | None = None
        self._movers: list[Vehicle] = []
        signals = road.signals
        self._signal_lanes = [network.index.get(int(i)) for i in signals.lane]
        self._stop_s = []
        for k, index in enumerate(self._signal_lanes):
            if index is None:
                self._stop_s.append(np.nan)
                continue
            p = _sim(*signals.stop_point[k])
            self._stop_s.append(float(network.get_lane(index).local_coordinates(p)[0]))
        self._red = signals.red
        self._red_or_yellow = signals.red_or_yellow

    # the neighbour search, once per lane per step
    def act(self) -> None:
        self._projections.clear()
        self._movers = [v for v in self.vehicles if v.collidable]
        self._positions = (np.array([v.position for v in self._movers])
                           if self._movers else np.zeros((0, 2)))
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
        self.clock[0] += 1
        self._positions = None
        for vehicle in self.vehicles:
            vehicle.step(dt)
        checking = [v for v in self.vehicles if v.check_collisions]
        for vehicle in checking:
            for other in self.vehicles:
                if other is not vehicle and (not other.check_collisions
                                             or id(other) > id(vehicle)):
                    vehicle.handle_collisions(other, dt)

    # signals
    def stop_distance(self, vehicle: Vehicle) -> float | None:
        """Distance [m] along the vehicle's lanes to the nearest stop point ahead whose signal
        is red, or yellow and far enough to stop at (comfortable braking); None if none."""
        k = min(self.clock[0], len(self._red) - 1)
        if not len(self._signal_lanes) or k < 0:
            return None
        active = np.flatnonzero(self._red_or_yellow[k])
        if not len(active):
            return None
        network = self.network
        lane_index = vehicle.lane_index
        s = network.get_lane(lane_index).local_coordinates(vehicle.position)[0]
        ahead = [(lane_index, -s)]
        route = getattr(vehicle, "route", None)
        offset = network.get_lane(lane_index).length - s
        current = lane_index
        for _ in range(3):
            if offset > STOP_LOOKAHEAD:
                break
            nxt = network.next_lane(current, route=route, position=vehicle.position)
            if nxt == current:
                break
            ahead.append((nxt, offset))
            offset += network.get_lane(nxt).length
            current = nxt
        best = None
        for j in active:
            index = self._signal_lanes[j]
            for lane, base in ahead:
                if lane != index or not np.isfinite(self._stop_s[j]):
                    continue
                d = base + self._stop_s[j]
                if d < -0.5 or d > STOP_LOOKAHEAD:
                    continue
                if not self._red[k, j]:  # yellow: stop only when it can
                    brake = vehicle.speed ** 2 / max(2 * (d - vehicle.LENGTH / 2), 0.1)
                    if brake > -getattr(vehicle, "COMFORT_ACC_MIN", -5.0):
                        continue
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

    def off_road(self, before: np.ndarray, after: np.ndarray) -> bool:
        """SPEC section 8: farther than half the lane's width + :data:`OFF_ROAD_MARGIN` from
        every lane centre line, or across a road edge on the move ``before -> after``."""
        ax, ay, bx, by, owner = self._lane_segments
        clear = _lane_clearance(ax, ay, bx, by, self._half, owner, float(after[0]),
                                float(after[1]))
        if clear > OFF_ROAD_MARGIN:
            return True
        ex, ey, fx, fy, _ = self._edges
        return bool(len(ex)) and bool(_crosses(ex, ey, fx, fy, float(before[0]),
                                               float(before[1]), float(after[0]),
                                               float(after[1])))


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


def _path_progress(path: np.ndarray, cum: np.ndarray, p: np.ndarray) -> tuple[float, float]:
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


class _WomdHighwayEnv(AbstractEnv):
    """The highway-env environment under :class:`WomdEnv` (one scene at a time)."""

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update({
            "observation": {"type": "Kinematics"},
            "action": {"type": "DiscreteMetaAction", "target_speeds": list(TARGET_SPEEDS)},
            "simulation_frequency": 10,
            "policy_frequency": 2,
            "collision_reward": -1.0,
            "progress_reward": 1.0,
            "off_road_reward": -1.0,
        })
        return config

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        self.scene: Scene | None = None
        self.traffic = "log"
        self.clock = [CURRENT_STEP]
        self.replaying_ego = False
        super().__init__(config=config, render_mode=render_mode)

    idm_vehicle_class = WomdIDMVehicle
    """What :func:`tap_bench.sim.idm.take_over_ego` puts in the ego's place."""

    def _reset(self) -> None:
        if self.scene is None:  # highway-env resets once in its constructor
            self.road = None
            return
        scene = self.scene
        self.clock[0] = CURRENT_STEP
        network = WomdNetwork(scene.road)
        self.road = WomdRoad(network, scene, self.clock, np_random=self.np_random)
        sim_xy = _sim(scene.x, scene.y)  # (n, T, 2)
        sim_h = -scene.heading
        states = np.concatenate([sim_xy, sim_h[..., None], scene.speed[..., None]], axis=-1)
        self.states = states
        e = scene.ego
        future = np.flatnonzero(scene.valid[e, CURRENT_STEP:]) + CURRENT_STEP
        self.route, off = logged_route(network, sim_xy[e, future], sim_h[e, future])
        if off > 0.5:
            raise SceneError(
                f"scenario {scene.scenario_id}: the logged ego's path leaves the mapped lanes "
                f"({off:.0%} of its future positions are more than {ROUTE_OFF_MAP} m beyond "
                "a lane), so it has no route to follow. Drive another track (--ego ID) or "
                "leave the scenario out.")
        path = sim_xy[e, future]
        step_len = np.hypot(*np.diff(path, axis=0).T)
        self.path = path
        self.path_cum = np.r_[0.0, np.cumsum(step_len)]
        self.path_length = float(self.path_cum[-1])
        x, y, h, v = states[e, CURRENT_STEP]
        lane_index = network.get_closest_lane_index(np.array([x, y]), h)
        limits = [network.get_lane(i).speed_limit for i in self.route]
        target = float(min(limits)) if limits else float(v)
        ego = WomdMDPVehicle(self.road, np.array([x, y]), heading=h, speed=v,
                             target_lane_index=lane_index, target_speed=target,
                             target_speeds=self.config["action"].get("target_speeds",
                                                                     TARGET_SPEEDS),
                             route=list(self.route))
        ego.LENGTH, ego.WIDTH = float(scene.length[e]), float(scene.width[e])
        ego.diagonal = math.hypot(ego.LENGTH, ego.WIDTH)
        self.road.vehicles.append(ego)
        self.controlled_vehicles = [ego]
        self.simulated: dict[int, Vehicle] = {}  # other simulated agents by row
        for row in range(len(scene.track_ids)):
            if row == e:
                continue
            vehicle = self._traffic_vehicle(network, row, states, sim_xy, sim_h)
            self.road.vehicles.append(vehicle)
            if not isinstance(vehicle, LogVehicle):
                self.simulated[row] = vehicle
        self.replaying_ego = False
        self._last_ego = np.array([x, y])
        self.progress = 0.0
        self.flags = {"off_road": False, "ran_red_light": False}

    def _traffic_vehicle(self, network: WomdNetwork, row: int, states: np.ndarray,
                         sim_xy: np.ndarray, sim_h: np.ndarray) -> Vehicle:
        scene = self.scene
        valid = scene.valid[row]
        replay = LogVehicle(self.road, row, states[row], valid, scene.length[row],
                            scene.width[row], self.clock)
        if self.traffic != "idm" or scene.object_types[row] != "vehicle" \
                or not valid[CURRENT_STEP]:
            return replay
        steps = np.flatnonzero(valid[CURRENT_STEP:]) + CURRENT_STEP
        xy = sim_xy[row, steps]
        if len(xy) < 2 or np.hypot(*(xy[-1] - xy[0])) < PARKED_DISTANCE:
            return replay
        route, off = logged_route(network, xy, sim_h[row, steps])
        if off > 0.25:
            return replay
        x, y, h, v = states[row, CURRENT_STEP]
        lane_index = network.get_closest_lane_index(np.array([x, y]), h)
        vehicle = WomdIDMVehicle(self.road, np.array([x, y]), heading=h, speed=v,
                                 target_lane_index=lane_index,
                                 target_speed=max(float(np.nanmax(scene.speed[row, steps])),
                                                  1.0),
                                 route=route)
        vehicle.LENGTH, vehicle.WIDTH = float(scene.length[row]), float(scene.width[row])
        vehicle.diagonal = math.hypot(vehicle.LENGTH, vehicle.WIDTH)
        vehicle.check_collisions = False  # the ego's collisions are checked (its pairs)
        vehicle.row = row
        return vehicle

    def replay_ego(self) -> None:
        """Make the ego replay its log (the policy ``log``: the human)."""
        scene = self.scene
        e = scene.ego
        old = self.vehicle
        new = LogVehicle(self.road, e, self.states[e], scene.valid[e], scene.length[e],
                         scene.width[e], self.clock)
        new.check_collisions = True
        new.lane_index = old.lane_index
        vehicles = self.road.vehicles
        vehicles[vehicles.index(old)] = new
        self.controlled_vehicles = [new]
        self.replaying_ego = True

    # per step bookkeeping (called by WomdEnv after every simulated step)
    def measure_step(self) -> dict[str, float]:
        ego = self.vehicle
        p = np.asarray(ego.position, float)
        off = self.road.off_road(self._last_ego, p)
        red = self.road.crossed_red(self._last_ego, p)
        self._last_ego = p.copy()
        if self.path_length > 0 and len(self.path) >= 2:
            s, d = _path_progress(self.path, self.path_cum, p)
            if d <= ROUTE_CORRIDOR:
                self.progress = max(self.progress, s / self.path_length)
        self.flags["off_road"] |= off
        self.flags["ran_red_light"] |= red
        k = self.clock[0]
        e = self.scene.ego
        if k < self.scene.n_steps and self.scene.valid[e, k]:
            lx, ly = self.states[e, k, :2]
            log_distance = math.hypot(p[0] - lx, p[1] - ly)
        else:
            log_distance = float("nan")
        return {"off_road": off, "ran_red_light": red,
                "route_progress": self.route_progress, "log_distance": log_distance}

    @property
    def route_progress(self) -> float:
        """Share of the logged ego's path covered so far (NaN when the human moved < 1 m)."""
        if self.path_length < 1.0:
            return float("nan")
        return float(min(self.progress, 1.0))

    def _info(self, obs: Any, action: Any = None) -> dict:
        if self.road is None or not self.controlled_vehicles:  # the constructor's reset
            return {}
        return super()._info(obs, action)

    def _reward(self, action: Any) -> float:
        cfg = self.config
        return float(cfg["collision_reward"] * self.vehicle.crashed
                     + cfg["off_road_reward"] * self.flags["off_road"]
                     + cfg["progress_reward"] * (0.0 if math.isnan(self.route_progress)
                                                 else self.route_progress)
                     / max(1, (self.scene.n_steps - CURRENT_STEP) * cfg["policy_frequency"]
                           / cfg["simulation_frequency"]))

    def _is_terminated(self) -> bool:
        if self.replaying_ego:
            return False
        return bool(self.vehicle.crashed or self.flags["off_road"])

    def _is_truncated(self) -> bool:
        return self.clock[0] >= self.scene.n_steps - 1


class WomdEnv(gym.Wrapper):
    """``tap_bench/womd-v0``: one recorded scenario per episode (see the module docstring).

    Behaves like the highway-env environment it wraps (``env.unwrapped``), and like
    :class:`~tap_bench.sim.scenario_env.ScenarioEnv` for rollouts: :meth:`trajectories`
    gives the episode's table, :meth:`episode_info` its measures.

    Args:
        scenes: the files and settings.
        record: build the trajectory table (off: faster training).
        render_mode: highway-env's.

    Attributes:
        scenario: the :class:`WomdScenes` (``scenario.name`` is the ``env`` column).
        catalog: the scenarios, in seed order.
        scene: the current :class:`~tap_bench.sim.womd_scene.Scene`.
    """

    def __init__(self, scenes: WomdScenes, *, record: bool = True,
                 render_mode: str | None = None) -> None:
        config = {**_WomdHighwayEnv.default_config(), "policy_frequency":
                  scenes.policy_frequency, **dict(scenes.config)}
        inner = _WomdHighwayEnv(config=config, render_mode=render_mode)
        super().__init__(inner)
        self.scenario = scenes
        self.record = record
        self.catalog = scenes.catalog()
        if not self.catalog:
            raise SceneError(f"{', '.join(scenes.files)}: no scenario in these files.")
        self.scene: Scene | None = None
        self._cache: dict[SceneRef, Scene] = {}
        self._seed: int | None = None
        self._render_frame = inner._automatic_rendering
        inner._automatic_rendering = self._intermediate_frame
        self._define_spaces = inner.define_spaces
        inner.define_spaces = self._fast_spaces
        self.max_steps = 0

    def _fast_spaces(self) -> None:
        from tap_bench.sim.observation import use_fast_observation

        self._define_spaces()
        if self.env.unwrapped.road is not None:
            use_fast_observation(self.env)

    def scene_at(self, index: int) -> Scene:
        """The scene of seed ``index`` (decoded once, a few kept)."""
        if not 0 <= index < len(self.catalog):
            raise ParameterError("seed", index, f"0 to {len(self.catalog) - 1}: the index of "
                                 f"a scenario in the {len(self.catalog)} of "
                                 f"{', '.join(self.scenario.files)}")
        ref = self.catalog[index]
        scene = self._cache.get(ref)
        if scene is None:
            scene = load_scene(ref, ego=self.scenario.ego)
            if len(self._cache) >= 4:
                self._cache.pop(next(iter(self._cache)))
            self._cache[ref] = scene
        return scene

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        """Start the scenario of ``seed`` (its index in the files) or of
        ``options["scenario_id"]``; without either, the next one."""
        options = dict(options or {})
        wanted = options.pop("scenario_id", None)
        if wanted is not None:
            index = self._index_of(str(wanted))
        elif seed is not None:
            index = int(seed)
        else:
            index = 0 if self._seed is None else (self._seed + 1) % len(self.catalog)
        self.scene = self.scene_at(index)
        self._seed = index
        inner = self.env.unwrapped
        inner.scene = self.scene
        inner.traffic = self.scenario.traffic
        obs, info = self.env.reset(seed=index, options=options or None)
        self.max_steps = int(np.ceil((self.scene.n_steps - 1 - CURRENT_STEP)
                                     * inner.config["policy_frequency"]
                                     / inner.config["simulation_frequency"]))
        self._start_record()
        return obs, info

    def _index_of(self, scenario_id: str) -> int:
        for i in range(len(self.catalog)):
            if self.scene_at(i).scenario_id == scenario_id:
                return i
        raise ParameterError("scenario_id", scenario_id, "the id of a scenario in "
                             f"{', '.join(self.scenario.files)}")

    # recording
    def _start_record(self) -> None:
        scene = self.scene
        n, t = scene.x.shape
        self._rec = {name: getattr(scene, name).copy() for name in
                     ("x", "y", "heading", "speed", "vx", "vy", "valid")}
        self._crashed = np.zeros((n, t), bool)
        self._ego_cols = {"off_road": np.zeros(t, bool), "ran_red_light": np.zeros(t, bool),
                          "route_progress": np.zeros(t),
                          "log_distance": np.full(t, np.nan)}
        self._last_step = CURRENT_STEP
        self.crash_with = ""
        self.crash_from_behind_by_log = False

    def _frame(self) -> None:
        inner = self.env.unwrapped
        k = inner.clock[0]
        if k <= self._last_step or k >= self.scene.n_steps:
            return
        self._last_step = k
        measured = inner.measure_step()
        e = self.scene.ego
        for name, value in measured.items():
            self._ego_cols[name][k] = value
        ego = inner.vehicle
        if ego.crashed and not self._crashed[e, :k].any():
            self._crash_partner(ego)
        if not self.record:
            return
        rec = self._rec
        # the ego as the policy left it (IDM and the log policy put their own in its place)
        for row, vehicle in (*inner.simulated.items(), (e, ego)):
            self._crashed[row, k] = vehicle.crashed
            if isinstance(vehicle, LogVehicle):
                continue
            heading = -vehicle.heading
            heading = math.pi - (math.pi - heading) % (2 * math.pi)
            speed = max(float(vehicle.speed), 0.0)
            rec["x"][row, k] = vehicle.position[0]
            rec["y"][row, k] = -vehicle.position[1]
            rec["heading"][row, k] = heading
            rec["speed"][row, k] = speed
            rec["vx"][row, k] = speed * math.cos(heading)
            rec["vy"][row, k] = speed * math.sin(heading)
            rec["valid"][row, k] = True

    def _crash_partner(self, ego: Vehicle) -> None:
        inner = self.env.unwrapped
        others = [v for v in inner.road.vehicles if v is not ego and v.collidable]
        if not others:
            return
        other = min(others, key=lambda v: float(np.hypot(*(v.position - ego.position))))
        row = getattr(other, "row", None)
        self.crash_with = str(self.scene.track_ids[row]) if row is not None else ""
        ahead = float(np.dot(other.position - ego.position, ego.direction))
        self.crash_from_behind_by_log = isinstance(other, LogVehicle) and ahead < 0

    def _intermediate_frame(self) -> None:
        self._frame()
        self._render_frame()

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._frame()
        info = {**info, "scenario_id": self.scene.scenario_id}
        return obs, reward, terminated, truncated and not terminated, info

    def trajectories(self, **columns: object) -> pd.DataFrame:
        """The episode so far as a trajectory table: every track, from the record's start
        to the last simulated step, in WOMD's axes (SPEC section 1).

        Args:
            **columns: constant columns to add (``policy="idm"``).
        """
        scene = self.scene
        n, _ = scene.x.shape
        last = self._last_step + 1
        t = last
        rec = self._rec
        ego_rows = np.arange(n) == scene.ego
        data = {
            "scenario_id": np.full(n * t, scene.scenario_id, dtype=object),
            "track_id": np.repeat(scene.track_ids.astype(object), t),
            "t": np.tile(np.round(scene.times[:t] - scene.times[0], 6), n),
            **{name: rec[name][:, :t].ravel() for name in
               ("x", "y", "heading", "speed", "valid", "vx", "vy")},
            "object_type": np.repeat(scene.object_types.astype(object), t),
            "is_ego": np.repeat(ego_rows, t),
            "source": np.full(n * t, "womd-sim", dtype=object),
            "env": np.full(n * t, self.scenario.name, dtype=object),
        }
        policy = columns.pop("policy", None)
        if policy is not None:
            data["policy"] = np.full(n * t, policy, dtype=object)
        data["seed"] = np.full(n * t, self._seed, dtype=np.int64)
        data["episode"] = np.zeros(n * t, np.int64)
        data["crashed"] = self._crashed[:, :t].ravel()
        data["length"] = np.repeat(scene.length, t)
        data["width"] = np.repeat(scene.width, t)
        for name, values in self._ego_cols.items():
            col = np.full((n, t), np.nan if values.dtype.kind == "f" else False,
                          dtype=values.dtype if values.dtype.kind == "f" else object)
            col[scene.ego] = values[:t]
            data[name] = col.ravel() if values.dtype.kind == "f" else \
                pd.array(col.ravel(), dtype="boolean")
        data.update({name: np.full(n * t, value, dtype=object) for name, value in
                     columns.items()})
        table = pd.DataFrame(data, copy=False)
        kin = ["x", "y", "heading", "speed", "vx", "vy"]
        table.loc[~table["valid"].to_numpy(bool), kin] = np.nan
        return table

    def episode_info(self) -> dict[str, Any]:
        """The episode's row beyond :data:`~tap_bench.sim.rollout.EPISODE_COLUMNS`."""
        inner = self.env.unwrapped
        dist = self._ego_cols["log_distance"][CURRENT_STEP + 1:self._last_step + 1]
        dist = dist[np.isfinite(dist)]
        return {"scenario_id": self.scene.scenario_id, "traffic": self.scenario.traffic,
                "off_road": bool(inner.flags["off_road"]),
                "route_progress": inner.route_progress,
                "ran_red_light": bool(inner.flags["ran_red_light"]),
                "log_ade": float(dist.mean()) if len(dist) else float("nan"),
                "log_fde": float(dist[-1]) if len(dist) else float("nan"),
                "crash_with": self.crash_with,
                "crash_from_behind_by_log": bool(self.crash_from_behind_by_log)}


def make_womd_env(files: str | os.PathLike | Iterable[str | os.PathLike] | WomdScenes,
                  *, traffic: str = "log", ego: str = "sdc", policy_frequency: int = 2,
                  config: Mapping[str, Any] | None = None, record: bool = True,
                  render_mode: str | None = None) -> WomdEnv:
    """Build ``tap_bench/womd-v0`` (what ``gymnasium.make("tap_bench/womd-v0", files=...)``
    calls).

    Args:
        files: WOMD files, patterns or folders, or :class:`WomdScenes`.
        traffic: ``"log"`` (replay, non-reactive) or ``"idm"`` (reactive).
        ego: ``"sdc"`` or a track id.
        policy_frequency: decisions per second (1, 2, 5 or 10).
        config: more highway-env config (observation, action, rewards).
        record: build the trajectory table.
        render_mode: highway-env's render mode.
    """
    if isinstance(files, WomdScenes):
        scenes = files
    else:
        items = [files] if isinstance(files, str | os.PathLike) else list(files)
        scenes = WomdScenes(tuple(str(f) for f in items), traffic, str(ego),
                            policy_frequency)
    if config:
        scenes = scenes.with_overrides(config)
    return WomdEnv(scenes, record=record, render_mode=render_mode)
