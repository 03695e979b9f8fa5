"""highway-env's IDM/MOBIL vehicles deciding all at once, the same decisions sooner.

In ``Road.act`` every :class:`~highway_env.vehicle.behavior.IDMVehicle` runs, one after the
other in Python: ``follow_road``, its lane-change policy (MOBIL, once a second), its steering
controller, a neighbour search and the IDM acceleration towards its leader (and towards the
leader on its target lane while it changes lanes). With 20 vehicles that was two thirds of a
rollout. :func:`act_all` gives every vehicle the same action, bit for bit:

- the lane-change decisions stay highway-env's own code, run per vehicle in the road's
  order, interleaved with the ``act`` of every vehicle that is not a plain IDM vehicle (the
  ego of another policy): a decision reads the target lanes and target speeds of vehicles
  that acted before it in the same step, so their order is kept;
- the steering command and the IDM accelerations, which read only positions, speeds,
  headings and lanes (none of which change during ``Road.act``) and the vehicle's own target
  lane, are then computed for every plain IDM vehicle at once with numpy, with
  highway-env's formulas term for term in its order of operations (``max``, ``min`` and
  ``np.clip`` keep their NaN and signed-zero behaviour; ``np.dot`` of two 2-vectors is
  ``a0 * b0 + a1 * b1`` where the BLAS kernel computes that, and ``np.dot`` row by row
  where it fuses the multiply-add);
- a vehicle on a lane that is not straight steers and brakes by :func:`_act_rest`, one
  vehicle at a time, and one whose class or instance changes any method involved is left
  to highway-env's own ``act``.

The lane-change policy (MOBIL) is :func:`_change_lane_policy`: highway-env's
``change_lane_policy`` and ``mobil`` line for line, with the IDM accelerations and desired
gaps of :func:`_idm` and :func:`_desired_gap` (the same float operations in the same order).
It is used only where the installed highway-env's source of these methods is the one it
repeats (:func:`_highway_env_decides_as_written`, highway-env 1.12) and for vehicles whose
class changes none of them; elsewhere highway-env's own methods run.

On small roads (:func:`act_each`, highway-env's order: each vehicle acts in full before
the next) the plain IDM vehicles run the lane-change policy and then
:func:`_act_rest`: the steering and IDM formulas term for term, in numpy scalars where
highway-env has them, without the calls that cost more than their arithmetic (``np.clip``
of one number, the velocity and direction arrays, a straight lane's ``np.dot``).

numpy's array kernels (``arcsin``, ``tan``, ``power`` ...) must give the same bits as its
scalar ones for this to hold; :func:`array_kernels_agree` checks that on this machine once
per process, and where they do not, :func:`act_all` is not used (``FastRoad`` falls back to
highway-env's ``Road.act``). Tested by simulating scenarios both ways and comparing every
vehicle's state bit for bit (``tests/sim/test_sim_fast_road.py``).

Parts of this module re-state highway-env's code (MIT License, Copyright (c) 2018 Edouard
Leurent, (c) 2023 Farama Foundation): see THIRD_PARTY_NOTICES.md.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
from operator import attrgetter
from typing import Any

import numpy as np
from highway_env import utils
from highway_env.road.lane import StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

__all__ = ["act_all", "act_each", "array_kernels_agree", "is_plain_idm", "lane_dots"]

_METHODS = ("act", "follow_road", "change_lane_policy", "mobil", "steering_control",
            "acceleration", "desired_gap", "lane_distance_to")
"""The methods of IDMVehicle that :func:`act_all` stands in for (or runs)."""

_INSTANCE_OVERRIDES = frozenset(_METHODS) | {"velocity", "direction"}
"""Attributes that, set on an instance, make it act differently from the class."""

_CONSTANTS = attrgetter("KP_LATERAL", "KP_HEADING", "LENGTH", "MAX_STEERING_ANGLE",
                        "ACC_MAX", "COMFORT_ACC_MAX", "COMFORT_ACC_MIN", "DELTA",
                        "DISTANCE_WANTED", "TIME_WANTED")
_STATE = attrgetter("speed", "heading")
_VELOCITY_CLASSES: dict[type, bool] = {}

_EPS = 1e-2  # highway_env.utils.not_zero's epsilon


@functools.cache
def _plain_class(cls: type) -> bool:
    return (all(getattr(cls, name) is getattr(IDMVehicle, name) for name in _METHODS)
            and _standard_velocity(cls))


def is_plain_idm(vehicle: Any) -> bool:
    """Whether ``vehicle`` acts exactly as highway-env's IDMVehicle: that class or a subclass
    (with other constants) that changes none of its decision methods, on the class or on the
    instance), and whose own ``velocity`` and ``direction`` are highway-env's (``desired_gap``
    reads them; :func:`act_all` computes them from speed and heading)."""
    return _plain_class(type(vehicle)) and not (vars(vehicle).keys() & _INSTANCE_OVERRIDES)


@functools.cache
def array_kernels_agree() -> bool:
    """Whether numpy's array kernels give the scalar kernels' bits on this machine, for
    every operation :func:`act_all` vectorises (checked once per process)."""
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-1, 1, 256), rng.uniform(-50, 50, 256)])
    y = rng.uniform(0.5, 60, 512)
    e = rng.uniform(3.5, 4.5, 512)
    checks = [
        (np.arcsin(np.clip(x, -1, 1)), [np.arcsin(np.clip(v, -1, 1)) for v in x]),
        (np.arctan(2 * np.tan(x)), [np.arctan(2 * np.tan(v)) for v in x]),
        (np.cos(x), [np.cos(v) for v in x]), (np.sin(x), [np.sin(v) for v in x]),
        (np.power(y / 30.0, e), [np.power(v / 30.0, w) for v, w in zip(y, e, strict=True)]),
        (np.power(x, 2), [np.power(v, 2) for v in x]),
        (np.remainder(x + np.pi, 2 * np.pi), [(v + np.pi) % (2 * np.pi) for v in x]),
    ]
    return all(np.array_equal(got, np.array(want, dtype=float)) for got, want in checks)


@functools.cache
def _dot_is_mul_add() -> bool:
    """Whether ``np.dot`` of two 2-vectors is ``a0 * b0 + a1 * b1`` here. It depends on the
    BLAS kernel numpy calls (OpenBLAS picks one per CPU; one with fused multiply-adds
    rounds differently), so it is checked once per process."""
    a, b = np.random.default_rng(1).uniform(-100, 100, (2, 512, 2))
    return np.array_equal(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1],
                          np.array([np.dot(u, w) for u, w in zip(a, b, strict=True)]))


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) ``np.dot(a[k], b[k])`` of (n, 2) rows (``b`` may be one (2,) vector for all),
    bit for bit: with numpy's arithmetic where the BLAS kernel computes
    ``a0 * b0 + a1 * b1``, else by ``np.dot`` row by row."""
    if _dot_is_mul_add():
        if b.ndim == 1:
            return a[:, 0] * b[0] + a[:, 1] * b[1]
        return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]
    a = np.ascontiguousarray(a, dtype=float)
    if b.ndim == 1:
        b = np.ascontiguousarray(b, dtype=float)
        return np.array([np.dot(u, b) for u in a], dtype=float)
    b = np.ascontiguousarray(b, dtype=float)
    return np.array([np.dot(u, w) for u, w in zip(a, b, strict=True)], dtype=float)


def _not_zero(x: np.ndarray) -> np.ndarray:
    """highway_env.utils.not_zero on each element."""
    return np.where(np.abs(x) > _EPS, x, np.where(x >= 0, _EPS, -_EPS))


def _standard_velocity(cls: type) -> bool:
    """Whether objects of ``cls`` have highway-env's ``velocity``: speed times (cos, sin)
    of the heading."""
    if cls not in _VELOCITY_CLASSES:
        _VELOCITY_CLASSES[cls] = (cls.velocity in (Vehicle.velocity, RoadObject.velocity)
                                  and cls.direction is RoadObject.direction)
    return _VELOCITY_CLASSES[cls]


def _velocity(objects: list[Any]) -> np.ndarray:
    """(n, 2) ``velocity`` of each object [m/s] (computed for highway-env's definition,
    asked of the object otherwise)."""
    out = np.empty((len(objects), 2))
    standard = [k for k, obj in enumerate(objects)
                if _standard_velocity(type(obj)) and "velocity" not in vars(obj)]
    if len(standard) < len(objects):
        for k in set(range(len(objects))) - set(standard):
            out[k] = objects[k].velocity
    if standard:
        speed, heading = np.array([_STATE(objects[k]) for k in standard], dtype=float).T
        out[standard, 0] = speed * np.cos(heading)
        out[standard, 1] = speed * np.sin(heading)
    return out


def act_all(road: Any, leaders: Any = None) -> None:
    """highway-env's ``Road.act`` for ``road``: every vehicle decides its action (see the
    module docstring); the same actions, target lanes and timers, bit for bit.

    The road's search (``road.neighbour_vehicles``) must not depend on what the vehicles
    decide (highway-env's does not; tap-bench's FastRoad neither). ``leaders(vehicles,
    lane_indices)``, when given, finds the vehicle ahead of each on a lane at once (as
    ``road.neighbour_vehicles(vehicle, lane_index)[0]`` would).
    """
    network = road.network
    plain = []
    for vehicle in road.vehicles:
        if not is_plain_idm(vehicle):
            vehicle.act()
            continue
        if vehicle.crashed:
            continue
        vehicle.follow_road()
        if vehicle.enable_lane_change:
            _change_lane_policy(vehicle)
        plain.append(vehicle)
    if not plain:
        return
    batch, lanes, targets = [], [], []
    for vehicle in plain:
        lane, target = vehicle.lane, network.get_lane(vehicle.target_lane_index)
        if type(lane) is StraightLane and type(target) is StraightLane:
            batch.append(vehicle)
            lanes.append(lane)
            targets.append(target)
        else:  # highway-env's own arithmetic, after the lane-change policy it already ran
            _act_rest(vehicle)
    if batch:
        _act_straight(road, batch, lanes, targets, leaders)


def _act_rest(vehicle: Any) -> None:
    """The part of ``IDMVehicle.act`` after the lane-change policy, as highway-env runs it:
    its steering and IDM formulas term for term, in numpy scalars where highway-env has
    them (:func:`_steering`, :func:`_idm`), without the calls that cost more than the
    arithmetic (``np.clip`` of a scalar, the velocity and direction arrays, a straight
    lane's ``np.dot``), whose results :func:`_clip` and :func:`_local` give bit for bit."""
    steering = _clip(_steering(vehicle), -vehicle.MAX_STEERING_ANGLE,
                     vehicle.MAX_STEERING_ANGLE)
    front = vehicle.road.neighbour_vehicles(vehicle, vehicle.lane_index)[0]
    acceleration = _idm(vehicle, front)
    if vehicle.lane_index != vehicle.target_lane_index:
        front = vehicle.road.neighbour_vehicles(vehicle, vehicle.target_lane_index)[0]
        target_acceleration = _idm(vehicle, front)
        acceleration = min(acceleration, target_acceleration)
    vehicle.action = {"steering": steering,
                      "acceleration": _clip(acceleration, -vehicle.ACC_MAX, vehicle.ACC_MAX)}


def act_each(road: Any) -> None:
    """highway-env's ``Road.act``, one vehicle after the other: a plain IDM vehicle (see
    :func:`is_plain_idm`) acts by highway-env's lane-change policy and then
    :func:`_act_rest`, any other by its own ``act``; the same actions, target lanes and
    timers, bit for bit."""
    for vehicle in road.vehicles:
        if not is_plain_idm(vehicle):
            vehicle.act()
        elif not vehicle.crashed:
            vehicle.follow_road()
            if vehicle.enable_lane_change:
                _change_lane_policy(vehicle)
            _act_rest(vehicle)


def _clip(x: Any, low: Any, high: Any) -> Any:
    """``np.clip(x, low, high)`` of one number, the same value (NaN and signed zeros
    included: numpy keeps ``x`` when it equals a bound), without numpy's call overhead."""
    if x != x or low != low or high != high:
        return np.clip(x, low, high)
    clipped = x if x >= low else low
    return clipped if clipped <= high else high


def _local(lane: Any, position: np.ndarray) -> tuple[Any, Any]:
    """``lane.local_coordinates(position)``: a straight lane's two ``np.dot`` as
    :func:`_dot2` (bit for bit), other lanes' by their own method."""
    if type(lane) is StraightLane and _dot_is_mul_add():
        dx, dy = position[0] - lane.start[0], position[1] - lane.start[1]
        d, lateral = lane.direction, lane.direction_lateral
        return float(dx * d[0] + dy * d[1]), float(dx * lateral[0] + dy * lateral[1])
    return lane.local_coordinates(position)


def _steering(vehicle: Any) -> float:
    """``ControlledVehicle.steering_control(vehicle.target_lane_index)``, term for term."""
    target = vehicle.road.network.get_lane(vehicle.target_lane_index)
    lane_coords = _local(target, vehicle.position)
    if type(target) is StraightLane:
        future_heading = target.heading
    else:
        future_heading = target.heading_at(lane_coords[0]
                                           + vehicle.speed * vehicle.TAU_PURSUIT)
    lateral_speed_command = -vehicle.KP_LATERAL * lane_coords[1]
    speed = _not_zero_one(vehicle.speed)
    heading_command = np.arcsin(_clip(lateral_speed_command / speed, -1, 1))
    heading_ref = future_heading + _clip(heading_command, -np.pi / 4, np.pi / 4)
    heading_rate_command = vehicle.KP_HEADING * (((heading_ref - vehicle.heading) + np.pi)
                                                 % (2 * np.pi) - np.pi)
    slip_angle = np.arcsin(_clip(vehicle.LENGTH / 2 / speed * heading_rate_command, -1, 1))
    steering_angle = np.arctan(2 * np.tan(slip_angle))
    return float(_clip(steering_angle, -vehicle.MAX_STEERING_ANGLE,
                       vehicle.MAX_STEERING_ANGLE))


def _not_zero_one(x: Any, eps: float = _EPS) -> Any:
    """highway_env.utils.not_zero of one number."""
    if abs(x) > eps:
        return x
    return eps if x >= 0 else -eps


_OWN = object()
"""The default ``ego`` of :func:`_idm`: the vehicle itself (None is "no vehicle")."""


def _idm(vehicle: Any, front: Any, ego: Any = _OWN) -> Any:
    """``vehicle.acceleration(ego_vehicle=ego, front_vehicle=front)`` (``ego``: ``vehicle``
    when not given; None or a non-vehicle: 0 as highway-env returns), term for term:
    ``vehicle``'s IDM constants, ``ego``'s speed, target speed and lane. An ``ego`` whose
    velocity, direction or ``lane_distance_to`` are not highway-env's is left to
    ``vehicle.acceleration``."""
    if ego is _OWN:
        ego = vehicle
    elif not ego or not isinstance(ego, Vehicle):
        return 0
    elif not _scalar_ego(ego):
        return vehicle.acceleration(ego_vehicle=ego, front_vehicle=front)
    target_speed = getattr(ego, "target_speed", 0)
    lane = ego.lane
    if lane and lane.speed_limit is not None:
        target_speed = _clip(target_speed, 0, lane.speed_limit)
    acceleration = vehicle.COMFORT_ACC_MAX * (1 - np.power(
        max(ego.speed, 0) / abs(_not_zero_one(target_speed)), vehicle.DELTA))
    if front:
        d = _local(lane, front.position)[0] - _local(lane, ego.position)[0]
        acceleration -= vehicle.COMFORT_ACC_MAX * np.power(
            _desired_gap(vehicle, front, ego) / _not_zero_one(d), 2)
    return acceleration


def _scalar_ego(obj: Any) -> bool:
    """Whether :func:`_idm` may compute for ``obj`` as the following vehicle: its velocity,
    direction and ``lane_distance_to`` are highway-env's (class and instance)."""
    return (_standard_velocity(type(obj)) and _own_lane_distance(type(obj))
            and not _EGO_OVERRIDES & vars(obj).keys())


_EGO_OVERRIDES = frozenset({"velocity", "direction", "lane_distance_to"})


@functools.cache
def _own_lane_distance(cls: type) -> bool:
    return getattr(cls, "lane_distance_to", None) is _HIGHWAY_ENV_DECIDE[4]


def _desired_gap(vehicle: Any, front: Any, ego: Any = None) -> Any:
    """``vehicle.desired_gap(ego, front)`` (``ego``: ``vehicle`` when not given), term for
    term (``np.dot`` as :func:`_dot` computes it); ``ego`` has highway-env's velocity and
    direction."""
    if ego is None:
        ego = vehicle
    ab = -vehicle.COMFORT_ACC_MAX * vehicle.COMFORT_ACC_MIN
    cos, sin = np.cos(ego.heading), np.sin(ego.heading)
    if _standard_velocity(type(front)) and not {"velocity", "direction"} & vars(front).keys():
        front_cos, front_sin = np.cos(front.heading), np.sin(front.heading)
        dvx = ego.speed * cos - front.speed * front_cos
        dvy = ego.speed * sin - front.speed * front_sin
    else:
        dvx, dvy = np.array([ego.speed * cos, ego.speed * sin]) - front.velocity
    if _dot_is_mul_add():
        dv = dvx * cos + dvy * sin
    else:
        dv = np.dot(np.array([dvx, dvy]), np.array([cos, sin]))
    return (vehicle.DISTANCE_WANTED + ego.speed * vehicle.TIME_WANTED
            + ego.speed * dv / (2 * np.sqrt(ab)))


_HIGHWAY_ENV_DECIDE = (IDMVehicle.change_lane_policy, IDMVehicle.mobil,
                       IDMVehicle.acceleration, IDMVehicle.desired_gap,
                       RoadObject.lane_distance_to, utils.do_every)
"""highway-env's own lane-change methods, as imported (a process may replace them)."""

_DECIDE_CODE = {  # sha256 of the source of the methods _change_lane_policy repeats
    "IDMVehicle.change_lane_policy": "fd17bcecf4e9a6d3",
    "IDMVehicle.mobil": "b5735ff10b6cde58",
    "IDMVehicle.acceleration": "39b9ba61a36409b0",
    "IDMVehicle.desired_gap": "fe6699a416db83f2",
    "RoadObject.lane_distance_to": "4db4f2b77cf0bdbe",
    "do_every": "6bc9a36388d1e424",
}


def sources_match(functions: Any, digests: dict[str, str]) -> bool:
    """Whether the installed source of ``functions`` is the code a fast path of tap-bench
    repeats: each function's source, by its qualified name, hashes (the first 16 hex digits
    of its SHA-256) to ``digests[name]``; False where a source cannot be read. The fast
    paths (this module's decisions, :mod:`tap_bench.sim.fast_road`'s motion,
    :mod:`tap_bench.sim.observation`'s Kinematics) run only where it holds."""
    try:
        sources = {f.__qualname__: inspect.getsource(f) for f in functions}
    except (OSError, TypeError):
        return False
    return all(hashlib.sha256(sources.get(name, "").encode()).hexdigest()[:16] == digest
               for name, digest in digests.items())


@functools.cache
def _highway_env_decides_as_written() -> bool:
    """Whether the installed highway-env's lane-change policy (``change_lane_policy``,
    ``mobil`` and what they call) is the code :func:`_change_lane_policy` repeats (that of
    highway-env 1.12); checked once per process."""
    return sources_match(_HIGHWAY_ENV_DECIDE, _DECIDE_CODE)


@functools.cache
def _decides_as_written(cls: type) -> bool:
    """Whether vehicles of ``cls`` change lanes by highway-env's own (repeated) code."""
    names = ("change_lane_policy", "mobil", "acceleration", "desired_gap",
             "lane_distance_to")
    return (_highway_env_decides_as_written()
            and all(getattr(cls, name) is f
                    for name, f in zip(names, _HIGHWAY_ENV_DECIDE[:5], strict=True))
            and utils.do_every is _HIGHWAY_ENV_DECIDE[5])


def _change_lane_policy(vehicle: Any) -> None:
    """``vehicle.change_lane_policy()`` (a plain IDM vehicle, see :func:`is_plain_idm`):
    highway-env's code line for line, with MOBIL's accelerations by :func:`_idm`; the
    same target lanes and timers, bit for bit. Left to highway-env where its code is not
    the one repeated here."""
    if not _decides_as_written(type(vehicle)):
        vehicle.change_lane_policy()
        return
    if vehicle.lane_index != vehicle.target_lane_index:
        # on the right route in the wrong lane: abort if another vehicle changes into it
        if vehicle.lane_index[:2] == vehicle.target_lane_index[:2]:
            lane = vehicle.lane
            for v in vehicle.road.vehicles:
                if (v is not vehicle and v.lane_index != vehicle.target_lane_index
                        and isinstance(v, ControlledVehicle)
                        and v.target_lane_index == vehicle.target_lane_index):
                    d = _local(lane, v.position)[0] - _local(lane, vehicle.position)[0]
                    d_star = _desired_gap(vehicle, v)
                    if 0 < d < d_star:
                        vehicle.target_lane_index = vehicle.lane_index
                        break
        return
    if not vehicle.LANE_CHANGE_DELAY < vehicle.timer:  # utils.do_every
        return
    vehicle.timer = 0
    network = vehicle.road.network
    for lane_index in network.side_lanes(vehicle.lane_index):
        if not network.get_lane(lane_index).is_reachable_from(vehicle.position):
            continue
        if np.abs(vehicle.speed) < 1:  # only a moving vehicle changes lanes
            continue
        if _mobil(vehicle, lane_index):
            vehicle.target_lane_index = lane_index


def _mobil(vehicle: Any, lane_index: tuple) -> bool:
    """``vehicle.mobil(lane_index)``: whether MOBIL changes to ``lane_index``, highway-env's
    code line for line with :func:`_idm` for its ``acceleration`` calls."""
    road = vehicle.road
    # is the manoeuvre unsafe for the new following vehicle?
    new_preceding, new_following = road.neighbour_vehicles(vehicle, lane_index)
    new_following_a = _idm(vehicle, new_preceding, new_following)
    new_following_pred_a = _idm(vehicle, vehicle, new_following)
    if new_following_pred_a < -vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED:
        return False
    old_preceding, old_following = road.neighbour_vehicles(vehicle)
    self_pred_a = _idm(vehicle, new_preceding)
    route = vehicle.route
    if route and route[0][2] is not None:
        # a planned lane: wrong direction, or unsafe braking for this vehicle
        if np.sign(lane_index[2] - vehicle.target_lane_index[2]) != np.sign(
                route[0][2] - vehicle.target_lane_index[2]):
            return False
        elif self_pred_a < -vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED:
            return False
    else:  # an acceleration advantage for this vehicle and/or its followers?
        self_a = _idm(vehicle, old_preceding)
        old_following_a = _idm(vehicle, vehicle, old_following)
        old_following_pred_a = _idm(vehicle, old_preceding, old_following)
        jerk = (self_pred_a - self_a
                + vehicle.POLITENESS * (new_following_pred_a - new_following_a
                                        + old_following_pred_a - old_following_a))
        if jerk < vehicle.LANE_CHANGE_MIN_ACC_GAIN:
            return False
    return True


def _lane_arrays(lanes: list[StraightLane]) -> tuple[np.ndarray, ...]:
    """start (n, 2), direction (n, 2), lateral direction (n, 2), heading (n,), speed limit
    (n,) (NaN: none) of each lane."""
    start = np.array([lane.start for lane in lanes], dtype=float)
    direction = np.array([lane.direction for lane in lanes], dtype=float)
    lateral = np.array([lane.direction_lateral for lane in lanes], dtype=float)
    heading = np.array([lane.heading for lane in lanes], dtype=float)
    limit = np.array([np.nan if lane.speed_limit is None else lane.speed_limit
                      for lane in lanes], dtype=float)
    return start, direction, lateral, heading, limit


def lane_dots(positions: np.ndarray, lane: StraightLane) -> tuple[np.ndarray, np.ndarray]:
    """(n,) longitudinal and (n,) lateral coordinates [m] of ``positions`` (n, 2) on a
    straight ``lane``: ``lane.local_coordinates(p)`` of each, bit for bit."""
    delta = positions - lane.start
    return _dot(delta, lane.direction), _dot(delta, lane.direction_lateral)


def _along(position: np.ndarray, start: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """StraightLane.local_coordinates(position)[0] of each row: np.dot(position - start,
    direction)."""
    return _dot(position - start, direction)


def _act_straight(road: Any, vehicles: list[Any], lanes: list[StraightLane],
                  targets: list[StraightLane], leaders: Any = None) -> None:
    """The steering and IDM part of ``IDMVehicle.act`` for ``vehicles`` (plain IDM, on
    straight ``lanes``, steering to straight ``targets``), all at once."""
    n = len(vehicles)
    (kp_lateral, kp_heading, length, max_steering, acc_max, comfort_max, comfort_min, delta,
     distance_wanted, time_wanted) = np.array([_CONSTANTS(v) for v in vehicles],
                                              dtype=float).T
    speed, heading = np.array([_STATE(v) for v in vehicles], dtype=float).T
    position = np.array([v.position for v in vehicles], dtype=float)
    target_speed = np.array([getattr(v, "target_speed", 0) for v in vehicles], dtype=float)

    # steering_control(target_lane_index), then act's clip
    t_start, _, t_lateral, t_heading, _ = _lane_arrays(targets)
    lat = _along(position, t_start, t_lateral)
    nz_speed = _not_zero(speed)
    heading_command = np.arcsin(np.clip(-kp_lateral * lat / nz_speed, -1, 1))
    heading_ref = t_heading + np.clip(heading_command, -np.pi / 4, np.pi / 4)
    heading_rate = kp_heading * (np.remainder(heading_ref - heading + np.pi, 2 * np.pi)
                                 - np.pi)
    slip = np.arcsin(np.clip(length / 2 / nz_speed * heading_rate, -1, 1))
    steering = np.clip(np.arctan(2 * np.tan(slip)), -max_steering, max_steering)
    steering = np.clip(steering, -max_steering, max_steering)

    # acceleration(self, leader on the own lane), and on the target lane when changing
    l_start, l_direction, _, _, limit = _lane_arrays(lanes)
    own_s = _along(position, l_start, l_direction)
    ego_target = np.where(np.isnan(limit), target_speed, np.clip(target_speed, 0, limit))
    free = comfort_max * (1 - np.power(np.where(0 > speed, 0.0, speed)
                                       / np.abs(_not_zero(ego_target)), delta))
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    velocity = speed[:, None] * direction
    gap_scale = 2 * np.sqrt(-comfort_max * comfort_min)

    def accelerations(fronts: list[Any]) -> np.ndarray:
        """IDM acceleration of each vehicle behind ``fronts`` (None: a free road)."""
        out = free.copy()
        rows = [k for k, front in enumerate(fronts) if front]
        if not rows:
            return out
        ahead = [fronts[k] for k in rows]
        front_position = np.array([f.position for f in ahead], dtype=float)
        d = _along(front_position, l_start[rows], l_direction[rows]) - own_s[rows]
        dv_vec = velocity[rows] - _velocity(ahead)
        dv = _dot(dv_vec, direction[rows])
        s = speed[rows]
        d_star = distance_wanted[rows] + s * time_wanted[rows] + s * dv / gap_scale[rows]
        out[rows] = out[rows] - comfort_max[rows] * np.power(d_star / _not_zero(d), 2)
        return out

    if leaders is None:
        def leaders(ask: list[Any], lane_indices: list[Any]) -> list[Any]:
            return [road.neighbour_vehicles(v, li)[0]
                    for v, li in zip(ask, lane_indices, strict=True)]

    acceleration = accelerations(leaders(vehicles, [v.lane_index for v in vehicles]))
    changing = [k for k, v in enumerate(vehicles) if v.lane_index != v.target_lane_index]
    if changing:
        fronts: list[Any] = [None] * n
        found = leaders([vehicles[k] for k in changing],
                        [vehicles[k].target_lane_index for k in changing])
        for k, front in zip(changing, found, strict=True):
            fronts[k] = front
        on_target = accelerations(fronts)
        for k in changing:  # min(a, b): b only when smaller
            if on_target[k] < acceleration[k]:
                acceleration[k] = on_target[k]
    acceleration = np.clip(acceleration, -acc_max, acc_max)
    for k, vehicle in enumerate(vehicles):
        vehicle.action = {"steering": steering[k], "acceleration": acceleration[k]}
