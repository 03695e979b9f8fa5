"""The traffic core: every IDM/MOBIL vehicle of a highway-env road decided and moved at once.

highway-env builds the scene (road network, vehicles, the ego's action and observation
types); :class:`TrafficRoad`, a subclass of its ``Road``, then runs each simulated step with
the whole road as arrays (:class:`RoadState`: positions, headings, speeds, and every lane's
coordinates of every vehicle, :mod:`tap_bench.sim.lane_frames`):

1. ``act``: in the road's order, each vehicle the core drives follows its route
   (highway-env's ``follow_road``, the network's routing), keeps or drops a lane change in
   progress, and, once per ``LANE_CHANGE_DELAY``, asks for a MOBIL decision. The decisions
   are taken together (:meth:`TrafficRoad._decide`: the six IDM accelerations MOBIL
   compares for every candidate lane in one array pass); a vehicle's new target lane is
   set before any later vehicle reads it (a vehicle dropping its lane change looks at who
   else targets that lane; the core takes the pending decisions first). Then every vehicle
   gets its steering (lane keeping to its target lane) and its IDM acceleration (towards
   its leader, and towards the leader on its target lane while changing: the smaller), all
   at once (:mod:`tap_bench.sim.driver_models`).
2. ``step``: every vehicle moves by the kinematic bicycle model at once, its lane is looked
   up (:meth:`~tap_bench.sim.lane_frames.LaneSet.closest`), and the pairs of objects close
   enough to touch are handed to highway-env's collision check (:func:`near_pairs`).

The core drives highway-env's :class:`~highway_env.vehicle.behavior.IDMVehicle` and its
subclasses that change only constants (``DISTANCE_WANTED``, ``POLITENESS`` ...), and
:class:`TrafficVehicle` subclasses, which adjust a decision through its hooks. Any other
vehicle (the ego of a policy, a user's class with its own ``act``) acts and moves by its
own methods, in its place in the road's order; for a class that drives itself as traffic
the run says so once (a warning).

Each model's constants are read from each vehicle (instance first, then class): highway-env's
names (``COMFORT_ACC_MAX``, ``TIME_WANTED``, ``POLITENESS``, ``LANE_CHANGE_MIN_ACC_GAIN``,
``LANE_CHANGE_MAX_BRAKING_IMPOSED``, ``LANE_CHANGE_DELAY``, ``KP_LATERAL`` ...).
"""

from __future__ import annotations

import bisect
import functools
import math
import warnings
from typing import Any

import numpy as np
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Landmark, RoadObject

from tap_bench.sim.driver_models import (
    bicycle_one,
    bicycle_step,
    desired_gap,
    desired_gap_one,
    idm_acceleration,
    idm_one,
    mobil_incentive,
    steering_angle,
    steering_one,
)
from tap_bench.sim.lane_frames import LaneSet, lane_coordinates

__all__ = ["ON_LANE_MARGIN", "SCALAR_MAX_OBJECTS", "TOUCH_MARGIN", "RoadState", "TrafficRoad",
           "TrafficVehicle", "near_pairs", "traffic_env_class"]

ON_LANE_MARGIN = 1.0
"""How far [m] beyond half its width a lane's neighbour search still finds a vehicle."""
TOUCH_MARGIN = 1e-6
"""Slack [m] of the proximity test of :func:`near_pairs`."""
_NEAR_END = 1e-6  # [m] slack of the test that a vehicle reached its target lane's end
SCALAR_MAX_OBJECTS = 400
"""Roads with at most this many objects are computed one vehicle at a time in plain floats
(the ``*_one`` forms of :mod:`tap_bench.sim.driver_models` and
:class:`~tap_bench.sim.lane_frames.LaneSet`); larger ones as arrays. The same equations;
numpy's fixed cost per call outweighs its speed per element up to this size at least
(docs/simulation.md, "The traffic core")."""


class TrafficVehicle(IDMVehicle):
    """An IDM/MOBIL vehicle whose decisions a subclass adjusts through three hooks, which
    the core calls as highway-env's own ``act`` and ``step`` would (off a
    :class:`TrafficRoad`, this class acts and moves by highway-env's methods, with the
    same hooks)."""

    def prepare_decision(self) -> None:
        """Called first in the vehicle's turn, before it follows its route and decides on a
        lane change (set ``route`` or ``target_lane_index`` here)."""

    def adjust_action(self) -> None:
        """Called after the vehicle's action is decided (change ``self.action`` here)."""

    def after_step(self, dt: float) -> None:
        """Called after the vehicle moved by ``dt`` [s]."""

    def act(self, action: dict | str | None = None) -> None:
        self.prepare_decision()
        super().act(action)
        self.adjust_action()

    def step(self, dt: float) -> None:
        super().step(dt)
        self.after_step(dt)


_DECISION_METHODS = ("change_lane_policy", "mobil", "acceleration", "desired_gap",
                     "steering_control", "lane_distance_to", "velocity", "direction")
_MOVE_METHODS = ("clip_actions", "on_state_update")


@functools.cache
def _driven(cls: type) -> str | None:
    """How the core drives vehicles of ``cls``: ``"idm"`` (highway-env's IDMVehicle model),
    ``"hooks"`` (a :class:`TrafficVehicle`), or None (the vehicle acts itself)."""
    if not issubclass(cls, IDMVehicle):
        return None
    if any(getattr(cls, name) is not getattr(IDMVehicle, name) for name in _DECISION_METHODS):
        return None
    if issubclass(cls, TrafficVehicle):
        return "hooks" if cls.act is TrafficVehicle.act else None
    return "idm" if cls.act is IDMVehicle.act else None


@functools.cache
def _moved(cls: type) -> str | None:
    """How the core moves objects of ``cls``: ``"plain"`` (the bicycle model),
    ``"timer"`` (and the IDM's decision timer), ``"hooks"`` (and
    :meth:`TrafficVehicle.after_step`), or None (the object moves itself)."""
    if not issubclass(cls, Vehicle) or any(getattr(cls, name) is not getattr(Vehicle, name)
                                           for name in _MOVE_METHODS):
        return None
    return {Vehicle.step: "plain", IDMVehicle.step: "timer",
            TrafficVehicle.step: "hooks"}.get(cls.step)


_HIGHWAY_ENV_ACTS = (Vehicle.act, ControlledVehicle.act, MDPVehicle.act)
_WARNED: set[type] = set()


def _warn_self_driven(cls: type) -> None:
    """Say once per class that highway-env drives vehicles of ``cls`` (a class of traffic
    with its own behaviour; the egos of highway-env's action types are not meant)."""
    if cls in _WARNED or (not issubclass(cls, IDMVehicle) and cls.act in _HIGHWAY_ENV_ACTS):
        return
    _WARNED.add(cls)
    own = [name for name in ("act", *_DECISION_METHODS)
           if issubclass(cls, IDMVehicle) and getattr(cls, name) is not getattr(
               TrafficVehicle if issubclass(cls, TrafficVehicle) else IDMVehicle, name)]
    warnings.warn(
        f"{cls.__module__}.{cls.__qualname__} defines its own "
        f"{', '.join(own) if own else 'act'}: tap-bench's traffic core does not drive it, "
        "highway-env does, one vehicle at a time (slower; the same model otherwise). To "
        "have the core drive it, keep IDMVehicle's methods and change constants, or adjust "
        "decisions through tap_bench.sim.traffic.TrafficVehicle's hooks.",
        RuntimeWarning, stacklevel=3)


@functools.cache
def _own_velocity(cls: type) -> bool:
    return cls.velocity not in (Vehicle.velocity, RoadObject.velocity)


class RoadState:
    """The road's searchable objects (vehicles and objects but landmarks, in the road's
    order) as arrays, and each lane's coordinates of all of them, as they stand while the
    vehicles act (nothing moves in ``act``).

    Attributes:
        objects: the objects, in order; ``index`` maps ``id(object)`` to its row.
        scalar: whether the road is computed one vehicle at a time
            (:data:`SCALAR_MAX_OBJECTS`), else as arrays.
        xs, ys, speed, heading, cos, sin, vx, vy: (n,) their state [m, m/s, rad] as
            Python lists; ``arrays``: (speed, cos, sin, vx, vy) as arrays (None when
            ``scalar``).
    """

    def __init__(self, road: TrafficRoad) -> None:
        self.road = road
        self.lanes = road.lane_set()
        self.objects = [o for o in road.vehicles + road.objects if not isinstance(o, Landmark)]
        self.index = {id(o): k for k, o in enumerate(self.objects)}
        n = len(self.objects)
        self.scalar = n <= SCALAR_MAX_OBJECTS
        if self.scalar:
            self.positions = self.arrays = None
            self.xs, self.ys, self.speed, self.heading = [], [], [], []
            self.cos, self.sin, self.vx, self.vy = [], [], [], []
            for o in self.objects:
                position, speed, heading = o.position, float(o.speed), float(o.heading)
                cos, sin = math.cos(heading), math.sin(heading)
                self.xs.append(float(position[0]))
                self.ys.append(float(position[1]))
                self.speed.append(speed)
                self.heading.append(heading)
                self.cos.append(cos)
                self.sin.append(sin)
                self.vx.append(speed * cos)
                self.vy.append(speed * sin)
        else:
            self.positions = np.array([o.position for o in self.objects],
                                      dtype=float).reshape(n, 2)
            self.xs, self.ys = self.positions[:, 0].tolist(), self.positions[:, 1].tolist()
            speed = np.array([o.speed for o in self.objects], dtype=float)
            heading = np.array([o.heading for o in self.objects], dtype=float)
            cos, sin = np.cos(heading), np.sin(heading)
            self.arrays = (speed, cos, sin, speed * cos, speed * sin)
            self.cos, self.sin = cos.tolist(), sin.tolist()
            self.speed, self.heading = speed.tolist(), heading.tolist()
            self.vx, self.vy = self.arrays[3].tolist(), self.arrays[4].tolist()
        for k, o in enumerate(self.objects):  # a class with its own velocity
            if _own_velocity(type(o)):
                self.vx[k], self.vy[k] = map(float, o.velocity)
                if self.arrays is not None:
                    self.arrays[3][k], self.arrays[4][k] = self.vx[k], self.vy[k]
        self._frames: dict[int, tuple[Any, list[float], list[float]]] = {}
        self._tables: dict[int, tuple[list[float], list[int]]] = {}
        self._s = self._r = None
        self._constants: dict[int, tuple[float, ...]] = {}
        self._own: tuple[list[bool], list[int], list[float]] | None = None
        self._own_arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def matrix(self) -> np.ndarray:
        """(n, m) every object's longitudinal coordinate [m] on every lane of the road."""
        if self._s is None:
            self._s, self._r = self.lanes.coordinates(self.positions)
        return self._s

    def constants(self, vehicle: Any) -> tuple[float, ...]:
        """The IDM constants of ``vehicle``: a_max, delta, s0 [m], T [s], b [m/s^2]."""
        got = self._constants.get(id(vehicle))
        if got is None:
            got = self._constants[id(vehicle)] = (
                vehicle.COMFORT_ACC_MAX, vehicle.DELTA, vehicle.DISTANCE_WANTED,
                vehicle.TIME_WANTED, -vehicle.COMFORT_ACC_MIN)
        return got

    def own(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(n,) per object: whether it is a vehicle, the column of its lane in the road's
        lanes (-1: none or not one of them), its desired speed [m/s] (``target_speed``,
        0 without one, within its lane's speed limit)."""
        if self._own_arrays is None:
            is_vehicle, columns, desired = self.own_lists()
            self._own_arrays = (np.array(is_vehicle, dtype=bool),
                                np.array(columns, dtype=int), np.array(desired, dtype=float))
        return self._own_arrays

    def own_lists(self) -> tuple[list[bool], list[int], list[float]]:
        """:meth:`own` as lists."""
        if self._own is None:
            column, is_vehicle = self.lanes.column, []
            columns, desired = [], []
            for o in self.objects:
                vehicle = isinstance(o, Vehicle)
                lane = getattr(o, "lane", None)
                is_vehicle.append(vehicle)
                columns.append(column.get(id(lane), -1) if lane is not None else -1)
                target = getattr(o, "target_speed", 0) if vehicle else 0
                if vehicle and lane and lane.speed_limit is not None:
                    target = min(max(target, 0), lane.speed_limit)
                desired.append(float(target))
            self._own = (is_vehicle, columns, desired)
        return self._own

    def frame(self, lane: Any) -> tuple[list[float], list[float]]:
        """Every object's longitudinal and lateral coordinate [m] on ``lane``."""
        got = self._frames.get(id(lane))
        if got is None:
            j = self.lanes.column.get(id(lane))
            if j is None:  # not a lane of the network
                points = self.positions if self.positions is not None else np.array(
                    [self.xs, self.ys], dtype=float).T.reshape(-1, 2)
                s, r = (a.tolist() for a in lane_coordinates(lane, points))
            elif self.scalar:
                s, r = self.lanes.frame_one(j, self.xs, self.ys)
            else:
                self.matrix()  # every lane's frame at once
                s, r = self._s[:, j].tolist(), self._r[:, j].tolist()
            got = self._frames[id(lane)] = (lane, s, r)
        return got[1], got[2]

    def table(self, lane: Any) -> tuple[list[float], list[int]]:
        """The objects on ``lane`` (within :data:`ON_LANE_MARGIN` of its sides, from a
        vehicle length before its start to a vehicle length after its end), sorted by
        longitudinal coordinate, then row: their coordinates and rows."""
        got = self._tables.get(id(lane))
        if got is None:
            s, r = self.frame(lane)
            j = self.lanes.column.get(id(lane))
            width = (self.lanes.widths(j, np.asarray(s)) if j is not None
                     else np.array([lane.width_at(v) for v in s], dtype=float))
            if np.ndim(width):
                half = (np.asarray(width) / 2 + ON_LANE_MARGIN).tolist()
            else:
                half = [width / 2 + ON_LANE_MARGIN] * len(s)
            low, high = -lane.VEHICLE_LENGTH, lane.length + lane.VEHICLE_LENGTH
            on = sorted((s_k, k) for k, (s_k, r_k, h) in enumerate(zip(s, r, half, strict=True))
                        if abs(r_k) <= h and low <= s_k < high)
            got = self._tables[id(lane)] = ([s_k for s_k, _ in on], [k for _, k in on])
        return got

    def fronts(self, lanes: list[Any], rows: list[int]) -> list[int]:
        """The row of the object just ahead of each row on each lane (-1: none), as
        :meth:`neighbours` finds it (which answers where coordinates tie)."""
        out = []
        for lane, k in zip(lanes, rows, strict=True):
            s_list, order = self.table(lane)
            s = self.frame(lane)[0][k]
            p = bisect.bisect_left(s_list, s)
            m = len(order)
            if p < m and order[p] == k:
                p += 1
            if p >= m:
                out.append(-1)
            elif s_list[p] == s or (p + 1 < m and s_list[p + 1] == s_list[p]):
                out.append(self.neighbours(lane, k)[0])
            else:
                out.append(order[p])
        return out

    def neighbours(self, lane: Any, k: int) -> tuple[int, int]:
        """Rows of the objects just ahead of and just behind row ``k`` on ``lane`` (-1:
        none). Ahead: the smallest coordinate at or beyond ``k``'s (ties: the last in the
        road's order); behind: the largest below it (ties: the first)."""
        s_list, rows = self.table(lane)
        s = self.frame(lane)[0][k]
        front = -1
        p = bisect.bisect_left(s_list, s)
        while p < len(rows):
            end = bisect.bisect_right(s_list, s_list[p], p)
            others = [j for j in rows[p:end] if j != k]
            if others:
                front = max(others)
                break
            p = end
        rear = -1
        p = bisect.bisect_left(s_list, s) - 1
        if p >= 0:
            rear = min(rows[bisect.bisect_left(s_list, s_list[p]):p + 1])
        return front, rear


class TrafficRoad(Road):
    """highway-env's road, its vehicles decided and moved by the traffic core (see the
    module docstring). Build one from a road highway-env made with :meth:`taking_over`."""

    @classmethod
    def taking_over(cls, road: Road) -> TrafficRoad:
        """A :class:`TrafficRoad` with ``road``'s network, vehicles, objects, random
        generator and settings; the vehicles and objects now on it."""
        new = cls.__new__(cls)
        new.__dict__.update(vars(road))
        for obj in new.vehicles + new.objects:
            if obj.road is road:
                obj.road = new
        return new

    def lane_set(self) -> LaneSet:
        """Every lane of the network as a :class:`~tap_bench.sim.lane_frames.LaneSet`, in
        the network's order (highway-env builds a network once per scene)."""
        lanes = self.__dict__.get("_lane_set")
        if lanes is None:
            lanes = self.__dict__["_lane_set"] = LaneSet([
                ((start, end, i), lane) for start, ends in self.network.graph.items()
                for end, row in ends.items() for i, lane in enumerate(row)])
        return lanes

    def _core_applies(self) -> bool:
        # the neighbour search over connected lanes (highway-env >= 1.12, off by default)
        # is highway-env's alone
        return not getattr(self, "neighbour_vehicles_connected_lanes", False)

    # -- act ---------------------------------------------------------------------------
    def act(self) -> None:
        """Every vehicle decides its action (see the module docstring)."""
        if not self._core_applies():
            super().act()
            return
        state = RoadState(self)
        network = self.network
        drivers: list[tuple[Any, str]] = []
        pending: list[tuple[Any, list[Any]]] = []
        for vehicle in self.vehicles:
            how = _driven(type(vehicle))
            if how is None:
                _warn_self_driven(type(vehicle))
                self._decide(pending, state)
                vehicle.act()
                continue
            if how == "hooks":
                vehicle.prepare_decision()
            if vehicle.crashed:  # a crashed vehicle keeps its last action
                if how == "hooks":
                    vehicle.adjust_action()
                continue
            self._follow_road(vehicle, state)
            drivers.append((vehicle, how))
            if not vehicle.enable_lane_change:
                continue
            if vehicle.lane_index != vehicle.target_lane_index:
                if vehicle.lane_index[:2] == vehicle.target_lane_index[:2]:
                    if any(vehicle.target_lane_index in lanes or
                           vehicle.target_lane_index == v.target_lane_index
                           for v, lanes in pending):
                        self._decide(pending, state)
                    self._keep_or_drop(vehicle, state)
                continue
            if not vehicle.LANE_CHANGE_DELAY < vehicle.timer:
                continue
            vehicle.timer = 0
            if abs(state.speed[state.index[id(vehicle)]]) < 1:  # only moving vehicles change
                continue
            lanes = [index for index in network.side_lanes(vehicle.lane_index)
                     if network.get_lane(index).is_reachable_from(vehicle.position)]
            if lanes:
                pending.append((vehicle, lanes))
        self._decide(pending, state)
        self._drive(drivers, state)

    def _follow_road(self, vehicle: Any, state: RoadState) -> None:
        """The vehicle's ``follow_road`` (the network's routing to the next lane), called
        where the vehicle may have reached its target lane's end, or always for a class
        with its own ``follow_road``."""
        if type(vehicle).follow_road is ControlledVehicle.follow_road:
            lane = self.network.get_lane(vehicle.target_lane_index)
            s = state.frame(lane)[0][state.index[id(vehicle)]]
            if not s > lane.length - lane.VEHICLE_LENGTH / 2 - _NEAR_END:
                return
        vehicle.follow_road()

    def _keep_or_drop(self, vehicle: Any, state: RoadState) -> None:
        """A vehicle changing lanes drops the change (targets its own lane again) when
        another controlled vehicle, not on the target lane, also targets it, ahead of it
        and closer than its desired gap (:func:`desired_gap`)."""
        target = vehicle.target_lane_index
        k = state.index[id(vehicle)]
        s = state.frame(vehicle.lane)[0]
        for other in self.vehicles:
            if (other is vehicle or other.lane_index == target
                    or not isinstance(other, ControlledVehicle)
                    or other.target_lane_index != target):
                continue
            j = state.index.get(id(other))
            if j is None:
                continue
            gap = s[j] - s[k]
            approach = ((state.vx[k] - state.vx[j]) * state.cos[k]
                        + (state.vy[k] - state.vy[j]) * state.sin[k])
            s_star = desired_gap_one(state.speed[k], approach, vehicle.DISTANCE_WANTED,
                                     vehicle.TIME_WANTED, vehicle.COMFORT_ACC_MAX,
                                     -vehicle.COMFORT_ACC_MIN)
            if 0 < gap < s_star:
                vehicle.target_lane_index = vehicle.lane_index
                return

    def _decide(self, pending: list[tuple[Any, list[Any]]], state: RoadState) -> None:
        """MOBIL for every (vehicle, candidate lane) of ``pending`` at once; each vehicle
        then targets the last candidate lane (in the network's side-lane order) that is
        safe for its new follower and worth it; ``pending`` is emptied."""
        if not pending:
            return
        network = self.network
        rows: list[tuple[Any, int, int]] = []  # (driver, follower row, leader row)
        for vehicle, lanes in pending:
            k = state.index[id(vehicle)]
            old_front, old_rear = state.neighbours(vehicle.lane, k)
            for lane_index in lanes:
                new_front, new_rear = state.neighbours(network.get_lane(lane_index), k)
                rows += [(vehicle, new_rear, new_front), (vehicle, new_rear, k),
                         (vehicle, k, new_front), (vehicle, k, old_front),
                         (vehicle, old_rear, k), (vehicle, old_rear, old_front)]
        a = self._idm(rows, state)
        r = 0
        for vehicle, lanes in pending:
            limit = -vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED
            for lane_index in lanes:
                (new_follower, new_follower_after, own_after, own, old_follower,
                 old_follower_after) = a[r:r + 6]
                r += 6
                if new_follower_after < limit:
                    continue  # unsafe for the new follower
                if vehicle.route and vehicle.route[0][2] is not None:
                    # a planned lane: towards it, and no hard braking for the driver
                    if (np.sign(lane_index[2] - vehicle.target_lane_index[2]) == np.sign(
                            vehicle.route[0][2] - vehicle.target_lane_index[2])
                            and not own_after < limit):
                        vehicle.target_lane_index = lane_index
                elif not mobil_incentive(own_after - own, new_follower_after - new_follower,
                                         old_follower_after - old_follower,
                                         vehicle.POLITENESS) < vehicle.LANE_CHANGE_MIN_ACC_GAIN:
                    vehicle.target_lane_index = lane_index
        pending.clear()

    def _idm(self, rows: list[tuple[Any, int, int]], state: RoadState) -> list[float]:
        """IDM accelerations [m/s^2] of the follower of each row (its row in ``state``; -1
        or an object that is not a vehicle: 0) behind the leader (-1: none), with the IDM
        constants of the row's driver. The gap is measured along the follower's own lane;
        its desired speed is its ``target_speed`` within that lane's speed limit."""
        if not rows:
            return []
        if state.scalar:
            return self._idm_one_by_one(rows, state)
        drivers, k, j = zip(*rows, strict=True)
        k, j = np.array(k), np.array(j)
        constants = np.array([state.constants(v) for v in drivers], dtype=float)
        is_vehicle, column, desired = state.own()
        speed, cos, sin, vx, vy = state.arrays
        kk, jj = np.maximum(k, 0), np.maximum(j, 0)
        valid = (k >= 0) & is_vehicle[kk]
        leader = valid & (j >= 0)
        col = column[kk]
        s = state.matrix()
        gap = np.where(leader, s[jj, col] - s[kk, col], 1.0)
        for i in np.flatnonzero(leader & (col < 0)).tolist():  # a lane not of the network
            follower = state.objects[k[i]]
            along = state.frame(follower.lane)[0]
            gap[i] = along[j[i]] - along[k[i]]
        approach = (vx[kk] - vx[jj]) * cos[kk] + (vy[kk] - vy[jj]) * sin[kk]
        v = speed[kk]
        a_max, delta, s0, time_gap, b = constants.T
        s_star = desired_gap(v, approach, s0, time_gap, a_max, b)
        out = idm_acceleration(v, desired[kk], delta, a_max, gap, s_star, leader)
        return np.where(valid, out, 0.0).tolist()

    @staticmethod
    def _idm_one_by_one(rows: list[tuple[Any, int, int]], state: RoadState) -> list[float]:
        """:meth:`_idm`, one row at a time in plain floats."""
        is_vehicle, _, desired = state.own_lists()
        speed, cos, sin, vx, vy = state.speed, state.cos, state.sin, state.vx, state.vy
        out = []
        for driver, k, j in rows:
            if k < 0 or not is_vehicle[k]:
                out.append(0.0)
                continue
            a_max, delta, s0, time_gap, b = state.constants(driver)
            v = speed[k]
            if j < 0:
                out.append(idm_one(v, desired[k], delta, a_max))
                continue
            along = state.frame(state.objects[k].lane)[0]
            approach = (vx[k] - vx[j]) * cos[k] + (vy[k] - vy[j]) * sin[k]
            s_star = desired_gap_one(v, approach, s0, time_gap, a_max, b)
            out.append(idm_one(v, desired[k], delta, a_max, along[j] - along[k], s_star))
        return out

    def _drive(self, drivers: list[tuple[Any, str]], state: RoadState) -> None:
        """Steering to the target lane and IDM acceleration of every driver at once."""
        if not drivers:
            return
        network = self.network
        n = len(drivers)
        vehicles = [v for v, _ in drivers]
        ks = [state.index[id(v)] for v in vehicles]
        targets = [network.get_lane(v.target_lane_index) for v in vehicles]
        steering = (self._steer_one_by_one if state.scalar else self._steer)(
            vehicles, ks, targets, state)
        changing = [i for i, v in enumerate(vehicles) if v.lane_index != v.target_lane_index]
        fronts = state.fronts([v.lane for v in vehicles] + [targets[i] for i in changing],
                              ks + [ks[i] for i in changing])
        rows = [(v, kv, f) for v, kv, f in zip(vehicles + [vehicles[i] for i in changing],
                                               ks + [ks[i] for i in changing], fronts,
                                               strict=True)]
        acceleration = self._idm(rows, state)
        for i, on_target in zip(changing, acceleration[n:], strict=True):
            acceleration[i] = min(acceleration[i], on_target)
        for (vehicle, how), steer, acc in zip(drivers, steering, acceleration[:n],
                                              strict=True):
            limit = vehicle.ACC_MAX
            vehicle.action = {"steering": steer,
                              "acceleration": -limit if acc < -limit else min(acc, limit)}
            if how == "hooks":
                vehicle.adjust_action()

    @staticmethod
    def _steer(vehicles: list[Any], ks: list[int], targets: list[Any],
               state: RoadState) -> list[float]:
        """Each vehicle's front-wheel angle [rad] towards its target lane, as arrays."""
        lane_set = state.lanes
        columns = np.array([lane_set.column.get(id(t), -1) for t in targets])
        k = np.array(ks)
        s_all = state.matrix()
        r_all = state._r
        known = columns >= 0
        cc = np.maximum(columns, 0)
        lateral, along = r_all[k, cc], s_all[k, cc]
        for i in np.flatnonzero(~known).tolist():
            along[i], lateral[i] = targets[i].local_coordinates(vehicles[i].position)
        constant = np.array([(v.LENGTH, v.KP_LATERAL, v.KP_HEADING, v.MAX_STEERING_ANGLE,
                              v.TAU_PURSUIT) for v in vehicles], dtype=float)
        length, kp_lateral, kp_heading, max_angle, pursuit = constant.T
        speed = state.arrays[0][k]
        future = along + speed * pursuit
        heading_ahead = lane_set.heading(cc, future)
        for i in np.flatnonzero(~known).tolist():
            heading_ahead[i] = targets[i].heading_at(future[i])
        heading = np.array([state.heading[i] for i in ks])
        return steering_angle(lateral, heading, heading_ahead, speed, length, kp_lateral,
                              kp_heading, max_angle).tolist()

    @staticmethod
    def _steer_one_by_one(vehicles: list[Any], ks: list[int], targets: list[Any],
                          state: RoadState) -> list[float]:
        """:meth:`_steer`, one vehicle at a time in plain floats."""
        lane_set = state.lanes
        out = []
        for v, k, target in zip(vehicles, ks, targets, strict=True):
            along, lateral = state.frame(target)
            speed = state.speed[k]
            future = along[k] + speed * v.TAU_PURSUIT
            j = lane_set.column.get(id(target))
            ahead = (lane_set.heading_one(j, future) if j is not None
                     else float(target.heading_at(future)))
            out.append(steering_one(lateral[k], state.heading[k], ahead, speed, v.LENGTH,
                                    v.KP_LATERAL, v.KP_HEADING, v.MAX_STEERING_ANGLE))
        return out

    # -- step --------------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Move every vehicle by ``dt`` [s], then check collisions (see the module
        docstring)."""
        if not self._core_applies():
            super().step(dt)
            return
        batch: list[tuple[Any, str]] = []
        for vehicle in self.vehicles:
            how = _moved(type(vehicle))
            if how is None:
                self._move(batch, dt)
                vehicle.step(dt)
            else:
                batch.append((vehicle, how))
        self._move(batch, dt)
        self._collide(dt)

    def _move(self, batch: list[tuple[Any, str]], dt: float) -> None:
        """The kinematic bicycle step of every vehicle of ``batch`` at once (actions
        clipped as the vehicle's own ``clip_actions`` does: a crashed vehicle stops
        straight, speeds kept within ``[MIN_SPEED, MAX_SPEED]``), a pending impact added,
        the lane looked up; ``batch`` is emptied."""
        if not batch:
            return
        vehicles = [v for v, _ in batch]
        n = len(vehicles)
        rows = []  # (x, y, heading, speed, steering, acceleration, length) per vehicle
        for v in vehicles:
            speed = float(v.speed)
            s, a = limited_action(v)
            rows.append((float(v.position[0]), float(v.position[1]), float(v.heading), speed,
                         s, a, float(v.LENGTH)))
        if n <= SCALAR_MAX_OBJECTS:
            moved = [bicycle_one(*row, dt) for row in rows]
        else:
            moved = list(zip(*(a.tolist() for a in bicycle_step(
                *np.array(rows, dtype=float).T, dt)), strict=True))
        positions = []
        for v, (x, y, _, _) in zip(vehicles, moved, strict=True):
            if v.impact is not None:
                x, y = x + float(v.impact[0]), y + float(v.impact[1])
                v.crashed = True
                v.impact = None
            positions.append((x, y))
        lane_set = self.lane_set()
        if n <= SCALAR_MAX_OBJECTS:
            found = [lane_set.closest_one(self.network, x, y, m[2])
                     for (x, y), m in zip(positions, moved, strict=True)]
        else:
            found = lane_set.closest(self.network, np.array(positions, dtype=float),
                                     np.array([m[2] for m in moved], dtype=float))
        get_lane, history = self.network.get_lane, self.record_history
        for (v, how), (x, y), (_, _, h, sp), index in zip(batch, positions, moved, found,
                                                          strict=True):
            if how != "plain":
                v.timer += dt
            v.position, v.heading, v.speed = np.array((x, y)), h, sp
            v.lane_index, v.lane = index, get_lane(index)
            if history:
                v.history.appendleft(v.create_from(v))
            if how == "hooks":
                v.after_step(dt)
        batch.clear()

    def _collide(self, dt: float) -> None:
        """highway-env's collision check (``handle_collisions``) on the pairs, in the
        road's order (each vehicle with the vehicles after it, then with the objects),
        that can touch within ``dt``: close enough (:func:`near_pairs`) and not apart on
        an axis of either rectangle (:func:`_swept_apart`)."""
        vehicles, objects = self.vehicles, self.objects
        everyone = vehicles + objects
        if len(everyone) <= SCALAR_MAX_OBJECTS:
            for i, j in _touching_pairs_one_by_one(everyone, len(vehicles), dt):
                vehicles[i].handle_collisions(everyone[j], dt)
            return
        shapes = _shapes(everyone)
        if shapes is None:
            pairs = [(i, j) for i in range(len(vehicles)) for j in range(i + 1, len(everyone))]
        else:
            i, j = np.nonzero(np.triu(_near(shapes, len(vehicles), dt), 1))
            keep = ~_swept_apart(shapes, i, j, dt)
            pairs = list(zip(i[keep].tolist(), j[keep].tolist(), strict=True))
        for i, j in pairs:
            vehicles[i].handle_collisions(everyone[j], dt)


_STANDARD_SHAPE = (RoadObject.handle_collisions, RoadObject._is_colliding, RoadObject.polygon)


@functools.cache
def _own_shape(cls: type) -> bool:
    """Whether ``cls`` has its own collision test, polygon or velocity."""
    return ((cls.handle_collisions, cls._is_colliding, cls.polygon) != _STANDARD_SHAPE
            or _own_velocity(cls))


def _shapes(everyone: list[Any]) -> dict[str, np.ndarray] | None:
    """Per object: position (n, 2) [m], diagonal, half length and width [m], heading [rad],
    velocity (vx, vy) [m/s], whether it checks collisions and is collidable, and whether its
    class has its own collision test, polygon or velocity (``own``); None when an object
    lacks one of these."""
    try:
        position = np.array([o.position for o in everyone], dtype=float)
        shape = np.array([(o.diagonal, o.LENGTH / 2, o.WIDTH / 2, o.heading, o.speed,
                           bool(o.check_collisions), bool(o.collidable), _own_shape(type(o)))
                          for o in everyone], dtype=float)
    except (AttributeError, TypeError, ValueError):
        return None
    if position.shape != (len(everyone), 2) or shape.shape != (len(everyone), 8):
        return None
    flags, own = shape[:, 5:7] != 0, shape[:, 7] != 0
    heading, speed = shape[:, 3], shape[:, 4]
    return {"position": position, "diagonal": shape[:, 0], "half_length": shape[:, 1],
            "half_width": shape[:, 2], "heading": heading, "vx": speed * np.cos(heading),
            "vy": speed * np.sin(heading), "checks": flags[:, 0], "collidable": flags[:, 1],
            "own": own}


def _touching_pairs_one_by_one(everyone: list[Any], n: int,
                               dt: float) -> list[tuple[int, int]]:
    """The pairs (i < j, i among the first ``n`` objects, the vehicles) that
    :meth:`TrafficRoad._collide` checks: near (:func:`near_pairs`) and not swept apart
    (:func:`_swept_apart`), one pair at a time in plain floats."""
    try:
        rows = []
        for o in everyone:
            position = o.position
            if len(position) != 2:
                raise ValueError
            heading, speed = float(o.heading), float(o.speed)
            cos, sin = math.cos(heading), math.sin(heading)
            rows.append((float(position[0]), float(position[1]), float(o.diagonal),
                         o.LENGTH / 2, o.WIDTH / 2, cos, sin, speed * cos, speed * sin,
                         bool(o.check_collisions), bool(o.collidable),
                         (type(o).handle_collisions, type(o)._is_colliding, type(o).polygon)
                         != _STANDARD_SHAPE or type(o).velocity not in (Vehicle.velocity,
                                                                         RoadObject.velocity)))
    except (AttributeError, TypeError, ValueError):
        return [(i, j) for i in range(n) for j in range(i + 1, len(everyone))]
    m = len(rows)
    if n == 0:
        return []
    # any two rectangles touching within dt have centres closer along x than the largest
    # diagonal plus twice the largest speed times dt: sweep along x within that reach
    speeds = [math.hypot(row[7], row[8]) for row in rows]
    reach = max(row[2] for row in rows) + 2 * dt * max(speeds) + TOUCH_MARGIN
    if all(math.isfinite(row[0] + row[2]) for row in rows) and all(map(math.isfinite, speeds)):
        order = sorted(range(m), key=lambda k: rows[k][0])
        candidates = [(i, j) if i < j else (j, i) for p, i in enumerate(order)
                      for j in _within(order, rows, p, reach)]
    else:
        candidates = [(i, j) for i in range(n) for j in range(i + 1, m)]
    owned = [k for k in range(m) if rows[k][11]]
    candidates = set(candidates).union(
        (min(i, k), max(i, k)) for k in owned for i in range(m) if i != k)
    pairs = []
    for i, j in sorted(candidates):
        if i >= n:
            continue
        a, b = rows[i], rows[j]
        if not (a[11] or b[11]):
            if not (a[10] and b[10] and (a[9] or b[9])):
                continue
            bound = (a[2] + b[2]) / 2 + math.hypot(a[7] - b[7], a[8] - b[8]) * dt
            if (math.hypot(b[0] - a[0], b[1] - a[1]) > bound + TOUCH_MARGIN
                    or _swept_apart_one(a, b, dt)):
                continue
        pairs.append((i, j))
    return pairs


def _within(order: list[int], rows: list[tuple], p: int, reach: float) -> list[int]:
    """The rows after position ``p`` of ``order`` (rows sorted by x) whose x is within
    ``reach`` [m] of row ``order[p]``'s."""
    x = rows[order[p]][0] + reach
    out = []
    for q in range(p + 1, len(order)):
        j = order[q]
        if rows[j][0] > x:
            break
        out.append(j)
    return out


def _swept_apart_one(a: tuple, b: tuple, dt: float) -> bool:
    """:func:`_swept_apart` of one pair, each a row of :func:`_touching_pairs_one_by_one`
    (x, y, diagonal, half length, half width, cos and sin of the heading, vx, vy, ...)."""
    xa, ya, _, la, wa, ca, sa, vxa, vya = a[:9]
    xb, yb, _, lb, wb, cb, sb, vxb, vyb = b[:9]
    dx, dy = (vxa - vxb) * dt, (vya - vyb) * dt
    for nx, ny in ((ca, sa), (-sa, ca), (cb, sb), (-sb, cb)):
        reach_a = la * abs(ca * nx + sa * ny) + wa * abs(ca * ny - sa * nx)
        reach_b = lb * abs(cb * nx + sb * ny) + wb * abs(cb * ny - sb * nx)
        centre_a, centre_b = xa * nx + ya * ny, xb * nx + yb * ny
        moved = dx * nx + dy * ny
        low_a = centre_a - reach_a + min(moved, 0.0)
        high_a = centre_a + reach_a + max(moved, 0.0)
        if max(centre_b - reach_b - high_a, low_a - (centre_b + reach_b)) > TOUCH_MARGIN:
            return True
    return False



def limited_action(vehicle: Any) -> tuple[float, float]:
    """The (steering [rad], acceleration [m/s^2]) a vehicle's step moves by, written back
    to ``vehicle.action``: a crashed vehicle brakes to a stop within a second, straight;
    a speed above ``MAX_SPEED`` or below ``MIN_SPEED`` is brought back within a second."""
    action, speed = vehicle.action, float(vehicle.speed)
    if vehicle.crashed:
        action["steering"], action["acceleration"] = 0, -1.0 * speed
    steering, acc = float(action["steering"]), float(action["acceleration"])
    if speed > vehicle.MAX_SPEED:
        acc = min(acc, 1.0 * (vehicle.MAX_SPEED - speed))
    elif speed < vehicle.MIN_SPEED:
        acc = max(acc, 1.0 * (vehicle.MIN_SPEED - speed))
    action["steering"], action["acceleration"] = steering, acc
    return steering, acc

def near_pairs(vehicles: list[Any], objects: list[Any], dt: float) -> np.ndarray | None:
    """(n_vehicles, n_vehicles + n_objects) bool: the pairs (vehicle, vehicle or object)
    whose rectangles can touch within ``dt`` [s] and in which one checks collisions.

    Two rectangles touch only if their centres are at most half the sum of their diagonals
    apart; within ``dt`` one moves relative to the other by their velocities' difference
    times ``dt`` (velocity: speed along the heading). Pairs farther apart than that (plus
    :data:`TOUCH_MARGIN`) are left out, and pairs in which neither object checks
    collisions or one is not collidable. Objects of a class with its own collision test are
    in every pair. None when some object lacks a position, diagonal, size or speed."""
    shapes = _shapes(vehicles + objects)
    return None if shapes is None else _near(shapes, len(vehicles), dt)


def shape_of(obj: Any) -> bool:
    """Whether ``obj``'s class has its own collision test, polygon or velocity (then
    :func:`near_pairs_of` puts it in every pair)."""
    return _own_shape(type(obj))


def shapes_of(position: np.ndarray, diagonal: np.ndarray, length: np.ndarray,
              width: np.ndarray, heading: np.ndarray, speed: np.ndarray, checks: np.ndarray,
              own: np.ndarray) -> dict[str, np.ndarray]:
    """The shapes :func:`near_pairs_of` and :func:`swept_apart` read, of collidable objects
    given as arrays: positions (m, 2) [m], diagonals, lengths and widths [m], headings
    [rad], speeds [m/s], whether each checks collisions and has its own test
    (:func:`shape_of`), all (m,)."""
    return {"position": position, "diagonal": diagonal, "half_length": length / 2,
            "half_width": width / 2, "heading": heading, "vx": speed * np.cos(heading),
            "vy": speed * np.sin(heading), "checks": checks,
            "collidable": np.ones(len(position), bool), "own": own}


def near_pairs_of(shapes: dict[str, np.ndarray], n: int, dt: float) -> np.ndarray:
    """:func:`near_pairs` of the objects of :func:`shapes_of` (the first ``n`` the
    vehicles)."""
    return _near(shapes, n, dt)


def swept_apart(shapes: dict[str, np.ndarray], i: np.ndarray, j: np.ndarray, dt: float
                ) -> np.ndarray:
    """Whether the pairs (i, j) of the objects of :func:`shapes_of` stay apart over ``dt``
    [s] (separating axis, :data:`TOUCH_MARGIN`): highway-env's collision test finds them
    neither intersecting nor about to, so checking them changes nothing."""
    return _swept_apart(shapes, i, j, dt)


def _near(shapes: dict[str, np.ndarray], n: int, dt: float) -> np.ndarray:
    """:func:`near_pairs` from :func:`_shapes` (the first ``n`` objects the vehicles).

    On many objects only the pairs closer along x than the largest diagonal plus twice the
    largest speed times ``dt`` are looked at (:func:`_near_swept`)."""
    if len(shapes["diagonal"]) > _DENSE_MAX_OBJECTS:
        near = _near_swept(shapes, n, dt)
        if near is not None:
            return near
    position, diagonal = shapes["position"], shapes["diagonal"]
    vx, vy = shapes["vx"], shapes["vy"]
    checks, collidable, own = shapes["checks"], shapes["collidable"], shapes["own"]
    checkers = np.flatnonzero(checks)
    if 2 * len(checkers) < n:  # few check collisions: only their rows and columns
        near = np.zeros((n, len(diagonal)), dtype=bool)
        for k in checkers.tolist():
            delta = position - position[k]
            distance = np.hypot(delta[:, 0], delta[:, 1])
            relative = np.hypot(vx[k] - vx, vy[k] - vy) * dt
            close = (~(distance > (diagonal[k] + diagonal) / 2 + relative + TOUCH_MARGIN)
                     & collidable[k] & collidable)
            if k < n:
                near[k] |= close
            near[:, k] |= close[:n]
        near[own[:n], :] = True
        near[:, own] = True
        return near
    delta = position[None, :, :] - position[:n, None, :]
    distance = np.hypot(delta[..., 0], delta[..., 1])
    relative = np.hypot(vx[:n, None] - vx[None, :], vy[:n, None] - vy[None, :]) * dt
    bound = (diagonal[:n, None] + diagonal[None, :]) / 2 + relative
    close = ~(distance > bound + TOUCH_MARGIN)  # NaN: close
    return ((close & (checks[:n, None] | checks[None, :]) & collidable[:n, None]
             & collidable[None, :]) | own[:n, None] | own[None, :])


_DENSE_MAX_OBJECTS = 150  # objects up to which near pairs are tested all against all


def _near_swept(shapes: dict[str, np.ndarray], n: int, dt: float) -> np.ndarray | None:
    """:func:`_near` by a sweep along x: the pairs closer along x than the largest diagonal
    plus twice the largest speed times ``dt`` (no other pair can be near) tested, every
    pair with an object of its own test (``own``) kept; None where a value is not finite
    (then every pair is tested)."""
    position, diagonal = shapes["position"], shapes["diagonal"]
    vx, vy = shapes["vx"], shapes["vy"]
    count = len(diagonal)
    speed = np.hypot(vx, vy)
    reach = diagonal.max() + 2 * dt * speed.max() + TOUCH_MARGIN
    x = position[:, 0]
    if not (np.isfinite(reach) and np.isfinite(x).all() and np.isfinite(position).all()):
        return None
    order = np.argsort(x, kind="stable")
    ends = np.searchsorted(x[order], x[order] + reach, side="right")
    counts = ends - np.arange(count) - 1
    first = np.repeat(np.arange(count), counts)
    second = first + 1 + np.arange(len(first)) - np.repeat(np.cumsum(counts) - counts, counts)
    a, b = order[first], order[second]
    a, b = np.minimum(a, b), np.maximum(a, b)
    keep = a < n
    a, b = a[keep], b[keep]
    distance = np.hypot(position[b, 0] - position[a, 0], position[b, 1] - position[a, 1])
    relative = np.hypot(vx[a] - vx[b], vy[a] - vy[b]) * dt
    checks, collidable, own = shapes["checks"], shapes["collidable"], shapes["own"]
    close = (~(distance > (diagonal[a] + diagonal[b]) / 2 + relative + TOUCH_MARGIN)
             & (checks[a] | checks[b]) & collidable[a] & collidable[b])
    near = np.zeros((n, count), dtype=bool)
    itself = np.arange(n)
    near[itself, itself] = checks[:n] & collidable[:n]
    a, b = a[close], b[close]
    near[a, b] = True
    inside = b < n
    near[b[inside], a[inside]] = True
    near[own[:n], :] = True
    near[:, own] = True
    return near


def _swept_apart(shapes: dict[str, np.ndarray], i: np.ndarray, j: np.ndarray,
                 dt: float) -> np.ndarray:
    """(len(i),) bool: whether rectangle ``i``, swept by its displacement relative to
    rectangle ``j`` over ``dt`` [s], stays apart from ``j`` by more than
    :data:`TOUCH_MARGIN` along the axis of a side of one of them (the separating axis
    theorem: then they neither touch now nor within ``dt``). False for objects with their
    own test (``own``) and where a value is not finite."""
    if len(i) == 0:
        return np.zeros(0, dtype=bool)
    position, heading = shapes["position"], shapes["heading"]
    half_length, half_width = shapes["half_length"], shapes["half_width"]
    dx = (shapes["vx"][i] - shapes["vx"][j]) * dt
    dy = (shapes["vy"][i] - shapes["vy"][j]) * dt
    cos_i, sin_i, cos_j, sin_j = (np.cos(heading[i]), np.sin(heading[i]),
                                  np.cos(heading[j]), np.sin(heading[j]))
    apart = np.zeros(len(i), dtype=bool)
    for nx, ny in ((cos_i, sin_i), (-sin_i, cos_i), (cos_j, sin_j), (-sin_j, cos_j)):
        reach_i = (half_length[i] * np.abs(cos_i * nx + sin_i * ny)
                   + half_width[i] * np.abs(cos_i * ny - sin_i * nx))
        reach_j = (half_length[j] * np.abs(cos_j * nx + sin_j * ny)
                   + half_width[j] * np.abs(cos_j * ny - sin_j * nx))
        centre_i = position[i, 0] * nx + position[i, 1] * ny
        centre_j = position[j, 0] * nx + position[j, 1] * ny
        moved = dx * nx + dy * ny
        low_i = centre_i - reach_i + np.minimum(moved, 0)
        high_i = centre_i + reach_i + np.maximum(moved, 0)
        gap = np.maximum(centre_j - reach_j - high_i, low_i - (centre_j + reach_j))
        apart |= gap > TOUCH_MARGIN
    return apart & ~shapes["own"][i] & ~shapes["own"][j]


@functools.cache
def traffic_env_class(cls: type) -> type:
    """A subclass of the highway-env env class ``cls`` whose road, built at each reset, is
    a :class:`TrafficRoad` (the same network, vehicles and objects)."""

    def _reset(self: Any) -> None:
        super(env, self)._reset()
        if not isinstance(self.road, TrafficRoad):
            self.road = TrafficRoad.taking_over(self.road)

    env = type(cls.__name__, (cls,), {"_reset": _reset, "__module__": cls.__module__,
                                      "__doc__": cls.__doc__})
    return env
