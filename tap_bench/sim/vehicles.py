"""Vehicle settings of the scenarios: lane-change dynamics and process-wide state.

highway-env steers every vehicle with a cascade of two proportional controllers: lateral
offset to lateral speed (time constant ``TAU_LATERAL``) and heading to yaw rate
(``TAU_HEADING``). Its defaults change lane in about 1 s with yaw-rate peaks above 1 rad/s,
far faster than people do; TAP then sees the short left turn of a left lane change as noise
and keeps only the longer counter-steer: a Right Turn. The ``realistic`` setting slows both
loops and feeds the lane's curvature forward; ``docs/simulation.md`` gives the yaw-rate peaks
each setting produces. Settings are applied per vehicle (instance
attributes), never by changing highway-env's classes, which all environments of a process
share.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

from highway_env.vehicle.behavior import IDMVehicle

from tap_bench.errors import ParameterError, TapBenchError

__all__ = [
    "LANE_CHANGE_SETTINGS",
    "IntersectionIDMVehicle",
    "LaneChange",
    "apply_lane_change",
    "guard_class_attributes",
]


@dataclass(frozen=True)
class LaneChange:
    """Time constants of highway-env's lateral controller.

    Attributes:
        tau_lateral: lateral offset to lateral speed time constant [s].
        tau_heading: heading to yaw rate time constant [s].
        tau_pursuit: look-ahead of the lane heading fed forward [s]. Equal to
            ``tau_heading`` it cancels the heading lag on curves, so a slow heading loop
            still follows roundabouts and turns; highway-env uses half of it.
    """

    tau_lateral: float
    tau_heading: float
    tau_pursuit: float

    def __post_init__(self) -> None:
        for name in ("tau_lateral", "tau_heading", "tau_pursuit"):
            if not getattr(self, name) > 0:
                raise ParameterError(f"LaneChange.{name}", getattr(self, name), "",
                    message=f"LaneChange.{name} must be a positive time [s], got "
                            f"{getattr(self, name)!r}.")


LANE_CHANGE_SETTINGS: dict[str, LaneChange] = {
    # highway-env's own ControlledVehicle constants: a 4 m lane change in about 1 s.
    "default": LaneChange(tau_lateral=0.6, tau_heading=0.2, tau_pursuit=0.1),
    # 10 % to 90 % of a 4 m lane change in 1.6 s (highway-env: 1.0 s), yaw-rate peaks
    # near 0.16 rad/s at 25 m/s (highway-env: 1.35 rad/s).
    "realistic": LaneChange(tau_lateral=1.0, tau_heading=1.0, tau_pursuit=1.0),
}
"""The lane-change settings a scenario can name."""


def apply_lane_change(vehicle: object, setting: LaneChange) -> None:
    """Give one vehicle the controller gains of ``setting`` (instance attributes).

    Vehicles without highway-env's lateral controller (obstacles, plain kinematic
    vehicles) are left alone.
    """
    if not hasattr(vehicle, "KP_LATERAL"):
        return
    vehicle.KP_LATERAL = 1.0 / setting.tau_lateral
    vehicle.KP_HEADING = 1.0 / setting.tau_heading
    vehicle.TAU_PURSUIT = setting.tau_pursuit


class IntersectionIDMVehicle(IDMVehicle):
    """The IDM/MOBIL vehicle of the intersection scenario.

    highway-env's intersection sets ``DISTANCE_WANTED``, ``COMFORT_ACC_MAX`` and
    ``COMFORT_ACC_MIN`` on the class of its other vehicles each time it builds a scene; on
    :class:`IDMVehicle` itself that would change every later highway, merge or roundabout
    of the process. The intersection scenario names this subclass instead, which already
    holds those values.
    """

    DISTANCE_WANTED = 7.0  # [m] jam distance at the intersection
    COMFORT_ACC_MAX = 6.0  # [m/s2]
    COMFORT_ACC_MIN = -3.0  # [m/s2]


def _watched_classes() -> tuple[type, ...]:
    from highway_env.vehicle import behavior, controller, kinematics

    return (kinematics.Vehicle, controller.ControlledVehicle, controller.MDPVehicle,
            behavior.IDMVehicle, behavior.LinearVehicle, behavior.AggressiveVehicle,
            behavior.DefensiveVehicle)


def _snapshot(classes: tuple[type, ...]) -> dict[type, dict[str, object]]:
    return {cls: {k: v for k, v in vars(cls).items() if k.isupper()} for cls in classes}


@contextlib.contextmanager
def guard_class_attributes(what: str) -> Iterator[None]:
    """Fail loudly when the code in the block changes highway-env's vehicle classes.

    The constants of highway-env's vehicle classes are shared by every environment of the
    process. When the block changes one, it is restored and a :class:`TapBenchError` names
    the class, the attributes and the fix.
    """
    classes = _watched_classes()
    before = _snapshot(classes)
    failed = False
    try:
        yield
    except BaseException:
        failed = True
        raise
    finally:
        after = _snapshot(classes)
        changed = []
        for cls in classes:
            if after[cls] == before[cls]:
                continue
            for key in set(before[cls]) | set(after[cls]):
                if before[cls].get(key, "<unset>") != after[cls].get(key, "<unset>"):
                    changed.append(f"{cls.__name__}.{key}")
                if key in before[cls]:
                    setattr(cls, key, before[cls][key])
                else:
                    delattr(cls, key)
        if changed and not failed:
            raise TapBenchError(
                f"{what} changed highway-env class attributes {', '.join(sorted(changed))}, "
                "which every environment of the process shares; they were restored. Use a "
                "subclass as other_vehicles_type, e.g. "
                "tap_bench.sim.vehicles.IntersectionIDMVehicle for an intersection.")
