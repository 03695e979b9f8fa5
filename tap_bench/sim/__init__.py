"""The simulation side: highway-env scenario envs, driving policies and rollouts.

Modules, by what they do:

- :mod:`~tap_bench.sim.scenario_format`: scenario files (``envs/``), validated against highway-env;
- :mod:`~tap_bench.sim.registration`: Gymnasium ids ``tap_bench/<name>-vN``;
- :mod:`~tap_bench.sim.scenario_env`: the env those ids build, recording at 10 Hz;
- :mod:`~tap_bench.sim.observation`: highway-env's Kinematics observation without pandas;
- :mod:`~tap_bench.sim.recorder`: vehicles to a trajectory table in Waymo axes;
- :mod:`~tap_bench.sim.roads`: a scenario's road network as a map table;
- :mod:`~tap_bench.sim.vehicles`: lane-change settings, process-wide vehicle state;
- :mod:`~tap_bench.sim.policies`, :mod:`~tap_bench.sim.idm`, :mod:`~tap_bench.sim.sb3`:
  the Policy protocol, its registry and the built-ins;
- :mod:`~tap_bench.sim.rollout`: deterministic, process-parallel rollouts;
- recorded WOMD scenes in closed loop (``tap_bench/womd-v0``):
  :mod:`~tap_bench.sim.womd_scene` (a scenario as arrays, :class:`WomdScenes`),
  :mod:`~tap_bench.sim.womd_lanes` (WOMD lanes as highway-env lanes, the compiled lane
  lookup), :mod:`~tap_bench.sim.womd_road` (network, vehicles, routes, signals),
  :mod:`~tap_bench.sim.womd_env` (the env);
- :mod:`~tap_bench.sim.wrappers`: Gymnasium integration (episode labels).

Training agents and their behaviour-coverage learning curve are :mod:`tap_bench.rl`.

Every name below is imported on first use (``tap_bench.sim.rollout`` imports the execution
layer, ``make_env`` Gymnasium and highway-env), so ``import tap_bench`` stays fast. highway-env
imports ``matplotlib.pyplot`` for one plotting helper (``highway_env.vehicle.dynamics``),
0.4 CPU s of each process that simulates; imported through tap-bench, it gets a module that
imports pyplot when that helper first uses it (:class:`_OnFirstUse`).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any, ClassVar

from tap_bench.importhooks import AroundImport

_LAZY_MODULES = {
    "tap_bench.sim.policies": ("Policy", "PolicyDefinition", "available_policies",
                               "load_policy", "register_policy", "register_policy_kind"),
    "tap_bench.sim.registration": ("register_scenario", "register_suite", "registered_ids"),
    "tap_bench.sim.rollout": ("EpisodeFailedWarning", "Rollout", "check_policy", "rollout",
                              "run_episode"),
    "tap_bench.sim.scenario_format": ("Scenario", "load_scenario", "parse_seeds", "scenario_names"),
    "tap_bench.sim.scenario_env": ("ScenarioEnv", "episode_trajectories", "get_scenario",
                                   "make_env"),
    "tap_bench.sim.wrappers": ("EpisodeLabels",),
    "tap_bench.sim.vehicles": ("LANE_CHANGE_SETTINGS",),
    "tap_bench.sim.womd_scene": ("WomdScenes",),
    "tap_bench.sim.womd_env": ("WomdEnv", "make_womd_env"),
}
_LAZY = {name: module for module, names in _LAZY_MODULES.items() for name in names}

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
    # recorded scenes
    "WomdEnv",
    "WomdScenes",
    "make_womd_env",
    # policies
    "Policy",
    "PolicyDefinition",
    "available_policies",
    "check_policy",
    "load_policy",
    "register_policy",
    "register_policy_kind",
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


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


class _Package(types.ModuleType):
    """``tap_bench.sim.rollout`` is the function that ``from tap_bench.sim import rollout``
    promises, also after its submodule has been imported: the import system then sets the
    package's attribute of that name to the submodule, which is refused here (the
    submodule stays in ``sys.modules``, where ``from tap_bench.sim.rollout import X``
    finds it)."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _LAZY and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


class _OnFirstUse(types.ModuleType):
    """Stands in for a module (``matplotlib``, ``matplotlib.pyplot``) while highway-env is
    imported, and imports the real one when an attribute is first asked of it."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):  # the import system probing a module
            raise AttributeError(name)
        _HighwayEnvImport.restore()
        return getattr(importlib.import_module(self.__name__), name)


class _HighwayEnvImport(AroundImport):
    """Imports ``highway_env`` (the first time, only while ``matplotlib`` is not imported)
    with :class:`_OnFirstUse` modules in place of ``matplotlib`` and ``matplotlib.pyplot``,
    which it removes again from ``sys.modules`` as soon as highway-env is imported: code
    that imports matplotlib later gets the real one, and highway-env's helper its stand-in,
    which imports the real pyplot on first use. It never changes the list ``sys.meta_path``
    in place (see :mod:`tap_bench.importhooks`)."""

    target = "highway_env"
    STANDS_IN = ("matplotlib", "matplotlib.pyplot")
    placed: ClassVar[list[types.ModuleType]] = []

    def wanted(self) -> bool:
        return not any(m in sys.modules for m in self.STANDS_IN)

    def exec_module(self, module: types.ModuleType) -> None:
        self.leave_meta_path()
        plt, mpl = _OnFirstUse("matplotlib.pyplot"), _OnFirstUse("matplotlib")
        mpl.pyplot = plt
        type(self).placed = [mpl, plt]
        sys.modules.update({"matplotlib": mpl, "matplotlib.pyplot": plt})
        try:
            self.real.exec_module(module)
            self.step_aside(module)  # highway-env's own loader again
        finally:
            self.restore()

    @classmethod
    def restore(cls) -> None:
        """Take the stand-ins out of ``sys.modules`` (where still there)."""
        for module in cls.placed:
            if sys.modules.get(module.__name__) is module:
                del sys.modules[module.__name__]
        cls.placed = []


if "highway_env" not in sys.modules:
    sys.meta_path.insert(0, _HighwayEnvImport())
