"""``tap_bench/womd-v0``: drive a policy through recorded WOMD scenes (SPEC section 8).

One episode is one recorded scenario. **Seeds and scenes**: the N scenarios of the files
given, in file and record order, are scenes 0 to N-1; ``reset(seed=s)`` starts scene
``s % N`` (any integer seed is valid, so seeds 0 to N-1 are the N scenes, and a training
library's seeds wrap around), ``reset(options={"scene": i})`` scene ``i`` and
``reset(options={"scenario_id": ...})`` the scenario of that id; a reset without either
starts the scene after the last one. ``env.unwrapped`` (the highway-env environment) picks
its scenes the same way, so both pass Gymnasium's ``check_env``. Its lanes become a
highway-env road network (:class:`WomdNetwork`: one :class:`~tap_bench.sim.womd_lanes.
FastPolyLane` per WOMD lane, 3.7 m wide unless the boundary lines say otherwise, connected by
WOMD's exit lanes, inferred where the data has none), so every highway-env policy and
observation works on it.

- **Time.** Before the current time (step 10, 1.0 s) everything replays the log; the env
  starts there, and the policy drives the ego to the end of the log at 10 Hz. The trajectory
  table holds the whole record (history and simulated future), so it lines up with the log
  step for step.
- **Ego and route.** The ego is the SDC unless a track id is given (``ego="123"``). Its route
  is the lanes its logged path follows (nearest lane by distance and heading, then along
  the graph: :func:`logged_route`); the controller follows it at every lane end, and lane
  changes go only to lanes the map names as neighbours at that point.
- **Traffic.** ``traffic="log"``: every other agent replays the log (non-reactive).
  ``traffic="idm"``: each vehicle that moves starts from its logged state (at the current
  time, or where and when it appears later, once its place is free) and drives along its
  own logged path, IDM deciding its speed (:class:`~tap_bench.sim.womd_road.WomdPathVehicle`:
  behind whatever box is in the path ahead, before pedestrians and cyclists that will be,
  giving way where logged paths cross to the vehicle that went first in the log, at red
  stop points and stop signs); parked vehicles and vehicles whose path leaves the lanes
  replay; one whose log ends before the record's leaves past its path's end. Pedestrians
  and cyclists always replay. The IDM ego (:class:`WomdIDMVehicle`, IDM/MOBIL along its
  route's lanes) stops at a stop point whose signal is red, and at a yellow one when it can
  stop comfortably; at stop signs; before pedestrians and cyclists crossing its way ahead
  (:meth:`~tap_bench.sim.womd_road.WomdRoad.walker_distance`); and it gives way to crossing
  and merging traffic by gap acceptance (:meth:`~tap_bench.sim.womd_road.WomdRoad.
  conflict_gap`). Each rollout (reset option ``rollout``) draws every idm vehicle's driver
  (:func:`~tap_bench.sim.womd_road.draw_driver`; rollout 0: the nominal one).
  ``traffic="constant-velocity"``: every agent valid at the current time keeps its velocity
  then (the realism score's floor, docs/realism.md).
  idm traffic checks collisions with everyone (highway-env's rule: crashed vehicles brake
  to a stop); the episode table counts them (``traffic_collisions``).
- **End.** At the log's end (truncated), on a collision of the ego or when the ego leaves
  the road (terminated): a corner of its box beyond the road edges
  (:mod:`tap_bench.sim.road_edges`; the lane centres where no edge is near), judged against
  where it started, so a policy is never ended for a start the human made. The human
  (policy ``log``) is never stopped early: its record is the reference, and its overlaps
  with other boxes are counted like anyone's.
- **Measured per step** on the ego's rows: ``off_road`` (left the road),
  ``off_road_distance`` [m] (signed, positive off the road), ``ran_red_light``,
  ``route_progress`` (share of the logged path covered so far), ``log_distance`` [m] (to the
  logged ego at the same step); :mod:`tap_bench.bench.measures` reduces them per episode.

Coordinates: highway-env's y axis points to the driver's right, so the scene is built
mirrored (y and headings negated) and recorded back in WOMD's axes, as
:mod:`tap_bench.sim.recorder` does; the driver's left stays the driver's left.

**What an RL agent observes.** By default ``{"type": "KinematicsRoute", "leader": true}``
(:mod:`tap_bench.sim.womd_observation`): highway-env's Kinematics observation (the ego and
the 4 nearest road users, relative, normalised) flattened, followed by the route seen from
the ego: the route's points every 10 m over the next 50 m in the ego's frame, the offset and
heading to the route lane, the distance and side of the route's next lane change, and
whether the ego is on a route lane; then the ego's speed and the gap, closing speed and
inverse time to collision to the road user in its path ahead (along the route's polyline).
The route also acts through the dynamics: with meta-actions the low-level controller
follows the route's lanes (at a lane end it takes the route's next lane), and
``LANE_LEFT``/``LANE_RIGHT`` move to the map's neighbour on that side; an action config
with ``safety_layer`` caps the ego's acceleration at every step by IDM's braking for the road
user in its swept box (:mod:`tap_bench.sim.womd_safety`; off by default). ``FASTER`` and
``SLOWER`` step the target speed along :data:`TARGET_SPEEDS` from the grid speed nearest the
ego's speed (``speed_index``, :data:`~tap_bench.sim.womd_road.SPEED_INDEX`: ``"uniform"``
keeps highway-env's reading of the grid as evenly spaced, for the models trained with it).
Any highway-env
observation can be configured instead (``config={"observation": ...}``; the shipped
highway agents read plain ``Kinematics``).

**Reward** (``collision_reward``, ``off_road_reward``, ``progress_reward``,
``progress_gain_reward``, ``ttc_reward``): -1 on a collision or leaving the road (both end
the episode), the route progress so far divided by the decisions of the scene at each
decision, ``progress_gain_reward`` (default 0) times the route progress gained since the
last decision (a whole route is worth that much), ``at_fault_reward`` (default 0) more on a
collision that was the ego's fault (SPEC section 8's rules, as the episode table's
``crash_at_fault``: judged by :class:`WomdEnv`), and up to ``ttc_reward`` (-0.05)
per decision while the time to collision with the road user in the path ahead is below
:data:`TTC_WARNING` (3 s), linear in 1 - TTC / 3 s (docs/agents.md says why).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import action_factory
from highway_env.envs.common.observation import observation_factory
from highway_env.vehicle.kinematics import Vehicle

from tap_bench.errors import ParameterError
from tap_bench.sim.collisions import Box, collision_partner, fault
from tap_bench.sim.womd_observation import OBSERVATION_TYPE, RouteObservation
from tap_bench.sim.womd_road import (
    HIDDEN,
    NOMINAL_DRIVER,
    ROUTE_CORRIDOR,
    ROUTE_OFF_MAP,
    ConstantVelocityVehicle,
    LogVehicle,
    WomdIDMVehicle,
    WomdMDPVehicle,
    WomdNetwork,
    WomdPathVehicle,
    WomdRoad,
    draw_driver,
    logged_path,
    logged_route,
    path_columns,
    path_progress,
    sim_frame,
)
from tap_bench.sim.womd_safety import safety_layer
from tap_bench.sim.womd_scene import (
    CURRENT_STEP,
    TRAFFIC,
    Scene,
    SceneError,
    SceneRef,
    WomdScenes,
    load_scene,
)
from tap_bench.stats.bootstrap import named_rng

__all__ = ["PARKED_DISTANCE", "TARGET_SPEEDS", "TRAFFIC", "MapWarning", "WomdEnv",
           "WomdScenes", "make_womd_env", "map_summary", "with_ego"]

PARKED_DISTANCE = 1.0  # [m] a vehicle that moves less over the record stays parked (replays)
LATE_HEADING = math.radians(30.0)  # [rad] a vehicle appearing later more across its lane
# than this replays
TTC_WARNING = 3.0  # [s] a time to collision with the leader below this is punished
TTC_REWARD = -0.05
"""The reward per decision at a time to collision of 0 with the road user in the ego's path
ahead (``ttc_reward``), linear in 1 - TTC / :data:`TTC_WARNING` down to 0 at TTC_WARNING."""
TARGET_SPEEDS = (0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0, 25.0, 30.0)
"""Target speeds of the meta-action ego [m/s] (highway-env's default 20-30 m/s is a
motorway's; these cover a city street too)."""


def _map_note(scene: Scene, network: WomdNetwork) -> str:
    """What the road network made of the scenario's map, in words (the episode table's
    ``map``), warned once per scene when it is not the map as given."""
    road = scene.road
    parts = [f"{len(network.index)} lanes"]
    if road.topology == "inferred":
        parts.append(f"successors inferred from lane ends that meet ({road.inferred_links} "
                     "links; the data names no entry or exit lanes)")
    if network.left_out:
        ids = ", ".join(map(str, network.left_out[:5]))
        parts.append(f"{len(network.left_out)} lane(s) of a single point left out ({ids}"
                     f"{' ...' if len(network.left_out) > 5 else ''})")
    note = "; ".join(parts)
    if len(parts) > 1 and scene.scenario_id not in _WARNED:
        _WARNED.add(scene.scenario_id)
        warnings.warn(f"scenario {scene.scenario_id} ({scene.ref}): {note}.", MapWarning,
                      stacklevel=4)
    return note


_SIGNAL_COLUMNS = ("ran_red_light",)
"""Per-step ego columns read from signal states: NA on a scene that records none."""


class MapWarning(UserWarning):
    """A recorded scene's map was completed (successors inferred) or trimmed (lanes of a
    single point left out)."""


def map_summary(notes: Sequence[object]) -> str | None:
    """One line for the map notes (the episode table's ``map``, one per episode) of many
    scenes: how many maps were completed or trimmed and how, or None when none was. A
    rollout over a shard warns this once, not once per scene."""
    given = [n for n in notes if isinstance(n, str) and n]
    changed = [n for n in given if "; " in n]  # more than the lane count: completed/trimmed
    if not changed:
        return None
    inferred = sum("successors inferred" in n for n in changed)
    trimmed = sum("left out" in n for n in changed)
    how = [f"{k} with {what}" for k, what in (
        (inferred, "successors inferred from lane ends that meet"),
        (trimmed, "lanes of a single point left out")) if k]
    return (f"the map of {len(changed)} of {len(given)} recorded scene(s) was completed or "
            f"trimmed ({', '.join(how)}); the episode table's 'map' column says what for each")


_WARNED: set[str] = set()


def with_ego(scene: Scene, track_id: str | int) -> Scene:
    """``scene`` with the vehicle of track ``track_id`` as its ego.

    Raises:
        SceneError: no such track, or it is not a vehicle valid at the current time (the
            message names the scenario and the track).
    """
    rows = np.flatnonzero(scene.track_ids.astype(str) == str(track_id))
    where = f"scenario {scene.scenario_id} ({scene.ref})"
    if not len(rows):
        raise SceneError(f"{where}: no track {track_id!r} to drive as the ego; its tracks "
                         f"are {', '.join(map(str, scene.track_ids[:10]))}"
                         f"{' ...' if len(scene.track_ids) > 10 else ''}.")
    row = int(rows[0])
    if scene.object_types[row] != "vehicle" or not scene.valid[row, CURRENT_STEP]:
        raise SceneError(f"{where}: track {track_id} is not a vehicle valid at the current "
                         "time (1.0 s), so it cannot be driven as the ego; choose another.")
    return scene if row == scene.ego else dataclasses.replace(scene, ego=row)


class _WomdHighwayEnv(AbstractEnv):
    """The highway-env environment under :class:`WomdEnv` (``env.unwrapped``): it picks the
    scene of a reset itself, so it is a complete Gymnasium env on its own.

    Args:
        scenes: the files and settings.
        config: more highway-env config (over :meth:`default_config`).
        render_mode: highway-env's.

    Attributes:
        catalog: the scenarios, in scene-index order (file and record order).
        scene: the current :class:`~tap_bench.sim.womd_scene.Scene` (None before the first
            reset).
        scene_index: its index in :attr:`catalog`.
        resets: resets so far (a listener knows which episode a frame belongs to).
        frame_listener: called as ``frame_listener(step, measured)`` after every simulated
            step (10 Hz) of an episode, with the ego's measures of that step (what
            :class:`WomdEnv` records); None: nobody listens.
    """

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update({
            "observation": {"type": OBSERVATION_TYPE, "leader": True},
            "action": {"type": "DiscreteMetaAction", "target_speeds": list(TARGET_SPEEDS),
                       "speed_index": "nearest"},
            "simulation_frequency": 10,
            "policy_frequency": 2,
            "collision_reward": -1.0,
            "progress_reward": 1.0,
            "off_road_reward": -1.0,
            "ttc_reward": TTC_REWARD,
            "progress_gain_reward": 0.0,
            "at_fault_reward": 0.0,
        })
        return config

    def __init__(self, scenes: WomdScenes, config: dict | None = None,
                 render_mode: str | None = None, keep_scenes: int = 4) -> None:
        self.scenes = scenes
        self.catalog = scenes.catalog()
        if not self.catalog:
            raise SceneError(f"{', '.join(scenes.files)}: no scenario in these files.")
        self.scene: Scene | None = None
        self.scene_index: int | None = None
        # decoded scenes and their road networks and ego routes, the last keep_scenes used
        # (training comes back to the same scenes: building a network is most of a reset)
        self.keep_scenes = max(1, int(keep_scenes))
        self._cache: dict[SceneRef, Scene] = {}
        self._built: dict[tuple[SceneRef, int], tuple[WomdNetwork, list, float]] = {}
        self.traffic = scenes.traffic
        self.rollout = 0  # which draw of stochastic traffic (reset option "rollout")
        self.clock = [CURRENT_STEP]
        self.replaying_ego = False
        self.resets = 0
        self.frame_listener: Callable[[int, dict[str, float]], None] | None = None
        self._measured_step = CURRENT_STEP
        self._building = True  # highway-env resets once in its constructor: no scene yet
        super().__init__(config={"policy_frequency": scenes.policy_frequency,
                                 **dict(config or {})}, render_mode=render_mode)
        self._building = False

    def render(self) -> np.ndarray | None:
        """highway-env's rendering of the current scene (None before the first reset: no
        scene to draw)."""
        if self.road is None:
            return None
        return super().render()

    def close(self) -> None:
        """highway-env's close, and the env lets go of its scenes: the road's vehicles
        released (:meth:`WomdRoad.release`), its road, scene and vehicles and the decoded
        scenes, networks and routes kept for later resets dropped (a reset after it decodes
        and builds them again; until then it has no road, as before its first). The env
        and its observation and action point at each other: without this a closed env's
        scenes would wait for the garbage collector's full pass."""
        if isinstance(self.road, WomdRoad):
            self.road.release()
        self.road, self.scene, self.states = None, None, None
        self.controlled_vehicles, self.simulated = [], {}
        self._cache.clear()
        self._built.clear()
        super().close()

    # the scenes
    def scene_at(self, index: int) -> Scene:
        """The scene of index ``index`` in :attr:`catalog` (decoded once, a few kept)."""
        if (isinstance(index, bool) or not isinstance(index, int | np.integer)
                or not 0 <= index < len(self.catalog)):
            raise ParameterError("scene", index, f"0 to {len(self.catalog) - 1}: the index "
                                 f"of a scenario in the {len(self.catalog)} of "
                                 f"{', '.join(self.scenes.files)}")
        ref = self.catalog[int(index)]
        scene = self._cache.get(ref)
        if scene is None:
            scene = load_scene(ref, ego=self.scenes.ego)
            if len(self._cache) >= self.keep_scenes:
                gone = next(iter(self._cache))
                self._cache.pop(gone)
                for key in [key for key in self._built if key[0] == gone]:
                    self._built.pop(key)
            self._cache[ref] = scene
        return scene

    def index_of(self, scenario_id: str) -> int:
        """The index of the scenario ``scenario_id`` in :attr:`catalog`."""
        for i in range(len(self.catalog)):
            if self.scene_at(i).scenario_id == scenario_id:
                return i
        raise ParameterError("scenario_id", scenario_id, "the id of a scenario in "
                             f"{', '.join(self.scenes.files)}")

    def scene_for(self, seed: int | None, options: Mapping[str, Any]) -> int:
        """The scene index a reset starts (see :meth:`reset`)."""
        if options.get("scenario_id") is not None:
            return self.index_of(str(options["scenario_id"]))
        if options.get("scene") is not None:
            return options["scene"]  # checked by scene_at
        if seed is not None:
            return int(seed) % len(self.catalog)
        return 0 if self.scene_index is None else (self.scene_index + 1) % len(self.catalog)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        """Start a recorded scenario: ``options["scenario_id"]`` (a WOMD id), else
        ``options["scene"]`` (an index in :attr:`catalog`), else the one of ``seed``:
        scene ``seed % len(catalog)`` (any integer seed is valid; seeds 0 to N-1 are the N
        scenes in file and record order), else the scene after the last one.
        ``options["rollout"]`` (default 0) picks the draw of stochastic traffic (idm
        traffic's drivers): the same scene and rollout give the same episode.
        ``options["ego"]`` (a track id) drives that vehicle of the scene instead of the
        env's ego (training on every driver of a scene; the former ego then replays or is
        traffic like any other track).

        ``seed`` also seeds the env's random generator (as Gymnasium's ``reset`` does);
        the other options are highway-env's (``{"config": ...}``; the observation and
        action spaces stay those of the constructor).
        """
        options = dict(options or {})
        selectors = {key: options.pop(key, None) for key in ("scenario_id", "scene")}
        rollout = options.pop("rollout", 0)
        ego = options.pop("ego", None)
        if not self._building:
            self.rollout = int(rollout)
            index = self.scene_for(seed, selectors)
            scene = self.scene_at(index)
            self.scene = scene if ego is None else with_ego(scene, ego)
            self.scene_index = int(index)
            self.resets += 1
        return super().reset(seed=seed, options=options or None)

    idm_vehicle_class = WomdIDMVehicle
    """What :func:`tap_bench.sim.idm.take_over_ego` puts in the ego's place."""

    def define_spaces(self) -> None:
        """highway-env's, with the route observation (:mod:`tap_bench.sim.womd_observation`)
        as one more observation type and highway-env's Kinematics observation computed
        without pandas (:mod:`tap_bench.sim.observation`).

        The spaces are fixed when the env is built: a reset whose ``config`` option would
        change them is refused.
        """
        from tap_bench.sim.observation import use_fast_observation

        config = self.config["observation"]
        if config.get("type") == OBSERVATION_TYPE:
            self.observation_type = RouteObservation(self, **config)
            self._lead_watch = self.observation_type
        else:
            self.observation_type = observation_factory(self, config)
            use_fast_observation(self)
            # the reward's time to collision needs the leader in the route's path
            self._lead_watch = RouteObservation(self)
        self.action_type = action_factory(self, self.config["action"])
        settings = {name: copy.deepcopy(dict(self.config[name]))
                    for name in ("observation", "action")}
        built = getattr(self, "_space_settings", None)
        if built is None:  # the constructor: the spaces are fixed here
            self._space_settings = settings
            self.observation_space = self.observation_type.space()
            self.action_space = self.action_type.space()
            return
        for name, value in settings.items():
            if value != built[name]:
                raise ParameterError(
                    f"config.{name}", value, "the settings the env was built with",
                    message=f"tap_bench/womd-v0: the {name} space is fixed when the env is "
                    f"built ({built[name]}); this reset's config makes it {value}. Build "
                    f"another env with config={{'{name}': ...}} instead.")

    def _reset(self) -> None:
        old = getattr(self, "road", None)
        if isinstance(old, WomdRoad):  # the last episode's: freed without the collector
            old.release()
        if self.scene is None:  # highway-env resets once in its constructor
            self.road = None
            return
        scene = self.scene
        self.clock[0] = CURRENT_STEP
        self._measured_step = CURRENT_STEP
        ref = self.catalog[self.scene_index]
        built = self._built.get((ref, scene.ego))
        if built is None:  # the network of another ego's episode in this scene
            other = next((b for key, b in self._built.items() if key[0] == ref), None)
            network = other[0] if other is not None else WomdNetwork(scene.road)
        else:
            network = built[0]
        self.map_note = _map_note(scene, network)
        self.road = WomdRoad(network, scene, self.clock, np_random=self.np_random)
        sim_xy = sim_frame(scene.x, scene.y)  # (n, T, 2)
        sim_h = -scene.heading
        states = np.concatenate([sim_xy, sim_h[..., None], scene.speed[..., None]], axis=-1)
        self.states = states
        e = scene.ego
        future = np.flatnonzero(scene.valid[e, CURRENT_STEP:]) + CURRENT_STEP
        if built is None:
            built = (network, *logged_route(network, sim_xy[e, future], sim_h[e, future]))
            if ref in self._cache:
                self._built[ref, scene.ego] = built
        route, off = built[1], built[2]
        self.route = list(route)
        self.route_missing = ""  # why the scene has no route (the human still replays)
        if off > 0.5:
            self.route_missing = (
                f"scenario {scene.scenario_id}: the logged ego's path leaves the mapped lanes "
                f"({off:.0%} of its future positions are more than {ROUTE_OFF_MAP} m beyond "
                "a lane), so it has no route to follow: the human (policy log) replays it, a "
                "policy that drives needs another track (--ego ID) or another scene.")
        path = sim_xy[e, future]
        step_len = np.hypot(*np.diff(path, axis=0).T)
        self.path = path
        self.path_cum = np.r_[0.0, np.cumsum(step_len)]
        self.path_length = float(self.path_cum[-1])
        self._path_columns = path_columns(path, self.path_cum)  # read at every step
        # every agent's lane where it starts (hidden where the log has no state then),
        # looked up at once for the vehicles made below
        rows = np.arange(len(scene.track_ids))
        start = np.where(scene.valid[:, CURRENT_STEP, None], states[:, CURRENT_STEP, :3],
                         np.c_[HIDDEN + 10.0 * rows, np.full(len(rows), HIDDEN),
                               np.zeros(len(rows))])
        network.look_up_lanes(start)
        x, y, h, v = states[e, CURRENT_STEP]
        lane_index = network.get_closest_lane_index(np.array([x, y]), h)
        limits = [network.get_lane(i).speed_limit for i in self.route]
        target = float(min(limits)) if limits else float(v)
        ego = WomdMDPVehicle(self.road, np.array([x, y]), heading=h, speed=v,
                             target_lane_index=lane_index, target_speed=target,
                             target_speeds=self.config["action"].get("target_speeds",
                                                                     TARGET_SPEEDS),
                             speed_index=self.config["action"].get("speed_index", "nearest"),
                             route=list(self.route))
        ego.LENGTH, ego.WIDTH = float(scene.length[e]), float(scene.width[e])
        ego.diagonal = math.hypot(ego.LENGTH, ego.WIDTH)
        ego.safety = safety_layer(self.config["action"].get("safety_layer"))
        self.road.vehicles.append(ego)
        self.controlled_vehicles = [ego]
        self.simulated: dict[int, Vehicle] = {}  # other simulated agents by row
        others = [row for row in range(len(scene.track_ids)) if row != e]
        replays = LogVehicle.many(self.road, others, states, scene.valid, scene.length,
                                  scene.width, self.clock)  # every log laid out at once
        for row, replay in zip(others, replays, strict=True):
            vehicle = self._traffic_vehicle(network, row, states, sim_xy, sim_h, replay)
            self.road.vehicles.append(vehicle)
            if not isinstance(vehicle, LogVehicle):
                self.simulated[row] = vehicle
        network.forget_lanes()
        self.road.start_collisions()
        self.road.start_off_road(ego)
        self.has_signals = bool(len(scene.road.signals.lane))  # signal states recorded
        self.replaying_ego = False
        self._last_ego = np.array([x, y])
        self.progress = 0.0
        self._rewarded_progress = 0.0  # the route progress at the last decision's reward
        self.ego_at_fault = False  # the ego's collision was its fault (WomdEnv judges it)
        self.flags = {"off_road": False, "ran_red_light": False}
        self.off_road_max = float("nan")  # [m] largest signed distance off the road
        self.off_road_rules: dict[str, int] = {}  # rule -> steps it decided

    def _traffic_vehicle(self, network: WomdNetwork, row: int, states: np.ndarray,
                         sim_xy: np.ndarray, sim_h: np.ndarray,
                         replay: LogVehicle | None = None) -> Vehicle:
        """The vehicle of scene row ``row``: ``replay`` (its log replayed, made here when
        None) or, by the traffic mode, a simulated one."""
        scene = self.scene
        valid = scene.valid[row]
        if replay is None:
            replay = LogVehicle(self.road, row, states[row], valid, scene.length[row],
                                scene.width[row], self.clock)
        if self.traffic == "constant-velocity" and valid[CURRENT_STEP]:
            vehicle = ConstantVelocityVehicle(
                self.road, states[row, CURRENT_STEP],
                sim_frame(scene.vx[row, CURRENT_STEP], scene.vy[row, CURRENT_STEP]),
                scene.length[row], scene.width[row], self.clock)
            vehicle.row = row
            return vehicle
        if self.traffic != "idm" or scene.object_types[row] != "vehicle":
            return replay
        steps = np.flatnonzero(valid[CURRENT_STEP:]) + CURRENT_STEP
        if not len(steps):
            return replay
        first = int(steps[0])  # a vehicle that appears later drives from where it appears
        xy = sim_xy[row, steps]
        if len(xy) < 2 or np.hypot(*(xy[-1] - xy[0])) < PARKED_DISTANCE:
            return replay
        off = network.path_off_map.get(row)
        if off is None:
            off = network.path_off_map[row] = logged_route(network, xy, sim_h[row, steps])[1]
        if off > 0.25:
            return replay
        x, y, h, v = states[row, first]
        lane_index = network.get_closest_lane_index(np.array([x, y]), h)
        if first > CURRENT_STEP:  # appearing off the lanes or across them (a driveway, a
            lane = network.get_lane(lane_index)  # car park): replays
            lon, lat = lane.local_coordinates(np.array([x, y]))
            turn = (h - lane.heading_at(lon) + math.pi) % (2 * math.pi) - math.pi
            if abs(lat) > lane.width / 2 or abs(turn) > LATE_HEADING:
                return replay
        # rollout 0: the nominal driver; rollout k: drawn from the stream of this scene,
        # track and rollout (the same k, the same drivers)
        driver = NOMINAL_DRIVER if self.rollout == 0 else draw_driver(named_rng(
            self.rollout, "idm traffic", scene.scenario_id, str(scene.track_ids[row])))
        vehicle = WomdPathVehicle(
            self.road, logged_path(xy, sim_h[row, steps], scene.speed[row, steps], steps), v,
            driver, float(scene.length[row]), float(scene.width[row]), row,
            last_step=int(steps[-1]))
        if first > CURRENT_STEP:
            vehicle.appear_at(first)
        return vehicle

    def replay_ego(self) -> None:
        """Make the ego replay its log (the policy ``log``: the human)."""
        scene = self.scene
        e = scene.ego
        old = self.vehicle
        new = LogVehicle(self.road, e, self.states[e], scene.valid[e], scene.length[e],
                         scene.width[e], self.clock)
        new.check_collisions = True
        new.lane_index = old.lane_index
        vehicles = self.road.vehicles
        vehicles[vehicles.index(old)] = new
        self.controlled_vehicles = [new]
        self.replaying_ego = True

    # per step bookkeeping: after every simulated step (highway-env calls
    # _automatic_rendering after each step of a decision but its last)
    def _automatic_rendering(self) -> None:
        self._end_frame()
        super()._automatic_rendering()

    def _simulate(self, action: Any = None) -> None:
        super()._simulate(action)
        self._end_frame()

    def _end_frame(self) -> None:
        """Measure the step just simulated (once per step, inside the record) and tell the
        listener, before the episode's end is decided."""
        k = self.clock[0]
        if self.scene is None or k <= self._measured_step or k >= self.scene.n_steps:
            return
        self._measured_step = k
        measured = self.measure_step()
        if self.frame_listener is not None:
            self.frame_listener(k, measured)

    def measure_step(self) -> dict[str, float]:
        ego = self.vehicle
        p = np.asarray(ego.position, float)
        off, off_distance, rule = self.road.off_road(ego)
        if math.isfinite(off_distance):
            self.off_road_max = (max(off_distance, self.off_road_max)
                if math.isfinite(self.off_road_max) else off_distance)
        if rule != "none":
            self.off_road_rules[rule] = self.off_road_rules.get(rule, 0) + 1
        red = self.road.crossed_red(self._last_ego, p)
        self._last_ego = p.copy()
        if self.path_length > 0 and len(self.path) >= 2:
            s, d = path_progress(self.path, self.path_cum, p, self._path_columns)
            if d <= ROUTE_CORRIDOR:
                self.progress = max(self.progress, s / self.path_length)
        self.flags["off_road"] |= off
        self.flags["ran_red_light"] |= red
        k = self.clock[0]
        e = self.scene.ego
        if k < self.scene.n_steps and self.scene.valid[e, k]:
            lx, ly = self.states[e, k, :2].tolist()  # floats: no numpy scalars
            log_distance = math.hypot(float(p[0]) - lx, float(p[1]) - ly)
        else:
            log_distance = float("nan")
        return {"off_road": off, "off_road_distance": off_distance, "ran_red_light": red,
                "route_progress": self.route_progress, "log_distance": log_distance}

    @property
    def route_progress(self) -> float:
        """Share of the logged ego's path covered so far (NaN when the human moved < 1 m or
        the scene has no route: :attr:`route_missing` says why)."""
        if self.path_length < 1.0 or self.route_missing:
            return float("nan")
        return float(min(self.progress, 1.0))

    def _info(self, obs: Any, action: Any = None) -> dict:
        if self.road is None or not self.controlled_vehicles:  # the constructor's reset
            return {}
        return super()._info(obs, action)

    def _reward(self, action: Any) -> float:
        cfg = self.config
        closing = 0.0
        if cfg.get("ttc_reward", 0.0):
            watch = self._lead_watch
            if watch is not self.observation_type and self.route:
                watch.update_lead()
            inverse_ttc = watch.lead.inverse_ttc
            if inverse_ttc > 0:
                closing = max(0.0, 1.0 - 1.0 / (inverse_ttc * TTC_WARNING))
        progress = 0.0 if math.isnan(self.route_progress) else self.route_progress
        gain, self._rewarded_progress = progress - self._rewarded_progress, progress
        return float(cfg["collision_reward"] * self.vehicle.crashed
                     + cfg.get("ttc_reward", 0.0) * closing
                     + cfg.get("progress_gain_reward", 0.0) * gain
                     + cfg.get("at_fault_reward", 0.0) * (self.vehicle.crashed
                                                          and self.ego_at_fault)
                     + cfg["off_road_reward"] * self.flags["off_road"]
                     + cfg["progress_reward"] * progress
                     / max(1, (self.scene.n_steps - CURRENT_STEP) * cfg["policy_frequency"]
                           / cfg["simulation_frequency"]))

    def _is_terminated(self) -> bool:
        if self.replaying_ego:
            return False
        return bool(self.vehicle.crashed or self.flags["off_road"])

    def _is_truncated(self) -> bool:
        return self.clock[0] >= self.scene.n_steps - 1


class WomdEnv(gym.Wrapper):
    """``tap_bench/womd-v0``: one recorded scenario per episode (see the module docstring).

    Behaves like the highway-env environment it wraps (``env.unwrapped``), and like
    :class:`~tap_bench.sim.scenario_env.ScenarioEnv` for rollouts: :meth:`trajectories`
    gives the episode's table, :meth:`episode_info` its measures.

    Args:
        scenes: the files and settings.
        record: build the trajectory table (off: faster training).
        render_mode: highway-env's.
        cycle: for training: a scenario that cannot be built is skipped (with a warning)
            for the next one.

    Attributes:
        scenario: the :class:`WomdScenes` (``scenario.name`` is the ``env`` column).
        catalog: the scenarios, in scene-index order.
        scene: the current :class:`~tap_bench.sim.womd_scene.Scene`.
        max_steps: decisions in the current episode when it runs to the log's end.
    """

    def __init__(self, scenes: WomdScenes, *, record: bool = True,
                 render_mode: str | None = None, cycle: bool = False) -> None:
        # cycling (training) comes back to every scene: keep up to 64 built
        inner = _WomdHighwayEnv(scenes, config=dict(scenes.config), render_mode=render_mode,
                                keep_scenes=64 if cycle else 4)
        super().__init__(inner)
        self.scenario = scenes
        self.record = record
        self.cycle = cycle
        self._seed: int | None = None
        self._episode = -1  # the inner env's reset this wrapper records
        inner.frame_listener = self._frame
        self.max_steps = 0

    @property
    def catalog(self) -> list[SceneRef]:
        """The scenarios, in scene-index order."""
        return self.env.unwrapped.catalog

    @property
    def scene(self) -> Scene | None:
        """The current scene (None before the first reset)."""
        return self.env.unwrapped.scene

    def scene_at(self, index: int) -> Scene:
        """The scene of index ``index`` (decoded once, a few kept)."""
        return self.env.unwrapped.scene_at(index)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        """Start a scenario: ``options["scenario_id"]``, else ``options["scene"]`` (its
        index in :attr:`catalog`), else scene ``seed % len(catalog)``, else the next one
        (:meth:`_WomdHighwayEnv.reset`). With ``cycle``, a scene that cannot be built is
        skipped, with a warning, for the next one."""
        inner = self.env.unwrapped
        options = dict(options or {})
        chosen = options.get("scene") is not None or options.get("scenario_id") is not None
        for _ in range(len(self.catalog) if self.cycle else 1):
            try:
                obs, info = self.env.reset(seed=seed, options=options or None)
                if self.cycle and inner.route_missing:  # training: a scene without a
                    raise SceneError(inner.route_missing)  # route is skipped
                break
            except SceneError as err:
                if not self.cycle:
                    raise
                warnings.warn(f"{err} Skipped.", stacklevel=2)
                failed = inner.scene_for(seed, options)
                options = {**options, "scenario_id": None, "ego": None,
                           "scene": (failed + 1) % len(self.catalog)}
        else:
            raise SceneError(f"{', '.join(self.scenario.files)}: no scenario can be built.")
        # the table's seed: the one given where an option chose the scene (a run sharded
        # by file names each scene by its file's index and keeps the run's seed), else the
        # scene's index (seed % N)
        self._seed = int(seed) if seed is not None and chosen else inner.scene_index
        self._episode = inner.resets
        self.max_steps = int(np.ceil((self.scene.n_steps - 1 - CURRENT_STEP)
                                     * inner.config["policy_frequency"]
                                     / inner.config["simulation_frequency"]))
        self._start_record()
        return obs, info

    # recording
    def _start_record(self) -> None:
        scene = self.scene
        n, t = scene.x.shape
        self._rec = {name: getattr(scene, name).copy() for name in
                     ("x", "y", "heading", "speed", "vx", "vy", "valid")}
        self._crashed = np.zeros((n, t), bool)
        self._ego_cols = {"off_road": np.zeros(t, bool), "off_road_distance": np.full(t, np.nan),
                          "crash_at_fault": np.zeros(t, bool),
                          "ran_red_light": np.zeros(t, bool),
                          "route_progress": np.full(t, np.nan),
                          "log_distance": np.full(t, np.nan)}
        self._last_step = CURRENT_STEP
        self.crash_with = ""
        self.crash_at_fault: bool | None = None
        self.crash_fault = ""
        self.crash_from_behind_by_log = False

    def _frame(self, k: int, measured: dict[str, float]) -> None:
        """Record simulated step ``k`` (the inner env's :attr:`frame_listener`)."""
        inner = self.env.unwrapped
        if inner.resets != self._episode:  # an episode this wrapper did not start
            return
        self._last_step = k
        e = self.scene.ego
        for name, value in measured.items():
            self._ego_cols[name][k] = value
        ego = inner.vehicle
        if ego.crashed and self.crash_at_fault is None:
            self._crash_partner(ego)
            inner.ego_at_fault = bool(self.crash_at_fault)  # the reward's at_fault_reward
        self._ego_cols["crash_at_fault"][k] = bool(ego.crashed and self.crash_at_fault)
        if not self.record:
            return
        rec = self._rec
        # the ego as the policy left it (IDM and the log policy put their own in its place)
        for _, a, b in inner.road.traffic_collisions:  # replayed vehicles hit by traffic
            self._crashed[[a, b], k] = True
        for row, vehicle in (*inner.simulated.items(), (e, ego)):
            self._crashed[row, k] = vehicle.crashed
            if isinstance(vehicle, LogVehicle):
                continue
            if getattr(vehicle, "hidden", False):  # not on the road (yet, or any more)
                rec["valid"][row, k] = False
                continue
            heading = -vehicle.heading
            heading = math.pi - (math.pi - heading) % (2 * math.pi)
            speed = max(float(vehicle.speed), 0.0)
            rec["x"][row, k] = vehicle.position[0]
            rec["y"][row, k] = -vehicle.position[1]
            rec["heading"][row, k] = heading
            rec["speed"][row, k] = speed
            rec["vx"][row, k] = speed * math.cos(heading)
            rec["vy"][row, k] = speed * math.sin(heading)
            rec["valid"][row, k] = True

    def _off_road_rule(self) -> str:
        """Which rule decided off-road over the episode's steps: ``"road edge"``, ``"lane
        centre"``, or both with their step counts (``"road edge 70, lane centre 10"``)."""
        rules = self.env.unwrapped.off_road_rules
        if len(rules) <= 1:
            return next(iter(rules), "none")
        return ", ".join(f"{rule} {n}" for rule, n in sorted(rules.items(), key=lambda r: -r[1]))

    def _crash_partner(self, ego: Vehicle) -> None:
        """Name the agent the ego collided with and the ego's fault
        (:mod:`tap_bench.sim.collisions`: the largest overlap of boxes; SPEC 8's rules)."""
        inner = self.env.unwrapped
        others = [v for v in inner.road.vehicles if v is not ego and v.collidable
                  and np.hypot(*(v.position - ego.position))
                  <= (v.diagonal + ego.diagonal) / 2 + 2.0]
        boxes = [self._box(v) for v in others]
        mine = self._box(ego)
        k = collision_partner(mine, boxes)
        if k is None:
            self.crash_at_fault, self.crash_fault = True, "at fault"
            return
        other = others[k]
        row = getattr(other, "row", None)
        self.crash_with = str(self.scene.track_ids[row]) if row is not None else ""
        verdict = fault(mine, boxes[k])
        self.crash_at_fault, self.crash_fault = verdict.at_fault, verdict.reason
        self.crash_from_behind_by_log = (isinstance(other, LogVehicle)
            and verdict.reason == "hit from behind")

    def _box(self, vehicle: Vehicle) -> Box:
        row = getattr(vehicle, "row", None)
        kind = str(self.scene.object_types[row]) if row is not None else "vehicle"
        return Box(float(vehicle.position[0]), float(vehicle.position[1]),
                   float(vehicle.heading), max(float(vehicle.speed), 0.0),
                   float(vehicle.LENGTH), float(vehicle.WIDTH), kind)

    def _traffic_collided(self) -> str:
        """The traffic collisions of the episode in words: ``"12 x 34 (log) at 3.4 s; ..."``
        (track ids, ``(log)`` for a replayed agent; time from the record's start)."""
        scene = self.scene
        ids = scene.track_ids
        simulated = self.env.unwrapped.simulated

        def name(row: int) -> str:
            return str(ids[row]) if row in simulated else f"{ids[row]} (log)"

        last = len(scene.times) - 1  # a pair crashed "at the next step" after the last one
        return "; ".join(f"{name(a)} x {name(b)} at "
                         f"{scene.times[min(k, last)] - scene.times[0]:.1f} s"
                         for k, a, b in self.env.unwrapped.road.traffic_collisions)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        info = {**info, "scenario_id": self.scene.scenario_id}
        return obs, reward, terminated, truncated and not terminated, info

    def trajectories(self, **columns: object) -> pd.DataFrame:
        """The episode so far as a trajectory table: every track, from the record's start
        to the last simulated step, in WOMD's axes (SPEC section 1).

        Args:
            **columns: constant columns to add (``policy="idm"``).
        """
        from functools import partial

        from tap_bench.sim.recorder import flag_column, string_dtype
        from tap_bench.sim.recorder import text_column as column

        text_column = partial(column, dtype=string_dtype())  # asked once for the table

        scene = self.scene
        n, _ = scene.x.shape
        inner = self.env.unwrapped
        t = self._last_step + 1
        rows = n * t
        rec = self._rec
        valid = rec["valid"][:, :t].ravel()
        track = np.repeat(np.arange(n), t)
        ego_rows = track == scene.ego
        ego_at = np.flatnonzero(ego_rows)
        one = np.zeros(rows, dtype=np.intp)

        def kinematic(name: str) -> np.ndarray:  # NaN where the agent is not on the road
            return np.where(valid, rec[name][:, :t].ravel(), np.nan)

        data = {
            "scenario_id": text_column([scene.scenario_id], one),
            "track_id": text_column(scene.track_ids, track),
            "t": np.tile(scene.times[:t] - scene.times[0], n),  # as read_womd gives them
            **{name: kinematic(name) for name in ("x", "y", "heading", "speed")},
            "valid": valid,
            **{name: kinematic(name) for name in ("vx", "vy")},
            "object_type": text_column(scene.object_types, track),
            "is_ego": ego_rows,
            "source": text_column(["womd-sim"], one),
            "env": text_column([self.scenario.name], one),
        }
        policy = columns.pop("policy", None)
        if policy is not None:
            data["policy"] = (text_column([policy], one) if isinstance(policy, str)
                else np.full(rows, policy, dtype=object))
        data["seed"] = np.full(rows, self._seed, dtype=np.int64)
        data["episode"] = np.zeros(rows, np.int64)
        data["crashed"] = self._crashed[:, :t].ravel()
        data["length"] = np.repeat(scene.length, t)
        data["width"] = np.repeat(scene.width, t)
        for name, values in self._ego_cols.items():
            if values.dtype.kind == "f":
                col = np.full(rows, np.nan)
                col[ego_at] = values[:t]
                data[name] = col
                continue
            flags = np.zeros(rows, dtype=bool)
            flags[ego_at] = values[:t]
            # no signal states: not a number (NA), not "never"
            unknown = ego_rows if name in _SIGNAL_COLUMNS and not inner.has_signals else None
            data[name] = flag_column(flags, unknown)
        data["ended_early"] = flag_column(ego_rows & self._ended_early())
        data.update({name: text_column([value], one) if isinstance(value, str)
                     else np.full(rows, value, dtype=object)
                     for name, value in columns.items()})
        return pd.DataFrame(data, copy=False)

    def recorded_states(self) -> dict[str, np.ndarray]:
        """The episode's states as (n_tracks, n_steps) arrays in WOMD's axes (``x``, ``y``,
        ``heading``, ``speed``, ``valid``): the record before the current time, the
        simulation after it; steps past the episode's end are invalid (NaN)."""
        last = self._last_step + 1
        out = {name: self._rec[name].copy() for name in ("x", "y", "heading", "speed",
                                                          "valid")}
        out["valid"][:, last:] = False
        for name in ("x", "y", "heading", "speed"):
            out[name][~out["valid"]] = np.nan
        return out

    def _ended_early(self) -> bool:
        """The ego's episode ended (a collision, off the road) before the log's end."""
        inner = self.env.unwrapped
        return self._last_step < self.scene.n_steps - 1 and inner._is_terminated()

    def episode_info(self) -> dict[str, Any]:
        """The episode's row beyond :data:`~tap_bench.sim.rollout.EPISODE_COLUMNS`."""
        inner = self.env.unwrapped
        dist = self._ego_cols["log_distance"][CURRENT_STEP + 1:self._last_step + 1]
        dist = dist[np.isfinite(dist)]
        if self._ended_early():  # ADE/FDE over the whole horizon only: full episodes
            dist = dist[:0]
        return {"scenario_id": self.scene.scenario_id, "traffic": self.scenario.traffic,
                "off_road": bool(inner.flags["off_road"]),
                "max_off_road_distance_m": float(inner.off_road_max),
                "off_road_rule": self._off_road_rule(),
                "route_progress": inner.route_progress,
                "route_missing": inner.route_missing,
                "ran_red_light": bool(inner.flags["ran_red_light"]) if inner.has_signals
                else float("nan"),
                "signal_states": inner.has_signals,
                "log_ade": float(dist.mean()) if len(dist) else float("nan"),
                "log_fde": float(dist[-1]) if len(dist) else float("nan"),
                "crash_with": self.crash_with,
                "crash_at_fault": bool(self.crash_at_fault),
                "crash_fault": self.crash_fault,
                "crash_from_behind_by_log": bool(self.crash_from_behind_by_log),
                "traffic_collisions": len(inner.road.traffic_collisions),
                "traffic_collisions_with_log": sum(
                    a not in inner.simulated or b not in inner.simulated
                    for _, a, b in inner.road.traffic_collisions),
                "traffic_collided": self._traffic_collided(),
                "map": inner.map_note}


def make_womd_env(files: str | os.PathLike | Iterable[str | os.PathLike] | WomdScenes,
                  *, traffic: str = "log", ego: str = "sdc", policy_frequency: int = 2,
                  config: Mapping[str, Any] | None = None, record: bool = True,
                  render_mode: str | None = None) -> WomdEnv:
    """Build ``tap_bench/womd-v0`` (what ``gymnasium.make("tap_bench/womd-v0", files=...)``
    calls).

    Args:
        files: WOMD files, patterns or folders, or :class:`WomdScenes`.
        traffic: ``"log"`` (replay, non-reactive), ``"idm"`` (reactive) or
            ``"constant-velocity"`` (the realism floor).
        ego: ``"sdc"`` or a track id.
        policy_frequency: decisions per second (1, 2, 5 or 10).
        config: more highway-env config (observation, action, rewards).
        record: build the trajectory table.
        render_mode: highway-env's render mode.
    """
    if isinstance(files, WomdScenes):
        scenes = files
    else:
        items = [files] if isinstance(files, str | os.PathLike) else list(files)
        scenes = WomdScenes(tuple(str(f) for f in items), traffic, str(ego),
                            policy_frequency)
    if config:
        scenes = scenes.with_overrides(config)
    return WomdEnv(scenes, record=record, render_mode=render_mode)
