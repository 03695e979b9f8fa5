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
  lane, are then computed for every plain IDM vehicle (:func:`_act_straight`), with
  highway-env's formulas term for term in its order of operations, in Python floats
  (IEEE ``+ - * /`` give numpy's bits; ``max``, ``min`` and ``np.clip`` keep their NaN and
  signed-zero behaviour; ``np.dot`` of two 2-vectors is ``a0 * b0 + a1 * b1`` where the
  BLAS kernel computes that, else ``np.dot``), numpy's own ``arcsin``, ``tan`` and
  ``arctan`` per vehicle and its ``power`` for all vehicles in one array call;
- the road's state is read once per ``Road.act`` (:class:`ActState`: positions, speeds,
  headings as Python floats, the cos and sin of the headings as numpy computes them, each
  straight lane's coordinates of every object), and the decisions read it rather than
  the vehicles' numpy arrays;
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
per process, and where they do not, :func:`act_all` is not used (``FastRoad`` decides one
vehicle at a time, :func:`act_each`, with numpy's scalar kernels). Tested by simulating
scenarios both ways and comparing every vehicle's state bit for bit, and every action on
drawn states (``tests/sim/test_sim_fast_road.py``).

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
from highway_env.road.lane import AbstractLane, StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

__all__ = ["ActState", "act_all", "act_each", "array_kernels_agree", "is_plain_idm", "lane_dots"]

_METHODS = ("act", "follow_road", "change_lane_policy", "mobil", "steering_control",
            "acceleration", "desired_gap", "lane_distance_to")
"""The methods of IDMVehicle that :func:`act_all` stands in for (or runs)."""

_INSTANCE_OVERRIDES = frozenset(_METHODS) | {"velocity", "direction"}
"""Attributes that, set on an instance, make it act differently from the class."""

_CONSTANTS = attrgetter("KP_LATERAL", "KP_HEADING", "LENGTH", "MAX_STEERING_ANGLE",
                        "ACC_MAX", "COMFORT_ACC_MAX", "COMFORT_ACC_MIN", "DELTA",
                        "DISTANCE_WANTED", "TIME_WANTED")
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
    return _plain_class(type(vehicle)) and _INSTANCE_OVERRIDES.isdisjoint(vars(vehicle))


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


def _standard_velocity(cls: type) -> bool:
    """Whether objects of ``cls`` have highway-env's ``velocity``: speed times (cos, sin)
    of the heading."""
    if cls not in _VELOCITY_CLASSES:
        _VELOCITY_CLASSES[cls] = (cls.velocity in (Vehicle.velocity, RoadObject.velocity)
                                  and cls.direction is RoadObject.direction)
    return _VELOCITY_CLASSES[cls]


def act_all(road: Any, leaders: Any = None, state: ActState | None = None) -> None:
    """highway-env's ``Road.act`` for ``road``: every vehicle decides its action (see the
    module docstring); the same actions, target lanes and timers, bit for bit.

    The road's search (``road.neighbour_vehicles``) must not depend on what the vehicles
    decide (highway-env's does not; tap-bench's FastRoad neither). ``leaders(vehicles,
    lane_indices)``, when given, finds the vehicle ahead of each on a lane at once (as
    ``road.neighbour_vehicles(vehicle, lane_index)[0]`` would); ``state``, when given, is
    the road's :class:`ActState` now (else it is read here).
    """
    if state is None:
        state = ActState.of(road)
    network = road.network
    plain = []
    for vehicle in road.vehicles:
        if not is_plain_idm(vehicle):
            if _controls_as_written(vehicle):
                _act_controlled(vehicle, state)
            else:
                vehicle.act()
            continue
        if vehicle.crashed:
            continue
        _follow_road(vehicle, state)
        if vehicle.enable_lane_change:
            _change_lane_policy(vehicle, state)
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
        _act_straight(road, batch, lanes, targets, leaders, state)


def _follow_road(vehicle: Any, state: ActState | None = None) -> None:
    """``vehicle.follow_road()`` (a plain IDM vehicle): whether it is past the end of its
    target lane is read from that lane's projection in ``state`` (highway-env's
    ``after_end``: the lane's ``local_coordinates``, which the projection gives bit for
    bit), and highway-env's own method runs only where it is (to switch lanes), where
    there is no projection, or where highway-env's code is not the one repeated here
    (:func:`_follows_as_written`)."""
    if state is not None and type(vehicle).follow_road is _FOLLOW_ROAD[0] \
            and _follows_as_written():
        lane = vehicle.road.network.get_lane(vehicle.target_lane_index)
        k = state.index.get(id(vehicle))
        if k is not None and type(lane).after_end is _FOLLOW_ROAD[1] \
                and "after_end" not in vars(lane):
            projection = state.projection(lane)
            if projection is not None \
                    and not projection[2][k] > lane.length - lane.VEHICLE_LENGTH / 2:
                return
    vehicle.follow_road()


_FOLLOW_ROAD = (ControlledVehicle.follow_road, AbstractLane.after_end)
"""highway-env's own methods :func:`_follow_road` repeats, as imported."""

_FOLLOW_CODE = {  # sha256 of their source (highway-env 1.12)
    "ControlledVehicle.follow_road": "64dcd58fe8bf5f73",
    "AbstractLane.after_end": "e3abae0b2fd4d84f",
}


@functools.cache
def _follows_as_written() -> bool:
    """Whether the installed highway-env's ``follow_road`` and ``after_end`` are the code
    :func:`_follow_road` repeats; checked once per process."""
    return sources_match(_FOLLOW_ROAD, _FOLLOW_CODE)


def _act_controlled(vehicle: Any, state: ActState | None = None) -> None:
    """``vehicle.act()`` of a ControlledVehicle or MDPVehicle (the ego of a discrete
    policy) with no new high-level action, as highway-env runs it: ``follow_road``
    (:func:`_follow_road`), the steering command (:func:`_steering`, highway-env's terms)
    clipped as ``np.clip`` clips it, and ``speed_control``'s acceleration. Only for
    vehicles whose ``act`` and what it calls are highway-env's own
    (:func:`_controls_as_written`)."""
    _follow_road(vehicle, state)
    steering = np.float64(_clip(_steering(vehicle), -vehicle.MAX_STEERING_ANGLE,
                                vehicle.MAX_STEERING_ANGLE))
    vehicle.action = {"steering": steering,
                      "acceleration": vehicle.KP_A * (vehicle.target_speed - vehicle.speed)}


_CONTROL = (MDPVehicle.act, ControlledVehicle.act, ControlledVehicle.steering_control,
            ControlledVehicle.speed_control, Vehicle.act, utils.not_zero, utils.wrap_to_pi)
"""highway-env's own methods :func:`_act_controlled` repeats, as imported."""

_CONTROL_CODE = {  # sha256 of their source (highway-env 1.12)
    "MDPVehicle.act": "8641588076a2069d",
    "ControlledVehicle.act": "0112c74c240362c5",
    "ControlledVehicle.steering_control": "43c0c692d1dee36c",
    "ControlledVehicle.speed_control": "7f396ad3b09632bd",
    "Vehicle.act": "fdb4fe0b64f7e4eb",
    "not_zero": "f9806f813c24b658",
    "wrap_to_pi": "603d745ca127a314",
}
_CONTROL_OVERRIDES = frozenset({"act", "follow_road", "steering_control", "speed_control"})


@functools.cache
def _control_class(cls: type) -> bool:
    """Whether ``cls`` acts by highway-env's ``MDPVehicle.act`` or ``ControlledVehicle.act``
    and their own ``follow_road``, ``steering_control`` and ``speed_control`` (source
    checked once per process)."""
    mdp_act, act, steering_control, speed_control, *_ = _CONTROL
    return (issubclass(cls, ControlledVehicle) and cls.act in (mdp_act, act)
            and cls.follow_road is _FOLLOW_ROAD[0]
            and cls.steering_control is steering_control
            and cls.speed_control is speed_control
            and super(ControlledVehicle, cls).act is _CONTROL[4]
            and sources_match(_CONTROL, _CONTROL_CODE))


def _controls_as_written(vehicle: Any) -> bool:
    """Whether ``vehicle.act()`` may be :func:`_act_controlled` (class, instance and
    highway-env's helpers as imported)."""
    cls = type(vehicle)
    return (_control_class(cls) and cls.act in _CONTROL[:2]
            and utils.not_zero is _CONTROL[5] and utils.wrap_to_pi is _CONTROL[6]
            and _CONTROL_OVERRIDES.isdisjoint(vars(vehicle)))


def _act_rest(vehicle: Any, state: ActState | None = None) -> None:
    """The part of ``IDMVehicle.act`` after the lane-change policy, as highway-env runs it:
    its steering and IDM formulas term for term, in numpy scalars where highway-env has
    them (:func:`_steering`, :func:`_idm`), without the calls that cost more than the
    arithmetic (``np.clip`` of a scalar, the velocity and direction arrays, a straight
    lane's ``np.dot``), whose results :func:`_clip` and :func:`_local` give bit for bit
    (``state``: the road's :class:`ActState`, if at hand)."""
    steering = _clip(_steering(vehicle), -vehicle.MAX_STEERING_ANGLE,
                     vehicle.MAX_STEERING_ANGLE)
    front = vehicle.road.neighbour_vehicles(vehicle, vehicle.lane_index)[0]
    acceleration = _idm(vehicle, front, _OWN, state)
    if vehicle.lane_index != vehicle.target_lane_index:
        front = vehicle.road.neighbour_vehicles(vehicle, vehicle.target_lane_index)[0]
        target_acceleration = _idm(vehicle, front, _OWN, state)
        acceleration = min(acceleration, target_acceleration)
    vehicle.action = {"steering": steering,
                      "acceleration": _clip(acceleration, -vehicle.ACC_MAX, vehicle.ACC_MAX)}


def act_each(road: Any, state: ActState | None = None) -> None:
    """highway-env's ``Road.act``, one vehicle after the other: a plain IDM vehicle (see
    :func:`is_plain_idm`) acts by highway-env's lane-change policy and then
    :func:`_act_rest`, any other by its own ``act``; the same actions, target lanes and
    timers, bit for bit (``state``: the road's :class:`ActState`, if at hand)."""
    for vehicle in road.vehicles:
        if not is_plain_idm(vehicle):
            if _controls_as_written(vehicle):
                _act_controlled(vehicle, state)
            else:
                vehicle.act()
        elif not vehicle.crashed:
            _follow_road(vehicle, state)
            if vehicle.enable_lane_change:
                _change_lane_policy(vehicle, state)
            _act_rest(vehicle, state)


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


def _idm(vehicle: Any, front: Any, ego: Any = _OWN, state: ActState | None = None) -> Any:
    """``vehicle.acceleration(ego_vehicle=ego, front_vehicle=front)`` (``ego``: ``vehicle``
    when not given; None or a non-vehicle: 0 as highway-env returns), term for term:
    ``vehicle``'s IDM constants, ``ego``'s speed, target speed and lane. An ``ego`` whose
    velocity, direction or ``lane_distance_to`` are not highway-env's is left to
    ``vehicle.acceleration``. ``state``: the road's :class:`ActState` during ``Road.act``
    (speeds, headings and lane coordinates read from it)."""
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
    speed = ego.speed if state is None else state.kinematics(ego)[2]
    acceleration = vehicle.COMFORT_ACC_MAX * (1 - np.power(
        max(speed, 0) / abs(_not_zero_one(target_speed)), vehicle.DELTA))
    if front:
        d = None if state is None else state.distance(lane, ego, front)
        if d is None:
            d = _local(lane, front.position)[0] - _local(lane, ego.position)[0]
        acceleration -= vehicle.COMFORT_ACC_MAX * np.power(
            _desired_gap(vehicle, front, ego, state) / _not_zero_one(d), 2)
    return acceleration


def _scalar_ego(obj: Any) -> bool:
    """Whether :func:`_idm` may compute for ``obj`` as the following vehicle: its velocity,
    direction and ``lane_distance_to`` are highway-env's (class and instance)."""
    return (_standard_velocity(type(obj)) and _own_lane_distance(type(obj))
            and _EGO_OVERRIDES.isdisjoint(vars(obj)))


_EGO_OVERRIDES = frozenset({"velocity", "direction", "lane_distance_to"})


@functools.cache
def _own_lane_distance(cls: type) -> bool:
    return getattr(cls, "lane_distance_to", None) is _HIGHWAY_ENV_DECIDE[4]


def _desired_gap(vehicle: Any, front: Any, ego: Any = None,
                 state: ActState | None = None) -> Any:
    """``vehicle.desired_gap(ego, front)`` (``ego``: ``vehicle`` when not given), term for
    term (``np.dot`` as :func:`_dot` computes it); ``ego`` has highway-env's velocity and
    direction. ``state``: the road's :class:`ActState` (speeds, headings, their cos and
    sin read from it)."""
    if ego is None:
        ego = vehicle
    ab = -vehicle.COMFORT_ACC_MAX * vehicle.COMFORT_ACC_MIN
    if state is not None:
        _, _, speed, _, cos, sin = state.kinematics(ego)
        front_vx, front_vy = state.velocity(front)
        dvx, dvy = speed * cos - front_vx, speed * sin - front_vy
    else:
        speed = ego.speed
        cos, sin = np.cos(ego.heading), np.sin(ego.heading)
        if _standard_velocity(type(front)) and "velocity" not in vars(front):
            front_cos, front_sin = np.cos(front.heading), np.sin(front.heading)
            dvx = speed * cos - front.speed * front_cos
            dvy = speed * sin - front.speed * front_sin
        else:
            dvx, dvy = np.array([speed * cos, speed * sin]) - front.velocity
    dv = _dot2(dvx, dvy, cos, sin, _dot_is_mul_add())
    return (vehicle.DISTANCE_WANTED + speed * vehicle.TIME_WANTED
            + speed * dv / (2 * np.sqrt(ab)))


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


def _change_lane_policy(vehicle: Any, state: ActState | None = None) -> None:
    """``vehicle.change_lane_policy()`` (a plain IDM vehicle, see :func:`is_plain_idm`):
    highway-env's code line for line, with MOBIL's accelerations by :func:`_idm`; the
    same target lanes and timers, bit for bit. Left to highway-env where its code is not
    the one repeated here. ``state``: the road's :class:`ActState` during ``Road.act``."""
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
                    d = None if state is None else state.distance(lane, vehicle, v)
                    if d is None:
                        d = _local(lane, v.position)[0] - _local(lane, vehicle.position)[0]
                    d_star = _desired_gap(vehicle, v, None, state)
                    if 0 < d < d_star:
                        vehicle.target_lane_index = vehicle.lane_index
                        break
        return
    if not vehicle.LANE_CHANGE_DELAY < vehicle.timer:  # utils.do_every
        return
    vehicle.timer = 0
    network = vehicle.road.network
    own_lane: list[Any] = []  # MOBIL's terms on the own lane, the same for both side lanes
    for lane_index in network.side_lanes(vehicle.lane_index):
        if not network.get_lane(lane_index).is_reachable_from(vehicle.position):
            continue
        if np.abs(vehicle.speed) < 1:  # only a moving vehicle changes lanes
            continue
        if _mobil(vehicle, lane_index, state, own_lane):
            vehicle.target_lane_index = lane_index


def _mobil(vehicle: Any, lane_index: tuple, state: ActState | None = None,
           own_lane: list[Any] | None = None) -> bool:
    """``vehicle.mobil(lane_index)``: whether MOBIL changes to ``lane_index``, highway-env's
    code line for line with :func:`_idm` for its ``acceleration`` calls. ``own_lane``: a
    list kept between the side lanes of one decision, which holds the accelerations on
    the vehicle's own lane once computed (they do not depend on the side lane)."""
    road = vehicle.road
    # is the manoeuvre unsafe for the new following vehicle?
    new_preceding, new_following = road.neighbour_vehicles(vehicle, lane_index)
    new_following_a = _idm(vehicle, new_preceding, new_following, state)
    new_following_pred_a = _idm(vehicle, vehicle, new_following, state)
    if new_following_pred_a < -vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED:
        return False
    if own_lane is None:
        own_lane = []
    if not own_lane:
        own_lane.append(road.neighbour_vehicles(vehicle))
    old_preceding, old_following = own_lane[0]
    self_pred_a = _idm(vehicle, new_preceding, _OWN, state)
    route = vehicle.route
    if route and route[0][2] is not None:
        # a planned lane: wrong direction, or unsafe braking for this vehicle
        if np.sign(lane_index[2] - vehicle.target_lane_index[2]) != np.sign(
                route[0][2] - vehicle.target_lane_index[2]):
            return False
        elif self_pred_a < -vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED:
            return False
    else:  # an acceleration advantage for this vehicle and/or its followers?
        if len(own_lane) == 1:
            own_lane += [_idm(vehicle, old_preceding, _OWN, state),
                         _idm(vehicle, vehicle, old_following, state),
                         _idm(vehicle, old_preceding, old_following, state)]
        self_a, old_following_a, old_following_pred_a = own_lane[1:]
        jerk = (self_pred_a - self_a
                + vehicle.POLITENESS * (new_following_pred_a - new_following_a
                                        + old_following_pred_a - old_following_a))
        if jerk < vehicle.LANE_CHANGE_MIN_ACC_GAIN:
            return False
    return True


def lane_dots(positions: np.ndarray, lane: StraightLane) -> tuple[np.ndarray, np.ndarray]:
    """(n,) longitudinal and (n,) lateral coordinates [m] of ``positions`` (n, 2) on a
    straight ``lane``: ``lane.local_coordinates(p)`` of each, bit for bit."""
    delta = positions - lane.start
    return _dot(delta, lane.direction), _dot(delta, lane.direction_lateral)


def _act_straight(road: Any, vehicles: list[Any], lanes: list[StraightLane],
                  targets: list[StraightLane], leaders: Any = None,
                  state: ActState | None = None) -> None:
    """The steering and IDM part of ``IDMVehicle.act`` for ``vehicles`` (plain IDM, on
    straight ``lanes``, steering to straight ``targets``): highway-env's formulas term for
    term, one vehicle after the other in Python floats (the road's :class:`ActState`:
    positions, speeds, headings and their cos and sin), numpy's ``arcsin``, ``tan`` and
    ``arctan`` of each vehicle, and the two ``np.power`` of the IDM accelerations for all
    vehicles at once (one array call each: numpy's per-call cost was most of this step)."""
    if state is None:
        state = ActState.of(road)
    if leaders is None:
        def leaders(ask: list[Any], lane_indices: list[Any]) -> list[Any]:
            return [road.neighbour_vehicles(v, li)[0]
                    for v, li in zip(ask, lane_indices, strict=True)]

    fronts = leaders(vehicles, [v.lane_index for v in vehicles])
    changing = [k for k, v in enumerate(vehicles) if v.lane_index != v.target_lane_index]
    on_target = dict(zip(changing, leaders([vehicles[k] for k in changing],
                                           [vehicles[k].target_lane_index for k in changing]),
                         strict=True)) if changing else {}
    mul_add = _dot_is_mul_add()
    geometry: dict[int, tuple] = {}
    quarter = np.pi / 4
    steering, free_base, deltas, gap_base, rows = [], [], [], [], []
    for k, vehicle in enumerate(vehicles):
        (kp_lateral, kp_heading, length, max_steering, acc_max, comfort_max, comfort_min,
         delta, distance_wanted, time_wanted) = _CONSTANTS(vehicle)
        x, y, speed, heading, cos, sin = state.kinematics(vehicle)

        # steering_control(target_lane_index), then act's clip (each clip of a number
        # already within its bounds is that number: _clip only for the others)
        target = geometry.get(id(targets[k])) or _geometry(targets[k], geometry)
        lat = _dot2(x - target[0], y - target[1], target[4], target[5], mul_add)
        nz_speed = speed if abs(speed) > _EPS else _not_zero_one(speed)
        command = -kp_lateral * lat / nz_speed
        heading_command = np.arcsin(command if -1 <= command <= 1 else _clip(command, -1, 1))
        if not -quarter <= heading_command <= quarter:
            heading_command = _clip(heading_command, -quarter, quarter)
        heading_ref = target[6] + heading_command
        heading_rate = kp_heading * ((heading_ref - heading + np.pi) % (2 * np.pi) - np.pi)
        slip = length / 2 / nz_speed * heading_rate
        slip = np.arcsin(slip if -1 <= slip <= 1 else _clip(slip, -1, 1))
        steer = np.arctan(2 * np.tan(slip))
        if not -max_steering <= steer <= max_steering:  # twice: steering_control and act
            steer = _clip(_clip(steer, -max_steering, max_steering), -max_steering,
                          max_steering)
        steering.append(np.float64(steer))

        # acceleration(self, leader on the own lane), and on the target lane when changing
        own = geometry.get(id(lanes[k])) or _geometry(lanes[k], geometry)
        own_s = _dot2(x - own[0], y - own[1], own[2], own[3], mul_add)
        target_speed = getattr(vehicle, "target_speed", 0)
        if own[7] is not None:
            target_speed = _clip(target_speed, 0, own[7])
        free_base.append((0.0 if 0 > speed else speed) / abs(_not_zero_one(target_speed)))
        deltas.append(delta)
        gaps = []
        for front in (fronts[k], on_target.get(k)):
            if not front:
                gaps.append(None)
                continue
            fx, fy = state.position(front)
            d = _dot2(fx - own[0], fy - own[1], own[2], own[3], mul_add) - own_s
            fvx, fvy = state.velocity(front)
            dv = _dot2(speed * cos - fvx, speed * sin - fvy, cos, sin, mul_add)
            d_star = (distance_wanted + speed * time_wanted
                      + speed * dv / (2 * np.sqrt(-comfort_max * comfort_min)))
            gaps.append(len(gap_base))
            gap_base.append(d_star / _not_zero_one(d))
        rows.append((comfort_max, acc_max, *gaps))
    free_power = np.power(np.array(free_base, dtype=float),
                          np.array(deltas, dtype=float)).tolist()
    gap_power = np.power(np.array(gap_base, dtype=float), 2).tolist() if gap_base else []
    for k, vehicle in enumerate(vehicles):
        comfort_max, acc_max, own_gap, target_gap = rows[k]
        free = comfort_max * (1 - free_power[k])
        acceleration = free if own_gap is None else free - comfort_max * gap_power[own_gap]
        if k in on_target:  # min(a, b): b only when smaller
            changed = free if target_gap is None else free - comfort_max * gap_power[target_gap]
            if changed < acceleration:
                acceleration = changed
        vehicle.action = {"steering": steering[k],
                          "acceleration": np.float64(_clip(acceleration, -acc_max, acc_max))}


def _geometry(lane: StraightLane, known: dict[int, tuple]) -> tuple:
    """A straight lane's start (x, y), direction, lateral direction, heading (as the lane
    has it) and speed limit (None: none), kept in ``known`` by the lane's id."""
    known[id(lane)] = geometry = (
        *map(float, lane.start), *map(float, lane.direction),
        *map(float, lane.direction_lateral), lane.heading, lane.speed_limit)
    return geometry


def _dot2(a0: float, a1: float, b0: float, b1: float, mul_add: bool) -> float:
    """``np.dot([a0, a1], [b0, b1])``, bit for bit: ``a0 * b0 + a1 * b1`` where the BLAS
    kernel computes that (``mul_add``, :func:`_dot_is_mul_add`), else ``np.dot``."""
    if mul_add:
        return a0 * b0 + a1 * b1
    return float(np.dot(np.array([a0, a1], dtype=float), np.array([b0, b1], dtype=float)))


class ActState:
    """The road's vehicles and objects as they stand while the vehicles act: during
    ``Road.act`` nothing moves (positions, speeds, headings and lanes change in
    ``Road.step``), so each object's position, speed and heading are read once, as Python
    floats, with the cos and sin of its heading as numpy computes them (for all at once
    where numpy's array kernels give its scalar kernels' bits, ``at_once``), and each
    straight lane's coordinates of every object are computed once (:meth:`projection`).

    Args:
        others: the objects a neighbour search may return (the road's vehicles and objects
            but Landmarks), in the road's order.
        positions: (n, 2) their positions [m] (None when there are none).
        at_once: whether numpy's array kernels agree with its scalar ones
            (:func:`array_kernels_agree`).
        projects: whether a lane's coordinates may be computed by :func:`lane_dots` (a
            straight lane whose projection is highway-env's own); None: never.
    """

    def __init__(self, others: list[Any], positions: np.ndarray | None, at_once: bool,
                 projects: Any = None) -> None:
        self.others = others
        self.positions = positions
        self.index = {id(obj): k for k, obj in enumerate(others)}
        self._projects = projects
        self._projections: dict[int, tuple[Any, ...]] = {}
        self._velocities: dict[int, tuple[float, float]] = {}
        n = len(others)
        try:
            speed = np.array([obj.speed for obj in others], dtype=float)
            heading = np.array([obj.heading for obj in others], dtype=float)
        except (AttributeError, TypeError, ValueError):
            speed = heading = None
        if speed is None or speed.shape != (n,) or heading.shape != (n,) or positions is None:
            self._rows: list[tuple[float, ...]] | None = None
            return
        if at_once:
            cos, sin = np.cos(heading).tolist(), np.sin(heading).tolist()
        else:
            cos = [float(np.cos(h)) for h in heading]
            sin = [float(np.sin(h)) for h in heading]
        self._rows = [(*xy, s, h, c, si) for xy, s, h, c, si in zip(
            positions.tolist(), speed.tolist(), heading.tolist(), cos, sin, strict=True)]

    @classmethod
    def of(cls, road: Any) -> ActState:
        """The state of ``road``'s searchable objects now (scalar cos and sin)."""
        from highway_env.vehicle.objects import Landmark

        others = [v for v in road.vehicles + road.objects if not isinstance(v, Landmark)]
        positions = np.array([v.position for v in others], dtype=float) if others else None
        return cls(others, positions, at_once=False)

    def kinematics(self, obj: Any) -> tuple[float, float, float, float, float, float]:
        """x, y [m], speed [m/s], heading [rad] and its cos and sin (numpy's) of ``obj``."""
        k = self.index.get(id(obj)) if self._rows is not None else None
        if k is not None:
            return self._rows[k]
        x, y = obj.position
        return (float(x), float(y), obj.speed, obj.heading, float(np.cos(obj.heading)),
                float(np.sin(obj.heading)))

    def position(self, obj: Any) -> tuple[float, float]:
        """x, y [m] of ``obj``."""
        k = self.index.get(id(obj)) if self._rows is not None else None
        if k is not None:
            return self._rows[k][:2]
        x, y = obj.position
        return float(x), float(y)

    def velocity(self, obj: Any) -> tuple[float, float]:
        """``obj.velocity`` [m/s] as two floats: speed times the cos and sin of the heading
        where it is highway-env's (class and instance), else asked of the object."""
        if _standard_velocity(type(obj)) and "velocity" not in vars(obj):
            _, _, speed, _, cos, sin = self.kinematics(obj)
            return speed * cos, speed * sin
        vx, vy = np.asarray(obj.velocity, dtype=float)
        return float(vx), float(vy)

    def distance(self, lane: Any, obj: Any, other: Any) -> float | None:
        """``obj.lane_distance_to(other, lane)``: ``other``'s longitudinal coordinate on
        ``lane`` minus ``obj``'s, from the lane's :meth:`projection` (None where there is
        none, or either object is not one of the road's)."""
        projection = self.projection(lane)
        if projection is None:
            return None
        k, j = self.index.get(id(obj)), self.index.get(id(other))
        if k is None or j is None:
            return None
        along = projection[2]
        return along[j] - along[k]

    def projection(self, lane: Any) -> tuple[np.ndarray, np.ndarray, list[float]] | None:
        """(n,) longitudinal and (n,) lateral coordinates [m] of every object on ``lane``
        (:func:`lane_dots`: ``lane.local_coordinates`` bit for bit), and the longitudinal
        ones as a list; None for a lane whose projection is not highway-env's straight
        lane's (see ``projects``)."""
        got = self._projections.get(id(lane))
        if got is None:
            if self.positions is None or self._projects is None or not self._projects(lane):
                got = (lane, None)
            else:
                along, across = lane_dots(self.positions, lane)
                got = (lane, (along, across, along.tolist()))
            self._projections[id(lane)] = got
        return got[1]
