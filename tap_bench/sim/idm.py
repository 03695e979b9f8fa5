"""IDM/MOBIL driving the ego vehicle.

The policy hands the ego to highway-env's :class:`~highway_env.vehicle.behavior.IDMVehicle`
(Intelligent Driver Model for the speed, MOBIL for lane changes) at the start of each
episode: the new ego has the same position, heading, speed, route and controller gains, so
the initial traffic is the one every other policy sees on that seed. The parameters are set
on that one vehicle, never on the class. The actions the policy returns are ignored by an
IDM vehicle (it decides itself); the env still needs one per decision.

Parameter sets live in ``policies/idm*.json`` and are documented in ``docs/simulation.md``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from tap_bench.errors import ParameterError, did_you_mean
from tap_bench.sim.policies import idle_action

if TYPE_CHECKING:
    import gymnasium as gym

__all__ = ["IDMParameters", "IDMPolicy", "take_over_ego"]


@dataclass(frozen=True)
class IDMParameters:
    """IDM and MOBIL parameters of the ego (highway-env's names in lower case).

    Defaults are highway-env's :class:`IDMVehicle` constants.

    Attributes:
        time_wanted: desired time gap to the leader [s].
        distance_wanted: jam distance to the leader, front to front [m].
        comfort_acc_max: desired maximum acceleration [m/s^2].
        comfort_acc_min: desired maximum deceleration [m/s^2], negative.
        delta: exponent of the free-road term [-].
        politeness: MOBIL weight of the other vehicles' gains, in [0, 1].
        lane_change_min_acc_gain: MOBIL incentive threshold [m/s^2].
        lane_change_max_braking_imposed: MOBIL safety limit on the new follower [m/s^2].
        lane_change_delay: time between lane-change decisions [s].
        target_speed_factor: desired speed as a multiple of the ego's initial target speed
            (the lane's speed limit still caps it) [-].
    """

    time_wanted: float = 1.5
    distance_wanted: float = 10.0
    comfort_acc_max: float = 3.0
    comfort_acc_min: float = -5.0
    delta: float = 4.0
    politeness: float = 0.0
    lane_change_min_acc_gain: float = 0.2
    lane_change_max_braking_imposed: float = 2.0
    lane_change_delay: float = 1.0
    target_speed_factor: float = 1.0

    def __post_init__(self) -> None:
        positive = ("time_wanted", "distance_wanted", "comfort_acc_max", "delta",
                    "lane_change_max_braking_imposed", "lane_change_delay",
                    "target_speed_factor")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ParameterError(name, getattr(self, name), "",
                    message=f"IDM parameter {name} must be positive, got "
                            f"{getattr(self, name)!r}.")
        if not self.comfort_acc_min < 0:
            raise ParameterError("comfort_acc_min", self.comfort_acc_min, "",
                message=f"IDM parameter comfort_acc_min is a deceleration and must be "
                        f"negative, got {self.comfort_acc_min!r}.")
        if not 0 <= self.politeness <= 1:
            raise ParameterError("politeness", self.politeness, "",
                message=f"IDM parameter politeness must lie in [0, 1], got "
                        f"{self.politeness!r}.")
        if self.lane_change_min_acc_gain < 0:
            raise ParameterError("lane_change_min_acc_gain", self.lane_change_min_acc_gain, "",
                message="IDM parameter lane_change_min_acc_gain must be >= 0, got "
                        f"{self.lane_change_min_acc_gain!r}.")

    def constants(self) -> dict[str, float]:
        """The highway-env attribute names and values (``TIME_WANTED`` ...)."""
        return {f.name.upper(): getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name != "target_speed_factor"}


def take_over_ego(env: gym.Env, params: IDMParameters) -> Any:
    """Replace the ego of a just-reset highway-env env by an IDM/MOBIL vehicle in the same
    state; return the new ego."""
    from highway_env.vehicle.behavior import IDMVehicle

    inner = env.unwrapped
    old = inner.vehicle
    # an env may drive its own IDM (tap_bench/womd-v0: routes, signals, map neighbours)
    new = getattr(inner, "idm_vehicle_class", IDMVehicle).create_from(old)
    # Per-vehicle settings of the scenario (lane-change gains) carry over.
    for key, value in vars(old).items():
        if key.isupper():
            setattr(new, key, value)
    for key, value in params.constants().items():
        setattr(new, key, value)
    new.target_speed = old.target_speed * params.target_speed_factor
    new.LENGTH, new.WIDTH = old.LENGTH, old.WIDTH
    new.diagonal = old.diagonal
    vehicles = inner.road.vehicles
    vehicles[vehicles.index(old)] = new
    inner.controlled_vehicles[inner.controlled_vehicles.index(old)] = new
    return new


class IDMPolicy:
    """IDM/MOBIL drives the ego (see the module docstring).

    Args:
        name: the policy's name.
        **params: :class:`IDMParameters` fields.
    """

    observation = None

    def __init__(self, name: str = "idm", **params: float) -> None:
        fields = {f.name for f in dataclasses.fields(IDMParameters)}
        unknown = sorted(set(params) - fields)
        if unknown:
            raise did_you_mean("IDM parameter", unknown[0], fields)
        self.name = name
        self.params = IDMParameters(**params)
        self._action: Any = None

    def reset(self, env: gym.Env, *, seed: int) -> None:
        take_over_ego(env, self.params)
        self._action = idle_action(env)

    def act(self, observation: Any) -> Any:
        if self._action is None:
            raise RuntimeError("IDMPolicy.act before reset: call reset(env, seed=...) first.")
        return self._action
