"""The old name of :mod:`tap_bench.sim.scenario_format` (the scenario file format), kept so
that ``from tap_bench.sim.suite import ...`` goes on working; import from
:mod:`tap_bench.sim.scenario_format` in new code. (Suites of scenarios and policies are
:mod:`tap_bench.bench.suite`.)
"""

from tap_bench.sim.scenario_format import (
    MAX_DURATION,
    MAX_SEED,
    MAX_SEEDS,
    SIMULATION_FREQUENCY,
    SIZE_LIMITS,
    VEHICLE_TYPE_KEYS,
    Scenario,
    check_config,
    load_scenario,
    parse_seeds,
    read_json,
    scenario_names,
    suite_dir,
)

__all__ = [
    "MAX_DURATION",
    "MAX_SEED",
    "MAX_SEEDS",
    "SIZE_LIMITS",
    "VEHICLE_TYPE_KEYS",
    "SIMULATION_FREQUENCY",
    "Scenario",
    "check_config",
    "load_scenario",
    "parse_seeds",
    "read_json",
    "scenario_names",
    "suite_dir",
]
