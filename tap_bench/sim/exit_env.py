"""highway-env's exit scene, drawn from its seed, with an IDM ego that takes the exit.

highway-env's ``exit-v0`` puts the ego in the left lane at 25 m/s, ahead of no one, and
draws the other vehicles' lanes with probabilities proportional to the lane's number, so
the left lane (number 0) is always empty: an IDM ego drove alone in it on every seed and
never reached the exit on its right (the scene gave one outcome on all 30 seeds of the
default suite). :class:`SeededExitEnv` (scenario kind :data:`KIND`) draws from the seed:

- the ego's lane (any of the ``lanes_count``), its speed (``ego_speed`` [m/s], low and
  high) and how many of the other vehicles start behind it (up to ``behind_share`` of
  them), so it starts among the traffic rather than at its back;
- the other vehicles' lanes with probabilities proportional to the lane's number + 1
  (every lane has traffic, the right ones more, as highway-env intends).

An IDM ego (the ``idm`` policies: :attr:`SeededExitEnv.idm_vehicle_class`) is routed to the
exit: MOBIL moves it towards the rightmost through lane whenever that is safe, it takes the
exit lane that opens at 400 m from there, and then the exit; an ego that is not in the
rightmost lane when the exit lane opens has missed the exit and drives on (it never crosses
several lanes at once). Other policies drive as they choose (highway-env's meta-actions).
"""

from __future__ import annotations

import numpy as np
from highway_env import utils
from highway_env.envs.exit_env import ExitEnv
from highway_env.vehicle.kinematics import Vehicle

from tap_bench.sim.traffic import TrafficVehicle

__all__ = ["KIND", "ExitIDMVehicle", "SeededExitEnv", "exit_route"]

KIND = "exit-seeded-v0"
"""The scenario kind (``highway_env_id``) of :class:`SeededExitEnv`."""

PREPARE_PER_LANE = 90.0
"""[m] an IDM ego heads for the rightmost lane when the exit lane (at 400 m) is this far
ahead per lane it has to cross, plus one (before that MOBIL decides on its gain alone)."""
CLEAR_BEHIND = 15.0  # [m] vehicles in the ego's lane this close behind it are removed
CLEAR_AHEAD_S = 1.5  # [s] ... and this many seconds of its speed (+ 15 m) ahead of it


def exit_route(lanes_count: int) -> list[tuple[str, str, int]]:
    """The lanes to the exit of highway-env's exit road: the rightmost through lane, the
    exit lane (number ``lanes_count`` from 400 to 500 m), the exit."""
    return [("0", "1", lanes_count - 1), ("1", "2", lanes_count), ("2", "exit", 0)]


class ExitIDMVehicle(TrafficVehicle):
    """IDM/MOBIL routed to the exit (see the module docstring)."""

    @classmethod
    def create_from(cls, vehicle: Vehicle) -> ExitIDMVehicle:
        new = super().create_from(vehicle)
        new.route = exit_route(len(vehicle.road.network.graph["0"]["1"]))
        return new

    def prepare_decision(self) -> None:
        route = self.route
        if route and route[0][:2] == ("0", "1") and self.lane_index[:2] == ("0", "1"):
            rightmost = len(self.road.network.graph["0"]["1"]) - 1
            lane = self.road.network.get_lane(self.lane_index)
            to_go = lane.length - lane.local_coordinates(self.position)[0]
            crossing = rightmost - self.lane_index[2]
            # far from the exit, MOBIL on its gain alone (a route lane of None)
            wanted = rightmost if to_go <= PREPARE_PER_LANE * (crossing + 1) else None
            route[0] = ("0", "1", wanted)

    def follow_road(self) -> None:
        lane = self.road.network.get_lane(self.target_lane_index)
        if self.route and self.route[0][:2] == ("0", "1") and lane.after_end(self.position):
            lane_id = self.target_lane_index[2]
            rightmost = len(self.road.network.graph["0"]["1"]) - 1
            if lane_id != rightmost:  # not in the rightmost lane: it missed the exit
                self.route = [("0", "1", lane_id), ("1", "2", lane_id), ("2", "3", lane_id)]
        super().follow_road()


class SeededExitEnv(ExitEnv):
    """highway-env's exit scene with the ego's lane, speed and place and the traffic's lanes
    drawn from the seed (see the module docstring)."""

    idm_vehicle_class = ExitIDMVehicle
    """What :func:`tap_bench.sim.idm.take_over_ego` puts in the ego's place."""

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update({"ego_start": [100.0, 300.0], "ego_speed_share": [0.85, 1.0]})
        return config

    def _create_vehicles(self) -> None:
        rng = self.np_random
        cfg = self.config
        lanes_count = int(cfg["lanes_count"])
        start = _bounds(cfg, "ego_start", 0.0, 390.0, "metres along the road")
        share = _bounds(cfg, "ego_speed_share", 0.0, 2.0, "shares of the lane's speed limit")
        network = self.road.network
        weights = np.arange(1, lanes_count + 1, dtype=float)
        vehicles_type = utils.class_from_path(cfg["other_vehicles_type"])
        for _ in range(int(cfg["vehicles_count"])):  # highway-env's generator, every lane
            lane_id = int(rng.choice(lanes_count, p=weights / weights.sum()))
            lane = network.get_lane(("0", "1", lane_id))
            vehicle = vehicles_type.create_random(
                self.road, lane_from="0", lane_to="1", lane_id=lane_id,
                speed=lane.speed_limit, spacing=1 / cfg["vehicles_density"]
            ).plan_route_to("3")
            vehicle.enable_lane_change = False
            self.road.vehicles.append(vehicle)
        self.controlled_vehicles = []
        for _ in range(cfg["controlled_vehicles"]):
            lane_index = ("0", "1", int(rng.integers(lanes_count)))
            lane = network.get_lane(lane_index)
            x = float(rng.uniform(*start))
            speed = float(rng.uniform(*share)) * lane.speed_limit
            for vehicle in list(self.road.vehicles):  # room in its lane
                if vehicle.lane_index == lane_index:
                    s = lane.local_coordinates(vehicle.position)[0]
                    if x - CLEAR_BEHIND <= s <= x + CLEAR_AHEAD_S * speed + 15.0:
                        self.road.vehicles.remove(vehicle)
            ego = self.action_type.vehicle_class(self.road, lane.position(x, 0.0),
                                                 lane.heading_at(x), speed)
            self.controlled_vehicles.append(ego)
            self.road.vehicles.append(ego)


def _bounds(cfg: dict, key: str, low: float, high: float, what: str) -> tuple[float, float]:
    """A [low, high] config pair within [low, high] (a clear error otherwise)."""
    value = cfg[key]
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"exit scene config {key!r}: [low, high] {what}, got "
                         f"{value!r}.") from None
    if not low <= a <= b <= high:
        raise ValueError(f"exit scene config {key!r}: [low, high] {what} with {low:g} <= low "
                         f"<= high <= {high:g}, got {value!r}.")
    return a, b
