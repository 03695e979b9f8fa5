"""highway-env's Kinematics observation, computed with numpy instead of pandas.

highway-env builds the Kinematics observation (``{"type": "Kinematics"}``, what the trained
agents read) through a pandas DataFrame at every decision: about 2.5 ms of CPU, more than
half a fast training step's simulation. :class:`FastKinematicObservation` returns the same
array, bit for bit, in about 0.1 ms:

- the nearby objects are highway-env's ``Road.close_objects_to`` (same filter, order and
  count), with each object's distance along the ego's lane computed once instead of twice
  (filter and sort key) and the distances to the ego computed for all objects at once
  (numpy); an object within :data:`DISTANCE_MARGIN` of the perception distance is
  re-checked with highway-env's own ``np.linalg.norm``;
- the features of highway-env's vehicles (``presence``, ``x``, ``y``, ``vx``, ``vy``,
  ``heading``, ``cos_h``, ``sin_h``: those of every tap-bench scenario) are read with the
  operations of ``Vehicle.to_dict`` (``speed * cos(heading)`` ...), without the dictionary
  of every feature ``to_dict`` builds (lane offsets and destination included); any other
  feature, and any object whose class or instance has its own ``to_dict``, ``velocity`` or
  ``direction``, goes through its ``to_dict`` as highway-env does;
- normalisation and clipping are highway-env's ``lmap`` and ``np.clip`` on the same
  columns (numpy arrays rather than pandas Series: the same element-wise float
  operations), and absent vehicles are rows of zeros.

This repeats highway-env 1.12's code; it is used only where the installed highway-env's
source of the methods it repeats has the sha256 recorded in :data:`_OBSERVE_CODE` (checked
once per process): elsewhere :class:`FastKinematicObservation` observes by highway-env's own
``KinematicObservation.observe``. Scenario envs use it in place of highway-env's whenever the
configured observation is exactly ``Kinematics`` (:func:`use_fast_observation`); the
route observation of ``tap_bench/womd-v0`` builds on it. Tested against highway-env's own
observation on drawn scenes and on every scenario, with mutations of each formula caught
(``tests/sim/test_sim_observation.py``).

Parts of this module re-state highway-env's code (MIT License, Copyright (c) 2018 Edouard
Leurent, (c) 2023 Farama Foundation): see THIRD_PARTY_NOTICES.md.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
from typing import Any

import gymnasium as gym
import numpy as np
from highway_env import utils
from highway_env.envs.common.observation import KinematicObservation
from highway_env.road.road import Road
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

__all__ = ["DISTANCE_MARGIN", "FastKinematicObservation", "use_fast_observation"]


def sources_match(functions: Any, digests: dict[str, str]) -> bool:
    """Whether each function's source, by qualified name, hashes (first 16 hex digits of
    its SHA-256) to ``digests[name]``; False where a source cannot be read."""
    try:
        sources = {f.__qualname__: inspect.getsource(f) for f in functions}
    except (OSError, TypeError):
        return False
    return all(hashlib.sha256(sources.get(name, "").encode()).hexdigest()[:16] == digest
               for name, digest in digests.items())

DISTANCE_MARGIN = 1e-6
"""Objects whose numpy distance to the ego is within this [m] of the perception distance
are measured again with highway-env's ``np.linalg.norm`` (the two may differ in the last
bit)."""

DIRECT_FEATURES = frozenset({"presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h"})
"""Features read directly from a highway-env vehicle (the others through ``to_dict``)."""

_RELATIVE = ("x", "y", "vx", "vy")  # the features to_dict gives relative to an origin

_HIGHWAY_ENV_OBSERVE = (KinematicObservation.observe, KinematicObservation.normalize_obs,
                        Vehicle.to_dict, Vehicle.velocity.fget, RoadObject.velocity.fget,
                        RoadObject.direction.fget, RoadObject.lane_distance_to,
                        Road.close_objects_to, utils.lmap)
"""highway-env's own code that this module repeats, as imported."""

_OBSERVE_CODE = {  # sha256 of the source of each, highway-env 1.12
    "KinematicObservation.observe": "bc4a7a71c6c3a8ee",
    "KinematicObservation.normalize_obs": "81370e6f2cc10bb0",
    "Vehicle.to_dict": "9196357e8d9ad247",
    "Vehicle.velocity": "8306b4e7bb130034",
    "RoadObject.velocity": "4adf0dc72944ece9",
    "RoadObject.direction": "a4c77726611faa88",
    "RoadObject.lane_distance_to": "4db4f2b77cf0bdbe",
    "Road.close_objects_to": "47179eca9acfb7e7",
    "lmap": "ed6e74b005122a31",
}


@functools.cache
def _highway_env_observes_as_written() -> bool:
    """Whether the installed highway-env's Kinematics observation (and what it calls) is the
    code this module repeats (that of highway-env 1.12); checked once per process."""
    return sources_match(_HIGHWAY_ENV_OBSERVE, _OBSERVE_CODE)


@functools.cache
def _direct_class(cls: type) -> bool:
    """Whether objects of ``cls`` have highway-env's ``Vehicle.to_dict``, ``velocity`` and
    ``direction``: their direct features are read without ``to_dict``."""
    return (issubclass(cls, Vehicle) and cls.to_dict is Vehicle.to_dict
            and cls.velocity in (Vehicle.velocity, RoadObject.velocity)
            and cls.direction is RoadObject.direction)


_OWN = frozenset({"to_dict", "velocity", "direction"})


def _direct(obj: Any) -> bool:
    """Whether ``obj``'s direct features may be read without its ``to_dict``."""
    return _direct_class(type(obj)) and not _OWN & vars(obj).keys()


def _values(vehicle: Any, features: list[str]) -> dict[str, Any]:
    """The direct ``features`` of ``vehicle``, as ``Vehicle.to_dict`` computes them (``vx``
    is ``velocity[0]``: ``speed * [cos(heading), sin(heading)]``, element 0)."""
    heading = vehicle.heading
    out: dict[str, Any] = {}
    for feature in features:
        if feature == "presence":
            out[feature] = 1
        elif feature == "x":
            out[feature] = vehicle.position[0]
        elif feature == "y":
            out[feature] = vehicle.position[1]
        elif feature == "vx":
            out[feature] = vehicle.speed * np.cos(heading)
        elif feature == "vy":
            out[feature] = vehicle.speed * np.sin(heading)
        elif feature == "heading":
            out[feature] = heading
        elif feature == "cos_h":
            out[feature] = np.cos(heading)
        else:  # "sin_h"
            out[feature] = np.sin(heading)
    return out


class FastKinematicObservation(KinematicObservation):
    """highway-env's :class:`KinematicObservation` without pandas: same parameters, same
    (vehicles_count, len(features)) float32 array (see the module docstring).

    The observation always has ``vehicles_count`` rows, so it lies in the space: with
    ``vehicles_count`` 1 the ego's row alone and with 0 no row, where highway-env's own
    returns the ego and every other vehicle near (a (9, 5) array in a (1, 5) space).

    Raises:
        ValueError: ``vehicles_count`` is not an integer >= 0.
    """

    def __init__(self, env: Any, *args: Any, **kwargs: Any) -> None:
        super().__init__(env, *args, **kwargs)
        count = self.vehicles_count
        if isinstance(count, bool) or not isinstance(count, int | np.integer) or count < 0:
            raise ValueError(f"Kinematics observation: vehicles_count {count!r} must be an "
                             "integer >= 0 (the rows observed: the ego, then the nearest "
                             "vehicles).")

    def observe(self) -> np.ndarray:
        """The observation: one row per vehicle (the observer first, then the closest ones),
        one column per feature, normalised and clipped as highway-env does; rows of zeros
        when fewer vehicles are near. ``vehicles_count`` rows (see the class docstring)."""
        return self._observe()[:self.vehicles_count]

    def _observe(self) -> np.ndarray:
        if not self.env.road:
            return np.zeros((self.vehicles_count, len(self.features)), self._dtype())
        if not _highway_env_observes_as_written():
            return KinematicObservation.observe(self)
        ego = self.observer_vehicle
        close = self._close_objects(ego) if self.vehicles_count > 1 else []
        features = list(self.features)
        if close:
            close = close[-self.vehicles_count + 1:]
        if DIRECT_FEATURES.issuperset(features) and _direct(ego) \
                and all(_direct(v) for v in close):
            rows = self._direct_rows(ego, close, features)
        else:
            rows = self._dict_rows(ego, close)
        if not all(any(f in row for row in rows) for f in features):
            return KinematicObservation.observe(self)  # a feature no record has: its error
        # the columns of highway-env's data frame: NaN where a record lacks the feature
        columns = {f: np.array([row.get(f, np.nan) for row in rows]) for f in features}
        if self.normalize:
            columns = self._normalize(columns)
        obs = np.zeros((max(self.vehicles_count, len(rows)), len(features)))
        obs[:len(rows)] = np.column_stack([columns[f] for f in features])
        if self.order == "shuffled":
            self.env.np_random.shuffle(obs[1:])
        return obs.astype(self._dtype())

    def _dtype(self) -> Any:
        if type(self).space is KinematicObservation.space:
            return np.float32
        return self.space().dtype

    def _dict_rows(self, ego: Any, close: list[Any]) -> list[dict[str, Any]]:
        """highway-env's records: ``to_dict`` of the observer, then of each object."""
        rows = [ego.to_dict()]
        origin = ego if not self.absolute else None
        rows += [v.to_dict(origin, observe_intentions=self.observe_intentions)
                 for v in close]
        return rows

    def _direct_rows(self, ego: Any, close: list[Any], features: list[str]
                     ) -> list[dict[str, Any]]:
        """The records of :meth:`_dict_rows`, restricted to ``features`` (all direct, all
        objects highway-env vehicles): ``to_dict``'s values without ``to_dict``."""
        own = _values(ego, features)
        rows = [own]
        if not close:
            return rows
        if self.absolute:
            return rows + [_values(v, features) for v in close]
        origin = _values(ego, [f for f in _RELATIVE if f in features])
        for v in close:
            row = _values(v, features)
            for key, value in origin.items():
                row[key] -= value
            rows.append(row)
        return rows

    def _close_objects(self, ego: Any) -> list[Any]:
        """``road.close_objects_to(ego, ...)`` with this observation's settings: highway-env's
        filter, sort and count, each object's ``lane_distance_to`` computed once, the
        distances to the ego at once (re-measured by ``np.linalg.norm`` near the limit)."""
        road = self.env.road
        count, see_behind = self.vehicles_count - 1, self.see_behind
        sort, vehicles_only = self.order == "sorted", not self.include_obstacles
        distance = self.env.PERCEPTION_DISTANCE
        if type(road).close_objects_to is not Road.close_objects_to \
                or "close_objects_to" in vars(road) \
                or type(ego).lane_distance_to is not RoadObject.lane_distance_to \
                or "lane_distance_to" in vars(ego):
            return road.close_objects_to(ego, distance, count=count, see_behind=see_behind,
                                         sort=sort, vehicles_only=vehicles_only)
        along: dict[int, Any] = {}

        def lane_distance(obj: Any) -> Any:
            key = id(obj)
            if key not in along:
                along[key] = ego.lane_distance_to(obj)
            return along[key]

        near_vehicles = self._near(road.vehicles, ego.position, distance)
        vehicles = [v for v, near in zip(road.vehicles, near_vehicles, strict=True)
                    if near and v is not ego
                    and (see_behind or -2 * ego.LENGTH < lane_distance(v))]
        near_objects = self._near(road.objects, ego.position, distance)
        obstacles = [o for o, near in zip(road.objects, near_objects, strict=True)
                     if near and -2 * ego.LENGTH < lane_distance(o)]
        objects = vehicles if vehicles_only else vehicles + obstacles
        if sort:
            objects = sorted(objects, key=lambda o: abs(lane_distance(o)))
        if count:
            objects = objects[:count]
        return objects

    @staticmethod
    def _near(objects: list[Any], position: np.ndarray, distance: float) -> list[bool]:
        """``np.linalg.norm(o.position - position) < distance`` of each object."""
        if not objects:
            return []
        delta = np.array([o.position for o in objects], dtype=float) - position
        estimate = np.sqrt(delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1])
        near = (estimate < distance).tolist()
        for k in np.flatnonzero(~(np.abs(estimate - distance) > DISTANCE_MARGIN)).tolist():
            near[k] = bool(np.linalg.norm(objects[k].position - position) < distance)
        return near

    def _normalize(self, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """highway-env's ``normalize_obs`` on the columns (its default ranges set on first
        use, as it does)."""
        if not self.features_range:
            self.normalize_obs({})
        for feature, f_range in self.features_range.items():
            if feature in columns:
                columns[feature] = utils.lmap(columns[feature], [f_range[0], f_range[1]],
                                              [-1, 1])
                if self.clip:
                    columns[feature] = np.clip(columns[feature], -1, 1)
        return columns


def use_fast_observation(env: gym.Env) -> bool:
    """Replace highway-env's Kinematics observation of ``env`` (after a reset: highway-env
    builds a new one at each reset) by :class:`FastKinematicObservation`.

    Returns:
        whether it was replaced: only an observation of exactly highway-env's
        :class:`KinematicObservation` class is (subclasses such as ``ExitObservation`` add
        features of their own). Where the installed highway-env's code is not the one
        repeated (:data:`_OBSERVE_CODE`), the replacement observes by highway-env's own code,
        kept to ``vehicles_count`` rows.
    """
    inner: Any = env.unwrapped
    if type(inner.observation_type) is not KinematicObservation:
        return False
    inner.observation_type = FastKinematicObservation(inner, **inner.config["observation"])
    return True
