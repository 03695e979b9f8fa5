"""The scenario environment: a highway-env environment configured from a scenario file,
recording every vehicle at 10 Hz.

``gymnasium.make("tap_bench/highway-v0")`` builds one (after ``import tap_bench``); so does
:func:`make_env`. The result behaves like the highway-env environment it wraps
(``env.unwrapped`` is that environment), with three differences:

- every simulated step (10 Hz) of every vehicle is recorded: :func:`episode_trajectories`
  returns the current episode as a trajectory table in Waymo axes;
- the episode is truncated by counting decisions (``duration * policy_frequency``), not by
  highway-env's floating-point clock, which drifts;
- the lane-change setting of the scenario is applied to every vehicle, and building a scene
  may not change highway-env's shared vehicle classes (see :mod:`tap_bench.sim.vehicles`);
- the Kinematics observation is computed without pandas (the same arrays, several times
  faster: :mod:`tap_bench.sim.observation`).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from tap_bench.errors import ParameterError, TapBenchError
from tap_bench.sim.recorder import TrajectoryRecorder
from tap_bench.sim.scenario_format import (  # get_scenario: defined there, away from Gymnasium
    Scenario,
    check_config,
    get_scenario,
)
from tap_bench.sim.schema import env_class
from tap_bench.sim.vehicles import LANE_CHANGE_SETTINGS, apply_lane_change, guard_class_attributes

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["FAST_SIMULATION_FREQUENCY", "ScenarioEnv", "episode_trajectories", "get_scenario",
           "make_env"]

FAST_SIMULATION_FREQUENCY = 5
"""Simulation rate of a ``fast`` scenario env [Hz]: highway-env's ``highway-fast-v0`` rate."""


class ScenarioEnv(gym.Wrapper):
    """A highway-env environment set up and recorded as a tap-bench scenario.

    Args:
        scenario: the scenario (see :func:`get_scenario`).
        render_mode: highway-env's ``"rgb_array"`` or ``"human"``, or None.
        record: record every vehicle at every step (turn off to train faster).
        fast: highway-env's fast training variant of the scenario (what ``highway-fast-v0``
            does to ``highway-v0``): simulated at :data:`FAST_SIMULATION_FREQUENCY` instead
            of 10 Hz, and collisions checked for the ego only (the others drive through each
            other instead of crashing; IDM traffic rarely comes that close). The decisions,
            observations, actions and rewards are those of the scenario, so an agent trained
            on it acts in the scenario; the dynamics differ slightly. It cannot record: the
            trajectory table is 10 Hz.

    Attributes:
        scenario: the validated scenario.
        max_steps: decisions in an episode that runs to its time limit.
        fast: whether this is the fast variant.
    """

    def __init__(self, scenario: Scenario, *, render_mode: str | None = None,
                 record: bool = True, fast: bool = False) -> None:
        config = scenario.config
        if fast:
            if record:
                raise ParameterError("record", record, "False for a fast env", message=(
                    f"{scenario.env_id}: a fast env simulates at {FAST_SIMULATION_FREQUENCY} "
                    "Hz and cannot record the 10 Hz trajectory table; build it with "
                    "record=False."))
            if FAST_SIMULATION_FREQUENCY % scenario.policy_frequency:
                raise ParameterError("fast", fast, "False here", message=(
                    f"{scenario.env_id}: policy_frequency {scenario.policy_frequency} Hz does "
                    f"not divide the fast simulation's {FAST_SIMULATION_FREQUENCY} Hz; use 1 "
                    f"or {FAST_SIMULATION_FREQUENCY} Hz, or fast=False."))
            config = {**config, "simulation_frequency": FAST_SIMULATION_FREQUENCY}
        cls = _scenario_env_class(env_class(scenario.highway_env_id))
        _check_vehicle_types(config, scenario)
        # highway-env builds a first scene in its constructor
        with guard_class_attributes(f"building {scenario.env_id}"):
            inner = cls(config=config, render_mode=render_mode)
        super().__init__(inner)
        self.scenario = scenario
        self.fast = fast
        self.max_steps = scenario.max_steps
        self._lane_change = (None if scenario.lane_change == "default"
                             else LANE_CHANGE_SETTINGS[scenario.lane_change])
        self.recorder = TrajectoryRecorder(record=record)
        self._decisions = 0
        self._seed: int | None = None
        self._episode = -1
        # the intermediate simulated steps of a decision are recorded (see _scenario_env_class)
        inner.on_intermediate_step = self._frame

    def _frame(self) -> None:
        env = self.env.unwrapped
        new = self.recorder.frame(env.steps, env.road.vehicles, env.vehicle)
        if self._lane_change is not None:
            for vehicle in new:
                apply_lane_change(vehicle, self._lane_change)
        if self.fast:
            for vehicle in new:
                if vehicle is not env.vehicle:
                    vehicle.check_collisions = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        """Reset to the initial traffic of ``seed`` (the same for every policy)."""
        if options and "config" in options:
            check_config(self.scenario.highway_env_id, options["config"],
                         source=f"{self.scenario.env_id} reset options")
        if seed is not None:
            self._seed, self._episode = int(seed), 0
        else:
            self._episode += 1
        with guard_class_attributes(f"resetting {self.scenario.env_id}"):
            obs, info = self.env.reset(seed=seed, options=options)
            if self.scenario.script is not None:
                inner = self.env.unwrapped
                self.scenario.script.install(inner)
                obs = inner.observation_type.observe()  # with the scripted vehicle
        self._decisions = 0
        # reset options may have changed the decision rate
        self.max_steps = round(self.scenario.duration
                               * self.env.unwrapped.config["policy_frequency"])
        self.recorder.start(self.scenario.name, self._seed, self._episode)
        self._frame()
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._decisions += 1
        self._frame()
        # highway-env's own time limit compares a drifting float clock (never earlier than
        # this count, at most one decision later); the count decides.
        truncated = (bool(truncated) or self._decisions >= self.max_steps) and not terminated
        return obs, reward, terminated, truncated, info

    def trajectories(self, **columns: object) -> pd.DataFrame:
        """The current episode so far as a trajectory table (SPEC section 1).

        Args:
            **columns: constant columns to add, e.g. ``policy="idm"``.
        """
        return self.recorder.table(**columns)


@functools.cache
def _scenario_env_class(cls: type) -> type:
    """The env class of a scenario of highway-env kind ``cls``: its road driven by the
    traffic core (:func:`~tap_bench.sim.traffic.traffic_env_class`), its Kinematics
    observation computed without pandas from each ``define_spaces`` on (highway-env builds
    a new observation at each reset and observes with it at once), and a hook,
    ``on_intermediate_step``, called after each intermediate simulated step of a decision
    (highway-env calls ``_automatic_rendering`` there; it is how its video recorder
    captures frames), where :class:`ScenarioEnv` records those steps."""
    from tap_bench.sim.observation import use_fast_observation
    from tap_bench.sim.traffic import traffic_env_class

    base = traffic_env_class(cls)

    def define_spaces(self: Any) -> None:
        base.define_spaces(self)
        use_fast_observation(self)

    def _automatic_rendering(self: Any) -> None:
        hook = self.__dict__.get("on_intermediate_step")
        if hook is not None:
            hook()
        base._automatic_rendering(self)

    return type(cls.__name__, (base,), {"define_spaces": define_spaces,
                                        "_automatic_rendering": _automatic_rendering,
                                        "__module__": cls.__module__, "__doc__": cls.__doc__})


def _check_vehicle_types(config: Mapping[str, Any], scenario: Scenario) -> None:
    """Each vehicle class the config names, checked as code before highway-env imports and
    builds it (:mod:`tap_bench.usercode`): defined as a class, a subclass of highway-env's
    ``Vehicle``."""
    from highway_env.vehicle.kinematics import Vehicle

    from tap_bench.sim.scenario_format import VEHICLE_TYPE_KEYS
    from tap_bench.usercode import import_checked_class

    for key in VEHICLE_TYPE_KEYS:
        if isinstance(config.get(key), str):
            import_checked_class(config[key], key, separator=".", base=Vehicle,
                                 kind="a highway-env vehicle class (a subclass of "
                                 "highway_env.vehicle.kinematics.Vehicle)",
                                 source=str(scenario.path or scenario.env_id))


def make_env(scenario: str | os.PathLike | Scenario, *, config: Mapping[str, Any] | None = None,
             duration: float | None = None, lane_change: str | None = None,
             record: bool = True, render_mode: str | None = None, fast: bool = False
             ) -> gym.Env:
    """Build a scenario environment; what ``gymnasium.make("tap_bench/<name>-v0")`` calls.

    Args:
        scenario: name, Gymnasium id, scenario file path or :class:`Scenario`.
        config: more highway-env config overrides, validated like the scenario file's.
        duration: another episode length [s].
        lane_change: another lane-change setting (``"default"``, ``"realistic"``).
        record: record every vehicle at every step.
        render_mode: highway-env's render mode.
        fast: the fast training variant (:class:`ScenarioEnv`; needs ``record=False``).
    """
    spec = get_scenario(scenario)
    if config or duration is not None or lane_change is not None:
        spec = spec.with_overrides(config, duration=duration, lane_change=lane_change)
    return ScenarioEnv(spec, render_mode=render_mode, record=record, fast=fast)


def find_scenario_env(env: gym.Env) -> ScenarioEnv:
    """The :class:`ScenarioEnv` (or :class:`~tap_bench.sim.womd_env.WomdEnv`) inside a stack
    of wrappers."""
    current = env
    while True:
        if isinstance(current, ScenarioEnv) or type(current).__name__ == "WomdEnv":
            return current  # (tap_bench/womd-v0 records and reports like a ScenarioEnv)
        inner = getattr(current, "env", None)
        if inner is None or inner is current:
            break
        current = inner
    raise TapBenchError(f"{env} is not a tap-bench scenario env; build it with "
                        "gymnasium.make('tap_bench/<scenario>-v0') or tap_bench.sim.make_env.")


def episode_trajectories(env: gym.Env, **columns: object) -> pd.DataFrame:
    """The trajectory table of the current (or just finished) episode of a scenario env,
    through any wrappers.

    Args:
        env: an env built by ``gymnasium.make("tap_bench/...")`` or :func:`make_env`.
        **columns: constant columns to add, e.g. ``policy="idm"``.
    """
    return find_scenario_env(env).trajectories(**columns)
