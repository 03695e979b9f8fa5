"""highway-env's per-step road work (``Road.act``, ``Road.step``, the lane lookup), the same
results sooner.

Every IDM/MOBIL vehicle asks the road for its leader and follower on its own lane and on
each lane it considers changing to, several times per simulated step; highway-env answers
by projecting every other vehicle on the lane, one at a time, in Python. With 20 vehicles
that was about 30 % of a training step (``benchmarks/profile_train.py``). ``Road.step``
then calls ``handle_collisions`` for every pair of vehicles, although in a fast training
env (:class:`tap_bench.sim.scenario_env.ScenarioEnv`) only the ego's pairs can collide, and
every vehicle looks up its lane by computing its distance to every lane of the network.

:class:`FastRoad` gives the same answers, object for object and bit for bit:

- the neighbour search, while the vehicles act (``Road.act``: positions do not change),
  projects all vehicles on a lane once per simulated step with highway-env's arithmetic
  (the bits of its ``np.dot``, :func:`fast_idm.lane_dots
  <tap_bench.sim.fast_idm.lane_dots>`), keeps those on the lane sorted by their
  coordinate and road order, and answers each query by bisection with highway-env's rules
  for ties (:meth:`FastRoad._from_table`). Outside ``Road.act`` it projects all vehicles at
  once with numpy, finds the few that can be the answer (those on the lane, or within
  :data:`TOLERANCE` of it, and no more than :data:`TOLERANCE` farther than the nearest
  vehicle that surely is on the lane ahead or behind), then runs highway-env's own loop,
  with highway-env's own arithmetic, on those few, in the road's order (the numpy
  projection may differ from highway-env's ``np.dot`` in the last bit, which the tolerance
  absorbs). The tables are used only where highway-env's search has the source they repeat
  (highway-env 1.12's, checked once per process);
- the IDM/MOBIL vehicles decide their actions all at once (:mod:`tap_bench.sim.fast_idm`),
  their leaders found together (:meth:`FastRoad.leaders`), on roads of at least
  :data:`AT_ONCE_FROM` vehicles; on smaller ones one after the other, with highway-env's
  formulas in cheaper calls (:func:`fast_idm.act_each <tap_bench.sim.fast_idm.act_each>`);
- the vehicles move by highway-env's ``Vehicle.step`` lines and, on roads of many
  (vehicle, lane) pairs, have their lanes looked up together (:meth:`FastRoad.move`);
- the collision loop skips the pairs in which neither vehicle checks collisions (the first
  thing highway-env's ``handle_collisions`` does for such a pair is return) and the pairs
  farther apart, by more than :data:`TOLERANCE`, than highway-env's spherical pre-check
  allows (for which it does nothing either; all distances at once with numpy), and calls
  the others in highway-env's order;
- the lane lookup (``RoadNetwork.get_closest_lane_index``, on networks of highway-env's
  straight, sine and circular lanes: highway, merge, roundabout, exit ...) estimates each
  lane's distance in Python floats and computes highway-env's own distance only for the
  lanes within :data:`TOLERANCE` of the nearest, keeping highway-env's first minimum.

In the neighbour search and the decisions, lanes that are not straight, and
``neighbour_vehicles_connected_lanes``, go to highway-env's methods unchanged; so does the
lane lookup of a network with a lane of another class. Tested by simulating scenarios
both ways and comparing every vehicle's state bit for bit, every query of a dense
simulation against highway-env's, slanted lanes, ties and lane boundaries, and the lane
lookup on drawn networks of every lane kind (mutations of each formula caught).

Parts of this module re-state highway-env's code (MIT License, Copyright (c) 2018 Edouard
Leurent, (c) 2023 Farama Foundation): see THIRD_PARTY_NOTICES.md.
"""

from __future__ import annotations

import bisect
import functools
import math
from typing import Any

import numpy as np
from highway_env.road.lane import AbstractLane, CircularLane, SineLane, StraightLane
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Landmark, RoadObject

from tap_bench.sim.fast_idm import (
    ActState,
    act_all,
    act_each,
    array_kernels_agree,
    sources_match,
)

__all__ = ["AT_ONCE_FROM", "MOVE_AT_ONCE_FROM", "MOVE_VEHICLES_AT_ONCE_FROM", "TOLERANCE",
           "FastRoad", "use_fast_road"]

TOLERANCE = 1e-6
"""Margin [m] by which a vehicle's numpy projection may be off and still be re-checked."""

_MARGIN = 1.0  # highway-env's on-lane margin in neighbour_vehicles [m]
_LANE_PROJECTION = frozenset({"local_coordinates", "on_lane", "width_at"})
"""Methods that, set on a lane instance, change how vehicles are found on it."""
AT_ONCE_FROM = 8
"""Fewest vehicles on a road for which decisions and collision checks are done all at once
(numpy); on smaller roads highway-env's loops cost less than numpy's fixed costs (the
answers are the same either way)."""
MOVE_AT_ONCE_FROM = 100
"""Fewest (vehicle, lane) pairs for which the vehicles move and have their lanes looked up
all at once (:meth:`FastRoad.move`): the roundabout's 5 vehicles on 32 lanes, a highway of
50 on 4; below, one vehicle at a time costs less (same answers either way), unless the
road has :data:`MOVE_VEHICLES_AT_ONCE_FROM` vehicles."""
MOVE_VEHICLES_AT_ONCE_FROM = 16
"""Fewest vehicles for which they move all at once whatever the lanes: the 21 vehicles of
the highway scenario on its 3 lanes move in 90 instead of 130 us a simulated step; merge's
5 and cut_in's 10 move faster one at a time (thread CPU, 2026-11)."""


class FastRoad:
    """The per-step work of one highway-env road (see the module docstring).

    Positions do not change while the vehicles act (they move in ``Road.step``), so during
    ``Road.act`` every lane's projection of all vehicles is computed once, at its first
    query, with highway-env's arithmetic, and kept sorted (:meth:`_table`); a query is then
    a bisection. Outside ``Road.act`` each query projects afresh.

    Args:
        road: the highway-env road; :meth:`install` makes it act, step and search through
            this object.
    """

    def __init__(self, road: Road) -> None:
        self.road = road
        self._others: list[Any] | None = None
        self._count = 0
        self._state: ActState | None = None
        self._lanes: dict[Any, tuple[list[float], list[int], list[float]] | None] = {}
        self._flat: list[tuple[Any, ...]] = []
        self._arrays: dict[str, np.ndarray] = {}
        self._decide_at_once = array_kernels_agree()

    def install(self) -> None:
        """Route the road's ``act``, ``step`` and ``neighbour_vehicles`` through this, and
        its network's ``get_closest_lane_index`` when every lane is one of highway-env's
        straight, sine or circular lanes (see :meth:`closest_lane_index`)."""
        self.road.act = self.act
        self.road.step = self.step
        self.road.neighbour_vehicles = self.neighbour_vehicles
        network = self.road.network
        lanes = [((start, end, i), lane) for start, ends in network.graph.items()
                 for end, row in ends.items() for i, lane in enumerate(row)]
        flat = [_lane_entry(index, lane) for index, lane in lanes]
        if flat and all(entry is not None for entry in flat) \
                and "get_closest_lane_index" not in vars(network):
            self._flat = flat
            self._arrays = _lane_arrays(flat)
            network.get_closest_lane_index = self.closest_lane_index

    def closest_lane_index(self, position: np.ndarray, heading: float | None = None
                           ) -> tuple[str, str, int]:
        """highway-env's ``RoadNetwork.get_closest_lane_index(position, heading)`` on a
        network of straight, sine and circular lanes, same result: each lane's distance
        (with heading) estimated in Python floats (:func:`_estimate`, off by far less than
        :data:`TOLERANCE`), then highway-env's own distance computed for the lanes within
        :data:`TOLERANCE` of the nearest, the first minimum in the network's order (that of
        ``np.argmin``); a lone candidate is the answer as it is (every other lane is farther
        by more than the estimates' rounding). The network's lanes are read at
        :meth:`install` (highway-env builds a network once per scene and does not change
        it)."""
        x, y = float(position[0]), float(position[1])
        h = None if heading is None else float(heading)
        estimates = [_estimate(entry, x, y, h) for entry in self._flat]
        bound = min(estimates) + TOLERANCE
        if not all(map(math.isfinite, estimates)):  # a position or heading not finite
            return type(self.road.network).get_closest_lane_index(self.road.network,
                                                                  position, heading)
        candidates = [entry for entry, estimate in zip(self._flat, estimates, strict=True)
                      if estimate <= bound]
        if len(candidates) == 1:  # every other lane is farther by more than the rounding
            return candidates[0][0]
        return _first_nearest(candidates, position, heading)

    def step(self, dt: float) -> None:
        """highway-env's ``Road.step``: move every vehicle by ``dt`` [s] (:meth:`move`),
        then check the pairs in which a vehicle checks collisions, in highway-env's
        order."""
        vehicles, objects = self.road.vehicles, self.road.objects
        if not all(map(_standard_collisions, vehicles + objects)):
            # a class with its own collision rule: every pair, as highway-env does
            Road.step(self.road, dt)
            return
        self.move(dt)
        near = _near_pairs(vehicles, objects, dt) \
            if len(vehicles) + len(objects) >= AT_ONCE_FROM else None
        if near is not None:
            everyone = vehicles + objects
            # each vehicle with the vehicles after it, then with every object, in order
            for i, j in zip(*(k.tolist() for k in np.nonzero(np.triu(near, 1))), strict=True):
                vehicles[i].handle_collisions(everyone[j], dt)
            return
        checking = [i for i, vehicle in enumerate(vehicles) if vehicle.check_collisions]
        for i, vehicle in enumerate(vehicles):
            if vehicle.check_collisions:
                for other in vehicles[i + 1:]:
                    vehicle.handle_collisions(other, dt)
            else:
                for j in checking:
                    if j > i:
                        vehicle.handle_collisions(vehicles[j], dt)
            for other in objects:
                vehicle.handle_collisions(other, dt)

    def move(self, dt: float) -> None:
        """``vehicle.step(dt)`` of every vehicle, in the road's order, the same states.

        When every vehicle moves by highway-env's own ``Vehicle.step`` (with
        ``IDMVehicle``'s timer; :func:`_moves_as_highway_env`) on a network whose lane
        lookup this road does, with at least :data:`MOVE_AT_ONCE_FROM` (vehicle, lane)
        pairs, the vehicles' kinematics are highway-env's lines, computed for all at once
        (:func:`_kinematics_at_once`; one at a time, :func:`_kinematics`, where numpy's
        array kernels do not give its scalar kernels' bits), and the lanes of all vehicles
        are then looked up at once (:meth:`closest_lane_indices`). A vehicle's step reads
        only its own state and the network, so looking its lane up after the others moved
        changes nothing."""
        vehicles = self.road.vehicles
        if not self._flat or (len(vehicles) * len(self._flat) < MOVE_AT_ONCE_FROM
                              and len(vehicles) < MOVE_VEHICLES_AT_ONCE_FROM) \
                or not all(_moves_as_highway_env(v, self.road) for v in vehicles):
            for vehicle in vehicles:
                vehicle.step(dt)
            return
        if self._decide_at_once:  # numpy's array kernels give its scalar kernels' bits
            _kinematics_at_once(vehicles, dt)
        else:
            for vehicle in vehicles:
                _kinematics(vehicle, dt)
        network, history = self.road.network, self.road.record_history
        found = self.closest_lane_indices([v.position for v in vehicles],
                                          [v.heading for v in vehicles])
        for vehicle, lane_index in zip(vehicles, found, strict=True):  # on_state_update
            vehicle.lane_index = lane_index
            vehicle.lane = network.get_lane(lane_index)
            if history:
                vehicle.history.appendleft(vehicle.create_from(vehicle))

    def closest_lane_indices(self, positions: list[np.ndarray], headings: list[Any]
                             ) -> list[tuple[str, str, int]]:
        """:meth:`closest_lane_index` of each (position, heading), the same answers: every
        lane's distance to every position estimated at once with numpy
        (:func:`_estimates`, off by rounding only), then highway-env's own distance on
        each position's candidates within :data:`TOLERANCE` of its nearest, in the
        network's order."""
        if not positions:
            return []
        estimates, exact = _estimates(self._arrays, np.array(positions, dtype=float),
                                      np.array(headings, dtype=float))
        for k, j in zip(*(a.tolist() for a in np.nonzero(exact)), strict=True):
            # on a circular lane's phase wrap: that lane's distance exactly
            estimates[k, j] = self._flat[j][1].distance_with_heading(positions[k], headings[k])
        finite = np.isfinite(estimates).all(axis=1)
        candidates = estimates <= estimates.min(axis=1, keepdims=True) + TOLERANCE
        count, first = candidates.sum(axis=1).tolist(), candidates.argmax(axis=1).tolist()
        out = []
        for k, (position, heading) in enumerate(zip(positions, headings, strict=True)):
            if not finite[k]:  # a position or heading not finite
                out.append(type(self.road.network).get_closest_lane_index(
                    self.road.network, position, heading))
            elif count[k] == 1:  # every other lane is farther by more than the rounding
                out.append(self._flat[first[k]][0])
            else:  # highway-env's arithmetic on the candidates, the first minimum
                out.append(_first_nearest([self._flat[j] for j in
                                           np.flatnonzero(candidates[k]).tolist()],
                                          position, heading))
        return out

    def act(self) -> None:
        """highway-env's ``Road.act`` with the road's state (:class:`fast_idm.ActState
        <tap_bench.sim.fast_idm.ActState>`) and the lanes' projections kept for its
        duration."""
        self._count = len(self.road.vehicles) + len(self.road.objects)
        self._others, positions = self._snapshot()
        self._state = ActState(self._others, positions, self._decide_at_once,
                               projects=_projects)
        try:
            if self._decide_at_once and len(self.road.vehicles) >= AT_ONCE_FROM:
                act_all(self.road, leaders=self.leaders, state=self._state)
            else:  # one vehicle after the other, as highway-env's Road.act
                act_each(self.road, state=self._state)
        finally:
            self._others = self._state = None
            self._lanes.clear()

    def _snapshot(self) -> tuple[list[Any], np.ndarray | None]:
        """The road's vehicles and objects a search may return (not Landmarks), in the
        road's order, and their positions (n, 2) [m] (None when there are none)."""
        others = [v for v in self.road.vehicles + self.road.objects
                  if not isinstance(v, Landmark)]
        positions = np.array([v.position for v in others], dtype=float) if others else None
        return others, positions

    def leaders(self, vehicles: list[Any], lane_indices: list[Any]) -> list[Any | None]:
        """The vehicle ahead of each of ``vehicles`` on its lane of ``lane_indices`` (None:
        its own): ``neighbour_vehicles(vehicle, lane_index)[0]`` for each, the same objects
        (during ``Road.act`` from the lane's table, :meth:`_table`)."""
        return [self.neighbour_vehicles(v, li)[0]
                for v, li in zip(vehicles, lane_indices, strict=True)]

    def _table(self, lane_index: Any, lane: StraightLane
               ) -> tuple[list[float], list[int], list[float]] | None:
        """During ``Road.act``: the vehicles and objects on the straight ``lane`` (highway-env's
        ``on_lane`` with its 1 m margin), sorted by their longitudinal coordinate on it and then
        by road order, as (coordinates, indices into the road's searchable objects), and every
        object's coordinate, all with highway-env's arithmetic (:func:`fast_idm.lane_dots
        <tap_bench.sim.fast_idm.lane_dots>`: the bits of its ``np.dot``); computed at the
        lane's first query of the step. None for a lane that changes how it projects."""
        table = self._lanes.get(lane_index)
        if table is None and lane_index not in self._lanes:
            projection = self._state.projection(lane)
            if projection is not None:
                along, across, listed = projection
                on = (np.abs(across) <= lane.width / 2 + _MARGIN) \
                    & (-lane.VEHICLE_LENGTH <= along) \
                    & (along < lane.length + lane.VEHICLE_LENGTH)
                rows = np.flatnonzero(on)
                order = rows[np.lexsort((rows, along[rows]))]
                table = along[order].tolist(), order.tolist(), listed
            self._lanes[lane_index] = table
        return table

    def neighbour_vehicles(self, vehicle: Any, lane_index: Any = None
                           ) -> tuple[Any | None, Any | None]:
        """The vehicle ahead of and behind ``vehicle`` on ``lane_index`` (its own lane by
        default): highway-env's ``Road.neighbour_vehicles(vehicle, lane_index)``, same
        result.

        Returns:
            (leader, follower); either is None when there is none.
        """
        road = self.road
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        lane = road.network.get_lane(lane_index)
        if type(lane) is not StraightLane or road.neighbour_vehicles_connected_lanes:
            return Road.neighbour_vehicles(road, vehicle, lane_index)
        if self._others is not None and self._count == len(road.vehicles) + len(road.objects):
            if not self._others:
                return None, None
            table = self._table(lane_index, lane)
            if table is not None:
                return self._from_table(vehicle, lane, table)
            return Road.neighbour_vehicles(road, vehicle, lane_index)
        # outside Road.act positions may change between queries; inside it a vehicle may
        # have been added or removed (none of highway-env's does): project afresh
        others, positions = self._snapshot()
        if not others:
            return None, None
        surely, maybe_s, maybe_i = _project(lane, positions)
        s = lane.local_coordinates(vehicle.position)[0]
        k = bisect.bisect_left(surely, s + TOLERANCE)
        front_bound = surely[k] + TOLERANCE if k < len(surely) else np.inf
        k = bisect.bisect_left(surely, s - TOLERANCE)
        rear_bound = surely[k - 1] - TOLERANCE if k > 0 else -np.inf
        candidates = sorted(maybe_i[bisect.bisect_left(maybe_s, rear_bound):
                                    bisect.bisect_right(maybe_s, front_bound)])
        s_front = s_rear = None
        v_front = v_rear = None
        for i in candidates:  # highway-env's loop, on the candidates, in the road's order
            v = others[i]
            if v is vehicle:
                continue
            sv, lat = lane.local_coordinates(v.position)
            if not lane.on_lane(v.position, sv, lat, margin=_MARGIN):
                continue
            if s <= sv and (s_front is None or sv <= s_front):
                s_front, v_front = sv, v
            if sv < s and (s_rear is None or sv > s_rear):
                s_rear, v_rear = sv, v
        return v_front, v_rear

    def _from_table(self, vehicle: Any, lane: StraightLane,
                    table: tuple[list[float], list[int], list[float]]
                    ) -> tuple[Any | None, Any | None]:
        """highway-env's answer from a lane's :meth:`_table`: the leader is the nearest
        object on the lane at or ahead of ``vehicle``'s coordinate ``s`` (``s <= s_v``), the
        last in road order among equal coordinates (highway-env's loop keeps a later one at
        ``s_v <= s_front``), ``vehicle`` itself excepted; the follower the nearest behind
        (``s_v < s``), the first in road order among equals (``s_v > s_rear``)."""
        keys, rows, along = table
        me = self._state.index.get(id(vehicle), -1)
        s = along[me] if me >= 0 else lane.local_coordinates(vehicle.position)[0]
        if s != s:  # NaN: highway-env's comparisons all fail
            return None, None
        start = bisect.bisect_left(keys, s)
        front = rear = None
        j = start
        if j < len(keys) and rows[j] == me:
            j += 1
        if j < len(keys):
            last = bisect.bisect_right(keys, keys[j], j) - 1
            if rows[last] == me:
                last -= 1
            front = self._others[rows[last]]
        if start > 0:
            rear = self._others[rows[bisect.bisect_left(keys, keys[start - 1])]]
        return front, rear


_STRAIGHT, _SINE, _CIRCULAR = 0, 1, 2
_LANE_KINDS = {StraightLane: _STRAIGHT, SineLane: _SINE, CircularLane: _CIRCULAR}
_LANE_METHODS = frozenset({"distance_with_heading", "distance", "local_coordinates",
                           "heading_at", "local_angle"})
_WRAP_MARGIN = 1e-9
"""How near [rad] to a circular lane's phase wrap (half a turn from its start) a position
must be for its distance to be computed exactly rather than estimated (there highway-env's
``wrap_to_pi`` may jump by a full turn on a rounding difference)."""


def _lane_entry(index: Any, lane: Any) -> tuple[Any, ...] | None:
    """(index, lane, kind, the lane's parameters as Python floats) for
    :func:`_estimate`; None for a lane of another class, or one that changes how its
    distance is computed (then the network keeps highway-env's lookup)."""
    kind = _LANE_KINDS.get(type(lane))
    if kind is None or _LANE_METHODS & vars(lane).keys():
        return None
    if kind == _CIRCULAR:
        return (index, lane, kind, float(lane.center[0]), float(lane.center[1]),
                float(lane.radius), float(lane.start_phase), float(lane.direction),
                float(lane.length))
    straight = (float(lane.start[0]), float(lane.start[1]), float(lane.direction[0]),
                float(lane.direction[1]), float(lane.direction_lateral[0]),
                float(lane.direction_lateral[1]), float(lane.length), float(lane.heading))
    if kind == _SINE:
        return (index, lane, kind, *straight, float(lane.amplitude), float(lane.pulsation),
                float(lane.phase))
    return (index, lane, kind, *straight)


def _estimate(entry: tuple[Any, ...], x: float, y: float, heading: float | None) -> float:
    """``lane.distance_with_heading((x, y), heading)`` of the lane of ``entry``
    (:func:`_lane_entry`) in Python floats: highway-env's formula, off from its numpy
    arithmetic by rounding only (about 1e-12 m at highway-env's scale, far below
    :data:`TOLERANCE`), or computed exactly where a rounding could change a branch."""
    kind = entry[2]
    if kind == _CIRCULAR:
        _, lane, _, cx, cy, radius, start_phase, direction, length = entry
        dx, dy = x - cx, y - cy
        turn = (math.atan2(dy, dx) - start_phase + math.pi) % (2 * math.pi) - math.pi
        if abs(turn) >= math.pi - _WRAP_MARGIN:
            return float(lane.distance_with_heading(np.array([x, y]), heading))
        s = direction * turn * radius
        r = direction * (radius - math.hypot(dx, dy))
        lane_heading = direction * s / radius + start_phase + math.pi / 2 * direction
    else:
        sx, sy, d0, d1, l0, l1, length, lane_heading = entry[3:11]
        dx, dy = x - sx, y - sy
        s = dx * d0 + dy * d1
        r = dx * l0 + dy * l1
        if kind == _SINE:
            amplitude, pulsation, phase = entry[11:]
            r -= amplitude * math.sin(pulsation * s + phase)
            lane_heading += math.atan(amplitude * pulsation * math.cos(pulsation * s + phase))
    distance = abs(r) + max(s - length, 0.0) + max(-s, 0.0)
    if heading is not None:
        distance += abs((heading - lane_heading + math.pi) % (2 * math.pi) - math.pi)
    return distance


def _kinematics(vehicle: Any, dt: float) -> None:
    """highway-env's ``Vehicle.step`` up to ``on_state_update`` (its lines, with
    ``IDMVehicle.step``'s timer): ``vehicle`` moved by ``dt`` [s], its lane not looked up."""
    if type(vehicle).step is _HIGHWAY_ENV_MOVE[3]:  # IDMVehicle's: its timer
        vehicle.timer += dt
    vehicle.clip_actions()
    delta_f = vehicle.action["steering"]
    beta = np.arctan(1 / 2 * np.tan(delta_f))
    v = vehicle.speed * np.array([np.cos(vehicle.heading + beta),
                                  np.sin(vehicle.heading + beta)])
    vehicle.position += v * dt
    if vehicle.impact is not None:
        vehicle.position += vehicle.impact
        vehicle.crashed = True
        vehicle.impact = None
    vehicle.heading += vehicle.speed * np.sin(beta) / (vehicle.LENGTH / 2) * dt
    vehicle.speed += vehicle.action["acceleration"] * dt


def _kinematics_at_once(vehicles: list[Any], dt: float) -> None:
    """:func:`_kinematics` of every one of ``vehicles``, the same states bit for bit: the
    timers and ``clip_actions`` one vehicle at a time in the road's order, then highway-env's
    formulas for all at once with numpy (element by element the same operations in the same
    order; numpy's array ``tan``, ``arctan``, ``cos`` and ``sin`` give its scalar kernels'
    bits where :func:`fast_idm.array_kernels_agree
    <tap_bench.sim.fast_idm.array_kernels_agree>` holds), each vehicle's position, heading
    and speed then updated as ``Vehicle.step`` updates them (in place, the same types)."""
    idm_step = _HIGHWAY_ENV_MOVE[3]
    for vehicle in vehicles:
        if type(vehicle).step is idm_step:  # IDMVehicle's: its timer
            vehicle.timer += dt
        vehicle.clip_actions()
    steering = np.array([v.action["steering"] for v in vehicles], dtype=float)
    speed = np.array([v.speed for v in vehicles], dtype=float)
    heading = np.array([v.heading for v in vehicles], dtype=float)
    half_length = np.array([v.LENGTH for v in vehicles], dtype=float) / 2
    beta = np.arctan(1 / 2 * np.tan(steering))
    angle = heading + beta
    moved = speed[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1) * dt
    turned = speed * np.sin(beta) / half_length * dt
    for k, vehicle in enumerate(vehicles):
        vehicle.position += moved[k]
        if vehicle.impact is not None:
            vehicle.position += vehicle.impact
            vehicle.crashed = True
            vehicle.impact = None
        vehicle.heading += turned[k]
        vehicle.speed += vehicle.action["acceleration"] * dt


def _first_nearest(candidates: list[tuple[Any, ...]], position: np.ndarray,
                   heading: Any) -> tuple[str, str, int]:
    """The index of the first of ``candidates`` (:func:`_lane_entry`, in the network's
    order) at the least ``lane.distance_with_heading(position, heading)`` (highway-env's
    own arithmetic): ``np.argmin``'s choice."""
    best = best_index = None
    for index, lane, *_ in candidates:
        distance = lane.distance_with_heading(position, heading)
        if best is None or distance < best:
            best, best_index = distance, index
    return best_index


def _lane_arrays(flat: list[tuple[Any, ...]]) -> dict[str, np.ndarray]:
    """The parameters of every lane of ``flat`` (:func:`_lane_entry`) as (L,) arrays, for
    :func:`_estimates` (zeros where a parameter is not the lane kind's)."""
    n = len(flat)
    out = {name: np.zeros(n) for name in ("sx", "sy", "d0", "d1", "l0", "l1", "length",
                                          "heading", "amplitude", "pulsation", "phase",
                                          "cx", "cy", "radius", "start_phase", "turning")}
    kind = np.array([entry[2] for entry in flat])
    for j, entry in enumerate(flat):
        if entry[2] == _CIRCULAR:
            values = dict(zip(("cx", "cy", "radius", "start_phase", "turning", "length"),
                              entry[3:9], strict=True))
        else:
            values = dict(zip(("sx", "sy", "d0", "d1", "l0", "l1", "length", "heading",
                               "amplitude", "pulsation", "phase"), entry[3:], strict=False))
        for name, value in values.items():
            out[name][j] = value
    out["circular"] = kind == _CIRCULAR
    return out


def _estimates(lanes: dict[str, np.ndarray], positions: np.ndarray, headings: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """(N, L) ``lane.distance_with_heading(position, heading)`` of every position (N, 2)
    [m] and heading (N,) [rad] to every lane of ``lanes`` (:func:`_lane_arrays`), estimated
    with numpy arrays (as :func:`_estimate`, off by rounding only), and (N, L) bool: the
    entries on a circular lane's phase wrap, whose estimate must not be used."""
    x, y = positions[:, 0:1], positions[:, 1:2]
    dx, dy = x - lanes["sx"], y - lanes["sy"]
    s = dx * lanes["d0"] + dy * lanes["d1"]
    r = dx * lanes["l0"] + dy * lanes["l1"]
    lane_heading = np.broadcast_to(lanes["heading"], s.shape)
    if lanes["amplitude"].any():  # sine lanes (a straight lane's amplitude is 0)
        phase = lanes["pulsation"] * s + lanes["phase"]
        r = r - lanes["amplitude"] * np.sin(phase)
        lane_heading = lane_heading + np.arctan(lanes["amplitude"] * lanes["pulsation"]
                                                * np.cos(phase))
    exact = np.zeros(s.shape, dtype=bool)
    circular = lanes["circular"]
    if circular.any():
        ex, ey = x - lanes["cx"][circular], y - lanes["cy"][circular]
        turn = np.remainder(np.arctan2(ey, ex) - lanes["start_phase"][circular] + np.pi,
                            2 * np.pi) - np.pi
        turning, radius = lanes["turning"][circular], lanes["radius"][circular]
        s_c = turning * turn * radius
        s = np.where(circular, 0.0, s)
        r = np.where(circular, 0.0, r)
        lane_heading = np.where(circular, 0.0, lane_heading)
        s[:, circular] = s_c
        r[:, circular] = turning * (radius - np.hypot(ex, ey))
        lane_heading[:, circular] = (turning * s_c / radius + lanes["start_phase"][circular]
                                     + np.pi / 2 * turning)
        exact[:, circular] = np.abs(turn) >= np.pi - _WRAP_MARGIN
    distance = (np.abs(r) + np.maximum(s - lanes["length"], 0.0) + np.maximum(-s, 0.0)
                + np.abs(np.remainder(headings[:, None] - lane_heading + np.pi, 2 * np.pi)
                         - np.pi))
    return distance, exact


_SEARCH_CODE = {  # sha256 of the source of the search FastRoad._table and _from_table repeat
    "Road.neighbour_vehicles": "6401966dd2bc7350",
    "AbstractLane.on_lane": "737440dd0b30c7fd",
    "StraightLane.local_coordinates": "cc85099a835712ba",
    "StraightLane.width_at": "a3f9e9578226633b",
}
_HIGHWAY_ENV_SEARCH = (Road.neighbour_vehicles, AbstractLane.on_lane,
                       StraightLane.local_coordinates, StraightLane.width_at)
"""highway-env's own search methods, as imported (a process may replace them)."""


def _searches_as_written() -> bool:
    """Whether highway-env's ``Road.neighbour_vehicles`` and the straight lane's methods it
    calls are, on their classes, the code (highway-env 1.12's) that the lane tables of
    :class:`FastRoad` repeat; the sources are checked once per process."""
    return (Road.neighbour_vehicles is _HIGHWAY_ENV_SEARCH[0]
            and StraightLane.on_lane is _HIGHWAY_ENV_SEARCH[1]
            and StraightLane.local_coordinates is _HIGHWAY_ENV_SEARCH[2]
            and StraightLane.width_at is _HIGHWAY_ENV_SEARCH[3]
            and _search_sources_match())


def _projects(lane: Any) -> bool:
    """Whether ``lane``'s coordinates of the road's objects may be computed at once by
    :func:`fast_idm.lane_dots <tap_bench.sim.fast_idm.lane_dots>` (highway-env's straight
    lane, its projection not changed on the instance, and highway-env's search code the
    one the lane tables repeat)."""
    return (type(lane) is StraightLane and not _LANE_PROJECTION & vars(lane).keys()
            and _searches_as_written())


@functools.cache
def _search_sources_match() -> bool:
    return sources_match(_HIGHWAY_ENV_SEARCH, _SEARCH_CODE)


_MOVE_CODE = {  # sha256 of the source of highway-env's methods FastRoad.move stands in for
    "Vehicle.step": "da2898cee3d632de",
    "Vehicle.clip_actions": "fe72ee0bf6986dac",
    "Vehicle.on_state_update": "2335ae4ab21c22c5",
    "IDMVehicle.step": "0a9d69d92d9e714f",
}


_HIGHWAY_ENV_MOVE = (Vehicle.step, Vehicle.clip_actions, Vehicle.on_state_update,
                     IDMVehicle.step, Vehicle.create_from.__func__,
                     IDMVehicle.create_from.__func__, ControlledVehicle.create_from.__func__)
"""highway-env's own methods, as imported (a process may replace them on the classes)."""


@functools.cache
def _highway_env_moves_as_written() -> bool:
    """Whether the installed highway-env's ``Vehicle.step`` (and what it calls) is the code
    :meth:`FastRoad.move` repeats (that of highway-env 1.12); checked once per process."""
    return sources_match(_HIGHWAY_ENV_MOVE[:4], _MOVE_CODE)


@functools.cache
def _moving_class(cls: type) -> bool:
    """Whether objects of ``cls`` move by highway-env's own ``Vehicle.step`` (or
    ``IDMVehicle``'s, which adds its timer) and lane lookup."""
    step, clip_actions, on_state_update, idm_step, *create_from = _HIGHWAY_ENV_MOVE
    return (issubclass(cls, Vehicle) and cls.step in (step, idm_step)
            and cls.clip_actions is clip_actions and cls.on_state_update is on_state_update
            and cls.create_from.__func__ in create_from
            and _highway_env_moves_as_written())


def _moves_as_highway_env(vehicle: Any, road: Road) -> bool:
    """Whether :meth:`FastRoad.move` may move ``vehicle`` (on ``road``) itself."""
    return (_moving_class(type(vehicle)) and vehicle.road is road
            and not {"step", "clip_actions", "on_state_update", "create_from"}
            & vars(vehicle).keys())


def _standard_collisions(obj: Any) -> bool:
    """Whether ``obj`` checks collisions with highway-env's own rule
    (``RoadObject.handle_collisions`` and ``_is_colliding``, on neither its class nor the
    instance replaced): the rule the pair pruning of :meth:`FastRoad.step` assumes."""
    cls = type(obj)
    return (getattr(cls, "handle_collisions", None) is RoadObject.handle_collisions
            and getattr(cls, "_is_colliding", None) is RoadObject._is_colliding
            and not {"handle_collisions", "_is_colliding"} & vars(obj).keys())


def _near_pairs(vehicles: list[Any], objects: list[Any], dt: float) -> np.ndarray | None:
    """(n_vehicles, n_vehicles + n_objects) bool: the pairs whose collision check can do
    anything, i.e. that fail highway-env's spherical pre-check (``_is_colliding``: farther
    apart than half their diagonals plus the first one's travel in ``dt``, nothing happens)
    by more than :data:`TOLERANCE`, and in which a vehicle checks collisions. None when
    some vehicle or object lacks the position or diagonal that check reads (then every
    pair is checked)."""
    everyone = vehicles + objects
    n = len(vehicles)
    try:
        position = np.array([o.position for o in everyone], dtype=float)
        diagonal = np.array([o.diagonal for o in everyone], dtype=float)
        speed = np.array([v.speed for v in vehicles], dtype=float)
        checks = np.array([bool(o.check_collisions) for o in everyone])
    except (AttributeError, TypeError, ValueError):
        return None
    if position.shape != (len(everyone), 2):
        return None
    delta = position[None, :, :] - position[:n, None, :]
    distance = np.sqrt(delta[..., 0] ** 2 + delta[..., 1] ** 2)
    bound = (diagonal[:n, None] + diagonal[None, :]) / 2 + speed[:, None] * dt
    near = ~(distance > bound + TOLERANCE)  # NaN: near, highway-env decides
    return near & (checks[:n, None] | checks[None, :])


def _project(lane: StraightLane, positions: np.ndarray
             ) -> tuple[list[float], list[float], list[int]]:
    """The vehicles at ``positions`` (n, 2) [m] on ``lane``: the sorted longitudinal
    coordinates of those surely on it, and the sorted coordinates and indices of those that
    may be on it (within :data:`TOLERANCE` of its bounds)."""
    delta = positions - lane.start
    s_v = delta[:, 0] * lane.direction[0] + delta[:, 1] * lane.direction[1]
    lat_v = np.abs(delta[:, 0] * lane.direction_lateral[0]
                   + delta[:, 1] * lane.direction_lateral[1])
    half = lane.width / 2 + _MARGIN
    lo, hi = -lane.VEHICLE_LENGTH, lane.length + lane.VEHICLE_LENGTH
    maybe = np.flatnonzero((lat_v <= half + TOLERANCE) & (s_v >= lo - TOLERANCE)
                           & (s_v < hi + TOLERANCE))
    surely = (lat_v <= half - TOLERANCE) & (s_v >= lo + TOLERANCE) & (s_v < hi - TOLERANCE)
    order = maybe[np.argsort(s_v[maybe], kind="stable")]
    return np.sort(s_v[surely]).tolist(), s_v[order].tolist(), order.tolist()


def use_fast_road(env: Any) -> bool:
    """Run ``env``'s current road through a :class:`FastRoad` (after a reset: highway-env
    builds a new road at each).

    Returns:
        whether it was installed: only on a road of exactly highway-env's ``Road`` class whose
        ``act``, ``step`` and search are highway-env's own (a subclass may do them
        differently).
    """
    road = getattr(env.unwrapped, "road", None)
    if type(road) is not Road or {"act", "step", "neighbour_vehicles"} & vars(road).keys():
        return False
    FastRoad(road).install()
    return True
