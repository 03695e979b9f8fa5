"""What a suite run will do: the suite read once into a plain plan (:class:`SuitePlan`) and one
task per (env, policy, seed), each env's scenario and each policy's definition resolved once
(part of :mod:`tap_bench.bench.run.runner`; how long it takes: :mod:`~tap_bench.bench.run.
estimate`)."""

from __future__ import annotations

import os
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from tap_bench.bench.cache import (
    ROAD_MAP,
    SCENE_MAP,
    EpisodeCache,
    episode_key,
    label_code,
    label_key,
    policy_fingerprint,
    scenario_fingerprint,
    simulation_fingerprint,
)
from tap_bench.bench.measures import MEASURES, Measure
from tap_bench.bench.suite import GateConfig, Suite, load_suite
from tap_bench.plugins import load_plugins, merge_plugins
from tap_bench.sim.policies import PolicyDefinition, expand_seed_groups
from tap_bench.sim.rollout import resolve_policy
from tap_bench.sim.sb3 import warn_untrusted_model
from tap_bench.sim.scenario_format import Scenario, parse_seeds
from tap_bench.sim.womd_scene import WomdScenes
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.thresholds import Thresholds, resolve_thresholds
from tap_bench.usercode import recording


@dataclass(frozen=True)
class _Task:
    """One episode of a suite run: what a worker needs, and nothing more (the scenario is
    resolved once, by the caller)."""

    env: str
    scenario: Scenario
    policy: str  # the policy's name
    definition: PolicyDefinition
    seed: int
    thresholds: Thresholds
    level: str
    keep_trajectories: bool
    cache: EpisodeCache | None = None
    key: str | None = None  # None: this episode is not cached (see bench.cache)
    key_doc: Mapping[str, Any] | None = None
    measures: tuple[str, ...] = ()  # the run's measures: the worker must have each
    label_key: str | None = None  # its labels and measures in the cache (bench.cache)
    label_doc: Mapping[str, Any] | None = None
    run: str = ""  # the run's id: what its code imports is noted under it (usercode)
    # the env's road (highway-env: a map table) as the run's process drew it, so that the
    # workers do not each build the env again to draw it; None: the worker draws it
    road: Any = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class SuitePlan:
    """A suite read once, before a run, into the plain values every later step of the run
    reads: no later step sees the suite, resolves a scenario, reads a policy file or the
    thresholds again, and every step sees the same measures.

    Attributes:
        name: the suite's name.
        envs: the env names, in the suite's order.
        scenarios: env -> its :class:`~tap_bench.sim.scenario_format.Scenario`, overrides
            applied (recorded scenes: its :class:`~tap_bench.sim.womd_scene.WomdScenes`).
        seeds: env -> the seeds it runs (recorded scenes: scenario indices in its files).
        definitions: each policy's definition, built once (a bad one fails here).
        reference: the reference policy's name.
        level: the SDL level scored.
        thresholds: the TAP thresholds.
        bootstrap: the interval settings.
        gate: the regression gate's settings, a margin for every measure of the run.
        measures: the run's measure entries, fixed after the plugins, the suite's plugins
            and the policies' own imports have registered theirs.
        plugins: the modules every worker imports before its first task (the execution
            layer carries them): those named on the command line and by the suite, and the
            modules that define the run's measures outside tap-bench.
        document: the suite as JSON (:meth:`~tap_bench.bench.suite.Suite.to_dict`, its
            gate margins filled): what ``summary.json`` records and the cache keys hold.
        suite_file: the file the suite was read from (None: built in Python).
        run: the run's id: the modules its policies, scenarios and measures import as
            they are built and run are noted under it (:func:`tap_bench.usercode.
            recording`) and kept with its cache entries.
    """

    name: str
    envs: tuple[str, ...]
    scenarios: Mapping[str, Scenario | WomdScenes]
    seeds: Mapping[str, tuple[int, ...]]
    definitions: tuple[PolicyDefinition, ...]
    reference: str
    level: str
    thresholds: Thresholds
    bootstrap: BootstrapConfig
    gate: GateConfig
    measures: tuple[Measure, ...]
    plugins: tuple[str, ...]
    document: Mapping[str, Any]
    suite_file: str | None = None
    run: str = field(default_factory=lambda: uuid.uuid4().hex)

    @property
    def recorded(self) -> bool:
        """Whether some env is recorded scenes (its scenario a :class:`~tap_bench.sim.
        womd_scene.WomdScenes`): the run spills its episodes' tables to disk and is never
        served whole from the cache. Read from the scenarios, as every step that reads an
        env's maps or keys its episodes tells recorded scenes, so that no flag can say
        otherwise."""
        return any(isinstance(s, WomdScenes) for s in self.scenarios.values())

    @property
    def measure_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.measures)

    @property
    def gate_metrics(self) -> tuple[str, ...]:
        """What the gate checks in this run: every measure and ``label_tv``."""
        return (*self.measure_names, "label_tv")


def plan_suite(suite: Suite | str | os.PathLike, *, plugins: Sequence[str] = (),
               seeds: str | Sequence[int] | None = None) -> SuitePlan:
    """Read ``suite`` once into a :class:`SuitePlan`: import the plugins (``plugins``, then
    the suite's), read the suite, resolve its scenarios, seeds, policies' definitions and
    thresholds, and fix the set of measures. A policy's SB3 model file that is not one of
    the shipped models warns here, once (:func:`tap_bench.sim.sb3.warn_untrusted_model`):
    the workers load models with warnings off.

    Raises:
        ParameterError: a plugin cannot be imported, or ``seeds`` is not a seed list.
        FileFormatError, UnknownNameError: the suite, a scenario or a policy is bad.
    """
    load_plugins(plugins)
    if isinstance(suite, Suite):  # built in Python: its plugins are not imported yet
        load_plugins(suite.plugins, source=f"suite {suite.name}")
    else:  # a suite file imports its plugins as it is read (they register its measures)
        suite = load_suite(suite)
    if seeds is not None:
        suite = replace(suite, seeds=tuple(parse_seeds(seeds, source="seeds")),
                        all_seeds=False)
    run = uuid.uuid4().hex
    # everything read from the suite, here and in one go; what the scenarios and policies
    # import as they are built is noted (the plugins' own code is keyed by the measures
    # and kinds they register)
    with recording(run):
        scenarios = {env: suite.scenario(env) for env in suite.envs}
        env_seeds = {env: suite.env_seeds(env) for env in suite.envs}
        # an agent of several training seeds (a policy of kind "seeds") runs as its seeds
        policies = expand_seed_groups(suite.policies)
        definitions = tuple(resolve_policy(policy) for policy in policies)
    measures = tuple(MEASURES)  # fixed here: after every import that may register one
    # margins of measures registered after the suite was read take their entry's default
    gate = replace(suite.gate, margins={**{m.name: float(m.margin) for m in measures},
                                        **suite.gate.margins})
    document = replace(suite, policies=policies, gate=gate).to_dict()
    thresholds = resolve_thresholds(suite.thresholds)
    _warn_untrusted_models(definitions)
    defined_in = (m.function.__module__ for m in measures if m.function is not None)
    outside = [name for name in defined_in
               if name != "__main__" and name.split(".")[0] != "tap_bench"]
    # recorded as loaded, so that every worker of the execution layer imports them first
    load_plugins(outside, source="measure")
    return SuitePlan(
        name=suite.name, envs=suite.envs, scenarios=scenarios, seeds=env_seeds,
        definitions=definitions, reference=document["reference_policy"],
        level=suite.level, thresholds=thresholds, bootstrap=suite.bootstrap, gate=gate,
        measures=measures, plugins=merge_plugins(plugins, suite.plugins, outside),
        document=document, suite_file=str(suite.path) if suite.path else None, run=run)


def _warn_untrusted_models(definitions: tuple[PolicyDefinition, ...]) -> None:
    """Warn, once each, of a policy's SB3 model file that is not one of the shipped models
    (the workers load models with warnings off)."""
    for d in definitions:
        if d.kind == "sb3" and isinstance(d.params.get("model"), str):
            model = Path(d.params["model"])
            if not model.is_absolute() and d.path is not None:
                model = d.path.parent / model
            warn_untrusted_model(model, stacklevel=4)


def _tasks(plan: SuitePlan, keep: bool, cache: EpisodeCache | None) -> list[_Task]:
    scenarios, thresholds, definitions = plan.scenarios, plan.thresholds, plan.definitions
    level, seeds = plan.level, plan.seeds
    common = {"measures": plan.measure_names, "run": plan.run}
    if cache is None:
        return [_Task(env, scenarios[env], d.name, d, seed, thresholds, level, keep, **common)
                for env in plan.envs for d in definitions for seed in seeds[env]]
    versions = simulation_fingerprint()
    envs = {env: _env_fingerprints(scenarios[env], env, seeds[env]) for env in plan.envs}
    policies = {d.name: policy_fingerprint(d) for d in definitions}
    code = label_code(plan.measures)
    made_by = thresholds.to_dict()
    tasks = []
    for env in plan.envs:
        for d in definitions:
            for seed in seeds[env]:
                key = doc = lkey = ldoc = None
                if policies[d.name] is not None and envs[env].get(seed) is not None:
                    key, doc = episode_key(envs[env][seed], policies[d.name], seed, versions)
                    lkey, ldoc = label_key(key, made_by, level, code,
                                           SCENE_MAP if isinstance(scenarios[env], WomdScenes)
                                           else ROAD_MAP)
                tasks.append(_Task(env, scenarios[env], d.name, d, seed, thresholds,
                                   level, keep, cache, key, doc, label_key=lkey,
                                   label_doc=ldoc, **common))
    return tasks


def _env_fingerprints(scenario: Scenario | WomdScenes, env: str, seeds: tuple[int, ...]
                      ) -> dict[int, dict[str, Any] | None]:
    """seed -> the env part of its episode key (None: not cached): the scenario's
    (:func:`~tap_bench.bench.cache.scenario_fingerprint`) for a synthetic env, the same for
    every seed; for recorded scenes, the env's name and each scenario's content hash and
    settings (a scenario that cannot be read is not cached; its episode reports why)."""
    if not isinstance(scenario, WomdScenes):
        return dict.fromkeys(seeds, scenario_fingerprint(scenario, env))
    catalog = scenario.catalog()
    out: dict[int, dict[str, Any] | None] = {}
    for seed in seeds:
        try:
            out[seed] = {"env": env, **scenario.fingerprint(catalog[seed])}
        except (IndexError, OSError, ValueError):
            out[seed] = None
    return out
