"""``bench run``: roll out every policy of a suite in every env over its seeds, label, score,
and write ``results/<run>/``.

What a run folder holds:

======================  ====================================================================
``summary.json``        suite, seeds, thresholds, level, versions, machine, timings, failed
                        episodes, the interval methods, headline figures, and the
                        provenance: each policy's full definition (with the SHA-256 of a
                        model file) and each env's resolved config
``episodes.parquet``    the episode table (:mod:`tap_bench.bench.episodes`), failed
                        episodes included with their error
``labels.parquet``      TAP labels of every track at every level
``trajectories.parquet``  the rollouts (unless ``keep_trajectories`` is False)
``segments.parquet``    the segment table (label timelines) of every track at the suite's
                        level
``roads.parquet``       each env's road network as a map table (:mod:`tap_bench.maps`), for
                        the replay viewer (with the trajectories)
``<table>.parquet``     every table of :class:`tap_bench.bench.scoring.Scores`
``plots/*.png``         label distributions, measures, coverage, forest plots, novelty
``report.html``         the static report (no server, images embedded)
``viewer/``             the replay viewer (:mod:`tap_bench.bench.viewer`; with the trajectories)
``.tap-bench-folder``   the marker that lets ``--overwrite`` replace the folder
======================  ====================================================================

The folder is built under a temporary name beside the target and renamed into place only
when complete, so an interrupted run leaves nothing that looks finished; an existing run
folder is never replaced unless ``overwrite`` is given, and then only when tap-bench wrote
it (its marker is there): any other folder, a file or a link is refused. Episodes run as
tasks of :mod:`tap_bench.execution` (local worker processes or Ray), one task per (env,
policy, seed), each labelling its own episode; an episode that fails is recorded with its
error and left out of the scores, and an episode whose worker dies is tried once more and
then recorded as failed: one bad episode never costs another. A run where every episode
failed is an error (:class:`~tap_bench.errors.EpisodesFailedError`), not an empty result.

With an episode cache (:mod:`tap_bench.bench.cache`), an episode whose inputs did not change
is read instead of simulated; labels, measures and scores are always recomputed, so a run
with the cache gives the same tables as one without. Before the episodes start, the run
estimates how long it will take, from the cache's timings of earlier runs or by timing a
first episode of each env.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.cache import (
    EpisodeCache,
    episode_key,
    policy_fingerprint,
    scenario_fingerprint,
    simulation_fingerprint,
)
from tap_bench.bench.episodes import episode_table
from tap_bench.bench.gap import behaviour_gap, labelled_with_speed
from tap_bench.bench.power import power_table
from tap_bench.bench.report import write_report
from tap_bench.bench.scenarios import match_scenarios
from tap_bench.bench.scoring import Scores, score
from tap_bench.bench.suite import Suite, gate_metrics, load_suite
from tap_bench.bench.viewer import write_run_viewer
from tap_bench.errors import (
    EpisodesFailedError,
    FileFormatError,
    LabelTableError,
    ParameterError,
    RunExistsError,
)
from tap_bench.execution import Backend, resolve_backend
from tap_bench.labelling import tap
from tap_bench.labels import validate_labels
from tap_bench.sim.policies import PolicyDefinition, get_definition
from tap_bench.sim.roads import road_table
from tap_bench.sim.rollout import EPISODE_COLUMNS, resolve_policy, rollout_episode
from tap_bench.sim.suite import Scenario, parse_seeds
from tap_bench.sources import read_womd
from tap_bench.tableio import atomic_folder, atomic_path, check_folder_output, read_table
from tap_bench.thresholds import Thresholds, resolve_thresholds

__all__ = ["CACHED_BATCH", "CACHED_EPISODE_S", "RunExistsError", "RunPlan", "RunResult",
           "check_output", "package_versions", "provenance", "read_run", "run_suite",
           "run_viewer", "write_results"]

def check_output(output: str | os.PathLike, overwrite: bool) -> Path:
    """``output`` as a Path, checked before any work (:func:`tap_bench.tableio.
    check_folder_output`): a new folder in a writable place, or, with ``overwrite``, a run
    folder tap-bench wrote.

    Raises:
        RunExistsError: naming the folder and the flag that replaces it.
        OutputPathError: the place is not writable, or ``output`` is a file, a link or a
            folder tap-bench did not write.
    """
    return check_folder_output(output, overwrite)


@dataclass(frozen=True)
class RunResult:
    """What :func:`run_suite` returns.

    Attributes:
        folder: the run folder written.
        summary: the content of ``summary.json``.
        episodes: the episode table.
        scores: the scored tables.
        report: path of ``report.html``.
    """

    folder: Path
    summary: dict[str, Any]
    episodes: pd.DataFrame
    scores: Scores
    report: Path


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


def _run_task(task: _Task) -> dict[str, Any]:
    """Roll out (or read from the cache), label and measure one episode (in a worker)."""
    t0 = time.perf_counter()
    cached = task.cache.get(task.key) if task.cache is not None and task.key else None
    if cached is not None:
        trajectories, row = cached.trajectories, cached.row
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            trajectories, row = rollout_episode(task.scenario, task.definition, task.seed)
        if row["status"] == "ok" and task.cache is not None and task.key:
            with contextlib.suppress(OSError):  # a full or read-only cache costs only reuse
                task.cache.put(task.key, task.key_doc or {}, trajectories, row,
                               time.perf_counter() - t0)
    trajectories = trajectories.reset_index(drop=True)
    episodes = pd.DataFrame([row], columns=list(EPISODE_COLUMNS))
    episodes["seed"] = episodes["seed"].astype(np.int64)
    t1 = time.perf_counter()
    labels = segments = pd.DataFrame()
    if len(trajectories):
        result = tap(trajectories, task.thresholds, interactions="ego",
                     source=f"{task.env}/{task.policy} rollout")
        labels = result.labels("all")
        segments = result.segments(task.level)
    t2 = time.perf_counter()
    eps = episode_table(labels=labels if len(labels) else None,
                        trajectories=trajectories if len(trajectories) else None,
                        episodes=episodes, level=task.level, policy=task.policy)
    t3 = time.perf_counter()
    timings = {"rollout": t1 - t0, "labelling": t2 - t1, "measures": t3 - t2}
    return {"episodes": eps, "labels": labels, "segments": segments,
            "trajectories": trajectories if task.keep_trajectories else None,
            "timings": timings, "cached": cached is not None}


def _failed_task(task: _Task, message: str) -> dict[str, Any]:
    eps = pd.DataFrame({"env": [task.env], "policy": [task.policy], "seed": [task.seed],
                        "status": ["error"], "error": [message]})
    return {"episodes": episode_table(episodes=eps, level=task.level),
            "labels": pd.DataFrame(), "segments": pd.DataFrame(), "trajectories": None,
            "timings": {}, "cached": False}


CACHED_BATCH = 30
"""Cached episodes of one env and policy labelled and measured together, in one task: TAP
and the measures cost mostly per call on tables of one episode (about 0.1 s each), so a
batch of 30 costs about what three single episodes do. The tables are the same."""


@dataclass(frozen=True)
class _CachedBatch:
    """Cached episodes of one env and policy (``tasks``), read, labelled and measured in
    one worker call; an entry that fails its checks is simulated there instead."""

    tasks: tuple[_Task, ...]


def _run_batch(batch: _CachedBatch) -> list[dict[str, Any]]:
    """One result per task of ``batch``, equal to what :func:`_run_task` gives for each."""
    t0 = time.perf_counter()
    first = batch.tasks[0]
    entries = [task.cache.get(task.key) if task.cache is not None and task.key else None
               for task in batch.tasks]
    found = [(task, entry) for task, entry in zip(batch.tasks, entries, strict=True)
             if entry is not None]
    results: dict[int, dict[str, Any]] = {}
    if found:
        trajectories = pd.concat([e.trajectories for _, e in found], ignore_index=True)
        rows = pd.DataFrame([e.row for _, e in found], columns=list(EPISODE_COLUMNS))
        rows["seed"] = rows["seed"].astype(np.int64)
        t1 = time.perf_counter()
        result = tap(trajectories, first.thresholds, interactions="ego",
                     source=f"{first.env}/{first.policy} rollout")
        labels, segments = result.labels("all"), result.segments(first.level)
        t2 = time.perf_counter()
        eps = episode_table(labels=labels, trajectories=trajectories, episodes=rows,
                            level=first.level, policy=first.policy)
        t3 = time.perf_counter()
        share = {"rollout": (t1 - t0) / len(found), "labelling": (t2 - t1) / len(found),
                 "measures": (t3 - t2) / len(found)}
        # one episode's rows, in the order its own tap and episode_table calls give them
        by_episode = {name: _split(table, "scenario_id")
                      for name, table in (("labels", labels), ("segments", segments),
                                          ("trajectories", trajectories))}
        eps_by_seed = _split(eps, "seed")
        for task, entry in found:
            sid = entry.trajectories["scenario_id"].iat[0]
            results[task.seed] = {
                "episodes": eps_by_seed[task.seed],
                "labels": by_episode["labels"].get(sid, pd.DataFrame()),
                "segments": by_episode["segments"].get(sid, pd.DataFrame()),
                "trajectories": by_episode["trajectories"][sid]
                if task.keep_trajectories else None,
                "timings": dict(share), "cached": True}
    return [results.get(task.seed) or _run_task(task) for task in batch.tasks]


def _split(table: pd.DataFrame, column: str) -> dict[Any, pd.DataFrame]:
    """``table``'s rows by value of ``column``, each in table order with a fresh index."""
    return {key: part.reset_index(drop=True)
            for key, part in table.groupby(column, sort=False, observed=True)}


def _run_item(item: _Task | _CachedBatch) -> list[dict[str, Any]]:
    """A task of the backend: one episode, or a batch of cached ones."""
    return _run_batch(item) if isinstance(item, _CachedBatch) else [_run_task(item)]


def _items(tasks: list[_Task], indices: list[int], cached: list[bool]
           ) -> list[tuple[list[int], _Task | _CachedBatch]]:
    """The work items of ``tasks[indices]``: each episode to simulate alone, cached ones
    of one env and policy in batches of up to :data:`CACHED_BATCH`."""
    items: list[tuple[list[int], _Task | _CachedBatch]] = []
    groups: dict[tuple[str, str], list[int]] = {}
    for i in indices:
        if cached[i]:
            groups.setdefault((tasks[i].env, tasks[i].policy), []).append(i)
        else:
            items.append(([i], tasks[i]))
    for members in groups.values():
        for start in range(0, len(members), CACHED_BATCH):
            chunk = members[start:start + CACHED_BATCH]
            items.append((chunk, _CachedBatch(tuple(tasks[i] for i in chunk))))
    return items


def _tasks(suite: Suite, thresholds: Thresholds, keep: bool, cache: EpisodeCache | None
           ) -> list[_Task]:
    scenarios = {env: suite.scenario(env) for env in suite.envs}  # resolved once
    definitions = [resolve_policy(policy) for policy in suite.policies]  # built once here
    if cache is None:
        return [_Task(env, scenarios[env], d.name, d, seed, thresholds, suite.level, keep)
                for env in suite.envs for d in definitions for seed in suite.seeds]
    versions = simulation_fingerprint()
    envs = {env: scenario_fingerprint(scenarios[env]) for env in suite.envs}
    policies = {d.name: policy_fingerprint(d) for d in definitions}
    tasks = []
    for env in suite.envs:
        for d in definitions:
            for seed in suite.seeds:
                key = doc = None
                if policies[d.name] is not None:
                    key, doc = episode_key(envs[env], policies[d.name], seed, versions)
                tasks.append(_Task(env, scenarios[env], d.name, d, seed, thresholds,
                                   suite.level, keep, cache, key, doc))
    return tasks


CACHED_EPISODE_S = 0.03
"""Estimate of a cached episode's worker time (read, verify, label and measure, in batches)
when no run has measured it yet [s]: 0.028 s in the default suite on the 2-core
development machine (``benchmarks/bench_incremental.py``)."""


@dataclass(frozen=True)
class RunPlan:
    """What a run will do and how long it should take, said before it starts.

    Attributes:
        episodes: episodes of the suite.
        cached: episodes found in the cache (checked when read).
        simulate: episodes to simulate.
        workers: processes the episodes are spread over.
        seconds: estimated wall time of the episodes' work [s] (NaN when unknown).
        overhead_seconds: estimated rest of the run: worker start-up, scoring, the report
            [s] (NaN when no run has measured it).
        basis: where the per-episode times come from, in words.
    """

    episodes: int
    cached: int
    simulate: int
    workers: int
    seconds: float
    overhead_seconds: float
    basis: str

    def describe(self, suite: str) -> str:
        """One line for the user: ``suite default: 750 episodes (600 cached, 150 to
        simulate) on 2 workers: about 4 min (...)``."""
        if math.isfinite(self.seconds):
            known = math.isfinite(self.overhead_seconds)
            total = self.seconds + (self.overhead_seconds if known else 0.0)
            when = f"about {_duration(total)}" + ("" if known else
                                                  " plus start-up, scoring and the report")
        else:
            when = "no estimate yet"
        return (f"suite {suite}: {self.episodes} episodes ({self.cached} cached, "
                f"{self.simulate} to simulate) on {self.workers} worker(s): {when} "
                f"({self.basis})")


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _plan(tasks: list[_Task], cached: list[bool], workers: int, known: Mapping[str, Any],
          measured: Mapping[str, float]) -> RunPlan:
    simulated = {**known.get("simulated", {}), **measured}
    per_hit = known.get("cached", {})
    fallback_hit = (float(np.mean(list(per_hit.values()))) if per_hit
                    else CACHED_EPISODE_S)
    total, unknown = 0.0, 0
    for task, hit in zip(tasks, cached, strict=True):
        if hit:
            total += per_hit.get(task.env, fallback_hit)
        elif task.env in simulated:
            total += simulated[task.env]
        else:
            unknown += 1
    n_hit = sum(cached)
    if unknown:
        seconds = float("nan")
    else:
        seconds = total / max(1, min(workers, len(tasks)))
    parts = []
    if measured:
        parts.append(f"timed a first episode of {', '.join(sorted(measured))}")
    if known.get("simulated") or known.get("cached"):
        parts.append("per-episode times of earlier runs in the cache")
    if unknown:
        parts.append(f"{unknown} episode(s) of envs whose first episode failed")
    return RunPlan(len(tasks), n_hit, len(tasks) - n_hit, workers, seconds,
                   float(known.get("overhead", float("nan"))),
                   "; ".join(parts) or "cached episodes only")


def _rollouts(suite: Suite, thresholds: Thresholds, backend: Backend, keep: bool,
              progress: bool | None, cache: EpisodeCache | None,
              announce: Callable[[str], None] | None
              ) -> tuple[list[dict[str, Any]], RunPlan]:
    """Every episode of the suite as a task on ``backend`` (one recovery rule: an episode
    whose worker died is tried once more, then recorded as failed), cached episodes read
    rather than simulated. Before the tasks start, ``announce`` gets the run's estimate,
    from the cache's timings or from a first episode of each env without one."""
    tasks = _tasks(suite, thresholds, keep, cache)
    cached = [cache is not None and t.key is not None and cache.contains(t.key)
              for t in tasks]
    known = cache.timings() if cache is not None else {}
    probes, seen = [], set(known.get("simulated", {}))
    for i, (task, hit) in enumerate(zip(tasks, cached, strict=True)):
        if announce is not None and not hit and task.env not in seen:  # no one to tell: no probe
            probes.append(i)
            seen.add(task.env)
    results: dict[int, dict[str, Any]] = {}
    seconds: dict[int, float] = {}
    measured: dict[str, float] = {}
    if probes:
        if announce is not None:
            announce(f"timing a first episode of {len(probes)} env(s) for the estimate ...")
        outcomes = backend.map(_run_task, [tasks[i] for i in probes], progress=False)
        for i, outcome in zip(probes, outcomes, strict=True):
            results[i] = outcome.value if outcome.ok else _failed_task(tasks[i], outcome.error)
            seconds[i] = outcome.seconds
            if outcome.ok:
                measured[tasks[i].env] = outcome.seconds
    plan = _plan(tasks, cached, backend.workers, known, measured)
    if announce is not None:
        announce(plan.describe(suite.name))
    items = _items(tasks, [i for i in range(len(tasks)) if i not in results], cached)
    outcomes = backend.map(_run_item, [item for _, item in items], unit="task",
                           progress=progress, desc=f"bench {suite.name} ({backend.name})")
    for (indices, _), outcome in zip(items, outcomes, strict=True):
        values = outcome.value if outcome.ok else [
            _failed_task(tasks[i], outcome.error) for i in indices]
        for i, value in zip(indices, values, strict=True):
            results[i] = value
            seconds[i] = outcome.seconds / len(indices)
    out = [results[i] for i in range(len(tasks))]
    for i, result in enumerate(out):
        result["seconds"] = seconds[i]
        result["env"] = tasks[i].env
    return out, plan


def _observed_timings(results: list[dict[str, Any]]) -> tuple[dict[str, float],
                                                              dict[str, float]]:
    """Mean wall time per episode by env [s]: (simulated, cached), successful ones only."""
    simulated: dict[str, list[float]] = {}
    cached: dict[str, list[float]] = {}
    for r in results:
        if (r["episodes"]["status"] == "ok").all() and math.isfinite(r["seconds"]):
            (cached if r["cached"] else simulated).setdefault(r["env"], []).append(
                r["seconds"])
    return ({env: float(np.mean(v)) for env, v in simulated.items()},
            {env: float(np.mean(v)) for env, v in cached.items()})


def package_versions() -> dict[str, str]:
    """Versions of tap-bench and the packages its results depend on."""
    from importlib import metadata

    out = {}
    for pkg in ("tap-bench", "numpy", "pandas", "pyarrow", "gymnasium", "highway-env",
                "matplotlib", "stable-baselines3", "torch"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            continue
    return out


def _machine() -> dict[str, Any]:
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = []
    return {"cores": os.cpu_count(), "load_avg": load, "python": sys.version.split()[0]}


def run_suite(suite: Suite | str | os.PathLike, output: str | os.PathLike, *,
              workers: int = 2, womd: Sequence[str | os.PathLike] | None = None,
              references: Mapping[str, ReferenceSource] | None = None,
              keep_trajectories: bool = True, overwrite: bool = False,
              progress: bool | None = None, report: bool = True,
              backend: Backend | None = None, seeds: str | Sequence[int] | None = None,
              cache: EpisodeCache | str | os.PathLike | None = None,
              announce: Callable[[str], None] | None = None) -> RunResult:
    """Run a benchmark suite and write its run folder.

    Args:
        suite: a :class:`Suite`, a suite name (``default``) or a suite JSON path.
        output: the run folder to create (``results/run-001``).
        workers: rollout processes (1: in this process).
        womd: WOMD files (TFRecord or ScenarioNet pickles): shorthand for
            ``references={"WOMD": womd}``.
        references: more coverage and novelty references, by name: a label table
            (DataFrame, or a .parquet/.csv label file), or driving-data files of any
            registered format (a path or a list of paths), which are labelled with the
            suite's thresholds and also matched scenario by scenario against the episodes.
        keep_trajectories: also write ``trajectories.parquet``.
        overwrite: replace an existing run folder.
        progress: progress bar (None: only on a terminal).
        report: write the plots and ``report.html``.
        backend: run the episodes as tasks on this :class:`tap_bench.execution.Backend`
            (a Ray cluster, say) instead of ``workers`` local processes; the tables are the
            same.
        seeds: run these seeds instead of the suite's (``"0-4"``, a list).
        cache: an :class:`~tap_bench.bench.cache.EpisodeCache` or its folder: episodes
            found there are read instead of simulated, new ones are stored, and the cache is
            pruned to its size bound afterwards (None: simulate everything, store nothing).
            The tables are the same either way.
        announce: called with one line saying how many episodes will be simulated and how
            long the run should take, before the episodes start (the CLI prints it); to
            estimate an env no earlier run timed, its first episode runs first. None: no
            estimate.

    Returns:
        :class:`RunResult`.

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
        EpisodesFailedError: every episode failed (naming the first errors); nothing is
            written.
    """
    suite = suite if isinstance(suite, Suite) else load_suite(suite)
    if seeds is not None:
        suite = dataclasses.replace(suite, seeds=tuple(parse_seeds(seeds, source="seeds")))
    if cache is not None and not isinstance(cache, EpisodeCache):
        cache = EpisodeCache(Path(cache))
    output = check_output(output, overwrite)
    runner = resolve_backend(backend, workers)
    thresholds = resolve_thresholds(suite.thresholds)
    timings: dict[str, float] = {}
    t_start = time.perf_counter()
    sources = dict(references or {})
    if womd:
        if "WOMD" in sources:
            raise ParameterError("references", sorted(sources), "names other than 'WOMD' "
                                 "when womd= is given (womd= is references={'WOMD': ...})")
        sources["WOMD"] = list(womd)
    t0 = time.perf_counter()
    corpora = {name: _reference(name, source, suite) for name, source in sources.items()}
    if corpora:
        timings["references"] = time.perf_counter() - t0
    with_trajectories = any(traj is not None for traj, _ in corpora.values())

    t0 = time.perf_counter()
    results, plan = _rollouts(suite, thresholds, runner,
                              keep_trajectories or with_trajectories, progress, cache, announce)
    timings["rollouts_wall"] = time.perf_counter() - t0
    if not any((r["episodes"]["status"] == "ok").all() for r in results):
        errors = [f"{row.env} {row.policy} seed {row.seed}: {row.error}"
                  for r in results for row in r["episodes"].itertuples()]
        raise EpisodesFailedError(f"the {len(results)} episode(s) of suite {suite.name}",
                                  errors)
    for key in ("rollout", "labelling", "measures"):
        timings[f"{key}_cpu_in_workers"] = sum(r["timings"].get(key, 0.0) for r in results)
    episodes = pd.concat([r["episodes"] for r in results], ignore_index=True)
    episodes = episodes.sort_values(["env", "policy", "seed"], kind="stable")
    episodes = episodes.reset_index(drop=True)
    labels = pd.concat([r["labels"] for r in results if len(r["labels"])], ignore_index=True) \
        if any(len(r["labels"]) for r in results) else pd.DataFrame()
    segments = pd.concat([r["segments"] for r in results if len(r["segments"])],
                         ignore_index=True) \
        if any(len(r["segments"]) for r in results) else None
    trajectories = None
    if keep_trajectories or with_trajectories:
        frames = [r["trajectories"] for r in results
                  if r["trajectories"] is not None and len(r["trajectories"])]
        trajectories = pd.concat(frames, ignore_index=True) if frames else None

    t0 = time.perf_counter()
    matches = []
    for name, (ref_traj, ref_labels) in corpora.items():
        if ref_traj is not None and len(labels):
            matches.append(match_scenarios(labels, trajectories, ref_labels, ref_traj,
                                           level=suite.level, top=3).assign(reference=name))
    power = power_table(episodes, suite.gate,
                        n_tests=len(suite.envs) * len(suite.policies) * len(gate_metrics()))
    scores = score(episodes, reference_policy=suite.reference, level=suite.level,
                   config=suite.bootstrap,
                   references={name: lab for name, (_, lab) in corpora.items()} or None,
                   scenario_matches=pd.concat(matches, ignore_index=True) if matches else None,
                   gate_power=power)
    scores = _with_gaps(scores, corpora, labels, episodes, suite)
    timings["scoring"] = time.perf_counter() - t0

    failed = episodes[episodes["status"] != "ok"]
    summary = {
        "format": "tap-bench-run", "format_version": 1,
        "run": output.name, "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "suite": suite.to_dict(), "suite_file": str(suite.path) if suite.path else None,
        "level": suite.level, "seeds": list(suite.seeds),
        "thresholds": thresholds.to_dict() if hasattr(thresholds, "to_dict") else
        str(suite.thresholds),
        "reference_policy": suite.reference,
        "references": {name: _describe_source(source) for name, source in sources.items()},
        "versions": package_versions(), "machine": _machine(),
        "n_episodes": len(episodes), "n_failed": len(failed),
        "failed": failed[["env", "policy", "seed", "error"]].to_dict("records"),
        "methods": scores.methods,
        "headline": _headline(scores, episodes),
        "provenance": provenance(suite),
        "timings": timings,
        "estimate": {"seconds": _round(plan.seconds),
                     "overhead": _round(plan.overhead_seconds), "basis": plan.basis},
        "cache": None if cache is None else {
            "dir": str(cache.root), "cached": sum(r["cached"] for r in results),
            "simulated": sum(not r["cached"] for r in results)},
    }
    t0 = time.perf_counter()
    roads = None
    if keep_trajectories:  # the replay viewer draws them; highway-env's road is seed-free
        roads = pd.concat([road_table(suite.scenario(env)) for env in suite.envs],
                          ignore_index=True)
    folder = write_results(output, overwrite, summary, episodes, labels, trajectories
                           if keep_trajectories else None, scores, report,
                           segments=segments, roads=roads)
    timings["writing_and_report"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    _write_json(folder / "summary.json", summary)  # with the final timings
    if cache is not None:
        simulated, cached = _observed_timings(results)
        work = sum(r["seconds"] for r in results if math.isfinite(r["seconds"]))
        overhead = timings["total"] - work / max(1, min(runner.workers, len(results)))
        with contextlib.suppress(OSError):  # the run is written; the cache is a convenience
            cache.record_timings(simulated, cached, overhead)
            cache.prune()
    return RunResult(folder, summary, episodes, scores, folder / "report.html")


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def provenance(suite: Suite) -> dict[str, Any]:
    """What every policy and env of a suite is, in full, so that ``bench check`` can say what
    changed since a baseline.

    Returns:
        ``{"policies": {name: {"kind", "params", "model_sha256"?}}, "envs": {name:
        {"highway_env_id", "version", "duration", "lane_change", "config"}}}``; a model
        file's SHA-256 is taken from the file its definition names.
    """
    policies = {}
    for name in suite.policies:
        definition = get_definition(name)
        entry: dict[str, Any] = {"kind": definition.kind, "params": dict(definition.params)}
        model = definition.params.get("model")
        if isinstance(model, str):
            path = Path(model)
            if not path.is_absolute() and definition.path is not None:
                path = definition.path.parent / path
            entry["model_sha256"] = _sha256(path) if path.is_file() else "(missing file)"
        policies[name] = json.loads(json.dumps(entry, default=str))
    envs = {}
    for env in suite.envs:
        scenario = suite.scenario(env)
        envs[env] = json.loads(json.dumps(
            {"highway_env_id": scenario.highway_env_id, "version": scenario.version,
             "duration": scenario.duration, "lane_change": scenario.lane_change,
             "config": scenario.config}, default=str))
    return {"policies": policies, "envs": envs}


ReferenceSource = pd.DataFrame | str | os.PathLike | Sequence[str | os.PathLike]
"""A coverage reference: a label table, a label file, or driving-data files."""

_LABEL_SUFFIXES = (".parquet", ".pq", ".csv", ".csv.gz")


def _reference(name: str, source: ReferenceSource, suite: Suite
               ) -> tuple[pd.DataFrame | None, pd.DataFrame]:
    """(trajectories or None, label table) of one named reference."""
    if isinstance(source, pd.DataFrame):
        validate_labels(source, suite.level, source=f"reference {name!r}")
        return None, source
    paths = [source] if isinstance(source, str | os.PathLike) else list(source)
    if not paths:
        raise ParameterError(f"references[{name!r}]", source, "a label table or data files")
    if len(paths) == 1 and str(paths[0]).lower().endswith(_LABEL_SUFFIXES):
        table = read_table(paths[0])
        if "sdl" in table.columns:  # a label file
            validate_labels(table, suite.level, source=str(paths[0]))
            return None, table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj = read_womd([str(p) for p in paths])
        labels = tap(traj, suite.thresholds, source=name).labels("all")
    return traj, labels


def _with_gaps(scores: Scores, corpora: Mapping[str, tuple[pd.DataFrame | None, pd.DataFrame]],
               labels: pd.DataFrame, episodes: pd.DataFrame, suite: Suite) -> Scores:
    """``scores`` with the sim-to-real gap of every policy from each reference given as
    driving-data files (:mod:`tap_bench.bench.gap`): the egos' labels at the suite's level,
    lateral, longitudinal and interaction, against the reference's vehicles at the speeds
    the policy drives."""
    real = {name: traj for name, (traj, _) in corpora.items() if traj is not None}
    if not real or not len(labels) or "is_ego" not in labels.columns:
        return scores
    egos = labels[(labels["level"] == suite.level) & labels["is_ego"].fillna(False)]
    speeds = episodes[["env", "policy", "seed", "mean_speed"]]
    egos = egos.drop(columns=["mean_speed"], errors="ignore").merge(
        speeds, on=["env", "policy", "seed"], how="left")
    axes = tuple(a for a in ("lateral", "longitudinal", "interaction") if a in egos.columns)
    rows, per_label = [], []
    for name, traj in real.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reference = labelled_with_speed(traj, suite.level, interactions="all",
                                            thresholds=suite.thresholds, source=name)
        for policy, mine in egos.groupby("policy", sort=True):
            try:
                gap = behaviour_gap(mine, reference, name=str(policy), axes=axes,
                                    config=suite.bootstrap, reference_name=name)
            except LabelTableError as err:  # nothing comparable: said, not scored
                scores.methods.setdefault("gap skipped", "")
                scores.methods["gap skipped"] += f"{policy} vs {name}: {err} "
                continue
            rows.append({"reference": name, **gap.row()})
            per_label.append(gap.labels.assign(reference=name, policy=str(policy)))
    if not rows:
        return scores
    scores.methods["gap"] = (
        "total variation distance between the shares of single labels ("
        + ", ".join(axes) + f") of the policy's egos and of the reference's vehicles at the "
        f"policy's speeds; {suite.bootstrap.level:.0%} percentile bootstrap "
        f"({suite.bootstrap.n_resamples} resamples); floor: two samples of the reference")
    return dataclasses.replace(scores, gap=pd.DataFrame(rows),
                               gap_labels=pd.concat(per_label, ignore_index=True))


def _describe_source(source: ReferenceSource) -> Any:
    if isinstance(source, pd.DataFrame):
        return f"a label table of {len(source)} rows"
    if isinstance(source, str | os.PathLike):
        return str(source)
    return [str(p) for p in source]


def _headline(scores: Scores, episodes: pd.DataFrame) -> dict[str, Any]:
    """Per policy, pooled over envs: crash rate, mean speed, coverage of the reference."""
    out: dict[str, Any] = {}
    m = scores.measures
    pooled_env = "all" if (m["env"] == "all").any() else m["env"].iloc[0] if len(m) else ""
    for policy in sorted(episodes["policy"].unique()):
        row: dict[str, Any] = {}
        sub = m[(m["policy"] == policy) & (m["env"] == pooled_env)]
        for r in sub.itertuples():
            row[r.measure] = _round(r.mean)
        cov = scores.coverage
        if len(cov):
            c = cov[(cov["policy"] == policy) & (cov["env"] == pooled_env)]
            for r in c.itertuples():
                row[f"coverage of {r.reference}"] = _round(r.coverage)
        out[policy] = row
    return out


def _round(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else round(float(x), 4)


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=2, default=_json_default) + "\n")


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return None if not np.isfinite(value) else float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, Path):
        return str(value)
    return str(value)


def write_results(output: str | os.PathLike, overwrite: bool, summary: dict[str, Any],
                  episodes: pd.DataFrame, labels: pd.DataFrame,
                  trajectories: pd.DataFrame | None, scores: Scores, report: bool = True, *,
                  segments: pd.DataFrame | None = None, roads: pd.DataFrame | None = None
                  ) -> Path:
    """Write a results folder (tables, ``summary.json``, plots, report, and the replay
    viewer when the trajectories are given) atomically.

    The folder is built under a temporary name beside ``output`` and renamed into place
    when complete (:func:`tap_bench.tableio.atomic_folder`); an existing ``output`` is
    replaced only when ``overwrite`` is True and tap-bench wrote it.

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
        OutputPathError: ``output`` is a file, a link or a folder tap-bench did not write.
    """
    with atomic_folder(output, overwrite, kind="run") as tmp:
        episodes.to_parquet(tmp / "episodes.parquet", index=False)
        if len(labels):
            labels.to_parquet(tmp / "labels.parquet", index=False)
        if trajectories is not None and len(trajectories):
            trajectories.to_parquet(tmp / "trajectories.parquet", index=False)
        for name, table in (("segments", segments), ("roads", roads)):
            if table is not None and len(table):
                table.to_parquet(tmp / f"{name}.parquet", index=False)
        for name, table in scores.tables().items():
            if len(table):
                _parquet_safe(table).to_parquet(tmp / f"{name}.parquet", index=False)
        _write_json(tmp / "summary.json", summary)
        viewer = report and trajectories is not None and len(trajectories) > 0
        if viewer:
            write_run_viewer(tmp / "viewer", summary, episodes, trajectories,
                             segments=segments, roads=roads, novel_labels=scores.novel_labels)
        if report:
            write_report(tmp, summary, episodes, scores, viewer="viewer/index.html"
                         if viewer else None)
    return Path(output)


def _parquet_safe(table: pd.DataFrame) -> pd.DataFrame:
    """Object columns holding mixed Python values as strings (Parquet needs one type)."""
    out = table.copy()
    for col in out.columns:
        if out[col].dtype == object:
            kinds = {type(v) for v in out[col].dropna()}
            if len(kinds) > 1:
                out[col] = out[col].astype("string")
    return out


def read_run(folder: str | os.PathLike) -> tuple[dict[str, Any], pd.DataFrame]:
    """``summary.json`` and the episode table of a run folder.

    Raises:
        FileFormatError: the folder is not a finished run (no summary or episode table), or
            one of them is damaged: not JSON, not an object, not Parquet, columns missing.
    """
    folder = Path(folder)
    summary_path = folder / "summary.json"
    episodes_path = folder / "episodes.parquet"
    for path in (summary_path, episodes_path):
        if not path.is_file():
            raise FileFormatError(f"{folder}: not a finished run folder ({path.name} is "
                                  "missing); make one with 'tap-bench bench run'.")
    redo = "The run folder is damaged; run 'tap-bench bench run' again."
    try:
        summary = json.loads(summary_path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise FileFormatError(f"{summary_path}: not valid JSON ({err}). {redo}") from None
    if not isinstance(summary, dict):
        raise FileFormatError(f"{summary_path}: holds a {type(summary).__name__}, not the "
                              f"run's summary object. {redo}")
    for key in ("suite", "thresholds"):
        if summary.get(key) is not None and not isinstance(summary[key], dict | str):
            raise FileFormatError(f"{summary_path}: {key!r} is a "
                                  f"{type(summary[key]).__name__}. {redo}")
    try:
        episodes = pd.read_parquet(episodes_path)
    except Exception as err:  # pyarrow raises several kinds for a damaged file
        raise FileFormatError(f"{episodes_path}: not a readable Parquet table "
                              f"({type(err).__name__}: {err}). {redo}") from None
    missing = [c for c in ("env", "policy", "seed", "status") if c not in episodes.columns]
    if missing:
        raise FileFormatError(f"{episodes_path}: not an episode table (no "
                              f"{', '.join(missing)} column). {redo}")
    return summary, episodes


def run_viewer(folder: str | os.PathLike, output: str | os.PathLike | None = None) -> Path:
    """Write (again) the replay viewer of a finished run folder.

    Reads ``trajectories.parquet`` and, when there, ``segments.parquet``, ``roads.parquet``
    and ``novel_labels.parquet`` (older runs lack the first two: the egos are labelled again
    with the run's thresholds and the roads rebuilt from its suite).

    Args:
        folder: the run folder.
        output: the viewer folder (default ``<folder>/viewer``).

    Returns:
        the path of the viewer's ``index.html``.

    Raises:
        FileFormatError: the folder is not a finished run, or has no trajectories.
    """
    folder = Path(folder)
    summary, episodes = read_run(folder)
    traj_path = folder / "trajectories.parquet"
    if not traj_path.is_file():
        raise FileFormatError(f"{folder}: no trajectories.parquet to replay; run the suite "
                              "again without --no-trajectories.")
    optional = {name: pd.read_parquet(folder / f"{name}.parquet")
                if (folder / f"{name}.parquet").is_file() else None
                for name in ("segments", "roads", "novel_labels")}
    return write_run_viewer(output if output is not None else folder / "viewer", summary,
                            episodes, pd.read_parquet(traj_path), **optional)
