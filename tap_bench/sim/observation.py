"""The Kinematics observation (``{"type": "Kinematics"}``) computed with numpy arrays.

What it observes (highway-env's documented Kinematics observation, whose parameters and
public attributes it takes over by subclassing its :class:`KinematicObservation`):

- an array of ``vehicles_count`` rows by ``len(features)`` columns; row 0 is the observer
  (the ego), then the objects within the env's ``PERCEPTION_DISTANCE`` [m] of it, nearest
  first by distance along the ego's lane (``lane_distance_to``); objects more than two ego
  lengths behind are left out unless ``see_behind`` (obstacles always); obstacles only with
  ``include_obstacles``; rows of zeros where fewer objects are near;
- features ``presence`` (1), ``x``, ``y`` [m], ``vx``, ``vy`` [m/s] (the velocity), and
  ``heading`` [rad], ``cos_h``, ``sin_h``; the other rows' ``x``, ``y``, ``vx``, ``vy``
  relative to the ego's unless ``absolute``; any other feature, and any object with a
  ``to_dict`` of its own class or that is not a vehicle, is read from its public
  ``to_dict`` (a feature one object lacks is NaN in its row, a feature none has a KeyError);
- with ``normalize``, each feature of ``features_range`` mapped linearly from its
  ``[min, max]`` to ``[-1, 1]`` (clipped to it with ``clip``); without configured ranges,
  x in +-5 maximum speeds, y in +-the road's width at the ego, vx and vy in +-2 maximum
  speeds (set on first use and kept in ``features_range``);
- ``order`` "shuffled": the rows after the ego's shuffled with the env's ``np_random``.

The positions of all objects are stacked once and their distances to the ego computed at
once; the direct features of all vehicle rows are read as arrays. Scenario envs use this
class whenever the configured observation is exactly ``Kinematics``
(:func:`use_fast_observation`); the route observation of ``tap_bench/womd-v0`` builds on it.
Equal to highway-env's own observation within 1e-9 (``tests/sim/test_sim_observation.py``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from highway_env.envs.common.observation import KinematicObservation
from highway_env.road.lane import AbstractLane
from highway_env.vehicle.kinematics import Vehicle

__all__ = ["DIRECT_FEATURES", "FastKinematicObservation", "use_fast_observation"]

DIRECT_FEATURES = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h")
"""Features read as arrays from the vehicles' public state (the others through ``to_dict``)."""

_OFFSET = ("x", "y", "vx", "vy")  # the features given relative to the ego


def _reads_state(obj: Any) -> bool:
    """Whether ``obj`` is a vehicle whose records are those of the vehicle class (no
    ``to_dict`` of its own class or instance): its features are read from its state."""
    return (isinstance(obj, Vehicle) and type(obj).to_dict is Vehicle.to_dict
            and "to_dict" not in vars(obj))


def _state_columns(objects: list[Any]) -> dict[str, np.ndarray]:
    """The direct features of ``objects`` (vehicles), one array of ``len(objects)`` each."""
    position = np.array([o.position for o in objects], dtype=float).reshape(-1, 2)
    velocity = np.array([o.velocity for o in objects], dtype=float).reshape(-1, 2)
    heading = np.array([o.heading for o in objects], dtype=float)
    return {"presence": np.ones(len(objects)), "x": position[:, 0], "y": position[:, 1],
            "vx": velocity[:, 0], "vy": velocity[:, 1], "heading": heading,
            "cos_h": np.cos(heading), "sin_h": np.sin(heading)}


class FastKinematicObservation(KinematicObservation):
    """The Kinematics observation as numpy arrays: highway-env's parameters, a
    (vehicles_count, len(features)) float32 array (see the module docstring).

    Exactly ``vehicles_count`` rows, so it lies in its space: with ``vehicles_count`` 1 the
    ego's row alone, with 0 no row.

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
        """The (vehicles_count, len(features)) float32 observation (module docstring)."""
        features = list(self.features)
        out = np.zeros((self.vehicles_count, len(features)))
        if not self.env.road or self.vehicles_count == 0:
            return out.astype(self._dtype())
        ego = self.observer_vehicle
        others = self.nearby_objects(ego)
        table = self._table(ego, others, features)
        if self.normalize:
            self._normalise(table, features)
        out[:table.shape[0]] = table
        if self.order == "shuffled":
            self.env.np_random.shuffle(out[1:])
        return out.astype(self._dtype())

    def _dtype(self) -> Any:
        """The observation's dtype: float32, or that of a subclass's own ``space``."""
        if type(self).space is KinematicObservation.space:
            return np.float32
        return self.space().dtype

    def nearby_objects(self, ego: Any) -> list[Any]:
        """The objects observed after ``ego``, nearest first along its lane: at most
        ``vehicles_count - 1`` within the perception distance [m] (see the module docstring)."""
        wanted = self.vehicles_count - 1
        if wanted <= 0:
            return []
        road = self.env.road
        vehicles = [v for v in road.vehicles if v is not ego]
        obstacles = list(road.objects) if self.include_obstacles else []
        candidates = vehicles + obstacles
        if not candidates:
            return []
        positions = np.array([c.position for c in candidates], dtype=float)
        delta = positions - ego.position
        within = np.sqrt(np.einsum("ij,ij->i", delta, delta)) < self.env.PERCEPTION_DISTANCE
        near = np.flatnonzero(within)
        lane = ego.lane
        project = getattr(lane, "project", None)  # a lane that projects many points at once
        if project is not None and len(near):
            # ego.lane_distance_to for every one at once: the same arithmetic per point
            lon, _ = project(positions[near, 0], positions[near, 1])
            distances = (lon - lane.local_coordinates(ego.position)[0]).tolist()
        else:
            distances = [ego.lane_distance_to(candidates[k]) for k in near.tolist()]
        kept, along = [], []
        behind = -2 * ego.LENGTH
        for k, d in zip(near.tolist(), distances, strict=True):
            obj = candidates[k]
            if (k < len(vehicles) and self.see_behind) or d > behind:
                kept.append(obj)
                along.append(abs(d))
        if self.order == "sorted":
            kept = [kept[k] for k in np.argsort(np.array(along), kind="stable")]
        return kept[:wanted]

    def _table(self, ego: Any, others: list[Any], features: list[str]) -> np.ndarray:
        """The rows of ``ego`` and ``others`` before normalisation, one column per feature."""
        rows = [ego, *others]
        table = np.full((len(rows), len(features)), np.nan)
        direct = set(features) <= set(DIRECT_FEATURES)
        by_state = [k for k, o in enumerate(rows) if direct and _reads_state(o)]
        if by_state:
            columns = _state_columns([rows[k] for k in by_state])
            table[by_state] = np.column_stack([columns[f] for f in features])
        found = set(features) if by_state else set()
        for k in sorted(set(range(len(rows))) - set(by_state)):
            if k == 0:
                record = ego.to_dict()
            else:
                record = rows[k].to_dict(None if self.absolute else ego,
                                         observe_intentions=self.observe_intentions)
            found |= record.keys()
            table[k] = [record.get(f, np.nan) for f in features]
        missing = [f for f in features if f not in found]
        if missing:
            raise KeyError(f"Kinematics observation: no observed object has the feature(s) "
                           f"{missing}")
        others_by_state = [k for k in by_state if k > 0]
        if not self.absolute and others_by_state:  # relative to the ego's own record
            offset = [j for j, f in enumerate(features) if f in _OFFSET]
            table[np.ix_(others_by_state, offset)] -= table[0, offset]
        return table

    def _normalise(self, table: np.ndarray, features: list[str]) -> None:
        """Map each ranged feature's column from ``[min, max]`` to [-1, 1] (clipped with
        ``clip``), in place; sets the default ranges on first use."""
        if not self.features_range:
            lanes = self.env.road.network.all_side_lanes(self.observer_vehicle.lane_index)
            width = AbstractLane.DEFAULT_WIDTH * len(lanes)
            self.features_range = {"x": [-5.0 * Vehicle.MAX_SPEED, 5.0 * Vehicle.MAX_SPEED],
                                   "y": [-width, width],
                                   "vx": [-2.0 * Vehicle.MAX_SPEED, 2.0 * Vehicle.MAX_SPEED],
                                   "vy": [-2.0 * Vehicle.MAX_SPEED, 2.0 * Vehicle.MAX_SPEED]}
        for j, f in enumerate(features):
            if f in self.features_range:
                low, high = self.features_range[f]
                table[:, j] = 2.0 * (table[:, j] - low) / (high - low) - 1.0
                if self.clip:
                    np.clip(table[:, j], -1.0, 1.0, out=table[:, j])


def use_fast_observation(env: gym.Env) -> bool:
    """Replace highway-env's Kinematics observation of ``env`` (after a reset: highway-env
    builds a new one at each reset) by :class:`FastKinematicObservation`.

    Returns:
        whether it was replaced: only an observation of exactly highway-env's
        :class:`KinematicObservation` class is (subclasses such as ``ExitObservation`` add
        features of their own).
    """
    inner: Any = env.unwrapped
    if type(inner.observation_type) is not KinematicObservation:
        return False
    inner.observation_type = FastKinematicObservation(inner, **inner.config["observation"])
    return True
