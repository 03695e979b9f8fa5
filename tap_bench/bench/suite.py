"""Benchmark suites as data: which envs, policies and seeds a run covers, and how it is scored.

A suite is a JSON file in ``envs/suites/`` (beside the scenario files it names; with
``$TAP_BENCH_SUITE`` set, in ``$TAP_BENCH_SUITE/envs/suites/``)::

    {
      "name": "default", "version": 0,
      "description": "every scenario x every built-in policy",
      "envs": ["highway", "merge"],                 # scenario names (tap-bench envs)
      "policies": ["idm", "idm-aggressive"],        # policy names (tap-bench policies)
      "seeds": "0-29",                              # every policy meets the same seeds
      "reference_policy": "idm",                    # compared with every other policy;
                                                    # its ego labels are the coverage reference
      "level": "maneuver",                          # SDL level scored
      "thresholds": "paper",                        # TAP thresholds (preset or JSON file)
      "env_overrides": {"highway": {"duration": 15, "config": {"vehicles_count": 10}}},
      "bootstrap": {"n_resamples": 2000, "level": 0.95, "seed": 0},
      "gate": {"alpha": 0.05, "n_permutations": 9999, "seed": 0,
               "margins": {"crashed": 0.1, "mean_speed": 1.0, "label_tv": 0.2}},
      "plugins": ["my_measures"]                    # modules registering your own measures,
                                                    # formats or policy kinds (imported first,
                                                    # and in every worker)
    }

Every field but ``name``, ``envs``, ``policies`` and ``seeds`` has the default shown in
:class:`Suite` (``plugins``: none). Unknown fields, envs and policies are refused with
"did you mean".

**Recorded scenes.** An entry of ``envs`` may name WOMD data instead of a synthetic scene
(``tap_bench/womd-v0``, SPEC section 8)::

    "envs": [{"womd": "data/scenes/*.tfrecord", "traffic": "log"}],
    "policies": ["log", "idm"], "reference_policy": "log", "seeds": "all"

``womd`` is a path, a glob pattern or a list of them (relative to the suite file's folder);
``traffic`` is ``log`` (default) or ``idm``; ``ego`` ``sdc`` (default) or a track id;
``name`` the env's name in the tables (default ``womd`` for log traffic, ``womd-idm`` for
idm). A seed is a scenario's index in the files, so episodes pair by scenario, and
``"seeds": "all"`` runs every scenario (allowed when every env is recorded scenes). The
policy ``log`` is the human who drove the scene.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tap_bench import catalogue, sdl
from tap_bench.bench.measures import MEASURES
from tap_bench.errors import (
    FileFormatError,
    ParameterError,
    RegistrationError,
    UnknownNameError,
    did_you_mean,
)
from tap_bench.plugins import load_plugins
from tap_bench.sim.policies import available_policies
from tap_bench.sim.scenario_format import get_scenario, parse_seeds, read_json, scenario_names
from tap_bench.sim.womd_scene import TRAFFIC, WomdScenes
from tap_bench.stats.bootstrap import BootstrapConfig

__all__ = ["GateConfig", "Suite", "available_suites", "default_margins",
           "default_weights", "gate_metrics", "load_suite", "suite_from_dict"]

MAX_PERMUTATIONS = 100_000
"""The most permutations the gate's test may ask for (ten times the default 9999)."""
LABEL_TV_MARGIN = 0.20
"""Default margin of ``label_tv``, the total variation distance of label distributions."""


def gate_metrics() -> tuple[str, ...]:
    """What the regression gate checks per (env, policy): every registered measure's mean
    (:data:`~tap_bench.bench.measures.MEASURES`) and ``label_tv``, the total variation
    distance between the ego label distributions of the run and of the baseline."""
    return (*MEASURES.names(), "label_tv")


def default_margins() -> dict[str, float]:
    """metric -> default gate margin: each measure's registered margin, and label_tv's."""
    return {**MEASURES.margins(), "label_tv": LABEL_TV_MARGIN}


def default_weights() -> dict[str, float]:
    """metric -> the gate's default weight (share of alpha within a cell): each registered
    measure's own ``gate_weight`` where it has one, the rest split equally.

    The built-in safety family takes 0.85 of alpha, and the crash rate most of it (0.65;
    min TTC and min headway 0.1 each), since a rate carries the least information per seed:
    its exact paired test reaches 1/2^k when k seeds turn to a crash, and 0.65 x 0.05 =
    0.0325 lets k = 5 fire (0.6 would need 6). Every other metric shares the remaining 0.15
    equally; a mean changes on every seed of a changed policy, so its small share still
    fires. Chosen by ``benchmarks/gate_calibration.py`` (docs/benchmark.md,
    "Multiplicity").

    Raises:
        RegistrationError: the measures' own weights add up to 1 or more (nothing left
            for the other metrics).
    """
    metrics = gate_metrics()
    own = {m.name: float(m.gate_weight) for m in MEASURES
           if m.gate_weight is not None and m.name in metrics}
    rest = [m for m in metrics if m not in own]
    left = 1.0 - sum(own.values())
    if rest and left <= 0:
        raise RegistrationError(
            f"the measures' gate weights ({', '.join(f'{k} {v:g}' for k, v in own.items())}) "
            "leave no share of alpha for the other metrics; lower a gate_weight.")
    return {**own, **{m: round(left / len(rest), 12) for m in rest}} if rest else own


_FIELDS = ("name", "version", "description", "envs", "policies", "seeds", "reference_policy",
           "level", "thresholds", "env_overrides", "bootstrap", "gate", "plugins")
_OVERRIDE_FIELDS = ("duration", "config", "lane_change")
_SCENE_FIELDS = ("womd", "traffic", "ego", "name", "policy_frequency")
_GATE_FIELDS = ("alpha", "n_permutations", "seed", "margins", "weights", "detect")


@dataclass(frozen=True)
class GateConfig:
    """How ``bench check`` decides that a metric moved.

    A metric of one (env, policy) fails when it moved the worse way (the measure's
    registered direction; for ``label_tv`` any change) by more than its margin **and** a
    one-sided permutation test rejects "no change" at ``alpha`` after the weighted Holm
    correction over every test of the check (:func:`tap_bench.bench.gate.regression.weighted_holm`).
    A move the better way by more than the margin is reported, never a failure.

    Attributes:
        margins: metric -> largest worsening tolerated (absolute, in the metric's unit).
        alpha: family-wise error rate of the gate.
        n_permutations: permutations per test (enough that the correction can reach alpha).
        seed: seed of the permutations.
        weights: metric -> share of alpha within a cell (:func:`default_weights`; relative,
            positive).
        detect: the worsening the gate must catch with 80 % power, in margins (2.5: a crash
            rate 25 points higher with the 0.10 margin); a check that cannot is
            underpowered.
    """

    margins: Mapping[str, float] = field(default_factory=default_margins)
    alpha: float = 0.05
    n_permutations: int = 9999
    seed: int = 0
    weights: Mapping[str, float] = field(default_factory=default_weights)
    detect: float = 2.5

    def __post_init__(self) -> None:
        if not isinstance(self.margins, Mapping):
            raise ValueError(f"gate margins must be an object metric -> margin, got "
                             f"{self.margins!r}.")
        for name, value, kind in (("alpha", self.alpha, "a number"),
                                  ("n_permutations", self.n_permutations, "an integer"),
                                  ("seed", self.seed, "an integer")):
            allowed = (int, float) if kind == "a number" else (int,)
            if isinstance(value, bool) or not isinstance(value, allowed):
                raise ValueError(f"gate {name} must be {kind}, got {value!r} "
                                 f"({type(value).__name__}).")
        metrics = gate_metrics()
        for key in self.margins:
            if key not in metrics:
                raise did_you_mean("gate metric", key, metrics)
        # every metric has a margin: those not given take their registered default
        object.__setattr__(self, "margins", {**default_margins(), **self.margins})
        for key, value in self.margins.items():
            if (not isinstance(value, int | float) or isinstance(value, bool)
                    or not math.isfinite(value) or value < 0):
                raise ParameterError(f"gate margin {key!r}", value, "a finite number >= 0")
        if not isinstance(self.weights, Mapping):
            raise ValueError(f"gate weights must be an object metric -> weight, got "
                             f"{self.weights!r}.")
        for key in self.weights:
            if key not in metrics:
                raise did_you_mean("gate metric", key, metrics)
        object.__setattr__(self, "weights", {**default_weights(), **self.weights})
        for key, value in self.weights.items():
            if (not isinstance(value, int | float) or isinstance(value, bool)
                    or not 0 < value < float("inf")):
                raise ParameterError(f"gate weight {key!r}", value, "a number > 0 (a metric "
                                     "with no share of alpha would never be checked)")
        if (isinstance(self.detect, bool) or not isinstance(self.detect, int | float)
                or not 1 <= self.detect < float("inf")):
            raise ParameterError("gate detect", self.detect, "a number of margins >= 1")
        if (isinstance(self.alpha, bool) or not isinstance(self.alpha, int | float)
                or not 0 < self.alpha < 1):
            raise ParameterError("gate alpha", self.alpha, "a number in (0, 1)")
        if (isinstance(self.n_permutations, bool) or not isinstance(self.n_permutations, int)
                or self.n_permutations < 99):
            raise ParameterError("gate n_permutations", self.n_permutations, "an integer >= 99")
        if self.n_permutations > MAX_PERMUTATIONS:
            raise ParameterError(
                "gate n_permutations", self.n_permutations, f"at most {MAX_PERMUTATIONS:,}",
                message=f"gate n_permutations {self.n_permutations:,} is more than the limit "
                f"of {MAX_PERMUTATIONS:,} (tap_bench.bench.suite.MAX_PERMUTATIONS): the "
                "smallest p-value is 1/(n+1) already at 1e-5, and memory grows with n.")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ParameterError("gate seed", self.seed, "a non-negative integer")

    def margin(self, metric: str) -> float:
        """The margin of ``metric``: the one given, else its registered default (a measure
        registered after this config was made, by a plugin, has its entry's margin).

        Raises:
            UnknownNameError: ``metric`` is not a gate metric (with "did you mean").
        """
        if metric in self.margins:
            return float(self.margins[metric])
        defaults = default_margins()
        if metric not in defaults:
            raise did_you_mean("gate metric", metric, defaults)
        return float(defaults[metric])

    def to_dict(self) -> dict[str, Any]:
        return {"alpha": self.alpha, "n_permutations": self.n_permutations, "seed": self.seed,
                "margins": dict(self.margins), "weights": dict(self.weights),
                "detect": self.detect}

    def weight(self, metric: str) -> float:
        """The weight of ``metric``: the one given, else its default (a measure registered
        after this config was made, by a plugin, shares the non-safety part)."""
        if metric in self.weights:
            return float(self.weights[metric])
        defaults = default_weights()
        if metric not in defaults:
            raise did_you_mean("gate metric", metric, defaults)
        return float(defaults[metric])

    def share(self, metric: str) -> float:
        """``metric``'s share of alpha within one (env, policy) cell (weights normalised
        over the gate metrics registered now)."""
        return self.weight(metric) / sum(self.weight(m) for m in gate_metrics())


@dataclass(frozen=True)
class Suite:
    """A validated benchmark suite (see the module docstring for the file format).

    Attributes:
        name, version, description: identity.
        envs: scenario names.
        policies: policy names.
        seeds: the seeds every policy runs in every env.
        reference_policy: the policy every other one is compared with, whose ego labels
            are the coverage reference (None: the first policy).
        level: the SDL level scored.
        thresholds: a thresholds preset name or JSON path.
        env_overrides: env -> {"duration": s, "config": {...}, "lane_change": name}.
        bootstrap: interval settings.
        gate: regression-gate settings.
        plugins: modules that register the suite's own measures, data formats or policy
            kinds (:mod:`tap_bench.plugins`): imported before the suite is checked, and by
            every worker of a run before its first task.
        path: the file it was read from.
        scenes: env name -> recorded WOMD scenes, for the envs that name WOMD data.
        all_seeds: ``"seeds": "all"``: every scenario of each recorded-scene env.
    """

    name: str
    envs: tuple[str, ...]
    policies: tuple[str, ...]
    seeds: tuple[int, ...]
    version: int = 0
    description: str = ""
    reference_policy: str | None = None
    level: str = "maneuver"
    thresholds: str = "paper"
    env_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    bootstrap: BootstrapConfig = field(default_factory=BootstrapConfig)
    gate: GateConfig = field(default_factory=GateConfig)
    plugins: tuple[str, ...] = ()
    path: Path | None = field(default=None, compare=False)
    scenes: Mapping[str, WomdScenes] = field(default_factory=dict)
    all_seeds: bool = False

    @property
    def reference(self) -> str:
        """The reference policy's name."""
        return self.reference_policy or self.policies[0]

    def scenario(self, env: str):
        """The env's :class:`tap_bench.sim.Scenario` with this suite's overrides, or its
        :class:`~tap_bench.sim.womd_scene.WomdScenes` for recorded scenes."""
        if env in self.scenes:
            return self.scenes[env]
        scenario = get_scenario(env)
        over = self.env_overrides.get(env)
        if over:
            scenario = scenario.with_overrides(over.get("config"), duration=over.get("duration"),
                                               lane_change=over.get("lane_change"))
        return scenario

    def road(self, env: str):
        """The env's map table (:mod:`tap_bench.maps`): highway-env's road (one per env), or
        the maps of recorded scenes (one per scenario, ``map_id`` its scenario id)."""
        if env in self.scenes:
            from tap_bench.sources.maps import read_maps

            return read_maps(self.scenes[env].files)
        from tap_bench.sim.roads import road_table

        return road_table(self.scenario(env))

    def env_seeds(self, env: str) -> tuple[int, ...]:
        """The seeds ``env`` runs: the suite's, or with ``"seeds": "all"`` the index of
        every scenario of its files."""
        if env in self.scenes:  # "all", or seeds within the files
            return self.scenes[env].seeds("all" if self.all_seeds else list(self.seeds))
        return self.seeds

    def to_dict(self) -> dict[str, Any]:
        """The suite as the JSON it was (or could have been) read from, defaults filled."""
        envs = [{"womd": list(self.scenes[e].files), "traffic": self.scenes[e].traffic,
                 "ego": self.scenes[e].ego, "name": e,
                 "policy_frequency": self.scenes[e].policy_frequency}
                if e in self.scenes else e for e in self.envs]
        return {"name": self.name, "version": self.version, "description": self.description,
                "envs": envs, "policies": list(self.policies),
                "seeds": "all" if self.all_seeds else list(self.seeds),
                "reference_policy": self.reference,
                "level": self.level, "thresholds": self.thresholds,
                "env_overrides": {k: dict(v) for k, v in self.env_overrides.items()},
                "bootstrap": {"n_resamples": self.bootstrap.n_resamples,
                              "level": self.bootstrap.level, "seed": self.bootstrap.seed},
                "gate": self.gate.to_dict(), "plugins": list(self.plugins)}


def suites_dir() -> Path:
    """The built-in folder of suite files (``envs/suites/``); :func:`available_suites` also
    lists those of ``$TAP_BENCH_PATH`` (:mod:`tap_bench.catalogue`)."""
    return catalogue.roots()[-1] / catalogue.KINDS["suites"]


def available_suites() -> list[str]:
    """Names of the suite files of every catalogue folder."""
    return sorted(catalogue.files("suites"))


def _strings(doc: Mapping[str, Any], key: str, source: str) -> tuple[str, ...]:
    value = doc[key]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise FileFormatError(f"{source}: {key!r} must be a non-empty list of names, got "
                              f"{value!r}.")
    if len(set(value)) != len(value):
        dup = next(v for v in value if value.count(v) > 1)
        raise FileFormatError(f"{source}: {key!r} names {dup!r} twice.")
    return tuple(value)


def suite_from_dict(doc: Any, *, source: str = "suite", path: Path | None = None,
                    check_names: bool = True) -> Suite:
    """Validate a suite document (the parsed JSON).

    Args:
        doc: the document.
        source: where it came from, for messages.
        path: the file, when there is one.
        check_names: check the envs and policies exist (needs highway-env's registry).

    Raises:
        FileFormatError: naming the field, the bad value and what is allowed.
    """
    if not isinstance(doc, dict):
        raise FileFormatError(f"{source}: a suite file holds one JSON object.")
    for key in doc:
        if key not in _FIELDS:
            raise FileFormatError(f"{source}: {did_you_mean('suite field', key, _FIELDS)}")
    missing = [k for k in ("name", "envs", "policies", "seeds") if k not in doc]
    if missing:
        raise FileFormatError(f"{source}: missing field(s) {', '.join(map(repr, missing))}; a "
                              "suite needs name, envs, policies and seeds.")
    plugins = doc.get("plugins", [])
    if not isinstance(plugins, list) or not all(isinstance(v, str) for v in plugins):
        raise FileFormatError(f"{source}: 'plugins' must be a list of module names "
                              f"(\"my_package.measures\"), got {plugins!r}.")
    try:  # first: the plugins register the measures the gate margins may name
        plugins = load_plugins(plugins, source=source)
    except ParameterError as err:
        raise FileFormatError(str(err)) from err
    envs, scenes = _envs(doc, source, path)
    policies = _strings(doc, "policies", source)
    all_seeds = doc["seeds"] == "all"
    if all_seeds and len(scenes) < len(envs):
        raise FileFormatError(f"{source}: seeds 'all' means every scenario of recorded scenes; "
                              "synthetic envs need seeds such as '0-29'.")
    try:
        seeds = () if all_seeds else tuple(parse_seeds(doc["seeds"],
                                                       source=f"{source}: seeds"))
    except ValueError as err:
        raise FileFormatError(str(err)) from err
    level = doc.get("level", "maneuver")
    if level not in sdl.LEVELS:
        raise FileFormatError(f"{source}: {did_you_mean('level', level, sdl.LEVELS)}")
    reference = doc.get("reference_policy")
    if reference is not None and reference not in policies:
        raise FileFormatError(f"{source}: reference_policy {reference!r} is not one of the "
                              f"suite's policies ({', '.join(policies)}).")
    overrides = doc.get("env_overrides", {})
    if not isinstance(overrides, dict):
        raise FileFormatError(f"{source}: env_overrides must be an object env -> overrides.")
    for env, over in overrides.items():
        if env not in envs:
            raise FileFormatError(f"{source}: env_overrides names {env!r}, which is not in "
                                  f"envs ({', '.join(envs)}).")
        if not isinstance(over, dict):
            raise FileFormatError(f"{source}: env_overrides[{env!r}] must be an object.")
        for key in over:
            if key not in _OVERRIDE_FIELDS:
                err = did_you_mean("env override", key, _OVERRIDE_FIELDS)
                raise FileFormatError(f"{source}: env_overrides[{env!r}]: {err}")
    try:
        boot = BootstrapConfig(**doc.get("bootstrap", {}))
    except (TypeError, ValueError) as err:
        raise FileFormatError(f"{source}: bootstrap: {err} (fields: n_resamples, level, "
                              "seed).") from err
    gate_doc = doc.get("gate", {})
    for key in gate_doc:
        if key not in _GATE_FIELDS:
            raise FileFormatError(f"{source}: gate: "
                                  f"{did_you_mean('gate field', key, _GATE_FIELDS)}")
    try:
        margins = {**default_margins(), **gate_doc.get("margins", {})}
        gate = GateConfig(**{**gate_doc, "margins": margins})
    except (TypeError, ValueError, UnknownNameError) as err:
        raise FileFormatError(f"{source}: gate: {err}") from err
    cells = len(envs) * len(policies)
    metric = min(gate_metrics(), key=gate.share)
    reach = gate.alpha * gate.share(metric) / cells  # its level when every cell is tested
    if 1.0 / (gate.n_permutations + 1) > reach * (1 + 1e-9):  # other seeds: never fires
        need = math.ceil(1.0 / reach - 1 - 1e-9)
        raise FileFormatError(
            f"{source}: gate: {len(envs)} envs x {len(policies)} policies = {cells} cells "
            f"x {len(gate_metrics())} metrics = {cells * len(gate_metrics())} tests: "
            f"{metric} (share {gate.share(metric):.3g} of alpha {gate.alpha:g} per cell) "
            f"is tested at {reach:.3g} when the seeds differ from the baseline's, but with "
            f"n_permutations {gate.n_permutations} no p-value is below "
            f"1/{gate.n_permutations + 1} = {1 / (gate.n_permutations + 1):.3g}: that metric "
            f"could never fire. Set gate.n_permutations to at least {need}.")
    thresholds = doc.get("thresholds", "paper")
    if not isinstance(thresholds, str):
        raise FileFormatError(f"{source}: thresholds must be a preset name or a JSON path.")
    if path is not None and thresholds.endswith(".json") and not os.path.isabs(thresholds):
        thresholds = str((path.parent / thresholds).resolve())
    version = doc.get("version", 0)
    if isinstance(version, bool) or not isinstance(version, int) or version < 0:
        raise FileFormatError(f"{source}: version must be a non-negative integer (the suite's "
                              f"version, raised when it changes), got {version!r}.")
    suite = Suite(name=str(doc["name"]), version=version,
                  description=str(doc.get("description", "")), envs=envs, policies=policies,
                  seeds=seeds, reference_policy=reference, level=level, thresholds=thresholds,
                  env_overrides=overrides, bootstrap=boot, gate=gate, plugins=plugins,
                  path=path, scenes=scenes, all_seeds=all_seeds)
    if check_names:
        _check_names(suite, source)
    return suite


def _envs(doc: Mapping[str, Any], source: str, path: Path | None
          ) -> tuple[tuple[str, ...], dict[str, WomdScenes]]:
    """The env names of a suite and the recorded scenes among them (module docstring)."""
    value = doc["envs"]
    if not isinstance(value, list) or not value:
        raise FileFormatError(f"{source}: 'envs' must be a non-empty list of scenario names "
                              f"or recorded scenes ({{\"womd\": \"PATH\"}}), got {value!r}.")
    names, scenes = [], {}
    for k, item in enumerate(value):
        if isinstance(item, str):
            names.append(item)
            continue
        where = f"{source}: envs[{k}]"
        if not isinstance(item, dict) or "womd" not in item:
            raise FileFormatError(f"{where}: an env is a scenario name or an object with "
                                  f"'womd' (files of recorded scenes), got {item!r}.")
        for key in item:
            if key not in _SCENE_FIELDS:
                raise FileFormatError(f"{where}: {did_you_mean('field', key, _SCENE_FIELDS)}")
        files = item["womd"] if isinstance(item["womd"], list) else [item["womd"]]
        if not files or not all(isinstance(f, str) and f for f in files):
            raise FileFormatError(f"{where}: 'womd' must be a path or pattern (or a list of "
                                  f"them), got {item['womd']!r}.")
        if path is not None:
            files = [f if os.path.isabs(f) else str(path.parent / f) for f in files]
        traffic = item.get("traffic", "log")
        if traffic not in TRAFFIC:
            raise FileFormatError(f"{where}: {did_you_mean('traffic', str(traffic), TRAFFIC)}")
        name = item.get("name", "womd" if traffic == "log" else f"womd-{traffic}")
        try:
            scenes[name] = WomdScenes(tuple(files), traffic=traffic,
                                      ego=str(item.get("ego", "sdc")),
                                      policy_frequency=item.get("policy_frequency", 2),
                                      name=name)
        except ValueError as err:
            raise FileFormatError(f"{where}: {err}") from err
        names.append(name)
    if len(set(names)) != len(names):
        dup = next(v for v in names if names.count(v) > 1)
        raise FileFormatError(f"{source}: 'envs' names {dup!r} twice; give recorded scenes "
                              "their own \"name\".")
    return tuple(names), scenes


def _check_names(suite: Suite, source: str) -> None:
    known_envs = scenario_names()
    for env in suite.envs:
        if env in suite.scenes:
            try:
                if not suite.scenes[env].catalog():
                    raise FileFormatError("no scenario in these files")
                suite.env_seeds(env)  # seeds beyond the files: refused up front
            except (FileFormatError, ValueError, OSError) as err:
                raise FileFormatError(f"{source}: env {env!r}: {err}") from err
            continue
        if env not in known_envs:
            raise FileFormatError(f"{source}: {did_you_mean('env', env, known_envs)}")
    known = available_policies()
    for policy in suite.policies:
        if policy not in known and not Path(policy).suffix:
            raise FileFormatError(f"{source}: {did_you_mean('policy', policy, known)}")
    for env in suite.env_overrides:
        try:
            suite.scenario(env)
        except (FileFormatError, ValueError) as err:
            raise FileFormatError(f"{source}: env_overrides[{env!r}]: {err}") from err


def load_suite(name_or_path: str | os.PathLike) -> Suite:
    """A suite by name (``default``, a file of :func:`suites_dir`) or by JSON path.

    Raises:
        UnknownNameError: no suite of that name (with the closest names).
        FileFormatError: the file is not JSON or breaks the format.
    """
    text = str(name_or_path)
    path = Path(text)
    if not text.endswith(".json"):
        found = catalogue.find("suites", text)
        if found is None:
            raise did_you_mean("suite", text, available_suites())
        path = found

    return suite_from_dict(read_json(path, "suite"), source=str(path), path=path)
