"""The simulation side: highway-env scenario envs, driving policies and rollouts.

Modules, by what they do:

- :mod:`~tap_bench.sim.suite`: scenario files (``envs/``), validated against highway-env;
- :mod:`~tap_bench.sim.registration`: Gymnasium ids ``tap_bench/<name>-vN``;
- :mod:`~tap_bench.sim.scenario_env`: the env those ids build, recording at 10 Hz;
- :mod:`~tap_bench.sim.observation`: highway-env's Kinematics observation without pandas;
- :mod:`~tap_bench.sim.recorder`: vehicles to a trajectory table in Waymo axes;
- :mod:`~tap_bench.sim.roads`: a scenario's road network as a map table;
- :mod:`~tap_bench.sim.vehicles`: lane-change settings, process-wide vehicle state;
- :mod:`~tap_bench.sim.policies`, :mod:`~tap_bench.sim.idm`, :mod:`~tap_bench.sim.sb3`:
  the Policy protocol, its registry and the built-ins;
- :mod:`~tap_bench.sim.rollout`: deterministic, process-parallel rollouts;
- :mod:`~tap_bench.sim.wrappers`: Gymnasium integration (episode labels).

Training agents and their behaviour-coverage learning curve are :mod:`tap_bench.rl`.

Names that need highway-env (``make_env``, ``ScenarioEnv``, ``EpisodeLabels`` ...) are
imported on first use, so ``import tap_bench`` stays fast.
"""

from __future__ import annotations

import importlib
from typing import Any

from tap_bench.sim.policies import (
    Policy,
    PolicyDefinition,
    available_policies,
    load_policy,
    register_policy,
)
from tap_bench.sim.registration import register_scenario, register_suite, registered_ids
from tap_bench.sim.rollout import EpisodeFailedWarning, Rollout, rollout, run_episode
from tap_bench.sim.suite import Scenario, load_scenario, parse_seeds, scenario_names

_LAZY = {
    "ScenarioEnv": "tap_bench.sim.scenario_env",
    "episode_trajectories": "tap_bench.sim.scenario_env",
    "get_scenario": "tap_bench.sim.scenario_env",
    "make_env": "tap_bench.sim.scenario_env",
    "EpisodeLabels": "tap_bench.sim.wrappers",
    "LANE_CHANGE_SETTINGS": "tap_bench.sim.vehicles",
}

__all__ = [
    # scenarios and envs
    "LANE_CHANGE_SETTINGS",
    "Scenario",
    "ScenarioEnv",
    "episode_trajectories",
    "get_scenario",
    "load_scenario",
    "make_env",
    "parse_seeds",
    "register_scenario",
    "register_suite",
    "registered_ids",
    "scenario_names",
    # policies
    "Policy",
    "PolicyDefinition",
    "available_policies",
    "load_policy",
    "register_policy",
    # rollouts and wrappers
    "EpisodeFailedWarning",
    "EpisodeLabels",
    "Rollout",
    "rollout",
    "run_episode",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tap_bench.sim' has no attribute {name!r}")
