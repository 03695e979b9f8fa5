"""Scripted events of a scenario: a vehicle that cuts in front of the ego, a leader that brakes.

A scenario file may hold one ``script`` (docs/interactions.md)::

    "script": {"kind": "cut_in", "at": 5.0, "gap": 20.0, "speed_offset": -3.0}
    "script": {"kind": "lead_braking", "at": 5.0, "gap": 30.0, "deceleration": 5.0,
               "duration": 2.0}

At reset a scripted vehicle is placed ``gap`` metres (centre to centre) ahead of the ego:
in the next lane for a cut-in, in the ego's lane for lead braking, driving ``speed_offset``
faster than the ego (negative: slower) without changing lanes by itself. ``at`` seconds
after reset the cut-in vehicle steers into the lane the ego is then in (highway-env's lane
controller, with the scenario's lane-change setting), or earlier when a faster ego has
closed in to :data:`CLOSE_CUT_IN_GAP`, and only while it is at least :data:`MIN_CUT_IN_GAP`
ahead of the ego (centre to centre: never into its side; an ego that has passed it meets no
cut-in); the braking leader decelerates at
``deceleration`` for ``duration`` and then drives on by IDM. Other vehicles in every lane
from 20 m behind the ego to ``clear`` metres ahead are removed at reset, so the event
happens as scripted whatever the seed's traffic. The seed still sets the rest of the
traffic, the ego's lane and its starting point.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from tap_bench.errors import FileFormatError, did_you_mean

__all__ = ["SCRIPT_KINDS", "Script", "ScriptedVehicle"]  # noqa: F822 (ScriptedVehicle: __getattr__)

SCRIPT_KINDS = ("cut_in", "lead_braking")
_FIELDS = ("kind", "at", "gap", "speed_offset", "deceleration", "duration", "clear", "blocker",
           "vary")
VARIABLE = ("at", "gap", "speed_offset", "deceleration", "duration")
"""The fields ``vary`` may draw per episode."""
CLEAR_BEHIND = 20.0  # [m] vehicles this far behind the ego are removed too
MIN_CUT_IN_GAP = 10.0  # [m] a cut-in waits until the vehicle is this far ahead of the ego
CLOSE_CUT_IN_GAP = 15.0  # [m] an ego closing in to this gap is cut in on before ``at``


@dataclass(frozen=True)
class Script:
    """One scripted event (see the module docstring).

    Attributes:
        kind: ``"cut_in"`` or ``"lead_braking"``.
        at: [s] after reset, when the event starts.
        gap: [m] centre gap ahead of the ego at reset.
        speed_offset: [m/s] the scripted vehicle's speed less the ego's, at reset.
        deceleration: [m/s^2] lead_braking: how hard the leader brakes (> 0).
        duration: [s] lead_braking: how long it brakes.
        clear: [m] other vehicles up to this far ahead (in every lane) are removed.
        blocker: cut_in: also put a vehicle beside the ego in the cutter's lane, at the ego's
            speed and never changing lanes, so that the ego cannot dodge the cut-in by
            moving into that lane (MOBIL's safety rule forbids it; an ego that swerves away
            never has the cutter on its path, and meets no cut-in).
        vary: field -> (low, high): drawn uniformly per episode (fields of
            :data:`VARIABLE`); the fixed value is used when a field is not named.
    """

    kind: str
    at: float
    gap: float
    speed_offset: float = 0.0
    deceleration: float = 5.0
    duration: float = 2.0
    clear: float = 80.0
    blocker: bool = False
    vary: Mapping[str, tuple[float, float]] | None = None

    def __post_init__(self) -> None:
        if self.kind not in SCRIPT_KINDS:
            raise did_you_mean("script kind", self.kind, SCRIPT_KINDS)
        if self.vary is not None:
            if not isinstance(self.vary, Mapping):
                raise FileFormatError(f"script vary must be an object field -> [low, high], "
                                      f"got {self.vary!r}.")
            ranges = {}
            for key, bounds in self.vary.items():
                if key not in VARIABLE:
                    raise FileFormatError(f"script vary: "
                                          f"{did_you_mean('variable field', key, VARIABLE)}")
                if (not isinstance(bounds, list | tuple) or len(bounds) != 2
                        or not all(isinstance(b, int | float) and not isinstance(b, bool)
                                   and np.isfinite(b) for b in bounds)
                        or bounds[0] > bounds[1]):
                    raise FileFormatError(f"script vary {key!r} must be [low, high] with "
                                          f"low <= high, got {bounds!r}.")
                ranges[key] = (float(bounds[0]), float(bounds[1]))
                # every value of the range must pass the checks below: check both ends
                for end in ranges[key]:
                    Script(**{**asdict(self), "vary": None, key: end})
            object.__setattr__(self, "vary", ranges or None)
        for name in ("at", "gap", "deceleration", "duration", "clear"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, int | float)
                    or not np.isfinite(value) or value <= 0):
                raise FileFormatError(f"script {name} must be a number > 0, got {value!r}.")
        if isinstance(self.speed_offset, bool) or not isinstance(self.speed_offset,
                                                                 int | float):
            raise FileFormatError(f"script speed_offset must be a number [m/s], got "
                                  f"{self.speed_offset!r}.")
        if not isinstance(self.blocker, bool):
            raise FileFormatError(f"script blocker must be true or false, got {self.blocker!r}.")
        if self.blocker and self.kind != "cut_in":
            raise FileFormatError("script blocker belongs to a cut_in script.")
        if self.clear < self.gap:
            raise FileFormatError(f"script clear ({self.clear} m) must reach the scripted "
                                  f"vehicle ({self.gap} m ahead).")

    @classmethod
    def from_dict(cls, doc: Any, *, source: str = "script") -> Script:
        """A script from its JSON object, every field checked."""
        if not isinstance(doc, Mapping):
            raise FileFormatError(f"{source}: script must be an object, e.g. {{\"kind\": "
                                  "\"cut_in\", \"at\": 5, \"gap\": 20}.")
        for key in doc:
            if key not in _FIELDS:
                raise FileFormatError(f"{source}: {did_you_mean('script field', key, _FIELDS)}")
        for key in ("kind", "at", "gap"):
            if key not in doc:
                raise FileFormatError(f"{source}: script needs {key!r}.")
        try:
            return cls(**dict(doc))
        except (FileFormatError, KeyError) as err:
            raise FileFormatError(f"{source}: {err}") from err

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        if self.vary is None:
            del out["vary"]
        else:
            out["vary"] = {k: list(v) for k, v in self.vary.items()}
        return out

    def drawn(self, rng: np.random.Generator) -> Script:
        """The script of one episode: every ``vary`` field drawn from ``rng`` (in
        :data:`VARIABLE` order), the others as they are."""
        if not self.vary:
            return self
        values = {k: float(rng.uniform(*self.vary[k])) for k in VARIABLE if k in self.vary}
        return Script(**{**asdict(self), "vary": None, **values})

    def install(self, env: Any) -> Any:
        """Place the scripted vehicle in a freshly reset highway-env env (``env.unwrapped``)
        and clear the lanes involved. Returns the vehicle (a :class:`ScriptedVehicle`).

        Raises:
            FileFormatError: a cut-in on a road where the ego's lane has no neighbour.
        """
        if self.vary:
            return self.drawn(env.np_random).install(env)
        road, ego = env.road, env.vehicle
        network = road.network
        ego_lane = network.get_lane(ego.lane_index)
        s_ego, _ = ego_lane.local_coordinates(ego.position)
        if self.kind == "cut_in":
            sides = network.side_lanes(ego.lane_index)
            if not sides:
                raise FileFormatError(f"script cut_in: the ego's lane {ego.lane_index} has no "
                                      "neighbouring lane to cut in from.")
            lane_index = sorted(sides, key=lambda index: index[2])[0]
        else:
            lane_index = ego.lane_index
        for vehicle in list(road.vehicles):
            if vehicle is ego:
                continue
            s, _ = network.get_lane(vehicle.lane_index).local_coordinates(vehicle.position)
            if s_ego - CLEAR_BEHIND <= s <= s_ego + self.clear:
                road.vehicles.remove(vehicle)
        lane = network.get_lane(lane_index)
        s = s_ego + self.gap
        speed = max(ego.speed + self.speed_offset, 0.0)
        from highway_env.vehicle.behavior import IDMVehicle

        vehicle = _scripted_vehicle()(road, lane.position(s, 0.0), lane.heading_at(s), speed,
                                  target_lane_index=lane_index, target_speed=speed,
                                  enable_lane_change=False)
        vehicle.script = self
        vehicle.ego = ego
        road.vehicles.append(vehicle)
        if self.blocker:
            beside = IDMVehicle(road, lane.position(s_ego, 0.0), lane.heading_at(s_ego),
                                ego.speed, target_lane_index=lane_index,
                                target_speed=ego.speed, enable_lane_change=False)
            road.vehicles.append(beside)
        return vehicle


@functools.cache
def _scripted_vehicle() -> type:
    """:class:`ScriptedVehicle`, made on first use: reading a scenario file with a script
    (``tap-bench envs``) must not import highway-env, whose vehicle class it extends."""
    from tap_bench.sim.traffic import TrafficVehicle

    class ScriptedVehicle(TrafficVehicle):
        """An IDM vehicle that follows a :class:`Script`: it keeps its lane until the event,
        then cuts into the ego's lane or brakes."""

        script: Script
        ego: Any
        elapsed: float = 0.0
        fired: bool = False

        def prepare_decision(self) -> None:
            if (self.script.kind == "cut_in" and not self.fired
                    and self.ego.lane_index != self.lane_index):
                lane = self.road.network.get_lane(self.ego.lane_index)
                ahead = (lane.local_coordinates(self.position)[0]
                         - lane.local_coordinates(self.ego.position)[0])
                if ahead >= MIN_CUT_IN_GAP and (self.elapsed >= self.script.at - 1e-9
                                                 or ahead <= CLOSE_CUT_IN_GAP):
                    self.target_lane_index = self.ego.lane_index
                    self.fired = True

        def adjust_action(self) -> None:
            script = self.script
            braking = (script.kind == "lead_braking" and
                script.at - 1e-9 <= self.elapsed < script.at + script.duration - 1e-9)
            if braking and not self.crashed and self.action:
                self.action["acceleration"] = -script.deceleration if self.speed > 0 else 0.0

        def after_step(self, dt: float) -> None:
            self.elapsed += dt

    ScriptedVehicle.__qualname__ = "ScriptedVehicle"  # found by name, as pickle looks it up
    return ScriptedVehicle


def __getattr__(name: str) -> Any:
    if name == "ScriptedVehicle":
        return _scripted_vehicle()
    raise AttributeError(f"module 'tap_bench.sim.scripts' has no attribute {name!r}")
