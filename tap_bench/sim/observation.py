"""highway-env's Kinematics observation, computed with numpy instead of pandas.

highway-env builds the Kinematics observation (``{"type": "Kinematics"}``, what the trained
agents read) through a pandas DataFrame at every decision: about 3 to 12 ms of CPU, a
tenth or more of a training step. :class:`FastKinematicObservation` returns the same array,
bit for bit (the tests compare them step by step on every scenario), from the same
vehicle records with the same arithmetic on numpy arrays. Scenario envs use it in place of
highway-env's whenever the configured observation is exactly ``Kinematics``
(:func:`use_fast_observation`).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from highway_env import utils
from highway_env.envs.common.observation import KinematicObservation

__all__ = ["FastKinematicObservation", "use_fast_observation"]


class FastKinematicObservation(KinematicObservation):
    """highway-env's :class:`KinematicObservation` without pandas: same parameters, same
    (vehicles_count, len(features)) float32 array."""

    def observe(self) -> np.ndarray:
        """The observation: one row per vehicle (the observer first, then the closest ones),
        one column per feature, normalised and clipped as highway-env does; rows of zeros
        when fewer vehicles are near."""
        if not self.env.road:
            return np.zeros(self.space().shape)
        ego = self.observer_vehicle
        records = [ego.to_dict()]
        close = self.env.road.close_objects_to(
            ego, self.env.PERCEPTION_DISTANCE, count=self.vehicles_count - 1,
            see_behind=self.see_behind, sort=self.order == "sorted",
            vehicles_only=not self.include_obstacles)
        if close:
            origin = ego if not self.absolute else None
            records += [v.to_dict(origin, observe_intentions=self.observe_intentions)
                        for v in close[-self.vehicles_count + 1:]]
        columns = {f: np.array([r.get(f, np.nan) for r in records]) for f in self.features}
        if self.normalize:
            columns = self._normalize(columns)
        obs = np.zeros((self.vehicles_count, len(self.features)))
        obs[:len(records)] = np.column_stack([columns[f] for f in self.features])
        if self.order == "shuffled":
            self.env.np_random.shuffle(obs[1:])
        return obs.astype(self.space().dtype)

    def _normalize(self, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        if not self.features_range:
            # highway-env's default ranges, set on first use as it does
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
        features of their own).
    """
    inner: Any = env.unwrapped
    if type(inner.observation_type) is not KinematicObservation:
        return False
    inner.observation_type = FastKinematicObservation(inner, **inner.config["observation"])
    return True
