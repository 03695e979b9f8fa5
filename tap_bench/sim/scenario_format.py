"""The scenario suite as data: one JSON file per scenario in ``envs/``.

A scenario file names a highway-env environment, overrides some of its configuration and
fixes the episode length and the default seeds::

    {
      "name": "highway",                  # the scenario; the Gymnasium id is tap_bench/highway-v0
      "version": 0,                       # bump it whenever the scenario's behaviour changes
      "highway_env_id": "highway-v0",     # a highway-env Gymnasium id
      "description": "...",
      "duration": 40,                     # episode length [s] (simulated time)
      "default_seeds": "0-49",            # seeds used when none are given ("0-49", "3,5,8-9")
      "lane_change": "default",           # "default" or "realistic" (tap_bench.sim.vehicles)
      "config": {"lanes_count": 4, ...}   # highway-env config overrides
    }

Every file is validated against the environment's own defaults: an unknown field or config
key is an error that names the file, the key and the closest known keys; so is a value of the
wrong type. ``simulation_frequency`` is always 10 Hz (the rate of the trajectory table) and
``policy_frequency`` must divide it, so every decision lasts a whole number of recorded steps.
"""

from __future__ import annotations

import copy
import functools
import json
import math
import operator
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tap_bench import catalogue
from tap_bench.errors import FileFormatError, ParameterError, TapBenchError, did_you_mean
from tap_bench.sim.schema import SPACES, default_config, space_parameters
from tap_bench.sim.vehicles import LANE_CHANGE_SETTINGS

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

SIMULATION_FREQUENCY = 10  # = tap_bench.trajectories.HZ, not imported: it brings pandas
"""Simulation rate of every scenario [Hz]: one simulated step is one trajectory-table row."""

_FIELDS = ("name", "version", "highway_env_id", "description", "duration", "default_seeds",
           "lane_change", "config", "script")
_REQUIRED = ("name", "version", "highway_env_id", "duration", "config")
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
# Keys the scenario file owns itself: highway-env's own copies are set from them.
_OWNED_KEYS = {
    "duration": "set the top-level field \"duration\" (seconds) instead",
    "simulation_frequency": "it is always 10 Hz, the rate of the trajectory table",
    "controlled_vehicles": "tap-bench records exactly one ego vehicle",
}


def suite_dir(kind: str) -> Path:
    """The last (built-in, or ``$TAP_BENCH_SUITE``) folder of ``kind`` files (``"envs"`` or
    ``"policies"``); :mod:`tap_bench.catalogue` searches every folder."""
    return catalogue.roots()[-1] / catalogue.KINDS[kind]


def _seeds_error(source: str, spec: object, message: str) -> ParameterError:
    return ParameterError(source, spec, "seeds as '0-49', '1,4,7', an int or a list",
                          message=message)


MAX_SEEDS = 100_000
"""The most seeds one seed list may name: 100,000 episodes per (env, policy) is more than a
thousand times the default suite's 30, and each episode's tables are held in memory. A
longer list is refused before anything is built (``"0-999999999"`` once took 21 GB)."""
MAX_SEED = 2**63 - 1
"""The largest seed: seeds are stored as 64-bit integers in every table."""


def parse_seeds(spec: str | int | list[int] | range, *, source: str = "seeds") -> list[int]:
    """Seeds from ``"0-49"``, ``"3,5,8-9"``, an int, a list or a range.

    The count is known from the ranges before a single seed is made, so a huge range costs
    nothing to refuse.

    Returns:
        the seeds in the order given, duplicates refused.

    Raises:
        ParameterError: naming ``source`` and the part that is not a seed or a range of
            seeds, a seed given twice, or more than :data:`MAX_SEEDS` seeds.
    """
    if isinstance(spec, bool):
        raise _seeds_error(source, spec, f"{source}: {spec!r} is not a seed; "
                                         f"give an int, '0-49' or '1,4,7'.")
    ranges: list[range] = []
    if isinstance(spec, int):
        ranges = [range(spec, spec + 1)]
    elif isinstance(spec, range):
        ranges = [spec]
    elif isinstance(spec, list | tuple):
        if len(spec) > MAX_SEEDS:
            raise _too_many(source, f"{len(spec):,} seeds", len(spec))
        for s in spec:
            try:
                if isinstance(s, bool):
                    raise TypeError(s)
                ranges.append(range(operator.index(s), operator.index(s) + 1))
            except TypeError:
                raise _seeds_error(source, spec, f"{source}: {s!r} in the list is not an "
                                   "integer seed.") from None
    elif isinstance(spec, str):
        for part in spec.replace(" ", "").split(","):
            match = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
            if not match:
                raise _seeds_error(source, spec, f"{source}: {part!r} in {spec!r} is not a seed "
                                   "or a range; write seeds as '0-49' (inclusive) or '1,4,7' "
                                   "(non-negative).")
            lo = int(match.group(1))
            hi = int(match.group(2)) if match.group(2) else lo
            if hi < lo:
                raise _seeds_error(source, spec, f"{source}: range {part!r} runs backwards; "
                                                 f"write '{hi}-{lo}'.")
            ranges.append(range(lo, hi + 1))
    else:
        raise _seeds_error(source, spec, f"{source}: {spec!r} is not a seed list; "
                                         f"give '0-49', an int or a list.")
    count = sum(len(r) for r in ranges)
    if count > MAX_SEEDS:
        raise _too_many(source, spec if isinstance(spec, str) else f"{count:,} seeds", count)
    if count == 0:
        raise _seeds_error(source, spec, f"{source}: no seeds given.")
    low = min(r.start for r in ranges if len(r))
    high = max(r[-1] for r in ranges if len(r))
    if low < 0:
        raise _seeds_error(source, spec, f"{source}: seeds must be non-negative, got {low}.")
    if high > MAX_SEED:
        raise _seeds_error(source, spec, f"{source}: seed {high} is larger than {MAX_SEED} "
                                         "(2^63 - 1), the largest a table stores.")
    seeds = [s for r in ranges for s in r]
    if len(set(seeds)) != len(seeds):
        seen: set[int] = set()
        dup = next(s for s in seeds if s in seen or seen.add(s))
        raise _seeds_error(source, spec if isinstance(spec, str) else f"{count:,} seeds",
                           f"{source}: seed {dup} is given twice; each seed is one episode.")
    return seeds


def _too_many(source: str, value: object, count: int) -> ParameterError:
    return ParameterError(
        source, value, f"at most {MAX_SEEDS:,} seeds", message=(
            f"{source}: {count:,} seeds, more than the maximum of {MAX_SEEDS:,} "
            "(tap_bench.sim.scenario_format.MAX_SEEDS) in one list; run the seeds in several lists "
            "(say '0-99999', then '100000-199999')."))


MAX_DURATION = 3600.0
"""The longest episode a scenario may ask for [s] of simulated time: an hour is 36,000 rows
per vehicle, 120 times the default suite's longest episode (a duration of 1e9 s never
ended)."""
SIZE_LIMITS: Mapping[str, int] = {"vehicles_count": 1000, "lanes_count": 50}
"""The largest value of highway-env config keys that size the scene: each costs time and
memory at every step (100,000 vehicles hung the simulator in its first reset)."""
VEHICLE_TYPE_KEYS = ("other_vehicles_type",)
"""highway-env config keys naming a vehicle class that highway-env imports by name: checked
as code before any import (:mod:`tap_bench.usercode`)."""


_AT_MOST = f"at most {MAX_SEEDS:,} seeds (tap_bench.sim.scenario_format.MAX_SEEDS)"
_SPLIT = "Run the seeds in several lists (say '0-99999', then '100000-199999')."


@dataclass(frozen=True)
class Scenario:
    """One validated scenario of the suite.

    Attributes:
        name: short name (``highway``); the Gymnasium id is :attr:`env_id`.
        version: the ``-vN`` of the id.
        highway_env_id: the highway-env environment it configures.
        description: one line for ``tap-bench envs``.
        duration: episode length [s].
        default_seeds: seeds used when a caller gives none.
        lane_change: name of the lane-change setting (see :mod:`tap_bench.sim.vehicles`).
        overrides: the highway-env config overrides of the file, validated.
        path: the file it was read from (None when built in code).
        script: a scripted event (a cut-in, a braking leader; :mod:`tap_bench.sim.scripts`).
    """

    name: str
    version: int
    highway_env_id: str
    duration: float
    overrides: Mapping[str, Any]
    description: str = ""
    default_seeds: tuple[int, ...] = tuple(range(10))
    lane_change: str = "default"
    path: Path | None = field(default=None, compare=False)
    script: Any = None  # tap_bench.sim.scripts.Script (imported where a scenario has one)

    @property
    def env_id(self) -> str:
        """The Gymnasium id, ``tap_bench/<name>-v<version>``."""
        return f"tap_bench/{self.name}-v{self.version}"

    @property
    def config(self) -> dict[str, Any]:
        """The full highway-env config overrides: :attr:`overrides` plus the keys the suite
        owns (``simulation_frequency`` 10 Hz, ``duration``, one controlled vehicle)."""
        full = copy.deepcopy(dict(self.overrides))
        full.setdefault("policy_frequency",
                        default_config(self.highway_env_id)["policy_frequency"])
        full["simulation_frequency"] = SIMULATION_FREQUENCY
        full["duration"] = self.duration
        full["controlled_vehicles"] = 1
        return full

    @property
    def env_config(self) -> dict[str, Any]:
        """The config the env runs with: highway-env's defaults of :attr:`highway_env_id`
        updated with :attr:`config` (a fresh dict)."""
        full = default_config(self.highway_env_id)
        full.update(self.config)
        return full

    @property
    def policy_frequency(self) -> int:
        """Decisions per simulated second [Hz]."""
        return int(self.config["policy_frequency"])

    @property
    def max_steps(self) -> int:
        """Decisions (``env.step`` calls) in an episode that runs to its time limit."""
        return round(self.duration * self.policy_frequency)

    def with_overrides(self, config: Mapping[str, Any] | None = None, *,
                       duration: float | None = None, lane_change: str | None = None
                       ) -> Scenario:
        """A copy with more config overrides, another duration or lane-change setting,
        validated as a scenario file is."""
        merged = copy.deepcopy(dict(self.overrides))
        defaults = default_config(self.highway_env_id)
        for key, value in (config or {}).items():
            if (key in ("observation", "action") and isinstance(value, Mapping)
                    and "type" not in value):
                # highway-env replaces the whole dict: keep the type and the other settings
                merged[key] = {**(merged.get(key) or defaults[key]), **value}
            else:
                merged[key] = copy.deepcopy(value)
        return _build(
            {"name": self.name, "version": self.version, "highway_env_id": self.highway_env_id,
             "description": self.description,
             "duration": self.duration if duration is None else duration,
             "default_seeds": list(self.default_seeds),
             "lane_change": self.lane_change if lane_change is None else lane_change,
             "config": merged,
             **({"script": self.script.to_dict()} if self.script is not None else {})},
            source=f"{self.env_id} overrides", path=self.path)


@functools.cache
def _type_name(value: Any) -> str:
    return {bool: "true/false", int: "a number", float: "a number", str: "a string",
            list: "a list", dict: "an object"}.get(type(value), type(value).__name__)


def _check_value(key: str, value: Any, default: Any, where: str) -> None:
    if default is None or value is None:
        return
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int | float):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    elif isinstance(default, list | tuple):
        ok = isinstance(value, list | tuple)
    elif isinstance(default, dict):
        ok = isinstance(value, dict)
    else:
        ok = True
    if not ok:
        raise FileFormatError(f"{where}: {key!r} is {value!r}, but highway-env expects "
                              f"{_type_name(default)} (default {default!r}).")


def _check_space(key: str, value: Any, default: Any, where: str) -> None:
    if not isinstance(value, dict):
        raise FileFormatError(f"{where}: {key!r} must be an object with a \"type\", got "
                              f"{value!r}.")
    kind = value.get("type", (default or {}).get("type"))
    if kind is None:
        raise FileFormatError(f"{where}: {key!r} needs a \"type\"; one of "
                              f"{', '.join(sorted(space_parameters(key)))}.")
    if kind.startswith("MultiAgent"):
        raise FileFormatError(f"{where}: {key} type {kind!r} drives several egos; tap-bench "
                              "records one ego per episode. Use a single-agent type.")
    parameters = space_parameters(key)
    if kind not in parameters:
        raise FileFormatError(f"{where}: {did_you_mean(f'{key} type', kind, parameters)}")
    allowed = parameters[kind]
    if isinstance(default, dict) and default.get("type") == kind:
        # the environment's own default passes keys its class takes through **kwargs
        # (intersection-v0's Kinematics has "flatten"): they are valid by definition
        allowed = allowed | set(default)
    for sub in value:
        if sub not in allowed:
            raise FileFormatError(
                f"{where}: {key}: {did_you_mean(f'{kind} parameter', sub, allowed)}")


def check_config(highway_env_id: str, config: Mapping[str, Any], *, source: str = "config"
                 ) -> None:
    """Check config overrides against the defaults of the highway-env environment.

    Args:
        highway_env_id: the highway-env id (``"highway-v0"``).
        config: the overrides.
        source: where they come from, for the message (a file path).

    Raises:
        FileFormatError: naming the key, with "did you mean", for an unknown key, a value of
            the wrong type, an unknown observation or action type or parameter.
    """
    defaults = default_config(highway_env_id)
    where = f"{source} ({highway_env_id})"
    for key, value in config.items():
        if key in _OWNED_KEYS:
            raise FileFormatError(f"{where}: config key {key!r} is not allowed here: "
                                  f"{_OWNED_KEYS[key]}.")
        if key not in defaults:
            raise FileFormatError(
                f"{where}: {did_you_mean('highway-env config key', key, defaults)}")
        if key in SPACES:
            _check_space(key, value, defaults[key], where)
        else:
            _check_value(key, value, defaults[key], where)
    for key, limit in SIZE_LIMITS.items():
        value = config.get(key)
        if (isinstance(value, int | float) and not isinstance(value, bool)
                and not value <= limit):
            raise ParameterError(key, value, f"at most {limit:,}", message=(
                f"{where}: {key} {value!r} is larger than the limit of {limit:,} "
                "(tap_bench.sim.scenario_format.SIZE_LIMITS); a scene that size takes hours "
                "a step."))
    for key in VEHICLE_TYPE_KEYS:
        if isinstance(config.get(key), str):
            from tap_bench.usercode import check_class_name

            check_class_name(config[key], key, separator=".", source=where)
    freq = config.get("policy_frequency", defaults.get("policy_frequency"))
    if (not isinstance(freq, int) or isinstance(freq, bool) or freq <= 0
            or SIMULATION_FREQUENCY % freq):
        raise FileFormatError(f"{where}: policy_frequency {freq!r} must be a whole divisor of "
                              f"the {SIMULATION_FREQUENCY} Hz simulation: 1, 2, 5 or 10.")


def _build(doc: Any, *, source: str, path: Path | None) -> Scenario:
    if not isinstance(doc, dict):
        raise FileFormatError(f"{source}: a scenario file holds one JSON object, got "
                              f"{type(doc).__name__}.")
    for key in doc:
        if key not in _FIELDS:
            raise FileFormatError(f"{source}: {did_you_mean('scenario field', key, _FIELDS)}")
    missing = [k for k in _REQUIRED if k not in doc]
    if missing:
        raise FileFormatError(f"{source}: missing field(s) {', '.join(map(repr, missing))}; "
                              f"a scenario needs {', '.join(_REQUIRED)}.")
    name = doc["name"]
    if not isinstance(name, str) or not _NAME.match(name):
        raise FileFormatError(f"{source}: name {name!r} must be lower case letters, digits and "
                              "underscores, starting with a letter (it becomes the env id).")
    version = doc["version"]
    if not isinstance(version, int) or isinstance(version, bool) or version < 0:
        raise FileFormatError(f"{source}: version {version!r} must be a non-negative integer.")
    duration = doc["duration"]
    if (not isinstance(duration, int | float) or isinstance(duration, bool)
            or not math.isfinite(duration) or duration <= 0):
        raise FileFormatError(f"{source}: duration {duration!r} must be a positive number of "
                              "seconds.")
    if duration > MAX_DURATION:
        raise ParameterError("duration", duration, f"at most {MAX_DURATION:g} s", message=(
            f"{source}: duration {duration!r} s is longer than the limit of {MAX_DURATION:g} "
            "s (tap_bench.sim.scenario_format.MAX_DURATION) of simulated time per episode."))
    lane_change = doc.get("lane_change", "default")

    if lane_change not in LANE_CHANGE_SETTINGS:
        err = did_you_mean("lane-change setting", lane_change, LANE_CHANGE_SETTINGS)
        raise FileFormatError(f"{source}: {err}")
    try:
        seeds = tuple(parse_seeds(doc.get("default_seeds", "0-9"), source="default_seeds"))
    except ValueError as err:
        raise FileFormatError(f"{source}: {err}") from err
    config = doc["config"]
    if not isinstance(config, dict):
        raise FileFormatError(f"{source}: config must be an object of highway-env settings.")
    check_config(doc["highway_env_id"], config, source=source)
    script = None
    if "script" in doc:
        from tap_bench.sim.scripts import Script  # imported where a scenario has a script

        script = Script.from_dict(doc["script"], source=source)
    scenario = Scenario(name=name, version=version, highway_env_id=doc["highway_env_id"],
                        duration=float(duration), overrides=copy.deepcopy(config),
                        description=str(doc.get("description", "")), default_seeds=seeds,
                        lane_change=lane_change, path=path, script=script)
    steps = duration * scenario.policy_frequency
    if abs(steps - round(steps)) > 1e-9:
        raise FileFormatError(f"{source}: duration {duration} s is not a whole number of "
                              f"decisions at policy_frequency {scenario.policy_frequency} Hz.")
    return scenario


def read_json(path: Path, what: str) -> dict[str, Any]:
    """The JSON object of a suite file (``what``: "scenario", "policy").

    Raises:
        FileFormatError: unreadable, not JSON, or not one object, naming the file.
    """
    try:
        doc = json.loads(path.read_text())
    except OSError as err:
        raise FileFormatError(f"{path}: cannot read the {what} file: {err}") from err
    except json.JSONDecodeError as err:
        raise FileFormatError(f"{path}: not valid JSON: {err}") from err
    if not isinstance(doc, dict):
        raise FileFormatError(f"{path}: a {what} file holds one JSON object, got "
                              f"{type(doc).__name__}.")
    return doc


def load_scenario(path: str | os.PathLike) -> Scenario:
    """Read and validate one scenario file.

    Raises:
        FileFormatError: the file is missing, is not JSON, or breaks the format above.
    """
    path = Path(path)
    scenario = _build(read_json(path, "scenario"), source=str(path), path=path)
    if scenario.name != path.stem:
        raise FileFormatError(f"{path}: name {scenario.name!r} differs from the file name; "
                              f"rename the file to {scenario.name}.json or fix the name.")
    return scenario


def scenario_names(folder: str | os.PathLike | None = None) -> list[str]:
    """Names of the scenario files in ``folder`` (default: the suite's ``envs/``)."""
    if folder:
        return sorted(p.stem for p in Path(folder).glob("*.json"))
    return sorted(catalogue.files("envs"))


@functools.lru_cache(maxsize=64)
def _load_cached(path: str, mtime: float) -> Scenario:
    return load_scenario(path)


def get_scenario(name: str | os.PathLike | Scenario) -> Scenario:
    """A scenario by name (``"highway"``), Gymnasium id (``"tap_bench/highway-v0"``) or the
    path of a scenario file (also :func:`tap_bench.sim.scenario_env.get_scenario`; here,
    away from Gymnasium, so that resolving a suite does not import it).

    Raises:
        UnknownNameError: no such scenario, with the closest names.
        FileFormatError: the file breaks the scenario format.
    """
    if isinstance(name, Scenario):
        return name
    text = str(name)
    path = Path(text)
    if text.endswith(".json"):
        if not path.is_file():
            raise FileFormatError(f"{path}: no such scenario file.")
    else:
        short = text.removeprefix("tap_bench/")
        base, _, version = short.rpartition("-v")
        if base and version.isdigit():
            short = base
        else:
            version = None
        known = scenario_names()
        if short not in known:
            raise did_you_mean("scenario", text, known)
        path = catalogue.files("envs")[short]
        scenario = _load_cached(str(path), path.stat().st_mtime)
        if version is not None and int(version) != scenario.version:
            raise TapBenchError(f"scenario {text!r}: the suite has {scenario.env_id}; version "
                                f"{version} is not available.")
        return scenario
    return _load_cached(str(path), path.stat().st_mtime)
